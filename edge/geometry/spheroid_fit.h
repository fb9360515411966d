// An apple is a little oblate: a spheroid (ellipsoid of revolution) about its stem axis,
// equatorial radius a, polar radius k·a with k ≈ 0.8–1. A sphere fitted to its front cap
// is off by millimetres in the centre and the diameter; this refines the sphere fit into
// a spheroid over the same points, with priors on what the few lines cannot fix (the
// aspect, the stem's tilt from vertical, the size). Levenberg–Marquardt, Eigen.
// Thread-safe (pure functions).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "common/result.h"
#include "geometry/sphere_fit.h"

namespace alacs::geometry {

struct SpheroidPriors {
  double radiusMm = 40.0;       // equatorial radius a
  double radiusSigmaMm = 6.0;
  double aspect = 0.9;          // polar / equatorial
  double aspectSigma = 0.05;
  Eigen::Vector3d stemAxis{0.0, -1.0, 0.0};  // up, in the camera frame (y is down)
  double stemTiltSigmaRad = 0.35;            // ~20°
  double pointsPerIndependent = 1.0;         // as SphereFitParams
  double huberMm = 1.0;
  int iterations = 40;
};

struct SpheroidFit {
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
  double radiusMm = 0.0;        // equatorial
  double aspect = 1.0;
  Eigen::Vector3d stemAxis = Eigen::Vector3d::UnitY();  // unit, the sign of the prior's
  double rmsMm = 0.0;
  // The points' χ² (the Huber loss, each point weighed as the fit weighs it) about this
  // spheroid, and about the sphere it was refined from: what its three more parameters
  // (the aspect, the stem's tilt) buy. spheroidWeight() reads them.
  double chiSquare = 0.0;
  double sphereChiSquare = 0.0;
  // Covariance of (c x, y, z; a; k; tilt α, β about two axes ⟂ the stem).
  Eigen::Matrix<double, 7, 7> covariance = Eigen::Matrix<double, 7, 7>::Zero();
};

// The spheroid's Akaike weight against the sphere it was refined from, 0..1: the evidence
// that the points show a fruit other than round. Each of the spheroid's three more
// parameters must lower χ² by 2 (AIC) to break even (weight 0.5). A cap that the lines saw
// only in part cannot tell the aspect: the weight then falls towards the sphere's, which
// keeps its diameter, where the aspect prior alone would bend it (docs/geometry.md).
double spheroidWeight(const SpheroidFit& fit);

// Refines `sphere` into a spheroid over the points marked in `use`. Errors: kBadInput
// when the fit diverges or leaves the fruit's range (the caller keeps the sphere).
Result<SpheroidFit> refineSpheroid(const std::vector<Eigen::Vector3d>& pointsMm, const std::vector<bool>& use,
                                   const SphereFit& sphere, const SpheroidPriors& priors);

// Where the sight line from the sensor (the origin) to the centre enters the surface, and
// the outward surface normal there. False when the line misses (never for a valid fit).
bool spheroidApproach(const Eigen::Vector3d& centerMm, double radiusMm, double aspect, const Eigen::Vector3d& stemAxis,
                      Eigen::Vector3d* pointMm, Eigen::Vector3d* normal);

// 1σ (3D) of the approach point, through the fit's covariance.
double spheroidApproachSigma(const SpheroidFit& fit);

}  // namespace alacs::geometry
