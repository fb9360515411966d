// The simulated orchard scene behind `alacsd --sim` and the tests: a camera, the laser
// on its slide, apples and a foliage wall, with the exact ground truth.
// Units: mm in the camera frame (x right, y down, z forward), pixels for the image.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"

namespace alacs::sim {

struct SimApple {
  int id = 0;
  Eigen::Vector3d centerMm{0.0, 0.0, 1200.0};
  double radiusMm = 40.0;
  Eigen::Vector3d skinRgb{0.62, 0.10, 0.08};  // diffuse albedo per channel
};

struct SimScene {
  geometry::Calibration truth;        // camera + laser as they really are
  std::vector<SimApple> apples;
  double backgroundDepthMm = 2000.0;  // foliage wall
  double ambient = 0.55;              // DN of a white Lambertian patch / 255 under the scene's light
  Eigen::Vector3d lightDir{-0.3, -0.5, -0.8};  // towards the light, camera frame
  double laserPeakDn = 170.0;         // red DN at the line centre on skin at 1.2 m
  double sheetSigmaMmAt1200 = 0.7;    // laser sheet 1σ half-thickness at 1.2 m range
  double haloSigmaMm = 2.5;           // sub-surface scattering halo on skin
  double haloFraction = 0.25;
  double speckle = 0.15;              // multiplicative speckle contrast on laser light
  double readNoiseDn = 1.5;
  double shotNoiseGain = 0.08;        // DN variance per DN of signal
  uint64_t seed = 1;

  Status validate() const;
};

// The built-in scene: one 80 mm apple at 1.2 m, a foliage wall at 2 m.
SimScene defaultScene();

// Loads a scene JSON (see docs/simulation.md); missing keys keep the defaults.
Result<SimScene> loadScene(const std::string& path);
// Writes the truth (apples, calibration) as JSON, for tests and the demo.
Status saveSceneTruth(const SimScene& scene, const std::string& path);

// Sub-pixel truth of one apple's laser line: for each image row crossed by the part of
// the plane ∩ sphere circle that the camera sees, the column where it crosses that row.
struct RowTruth {
  int row = 0;
  double column = 0.0;
};
std::vector<RowTruth> laserLineTruth(const SimScene& scene, const SimApple& apple, double slideMm);

// The point of the apple's surface nearest the sensor on the line to its centre.
Eigen::Vector3d approachPoint(const SimApple& apple);

}  // namespace alacs::sim
