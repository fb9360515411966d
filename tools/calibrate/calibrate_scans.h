// The calibration pipeline behind `alacs_calibrate`, apart from its command line so that
// tests can drive it: corners of the checkerboard views -> intrinsics and distortion;
// per target placement, the board's pose and the laser line of every slide position on
// it -> the laser plane and the slide; the quality figures for the gate.
// Images are loaded one at a time through `ImageLoader` (a calibration set is hundreds
// of megabytes of pixels).
#pragma once

#include <Eigen/Core>
#include <functional>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"
#include "geometry/calibration_uncertainty.h"
#include "geometry/camera_calibration.h"
#include "geometry/checkerboard_corners.h"
#include "geometry/laser_calibration.h"
#include "image/lle.h"

namespace alacs::calib {

// A checkerboard of squaresX × squaresY squares (inner corners one fewer each way), with a
// plain margin around it that also catches the laser.
struct BoardSpec {
  int squaresX = 10;
  int squaresY = 7;
  double squareMm = 40.0;
  double marginMm = 60.0;
};

// Loads one image (8-bit BGR, full frame) by its name.
using ImageLoader = std::function<Result<cv::Mat>(const std::string& name)>;

struct LaserFrameRef {
  double slideMm = 0.0;
  std::string image;       // laser on
};

// The board at one pose: an image with the laser off (its corners give the pose) and
// frames with the laser on at several slide positions.
struct PlacementRef {
  std::string name;
  std::string boardImage;  // laser off
  std::vector<LaserFrameRef> laserFrames;
};

struct CalibrationInput {
  BoardSpec board;
  int widthPx = 0;
  int heightPx = 0;
  std::vector<std::string> cameraViews;  // checkerboard, laser off; placements' board images are added
  std::vector<PlacementRef> placements;
  Eigen::Vector3d nominalSlideAxis{1.0, 0.0, 0.0};
  geometry::CameraFitOptions cameraOptions;
  geometry::CornerOptions corners;  // the detector (default: chosen on the twin's tuning set)
  image::LleParams lle;
  double boardEdgeGuardMm = 8.0;  // laser pixels this close to the board's edge are not used
  int uncertaintyDraws = 0;       // 0: linearised total σ; > 0: Monte Carlo with this many draws
  // Called as each view or placement is skipped, with why (also when a later stage then
  // fails, so the person at the rig always learns which views to redo). May be empty.
  std::function<void(const std::string& name, const std::string& why)> onSkipped;
};

struct CalibrationRun {
  geometry::Calibration calibration;  // with its quality figures (gate not yet applied)
  geometry::CameraFit camera;
  geometry::LaserFit laser;
  geometry::CalibrationUncertainty uncertainty;  // total σ per working distance
  // Why the total σ could not be computed (empty: it was). The calibration is still
  // returned, its total-σ figures NaN ("not measured"), so that the quality gate gives
  // its verdict with that among its reasons instead of the run ending before it.
  std::string uncertaintyError;
  std::vector<std::string> skippedViews;  // "<view>: <why the board was not found>" (also to onSkipped)
  std::vector<std::string> log;       // what was used and what was skipped, and why
};

// Inner corners of the checkerboard in `bgr`, with their board coordinates (mm, z = 0).
// Errors: kNotFound when the board is not found, with the reason for the technician.
Result<geometry::TargetView> detectCheckerboard(const cv::Mat& bgr, const BoardSpec& board,
                                                const geometry::CornerOptions& options = {});

// Runs the whole calibration. Errors: kBadInput naming what is missing (too few views
// with a board, no laser on the board, ...).
Result<CalibrationRun> runCalibration(const CalibrationInput& input, const ImageLoader& load);

}  // namespace alacs::calib
