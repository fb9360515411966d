// Camera intrinsics and distortion from views of a planar target (checkerboard or
// ChArUco corners), and the pose of that target in a calibrated camera. OpenCV calib3d
// does the work; this file converts its exceptions into Status and its covariance into
// the quality figures the gate reads (docs/calibration.md).
//
// Detection (finding the corners in an image) is in checkerboard_corners.h; images reach
// it decoded (this library reads no files). Thread-safe (pure functions).
#pragma once

#include <Eigen/Core>
#include <array>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"

namespace alacs::geometry {

// Corners of a planar target as found in one image. `objectMm` lie on the target's plane
// (z = 0 in the target frame); `imagePx` are their pixels (centres at integers).
struct TargetView {
  std::vector<Eigen::Vector3d> objectMm;
  std::vector<Eigen::Vector2d> imagePx;
};

// A target's pose in the camera frame: X_cam = rotation · X_target + translationMm.
struct TargetPose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translationMm = Eigen::Vector3d::Zero();
  double rmsPx = 0.0;  // reprojection RMS of this view

  // The target's plane in the camera frame: normal·X = offset.
  Eigen::Vector3d planeNormal() const { return rotation.col(2); }
  double planeOffsetMm() const { return rotation.col(2).dot(translationMm); }
};

struct CameraFitOptions {
  bool fixK3 = true;             // k3 = 0: the lens needs no sixth-order term (ours does not)
  bool fixTangential = false;
  size_t minViews = 6;
  size_t minCornersPerView = 12;
  // Corners the detector misplaced: on blurred, noisy views the sector detector puts a few
  // corners 4-6 px off among ~1,500 within 0.2 px (docs/calibration.md). In calib3d's least
  // squares one such corner weighs as much as ~1,000 good ones, so after a first solve the
  // corners whose reprojection residual exceeds max(outlierMinPx, outlierSigmas × σ) are
  // left out and the camera is solved again (σ: the residuals' robust per-axis spread, from
  // their median). 0 sigmas: off (every corner is kept).
  double outlierSigmas = 5.0;
  double outlierMinPx = 1.0;
};

// The corners of each view that a solve's residuals mark as misplaced (indices into the
// view's corners), and the bound they exceeded.
struct CornerOutliers {
  double boundPx = 0.0;
  double sigmaPx = 0.0;  // the residuals' robust per-axis σ the bound was set from
  std::vector<std::vector<size_t>> perView;
  size_t count() const;
};

// The views without the corners `outliers` names (a view's corners keep their order).
std::vector<TargetView> withoutCorners(const std::vector<TargetView>& views, const CornerOutliers& outliers);

// Order of the intrinsic parameters in a covariance: fx, fy, cx, cy, k1, k2, p1, p2, k3.
using IntrinsicsCovariance = Eigen::Matrix<double, 9, 9>;
using IntrinsicsVector = Eigen::Matrix<double, 9, 1>;

// `camera` with its intrinsics moved by `delta` (same order as IntrinsicsCovariance).
CameraIntrinsics perturbIntrinsics(const CameraIntrinsics& camera, const IntrinsicsVector& delta);

struct CameraFit {
  CameraIntrinsics camera;
  double rmsPx = 0.0;                      // over all corners of all views
  std::array<double, 4> sigmaPx{};         // 1σ of fx, fy, cx, cy
  std::array<double, 5> sigmaDistortion{};  // 1σ of k1, k2, p1, p2, k3
  // Full covariance of (fx, fy, cx, cy [px], k1, k2, p1, p2, k3) with the board poses
  // marginalised out (Schur complement of the normal matrix), scaled by the residual
  // variance as calib3d scales its σ. Rows and columns of fixed parameters are zero.
  // calib3d only reports the diagonal; the off-diagonal terms matter (fx and fy move
  // together: a common focal-length error is a depth-scale error).
  IntrinsicsCovariance covariance = IntrinsicsCovariance::Zero();
  std::vector<TargetPose> poses;           // one per view, in input order
  // The corners left out as misplaced before the final solve (CameraFitOptions::
  // outlierSigmas); their poses and σ are those of the views without them.
  CornerOutliers outliers;
};

// cv::calibrateCamera over all views; with outlierSigmas > 0, solved again without the
// corners the first solve marks as misplaced (CameraFit::outliers; a view keeps all its
// corners when fewer than minCornersPerView would be left). Errors: kBadInput for too few
// views or corners, mismatched sizes, or when calib3d fails.
Result<CameraFit> calibrateCamera(const std::vector<TargetView>& views, int widthPx, int heightPx,
                                  const CameraFitOptions& options = {});

// The corners whose reprojection residual under `fit` (its camera and poses, one per view)
// exceeds max(options.outlierMinPx, options.outlierSigmas × σ), σ the residuals' robust
// per-axis spread (median norm / 1.1774, the Rayleigh median). Empty with outlierSigmas 0.
CornerOutliers findCornerOutliers(const std::vector<TargetView>& views, const CameraFit& fit,
                                  const CameraFitOptions& options);

// Pose of a planar target seen by a calibrated camera (IPPE start, LM refinement).
// Errors: kBadInput for fewer than 4 corners or a failed solve.
Result<TargetPose> locateTarget(const CameraIntrinsics& camera, const TargetView& view);

// The object corners of a checkerboard with `cols` × `rows` inner corners and square
// `pitchMm`, in the row-major order cv::findChessboardCorners reports them.
std::vector<Eigen::Vector3d> checkerboardCorners(int cols, int rows, double pitchMm);

}  // namespace alacs::geometry
