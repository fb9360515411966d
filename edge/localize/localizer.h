// Localization of one target apple from the laser lines of a scan. Pure logic: frames
// and slide positions in, an estimate out; no device, thread or clock.
//
//   plan:      rough position (from the arm's RGB-D camera) -> slide stops + image ROI
//   addFrame:  LLE on the ROI, triangulation of every row, gating around the target
//   finish:    robust sphere fit to the points of every line (beyond the paper), with
//              the paper's single-line candidate (P = w1·N − w2·Δd) as the fallback
#pragma once

#include <Eigen/Core>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"
#include "geometry/sphere_fit.h"
#include "geometry/triangulation.h"
#include "image/lle.h"

namespace alacs::localize {

struct ScanParams {
  int stops = 5;                 // paper: five stops
  double stopSpacingMm = 20.0;   // paper: 2 cm
  double roiMarginMm = 35.0;     // added to the largest apple radius around the rough position
  double maxAppleRadiusMm = 50.0;
  double gateMm = 90.0;          // 3D points farther than this from the rough centre are not the target
  double paperW1 = 1.0;          // ω1: weight of the line's pixel count
  double paperW2 = 2.0;          // ω2: weight of its distance (px) from the expected centre
  Status validate() const;
};

struct ScanPlan {
  std::vector<double> stopsMm;   // commanded slide positions, in scan order
  image::Roi roi;                // where the target can appear
  Eigen::Vector3d roughMm = Eigen::Vector3d::Zero();
};

struct LineObservation {
  double slideMm = 0.0;
  image::LaserLine line;
  std::vector<Eigen::Vector3d> pointsMm;  // gated 3D points of this line
};

struct AppleEstimate {
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
  Eigen::Vector3d approachMm = Eigen::Vector3d::Zero();  // surface point nearest the sensor towards the centre
  Eigen::Vector3d approachNormal = Eigen::Vector3d::Zero();  // outward unit normal there
  double diameterMm = 0.0;
  double sigmaMm = 0.0;
  double confidencePct = 0.0;
  double occlusionPct = 0.0;
  int linesUsed = 0;
  int pointsUsed = 0;
  bool sphereFit = false;  // false: the paper's single-line fallback
};

class Localizer {
 public:
  Localizer(const geometry::Calibration& cal, const image::LleParams& lle, const ScanParams& scan,
            const geometry::WorkingRange& range = {});

  // Plans the stops around a rough target position, clamped to [0, strokeMm].
  // Errors: kOutOfRange when no stop can reach the target.
  Result<ScanPlan> plan(const Eigen::Vector3d& roughMm, double strokeMm) const;

  // Processes one frame taken at `slideMm`. Errors: those of LLE (bad frame or ROI).
  Result<LineObservation> observe(const image::ImageView& frame, const ScanPlan& plan, double slideMm,
                                  image::LleWorkspace& ws) const;

  // Fuses the observations. Errors: kNotFound when no line hit the target.
  Result<AppleEstimate> estimate(const ScanPlan& plan, const std::vector<LineObservation>& lines) const;

 private:
  geometry::Calibration cal_;
  image::LleParams lle_;
  ScanParams scan_;
  geometry::WorkingRange range_;
};

}  // namespace alacs::localize
