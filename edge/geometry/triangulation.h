// Pixel + slide position -> 3D point on the laser plane (the paper's Eq. (1),
// generalised to any plane pose and a slide axis not parallel to the image rows).
// Double precision throughout. Thread-safe (pure functions).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "geometry/calibration.h"

namespace alacs::geometry {

struct WorkingRange {
  double minDepthMm = 500.0;
  double maxDepthMm = 2000.0;
  double minCosIncidence = 0.02;  // |n·r̂| below this: ray nearly parallel to the plane
};

struct PixelPoint {
  double columnPx = 0.0;
  double rowPx = 0.0;
};

struct TriangulatedPoint {
  Eigen::Vector3d pointMm = Eigen::Vector3d::Zero();
  bool valid = false;
};

// Undistorted normalized coordinates (x/z, y/z) of pixels, via OpenCV.
std::vector<Eigen::Vector2d> undistortPixels(const CameraIntrinsics& cam,
                                             const std::vector<PixelPoint>& pixels);

// Intersects the ray through normalized point `xn` with the laser plane at `slideMm`.
// Invalid (never NaN) for rays nearly parallel to the plane, points behind the camera
// and points outside `range`.
TriangulatedPoint triangulate(const LaserGeometry& laser, double slideMm, const Eigen::Vector2d& xn,
                              const WorkingRange& range = {});

// Projects a camera-frame point to pixels with distortion (OpenCV's model).
PixelPoint projectPoint(const CameraIntrinsics& cam, const Eigen::Vector3d& pointMm);
std::vector<PixelPoint> projectPoints(const CameraIntrinsics& cam, const std::vector<Eigen::Vector3d>& pointsMm);

}  // namespace alacs::geometry
