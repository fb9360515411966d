// How far a triangulated point may be off because the calibration is an estimate: the
// laser plane's own uncertainty *and* the camera intrinsics' uncertainty, carried through
// everything that depends on the intrinsics (docs/calibration.md, "Total σ").
//
// Why the intrinsics matter so much: the board poses come from the same intrinsics, so a
// focal length a little low puts every board (and so the fitted laser plane) a little
// closer, and then the triangulation with that focal length agrees with it. The result is
// a depth-scale error proportional to depth that the laser fit's residuals cannot see.
//
// Method (linearised, deterministic): the intrinsics' covariance is factored into
// independent directions (eigenvectors of the correlation matrix, scaled back to units).
// Along each direction the intrinsics are moved by ±1σ, the board poses are solved again,
// the laser plane is refitted from the same line pixels, and a fixed grid of pixels on the
// laser planes is triangulated; half the difference between + and − is that direction's
// contribution. The laser parameters' own covariance (Gauss–Newton + placement jackknife,
// LaserFit::covariance) is carried the same way at fixed intrinsics, and the two are added
// (they come from different measurements: checkerboard corners vs laser line pixels and
// target placement). A Monte Carlo of the intrinsics (`draws` > 0) is kept for checking the
// linearisation; it agrees within its sampling noise. Thread-safe (pure function).
#pragma once

#include <cstdint>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"
#include "geometry/camera_calibration.h"
#include "geometry/laser_calibration.h"
#include "geometry/triangulation.h"

namespace alacs::geometry {

// One laser line as the camera saw it (pixels, distorted), so it can be undistorted again
// under other intrinsics.
struct LaserPixelLine {
  int placement = 0;  // index into CalibrationObservations::placementViews
  double slideMm = 0.0;
  std::vector<PixelPoint> pixels;
};

// What the laser fit was made from, before the intrinsics touched it.
struct CalibrationObservations {
  std::vector<TargetView> placementViews;  // the flat board's corners at each placement
  std::vector<LaserPixelLine> lines;
};

struct UncertaintyOptions {
  std::vector<double> depthsMm{1000.0, 1200.0, 1400.0, 1600.0};
  double strokeStartMm = 0.0;  // slide positions of the grid: start..end in strokeSteps steps
  double strokeEndMm = 200.0;
  int strokeSteps = 8;
  double heightSpan = 0.3;     // grid rows from −span·z to +span·z (the frame's height at z)
  int draws = 0;               // 0: ±1σ along each direction (default); > 0: Monte Carlo draws
  uint64_t seed = 1;           // Monte Carlo only
  LaserFitOptions laser;       // as the laser fit ran (slide axis, bands)
};

struct DepthUncertainty {
  double depthMm = 0.0;
  int points = 0;                     // grid pixels inside the frame at this depth
  double depthSigmaLaserMm = 0.0;     // RMS over the grid, laser parameters only
  double depthSigmaIntrinsicsMm = 0.0;  // intrinsics, through board poses and laser refit
  double depthSigmaTotalMm = 0.0;     // both
  double sigma3dTotalMm = 0.0;        // √(trace of the 3D covariance), RMS over the grid
};

struct CalibrationUncertainty {
  std::vector<DepthUncertainty> byDepth;  // in the order of UncertaintyOptions::depthsMm
  int solves = 0;                         // pose + laser re-solves it took
};

// Errors: kBadInput when a placement's pose or the laser refit fails under perturbed
// intrinsics, or when no grid pixel lands inside the frame at some depth.
Result<CalibrationUncertainty> propagateCalibrationUncertainty(const CameraIntrinsics& camera,
                                                               const IntrinsicsCovariance& intrinsicsCovariance,
                                                               const LaserFit& laser,
                                                               const CalibrationObservations& observations,
                                                               const UncertaintyOptions& options = {});

}  // namespace alacs::geometry
