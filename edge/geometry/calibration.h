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
#include <string>

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

struct CalibrationQuality {
  double reprojectionRmsPx = 0.0;  // camera calibration
  double planeRmsMm = 0.0;         // laser plane fit
  bool fromTruth = false;          // written by the simulator from its own truth
};

struct Calibration {
  CameraIntrinsics camera;
  LaserGeometry laser;
  CalibrationQuality quality;
};

// Reads and validates calibration.json. Every error names the offending field.
Result<Calibration> loadCalibration(const std::string& path);
// Writes calibration.json atomically (temp file + rename).
Status saveCalibration(const Calibration& cal, const std::string& path);
// Checks ranges and consistency; the error names the field.
Status validateCalibration(const Calibration& cal);

}  // namespace alacs::geometry
