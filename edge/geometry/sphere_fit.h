// Robust sphere fit to the 3D points of every laser line on a fruit (Eigen).
//
// The points come in groups: pieces of one laser line that are continuous in 3D (a leaf
// or a neighbouring fruit breaks a line into pieces). A piece lies on one surface, so a
// sphere either explains most of a piece or it does not explain it. Hypotheses come from
// every pair of pieces on different lines (least squares through both) and from random
// four-point samples across lines; each is scored by the pieces it explains
// (coherently), its radius against the prior and its centre's nearness to the rough
// position. Gauss–Newton on the geometric distance with Huber weights then refines it
// over the pieces it explains. Thread-safe (pure functions, deterministic for a seed).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "common/result.h"

namespace alacs::geometry {

struct SphereFitParams {
  double huberMm = 1.0;         // residuals beyond this weigh as |r| rather than r²
  double ransacBandMm = 1.5;    // hypothesis inlier band
  double outlierMm = 4.0;       // final inlier band
  double minRadiusMm = 20.0;
  double maxRadiusMm = 80.0;
  double priorRadiusMm = 0.0;        // > 0: a prior on the radius (fruit of this kind)
  double priorRadiusSigmaMm = 10.0;  // its 1σ; weak in the fit, it only matters when the cap is small
  // > 0: hypotheses are ranked by nearness of their centre to `priorCenterMm` (the rough
  // position), exp(−d²/2σ²): in a cluster a neighbour can show more skin than an
  // occluded target. The refinement itself is not pulled.
  double priorCenterSigmaMm = 0.0;
  Eigen::Vector3d priorCenterMm = Eigen::Vector3d::Zero();
  double coherentShare = 0.6;   // a piece counts fully when this share of it is explained
  // Free space: a point the camera sees cannot lie behind (or inside) the fruit. A
  // hypothesis whose sphere, shrunk to its core (radius·(1 − share) − margin), the sight
  // line to a point crosses is contradicted by that point; each such point (weighted by
  // how deep the line passes, up to 1 at `freeSpaceDepthMm`) costs a factor
  // exp(−1/freeSpacePoints). The share covers an oblate fruit's departure from the sphere
  // fitted to it (polar radius down to 0.82 of the equatorial), the margin the noise near
  // the limb. freeSpacePoints 0: off.
  double freeSpaceMarginShare = 0.18;
  double freeSpaceMarginMm = 2.0;
  double freeSpaceDepthMm = 3.0;
  double freeSpacePoints = 4.0;
  // Points per independent measurement: neighbouring rows of a line share their errors
  // (speckle grain, the line extraction's smoothing along the line), so the covariance
  // is scaled by this (1: independent points).
  double pointsPerIndependent = 1.0;
  // A multi-line sphere whose centre is less certain than this (1σ, 3D) may be two
  // objects' pieces bent into one: it then has to beat the one-line estimate on score.
  double maxPlausibleCenterSigmaMm = 8.0;
  // The unit normal of the planes the lines lie on, when known (a laser plane moved by a
  // slide keeps its normal): one line's plane then comes from it, not from the points
  // (a short arc is nearly straight and leaves its plane open). Zero: unknown.
  Eigen::Vector3d linePlaneNormal = Eigen::Vector3d::Zero();
  int ransacIterations = 300;
  int iterations = 50;
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
  int groupsUsed = 0;            // pieces explained
  int linesUsed = 0;             // lines with an explained piece
  std::vector<bool> inlier;      // per input point
  // The competition the fit won: its own score (support × priors) and the best score of
  // another object in the same points whose centre lies more than kRivalSeparationMm away
  // (0: none). Two objects that explain the lines about equally well leave the choice to
  // the priors (two surfaces: the target and a neighbour, or a leaf).
  double score = 0.0;
  double rivalScore = 0.0;
  Eigen::Vector3d rivalCenterMm = Eigen::Vector3d::Zero();
  // Every other object so found (the rival among them), each with its score: where the
  // caller weighs the objects by more than their support (the localizer's distance from
  // the rough position), a weaker one may be the likelier target.
  // One per place: the strongest first (the rival), each more than kRivalSeparationMm from
  // the fit and from every stronger one.
  struct Other {
    Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
    double score = 0.0;
  };
  std::vector<Other> others;
};

// Centres closer than this are the same object for the rival above.
constexpr double kRivalSeparationMm = 20.0;

// Fits without knowing lines or pieces (all points one piece, random samples only).
// Errors: kBadInput (too few points or inliers), kOutOfRange (the radius is larger than any
// fruit's; a smaller one is held at minRadiusMm, see finish() in sphere_fit.cpp).
Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pointsMm, const SphereFitParams& p = {});

// `lineIds[i]` names the laser line of point i; `groupIds[i]` its piece (unique across
// lines; empty: one piece per line). Pieces on at least two lines are needed.
Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pointsMm, const std::vector<int>& lineIds,
                            const std::vector<int>& groupIds, const SphereFitParams& p = {});

// Splits one line's points (in row order) into pieces continuous in 3D: a new piece where
// consecutive points are farther apart than `breakMm`. Returns a piece index per point,
// starting at `firstId`.
std::vector<int> splitPieces(const std::vector<Eigen::Vector3d>& linePointsMm, double breakMm, int firstId);

}  // namespace alacs::geometry
