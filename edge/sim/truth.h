// The exact ground truth of the digital twin: geometry, not rendered intensity.
//
// Laser line: the laser plane at a slide position cuts an apple in a circle; for each
// image row that the camera-facing part of that circle crosses, the exact sub-pixel
// column (the crossing is solved to 1e-12 of the circle's parameter, then projected
// with the camera's distortion), the 3D surface point, and flags that say whether the
// camera sees it and the laser lights it. The same for the calibration board (plane ∩
// plane). Thread-safe (pure functions).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "sim/scene.h"

namespace alacs::sim {

// Why a truth row is not visible laser-lit fruit surface (0: it is).
enum TruthFlag : uint8_t {
  kTruthHidden = 1,    // something (leaf, branch, another apple, the board) is between it and the camera
  kTruthShadowed = 2,  // something is between it and the laser's emitter
  kTruthUnlit = 4,     // it faces away from the emitter, or lies outside the fan
  kTruthOutside = 8,   // its column lies outside the frame
};

struct RowTruth {
  int row = 0;
  double column = 0.0;                               // sub-pixel, pixel centres at integers
  Eigen::Vector3d pointMm = Eigen::Vector3d::Zero(); // on the surface and on the laser plane
  uint8_t flags = 0;
  int appleId = 0;                                   // -1: the calibration board
  bool visibleLit() const { return flags == 0; }
};

// Every row crossed by the camera-facing part of the plane ∩ sphere circle, with flags,
// ascending by row (a row can appear twice where the arc turns back near the limb).
std::vector<RowTruth> laserLineTruthAll(const SimScene& scene, const SimApple& apple, double slideMm);
// Only the visible, laser-lit rows (flags == 0).
std::vector<RowTruth> laserLineTruth(const SimScene& scene, const SimApple& apple, double slideMm);
// The laser line on the calibration board (empty without a board), with flags.
std::vector<RowTruth> boardLineTruth(const SimScene& scene, double slideMm);

// The board's inner checkerboard corners: index (i, j) in 1..squares-1, 3D point, pixel
// (with distortion), and whether the camera sees it (in the frame, board facing it,
// nothing in between).
struct CornerTruth {
  int i = 0;
  int j = 0;
  Eigen::Vector3d pointMm = Eigen::Vector3d::Zero();
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();
  bool visible = false;
};
std::vector<CornerTruth> boardCorners(const SimScene& scene);

// Share (0..1) of the apple's camera-facing disc hidden from the camera by other
// objects, from a deterministic grid of `samples` rays.
double occlusionShare(const SimScene& scene, const SimApple& apple, int samples = 900);

}  // namespace alacs::sim
