// The laser plane and the slide from laser lines on a flat target (docs/calibration.md).
//
// Each frame shows the laser line on a flat target whose plane in the camera frame is
// known (from the target's corners, `locateTarget`), at a known commanded slide position.
// Every line pixel's ray meets the target plane in a 3D point that lies on the laser plane
// of that slide position:   n · X = d0 + k · s,   k = slide_scale · (n · slide_axis).
//
// What the data can tell: n (2 degrees of freedom), d0 and k. Sliding the laser *within*
// its own plane changes nothing the camera sees, so only the slide axis' component along n
// is observable: the axis is taken from the drawing (`nominalSlideAxis`) and the scale
// absorbs the rest, which leaves triangulation and planning exact.
//
// Method: RANSAC over lines (four pixels from four different lines, a linear solve) to
// find the inliers despite stray reflections, then Levenberg–Marquardt with Huber weights
// on the image residual (px, the quantity the line extraction errs in). Uncertainty: the
// Gauss–Newton covariance plus a leave-one-placement-out jackknife, because each target
// pose carries its own error that no pixel count averages away. Thread-safe.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"

namespace alacs::geometry {

// One frame's laser line on the flat target.
struct LaserLineSample {
  int placement = 0;                    // which target pose (groups frames for the jackknife)
  Eigen::Vector3d targetNormal{0, 0, -1};  // target plane in the camera frame: normal·X = offset
  double targetOffsetMm = -1000.0;
  double slideMm = 0.0;                 // commanded slide position of the frame
  std::vector<Eigen::Vector2d> normalized;  // undistorted normalized coordinates of line pixels
};

struct LaserFitOptions {
  Eigen::Vector3d nominalSlideAxis{1.0, 0.0, 0.0};  // unit, from the drawing
  double focalPx = 2400.0;       // turns normalized residuals into pixels
  double ransacBandPx = 1.5;
  int ransacIterations = 500;
  double huberPx = 0.5;
  double inlierBandPx = 2.0;     // final inlier band
  int maxIterations = 100;
  uint64_t seed = 1;
  size_t minPoints = 50;
};

struct LaserFit {
  LaserGeometry laser;
  double rmsPx = 0.0;           // inlier image residual
  double rmsMm = 0.0;           // inlier distance from the laser plane
  size_t points = 0;
  size_t inliers = 0;
  int placements = 0;
  int slidePositions = 0;
  // Covariance of (α, β [rad]: tilt of n about two axes ⟂ n; d0 [mm]; k) and derived 1σ.
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();
  double normalSigmaMrad = 0.0;
  double offsetSigmaMm = 0.0;
  double scaleSigma = 0.0;
  double depthSigmaMmAt1000 = 0.0;  // on the optical axis, slide where the plane crosses it
  double depthSigmaMmAt1600 = 0.0;
  std::vector<double> placementRmsPx;  // per placement id 0..max, for naming a bad pose
};

// Errors: kBadInput for too few points, fewer than two slide positions, or no consensus.
Result<LaserFit> calibrateLaser(const std::vector<LaserLineSample>& samples, const LaserFitOptions& options = {});

// Levenberg–Marquardt only (no RANSAC, no covariance), from `start`: the plane that the
// same samples give when something upstream moved a little, e.g. the target poses under
// perturbed intrinsics (calibration_uncertainty.h). Errors: kBadInput for too few points
// or too few inliers after refinement.
Result<LaserGeometry> refineLaser(const std::vector<LaserLineSample>& samples, const LaserGeometry& start,
                                  const LaserFitOptions& options = {});

// `laser` moved by `delta` in the coordinates of LaserFit::covariance: (α, β) tilt the
// normal along the tangent basis the fit uses, then d0 and k (= scale·(n·axis)) shift.
LaserGeometry perturbLaser(const LaserGeometry& laser, const Eigen::Vector4d& delta);

// Image residual (px, perpendicular to the predicted line) of one normalized point of a
// sample under `laser`: the predicted line is where the laser plane at the sample's slide
// position meets the target plane.
double laserResidualPx(const LaserGeometry& laser, const LaserLineSample& sample, const Eigen::Vector2d& xn,
                       double focalPx);

// Depth 1σ (mm) at depth `depthMm` on the optical axis given the covariance of a LaserFit.
double depthSigmaOnAxis(const LaserGeometry& laser, const Eigen::Matrix4d& covariance, double depthMm);

}  // namespace alacs::geometry
