// Robust sphere fit to the 3D points of every laser line on a fruit (Eigen).
// RANSAC over four points from at least two lines (points of one line are coplanar and
// cannot fix a sphere) gives the start and the inliers, so that leaf and branch points do
// not pull it; Gauss–Newton on the geometric distance with Huber weights refines it.
// Thread-safe (pure functions, deterministic for a seed).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "common/result.h"

namespace alacs::geometry {

struct SphereFitParams {
  double huberMm = 1.0;         // residuals beyond this weigh as |r| rather than r²
  double ransacBandMm = 1.5;    // RANSAC inlier band
  double outlierMm = 5.0;       // final inlier band
  double minRadiusMm = 20.0;
  double maxRadiusMm = 80.0;
  double priorRadiusMm = 0.0;        // > 0: a soft prior on the radius (fruit of this kind)
  double priorRadiusSigmaMm = 10.0;  // its 1σ; weak, it only matters when the cap is small
  // > 0: RANSAC prefers spheres whose centre is near `priorCenterMm` (the rough position):
  // support × exp(−d²/2σ²). A neighbour in the fruit's cluster can show more skin than
  // an occluded target; the refinement itself is not pulled.
  double priorCenterSigmaMm = 0.0;
  Eigen::Vector3d priorCenterMm = Eigen::Vector3d::Zero();
  int ransacIterations = 400;
  int iterations = 30;
  size_t minPoints = 12;
  uint64_t seed = 1;
};

struct SphereFit {
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
  double radiusMm = 0.0;
  double rmsMm = 0.0;            // RMS geometric residual of the inliers
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();  // of (centre x, y, z, radius), mm²
  double centerSigmaMm = 0.0;    // sqrt(trace) of the centre block: 3D 1σ
  double radiusSigmaMm = 0.0;
  size_t inliers = 0;
  std::vector<bool> inlier;      // per input point
};

// Fits without knowing which line a point came from. Errors: kBadInput (too few points
// or inliers), kOutOfRange (the radius is not a fruit's).
Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pointsMm, const SphereFitParams& p = {});

// `lineIds[i]` names the laser line of point i; RANSAC samples span two lines or more.
Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pointsMm, const std::vector<int>& lineIds,
                            const SphereFitParams& p = {});

}  // namespace alacs::geometry
