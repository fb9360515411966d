// Robust sphere fit to the 3D points of every laser line on a fruit (Eigen).
// Algebraic least squares for the start, then Gauss–Newton on the geometric distance
// with Huber weights, so that leaf and branch points do not pull the centre.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "common/result.h"

namespace alacs::geometry {

struct SphereFitParams {
  double huberMm = 1.5;        // residuals beyond this weigh as |r| rather than r²
  double outlierMm = 6.0;      // final inlier band
  double minRadiusMm = 20.0;
  double maxRadiusMm = 80.0;
  int iterations = 30;
  size_t minPoints = 12;
};

struct SphereFit {
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
  double radiusMm = 0.0;
  double rmsMm = 0.0;           // RMS geometric residual of the inliers
  double centerSigmaMm = 0.0;   // 1σ of the centre from the Gauss–Newton covariance
  size_t inliers = 0;
};

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pointsMm, const SphereFitParams& p = {});

}  // namespace alacs::geometry
