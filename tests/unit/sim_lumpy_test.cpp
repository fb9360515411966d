// The twin's irregular, lumpy fruit (sim::AppleShape): the ray intersection, the laser
// line's truth and the approach point all lie on the same surface |u| = radialFactor(û),
// the normal is perpendicular to it, and the lumps are there (the line departs from the
// smooth ellipsoid's by millimetres).
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <cmath>

#include "sim/raycast.h"
#include "sim/scene.h"
#include "sim/truth.h"

using namespace alacs;

namespace {

sim::SimApple lumpyApple() {
  sim::SimApple a;
  a.id = 1;
  a.centerMm = Eigen::Vector3d(15.0, -10.0, 1150.0);
  a.radiusMm = 38.0;
  a.aspect = 0.9;
  a.stemAxis = Eigen::Vector3d(0.2, -0.95, 0.1).normalized();
  a.lumpAmplitude = 0.06;
  a.lumpSeed = 1234;
  return a;
}

// How far a world point lies off the lumpy surface, in the scaled frame's units.
double offSurface(const sim::AppleShape& shape, const Eigen::Vector3d& p) {
  const Eigen::Vector3d u = shape.toScaled(p);
  return u.norm() - shape.radialFactor(u.normalized());
}

}  // namespace

TEST_CASE("A lumpy apple's radial factor stays within its amplitude and varies", "[sim][lumpy]") {
  const sim::AppleShape shape(lumpyApple());
  double lo = 2.0;
  double hi = 0.0;
  for (int i = 0; i < 2000; ++i) {
    const double z = -1.0 + 2.0 * (i + 0.5) / 2000.0;
    const double phi = 2.39996 * i;  // a golden-angle spiral over the sphere
    const double r = std::sqrt(1.0 - z * z);
    const double f = shape.radialFactor(Eigen::Vector3d(r * std::cos(phi), r * std::sin(phi), z));
    lo = std::min(lo, f);
    hi = std::max(hi, f);
  }
  CHECK(lo >= 1.0 - 0.06);
  CHECK(hi <= 1.0 + 0.06);
  CHECK(hi - lo > 0.04);  // lumps of several millimetres on a 38 mm radius
  sim::SimApple smooth = lumpyApple();
  smooth.lumpAmplitude = 0.0;
  CHECK(sim::AppleShape(smooth).radialFactor(Eigen::Vector3d(0.6, 0.0, 0.8)) == 1.0);
}

TEST_CASE("Rays hit a lumpy apple on its surface, with a normal perpendicular to it", "[sim][lumpy]") {
  sim::SimScene s = sim::defaultScene();
  s.apples = {lumpyApple()};
  s.leaves.clear();
  s.branches.clear();
  const sim::SceneGeometry geo(s);
  const sim::AppleShape shape(s.apples[0]);
  int hits = 0;
  for (int i = -12; i <= 12; ++i) {
    for (int j = -12; j <= 12; ++j) {
      const Eigen::Vector3d dir = (s.apples[0].centerMm + Eigen::Vector3d(3.4 * i, 3.4 * j, 0.0)).normalized();
      sim::Hit h;
      if (!geo.intersect(Eigen::Vector3d::Zero(), dir, 1e-6, 1e9, &h)) continue;
      ++hits;
      const Eigen::Vector3d p = h.t * dir;
      CHECK(std::abs(offSurface(shape, p)) < 1e-9);
      // The normal against two tangent steps along the surface (numerical, 0.05 mm).
      const Eigen::Vector3d t1 = h.normal.unitOrthogonal();
      const Eigen::Vector3d t2 = h.normal.cross(t1);
      for (const Eigen::Vector3d& t : {t1, t2}) {
        Eigen::Vector3d q = p + 0.05 * t;
        const Eigen::Vector3d uq = shape.toScaled(q);
        q = shape.fromScaled(uq * shape.radialFactor(uq.normalized()) / uq.norm());  // back onto the surface
        CHECK(std::abs((q - p).normalized().dot(h.normal)) < 0.02);
      }
      CHECK(h.normal.dot(dir) < 0.0);
    }
  }
  CHECK(hits > 300);
}

TEST_CASE("The laser line's truth on a lumpy apple is on its surface and departs from the smooth one", "[sim][lumpy]") {
  sim::SimScene s = sim::defaultScene();
  s.apples = {lumpyApple()};
  s.leaves.clear();
  s.branches.clear();
  const sim::SimApple& apple = s.apples[0];
  const sim::AppleShape shape(apple);
  const double slide = s.truth.laser.slideForPoint(apple.centerMm + Eigen::Vector3d(-6, 0, 0));
  const auto rows = sim::laserLineTruth(s, apple, slide);
  REQUIRE(rows.size() > 100);
  const double d = s.truth.laser.planeOffsetAt(slide);
  for (const auto& r : rows) {
    CHECK(std::abs(offSurface(shape, r.pointMm)) < 1e-9);
    CHECK(std::abs(s.truth.laser.planeNormal.dot(r.pointMm) - d) < 1e-9);
    CHECK(std::abs(sim::projectPx(s.truth.camera, r.pointMm).y() - r.row) < 1e-6);
  }
  // The smooth apple's line on the same rows: the lumps move it by up to ~a·R in depth,
  // which the camera sees as columns (the laser is off to the side).
  sim::SimScene smoothScene = s;
  smoothScene.apples[0].lumpAmplitude = 0.0;
  const auto smooth = sim::laserLineTruth(smoothScene, smoothScene.apples[0], slide);
  double maxDepthMm = 0.0;
  for (const auto& r : rows)
    for (const auto& q : smooth)
      if (q.row == r.row) maxDepthMm = std::max(maxDepthMm, std::abs(q.pointMm.z() - r.pointMm.z()));
  CHECK(maxDepthMm > 0.5);
  CHECK(maxDepthMm < 0.06 * 38.0 * 3.0);
  // The approach point: on the surface and on the sight line to the centre.
  const Eigen::Vector3d ap = sim::approachPoint(apple);
  CHECK(std::abs(offSurface(shape, ap)) < 1e-12);
  CHECK(ap.normalized().cross(apple.centerMm.normalized()).norm() < 1e-12);
}

TEST_CASE("A scene file keeps a lumpy apple's amplitude and seed, and refuses lumps beyond 0.15", "[sim][lumpy]") {
  sim::SimScene s = sim::defaultScene();
  s.apples = {lumpyApple()};
  const std::string path = "/tmp/alacs_lumpy_scene_test.json";
  REQUIRE(sim::saveScene(s, path));
  Result<sim::SimScene> back = sim::loadScene(path);
  REQUIRE(back);
  CHECK(back->apples[0].lumpAmplitude == Approx(0.06));
  CHECK(back->apples[0].lumpSeed == 1234u);
  s.apples[0].lumpAmplitude = 0.2;
  const Status st = s.validate();
  CHECK_FALSE(st);
  CHECK_THAT(st.reason(), Catch::Contains("lump_amplitude"));
}
