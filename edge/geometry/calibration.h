// The sensor's calibration: camera intrinsics and distortion, the laser plane at slide
// home, the slide axis and scale. Units: millimetres in the camera frame (x right,
// y down, z forward, origin at the optical centre), pixels for intrinsics.
//
// The laser plane at commanded slide position s (mm) is
//     n · X = d0 + scale · s · (n · a)
// where n is the plane's unit normal, d0 its offset at home, a the slide's unit
// direction: the slide translates the laser without rotating it.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>

#include "common/json_file.h"
#include "common/result.h"

namespace alacs::geometry {

struct CameraIntrinsics {
  int widthPx = 2048;
  int heightPx = 1536;
  double fxPx = 2400.0;
  double fyPx = 2400.0;
  double cxPx = 1023.5;
  double cyPx = 767.5;
  std::array<double, 5> distortion{};  // Brown–Conrady k1, k2, p1, p2, k3 (OpenCV order)
};

struct LaserGeometry {
  Eigen::Vector3d planeNormal{1.0, 0.0, 0.0};  // unit
  double planeOffsetMm = 0.0;                  // d0: n·X at slide home
  Eigen::Vector3d slideAxis{1.0, 0.0, 0.0};    // unit, direction of increasing slide mm
  double slideScale = 1.0;                     // true mm per commanded mm

  // Plane offset d(s) for commanded slide position `slideMm`.
  double planeOffsetAt(double slideMm) const {
    return planeOffsetMm + slideScale * slideMm * planeNormal.dot(slideAxis);
  }
  // Commanded slide position that puts the plane through `point`; NaN if the slide
  // does not move the plane (n ⟂ a).
  double slideForPoint(const Eigen::Vector3d& point) const;
};

// The figures the calibration was accepted on (docs/calibration.md). All optional in the
// file: a hand-made or simulator calibration has none. Zero means "not measured".
struct CalibrationQuality {
  // Camera (OpenCV calib3d on checkerboard/ChArUco views).
  double reprojectionRmsPx = 0.0;
  int cameraViews = 0;
  double fxSigmaPx = 0.0;  // 1σ of the intrinsics from calib3d's covariance
  double fySigmaPx = 0.0;
  double cxSigmaPx = 0.0;
  double cySigmaPx = 0.0;
  // Laser plane and slide (RANSAC, then Levenberg–Marquardt on laser lines on a flat target).
  double planeRmsMm = 0.0;     // RMS distance of the inlier target points from the laser plane
  double laserRmsPx = 0.0;     // RMS image residual of the inlier laser pixels
  double inlierShare = 0.0;    // share of laser pixels the fit kept
  int targetPlacements = 0;    // distinct flat-target poses
  int slidePositions = 0;      // distinct slide positions
  double normalSigmaMrad = 0.0;
  double offsetSigmaMm = 0.0;
  double scaleSigma = 0.0;          // 1σ of slide_scale (dimensionless)
  // Depth 1σ on the optical axis from the laser parameters' covariance ALONE, the
  // intrinsics taken as exact: a lower bound, blind to a focal-length (depth-scale) error.
  double depthSigmaMmAt1000 = 0.0;
  double depthSigmaMmAt1600 = 0.0;
  // Total 1σ (calibration_uncertainty.h): laser parameters plus the intrinsics' covariance
  // carried through the board poses and the laser refit; RMS over pixels on the laser
  // planes across the stroke and the frame's height at that depth. Depth (z) and 3D.
  double depthSigmaTotalMmAt1000 = 0.0;
  double depthSigmaTotalMmAt1200 = 0.0;
  double depthSigmaTotalMmAt1400 = 0.0;
  double depthSigmaTotalMmAt1600 = 0.0;
  double sigma3dTotalMmAt1000 = 0.0;
  double sigma3dTotalMmAt1200 = 0.0;
  double sigma3dTotalMmAt1400 = 0.0;
  double sigma3dTotalMmAt1600 = 0.0;
  enum class Gate : uint8_t { kNotRun, kPassed, kRefused };
  Gate gate = Gate::kNotRun;  // the calibrate tool's quality gate; a refused file never loads
  bool fromTruth = false;     // written by the simulator from its own truth
};

struct Calibration {
  CameraIntrinsics camera;
  LaserGeometry laser;
  CalibrationQuality quality;
};

inline constexpr const char* kCalibrationFormat = "alacs-calibration/1";
inline constexpr size_t kCalibrationMaxBytes = 1 << 20;

// The calibration schema (docs/calibration.md), shared by calibration.json and the
// simulator's scene. The readers record errors in the reader's JsonErrors and check
// types and presence (every field required), not ranges: validateCalibration does that.
void cameraFromJson(JsonObjectReader& camera, CameraIntrinsics& out);
void laserFromJson(JsonObjectReader& laser, LaserGeometry& out);
// The whole file: "format", "camera", "laser" and the optional "quality". A "refused"
// gate is read as such; loadCalibration refuses it. Errors: kBadInput naming the field.
Status calibrationFromJson(const Json& json, Calibration& out);
OrderedJson cameraToJson(const CameraIntrinsics& camera);
OrderedJson laserToJson(const LaserGeometry& laser);
OrderedJson calibrationToJson(const Calibration& cal);

// Reads (a regular file of at most kCalibrationMaxBytes) and validates calibration.json.
// Every error names the offending field.
Result<Calibration> loadCalibration(const std::string& path);
// The same for a scan directory's calibration: `relPath` inside `dir`, never leaving it.
Result<Calibration> loadCalibrationBeneath(const std::string& dir, const std::string& relPath);
// Writes calibration.json atomically (temp file in the same directory, fsync, rename):
// a reader sees the old file or the whole new one. Refuses an invalid calibration.
Status saveCalibration(const Calibration& cal, const std::string& path);
// The JSON text saveCalibration writes.
std::string calibrationJson(const Calibration& cal);
// Writes `text` to `path` atomically, as saveCalibration does. Errors: kIo.
Status writeFileAtomically(const std::string& path, const std::string& text);
// Checks ranges and consistency; the error names the field.
Status validateCalibration(const Calibration& cal);

}  // namespace alacs::geometry
