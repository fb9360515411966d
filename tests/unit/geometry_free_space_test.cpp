// Free space in the sphere fit: one laser line alone leaves the side of the centre to the
// priors, and a rough position off by 2σ (RealSense) picks the wrong side. What another
// line saw behind the fruit's place on that side (a surface farther away, in plain view)
// rules the wrong side out: the fruit would hide it.
#include <catch2/catch.hpp>

#include <cmath>

#include "geometry/sphere_fit.h"

using namespace alacs;
using namespace alacs::geometry;

namespace {

struct Scene {
  std::vector<Eigen::Vector3d> pts;
  std::vector<int> lines;
};

// A sphere (0, 0, 1200) r 38 cut by the plane x = −12 (its camera-facing arc), and the
// planes x = −42 and −55 (past the fruit's limb) lighting a wall 80 mm behind its centre.
Scene scene() {
  Scene s;
  const Eigen::Vector3d c(0.0, 0.0, 1200.0);
  const double r = 38.0;
  const double x0 = -12.0;
  const double rho = std::sqrt(r * r - x0 * x0);
  for (double deg = -70.0; deg <= 70.0; deg += 2.0) {
    const double t = deg * M_PI / 180.0;
    s.pts.emplace_back(x0, c.y() + rho * std::sin(t), c.z() - rho * std::cos(t));
    s.lines.push_back(0);
  }
  for (int line = 1; line <= 2; ++line)
    for (double y = -30.0; y <= 30.0; y += 1.5) {
      s.pts.emplace_back(line == 1 ? -42.0 : -55.0, y, c.z() + 80.0);
      s.lines.push_back(line);
    }
  return s;
}

SphereFitParams params() {
  SphereFitParams p;
  p.priorRadiusMm = 40.0;
  p.priorRadiusSigmaMm = 6.0;
  p.minRadiusMm = 27.5;
  p.maxRadiusMm = 52.5;
  p.priorCenterMm = Eigen::Vector3d(-40.0, 0.0, 1200.0);  // 40 mm off, on the wrong side
  p.priorCenterSigmaMm = 15.0;
  return p;
}

}  // namespace

TEST_CASE("What the camera sees behind the fruit's place rules out the wrong side of one line", "[geometry][sphere]") {
  const Scene s = scene();
  SphereFitParams off = params();
  off.freeSpacePoints = 0.0;
  const auto blind = fitSphere(s.pts, s.lines, {}, off);
  REQUIRE(blind.isOk());
  INFO("without free space: centre (" << blind->centerMm.transpose() << ")");
  // The priors alone take the side of the rough position.
  CHECK(blind->centerMm.x() < -12.0);

  const auto fit = fitSphere(s.pts, s.lines, {}, params());
  REQUIRE(fit.isOk());
  INFO("with free space: centre (" << fit->centerMm.transpose() << "), r " << fit->radiusMm);
  // Not on the wrong side; how far onto the right one is the priors' (the rough position
  // pulls back towards the line's plane).
  CHECK(fit->centerMm.x() > -12.5);
  CHECK((fit->centerMm - Eigen::Vector3d(0.0, 0.0, 1200.0)).norm() < 15.0);
  // Only the arc is the fruit.
  for (size_t i = 0; i < s.pts.size(); ++i)
    if (s.lines[i] != 0) CHECK_FALSE(fit->inlier[i]);
}

TEST_CASE("Free space does not reject the fruit for what lies in front of it or beside it", "[geometry][sphere]") {
  // Leaf points in front of the fruit and a neighbour's skin beside it, in plain view.
  Scene s = scene();
  for (double y = -10.0; y <= 10.0; y += 1.0) {
    s.pts.emplace_back(5.0, y, 1130.0);  // a leaf 32 mm in front of the surface
    s.lines.push_back(3);
  }
  SphereFitParams p = params();
  p.priorCenterMm = Eigen::Vector3d(5.0, 0.0, 1195.0);  // near the truth
  const auto fit = fitSphere(s.pts, s.lines, {}, p);
  REQUIRE(fit.isOk());
  INFO("centre (" << fit->centerMm.transpose() << "), r " << fit->radiusMm);
  CHECK((fit->centerMm - Eigen::Vector3d(0.0, 0.0, 1200.0)).norm() < 10.0);
}
