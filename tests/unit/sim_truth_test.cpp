// The twin's ground truth against closed forms and independent computations: the laser
// line on a sphere (plane ∩ sphere), the visibility and laser-shadow flags, the board's
// line and corners, the occlusion share, and the distortion model.
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <cmath>

#include "geometry/triangulation.h"
#include "sim/raycast.h"
#include "sim/scene.h"
#include "sim/truth.h"

using namespace alacs;

namespace {

// A pinhole camera without distortion and a vertical laser plane x = d0 + s (slide along x).
sim::SimScene analyticScene(double planeXMm) {
  sim::SimScene s = sim::defaultScene();
  auto& cam = s.truth.camera;
  cam.fxPx = 2000.0;
  cam.fyPx = 2000.0;
  cam.cxPx = 1023.5;
  cam.cyPx = 767.5;
  cam.distortion = {0, 0, 0, 0, 0};
  auto& las = s.truth.laser;
  las.planeNormal = Eigen::Vector3d(1, 0, 0);
  las.slideAxis = Eigen::Vector3d(1, 0, 0);
  las.slideScale = 1.0;
  s.laser.originAtHomeMm = Eigen::Vector3d(planeXMm, 0.0, 0.0);
  las.planeOffsetMm = planeXMm;
  s.laser.fanDeg = 120.0;
  s.apples.clear();
  sim::SimApple a;
  a.id = 1;
  a.centerMm = Eigen::Vector3d(0.0, 0.0, 1000.0);
  a.radiusMm = 40.0;
  s.apples.push_back(a);
  return s;
}

// Nearer and farther depth where the ray of row `row` meets the circle x = d on the sphere.
bool closedForm(const sim::SimScene& s, int row, double* zNear, double* zFar) {
  const auto& cam = s.truth.camera;
  const auto& a = s.apples[0];
  const double d = s.truth.laser.planeOffsetMm;
  const double rho2 = a.radiusMm * a.radiusMm - d * d;
  const double k = (row - cam.cyPx) / cam.fyPx;
  const double zc = a.centerMm.z();
  const double disc = zc * zc - (1 + k * k) * (zc * zc - rho2);
  if (disc < 0) return false;
  *zNear = (zc - std::sqrt(disc)) / (1 + k * k);
  *zFar = (zc + std::sqrt(disc)) / (1 + k * k);
  return true;
}

}  // namespace

TEST_CASE("Truth of the laser line on a sphere equals the closed form of plane ∩ sphere", "[sim][truth]") {
  const sim::SimScene s = analyticScene(25.0);
  const auto rows = sim::laserLineTruthAll(s, s.apples[0], 0.0);
  REQUIRE(rows.size() > 40);
  const auto& cam = s.truth.camera;
  double worst = 0.0;
  for (const auto& r : rows) {
    double zn = 0, zf = 0;
    REQUIRE(closedForm(s, r.row, &zn, &zf));
    const double un = cam.cxPx + cam.fxPx * 25.0 / zn;
    const double uf = cam.cxPx + cam.fxPx * 25.0 / zf;
    const double err = std::min(std::abs(r.column - un), std::abs(r.column - uf));
    worst = std::max(worst, err);
    // The 3D point lies on the plane and on the sphere, and projects onto its row.
    CHECK(std::abs(r.pointMm.x() - 25.0) < 1e-9);
    CHECK(std::abs((r.pointMm - s.apples[0].centerMm).norm() - 40.0) < 1e-9);
    CHECK(std::abs(cam.cyPx + cam.fyPx * r.pointMm.y() / r.pointMm.z() - r.row) < 1e-6);
    CHECK(r.flags == 0);  // nothing in the way, the emitter lies on the lit side
  }
  INFO("worst column error " << worst << " px");
  CHECK(worst < 1e-6);
  // Every row where the nearer intersection faces the camera is in the truth.
  int expected = 0;
  for (int row = 0; row < cam.heightPx; ++row) {
    double zn = 0, zf = 0;
    if (!closedForm(s, row, &zn, &zf)) continue;
    const double k = (row - cam.cyPx) / cam.fyPx;
    const Eigen::Vector3d p(25.0, k * zn, zn);
    if ((p - s.apples[0].centerMm).dot(-p) > 1e-3) ++expected;
  }
  int near = 0;
  for (const auto& r : rows) {
    double zn = 0, zf = 0;
    (void)closedForm(s, r.row, &zn, &zf);
    if (std::abs(r.pointMm.z() - zn) < 1e-6) ++near;
  }
  CHECK(near >= expected - 1);  // the limb's last fraction of a row may fall between samples
  CHECK(near <= expected + 1);
}

TEST_CASE("The plane that misses the sphere gives no truth; the slide moves the line", "[sim][truth]") {
  const sim::SimScene s = analyticScene(0.0);
  CHECK(sim::laserLineTruthAll(s, s.apples[0], 41.0).empty());   // plane x = 41 > r
  CHECK(sim::laserLineTruthAll(s, s.apples[0], -41.0).empty());
  const auto mid = sim::laserLineTruth(s, s.apples[0], 0.0);
  const auto right = sim::laserLineTruth(s, s.apples[0], 20.0);
  REQUIRE(!mid.empty());
  REQUIRE(!right.empty());
  // At x = 0 the line runs through the image centre column; at x = 20 mm to its right.
  const auto& centreRow = mid[mid.size() / 2];
  CHECK(std::abs(centreRow.column - s.truth.camera.cxPx) < 1e-6);
  for (const auto& r : right) CHECK(r.column > s.truth.camera.cxPx);
}

TEST_CASE("With distortion every truth point is on the sphere and the plane and projects onto its row", "[sim][truth]") {
  const sim::SimScene s = sim::defaultScene();
  const auto& apple = s.apples[0];
  const double slide = s.truth.laser.slideForPoint(apple.centerMm + Eigen::Vector3d(12, 0, 0));
  const auto rows = sim::laserLineTruth(s, apple, slide);
  REQUIRE(rows.size() > 100);
  std::vector<Eigen::Vector3d> pts;
  for (const auto& r : rows) pts.push_back(r.pointMm);
  const auto px = geometry::projectPoints(s.truth.camera, pts);  // OpenCV's projection
  const double d = s.truth.laser.planeOffsetAt(slide);
  for (size_t i = 0; i < rows.size(); ++i) {
    CHECK(std::abs(s.truth.laser.planeNormal.dot(rows[i].pointMm) - d) < 1e-9);
    CHECK(std::abs((rows[i].pointMm - apple.centerMm).norm() - apple.radiusMm) < 1e-9);
    CHECK(std::abs(px[i].rowPx - rows[i].row) < 1e-6);
    CHECK(std::abs(px[i].columnPx - rows[i].column) < 1e-6);
  }
}

TEST_CASE("On an oblate, tilted apple every truth point is on the ellipsoid and the plane", "[sim][truth]") {
  sim::SimScene s = sim::defaultScene();
  auto& apple = s.apples[0];
  apple.aspect = 0.85;
  apple.stemAxis = Eigen::Vector3d(0.3, -0.9, 0.2).normalized();
  const double slide = s.truth.laser.slideForPoint(apple.centerMm + Eigen::Vector3d(-9, 0, 0));
  const auto rows = sim::laserLineTruth(s, apple, slide);
  REQUIRE(rows.size() > 100);
  const Eigen::Matrix3d f = sim::appleFrame(apple);
  const double d = s.truth.laser.planeOffsetAt(slide);
  for (const auto& r : rows) {
    const Eigen::Vector3d l = f.transpose() * (r.pointMm - apple.centerMm);
    const double q = (l.x() * l.x() + l.y() * l.y()) / (40.0 * 40.0) + l.z() * l.z() / (34.0 * 34.0);
    CHECK(std::abs(q - 1.0) < 1e-9);
    CHECK(std::abs(s.truth.laser.planeNormal.dot(r.pointMm) - d) < 1e-9);
    CHECK(std::abs(sim::projectPx(s.truth.camera, r.pointMm).y() - r.row) < 1e-6);
    CHECK(sim::appleNormal(apple, r.pointMm).dot(-r.pointMm) > 0.0);
  }
  // The approach point: on the surface, on the sight line to the centre, nearer than it.
  const Eigen::Vector3d ap = sim::approachPoint(apple);
  const Eigen::Vector3d l = f.transpose() * (ap - apple.centerMm);
  CHECK(std::abs((l.x() * l.x() + l.y() * l.y()) / 1600.0 + l.z() * l.z() / (34.0 * 34.0) - 1.0) < 1e-9);
  CHECK(ap.normalized().cross(apple.centerMm.normalized()).norm() < 1e-12);
  CHECK(ap.norm() < apple.centerMm.norm());
  // A sphere's approach point is one radius short of the centre.
  sim::SimApple round = apple;
  round.aspect = 1.0;
  CHECK((sim::approachPoint(round) - (round.centerMm - 40.0 * round.centerMm.normalized())).norm() < 1e-9);
}

TEST_CASE("The distortion model matches OpenCV's projectPoints", "[sim][truth]") {
  const sim::SimScene s = sim::defaultScene();
  std::vector<Eigen::Vector3d> pts;
  for (int i = -6; i <= 6; ++i)
    for (int j = -5; j <= 5; ++j) pts.emplace_back(i * 90.0, j * 70.0, 1000.0 + 13.0 * i * j);
  const auto cv = geometry::projectPoints(s.truth.camera, pts);
  for (size_t k = 0; k < pts.size(); ++k) {
    const Eigen::Vector2d p = sim::projectPx(s.truth.camera, pts[k]);
    CHECK(std::abs(p.x() - cv[k].columnPx) < 1e-7);
    CHECK(std::abs(p.y() - cv[k].rowPx) < 1e-7);
  }
}

TEST_CASE("A leaf before the camera hides exactly the rows whose sight line crosses its blade", "[sim][truth]") {
  sim::SimScene s = analyticScene(10.0);
  // A leaf at z = 800 facing the camera, over the upper part of the apple's image.
  sim::SimLeaf leaf;
  leaf.centerMm = Eigen::Vector3d(8.0, -26.0, 800.0);
  leaf.normal = Eigen::Vector3d(0, 0, -1);
  leaf.axis = Eigen::Vector3d(1, 0, 0);
  leaf.lengthMm = 60.0;
  leaf.widthMm = 30.0;
  s.leaves.push_back(leaf);
  const auto rows = sim::laserLineTruthAll(s, s.apples[0], 0.0);
  REQUIRE(!rows.empty());
  int hidden = 0;
  for (const auto& r : rows) {
    // Independent: where the sight line crosses z = 800, inside the blade's outline?
    const Eigen::Vector3d q = r.pointMm * (800.0 / r.pointMm.z()) - leaf.centerMm;
    const double u = q.x() / 30.0;
    const bool inside = std::abs(u) <= 1.0 && std::abs(q.y()) <= 15.0 * (1.0 - u * u);
    CHECK(((r.flags & sim::kTruthHidden) != 0) == inside);
    hidden += inside ? 1 : 0;
  }
  CHECK(hidden > 5);
  CHECK(hidden < static_cast<int>(rows.size()));

}

TEST_CASE("A branch between the emitter and the apple casts a laser shadow", "[sim][truth]") {
  sim::SimScene s = analyticScene(10.0);
  // The emitter 150 mm right of the camera; the sheet x = 10 is then not through it, so
  // tilt it: plane through the emitter (150, 0, 0) and the line x = 10 at z = 1000.
  const Eigen::Vector3d emitter(150.0, 0.0, 0.0);
  const Eigen::Vector3d n = Eigen::Vector3d(1000.0, 0.0, 140.0).normalized();
  s.truth.laser.planeNormal = n;
  s.truth.laser.planeOffsetMm = n.dot(emitter);
  s.laser.originAtHomeMm = emitter;
  // A horizontal branch across the sheet between emitter and apple, above the middle.
  sim::SimBranch b;
  b.aMm = Eigen::Vector3d(0.0, -12.0, 600.0);
  b.bMm = Eigen::Vector3d(200.0, -12.0, 600.0);
  b.radiusMm = 3.0;
  s.branches.push_back(b);
  const auto rows = sim::laserLineTruthAll(s, s.apples[0], 0.0);
  REQUIRE(rows.size() > 40);
  int shadowed = 0;
  for (const auto& r : rows) {
    // Independent: distance of the segment emitter -> point from the branch's axis line
    // y = -12, z = 600 (the branch is long enough in x).
    const Eigen::Vector3d d = r.pointMm - emitter;
    const double t = (600.0 - emitter.z()) / d.z();
    const Eigen::Vector3d q = emitter + t * d;
    const double dist = std::abs(q.y() + 12.0);
    // Near the branch's edge the capsule's round section differs from this slice test.
    if (std::abs(dist - 3.0) < 0.3) continue;
    CHECK(((r.flags & sim::kTruthShadowed) != 0) == (dist < 3.0));
    shadowed += dist < 3.0 ? 1 : 0;
  }
  CHECK(shadowed > 2);
}

TEST_CASE("Rows outside the fan are unlit; laserLineTruth keeps only visible lit rows", "[sim][truth]") {
  sim::SimScene s = analyticScene(10.0);
  s.laser.fanDeg = 2.0;  // ±1°: about ±17 mm at 1 m
  const auto all = sim::laserLineTruthAll(s, s.apples[0], 0.0);
  const auto lit = sim::laserLineTruth(s, s.apples[0], 0.0);
  REQUIRE(!all.empty());
  size_t unlit = 0;
  for (const auto& r : all) {
    const double angle = std::atan2(std::abs(r.pointMm.y()), r.pointMm.z() - 0.0) * 180.0 / M_PI;
    if (std::abs(angle - 1.0) > 0.02) CHECK(((r.flags & sim::kTruthUnlit) != 0) == (angle > 1.0));
    unlit += (r.flags != 0) ? 1 : 0;
  }
  CHECK(unlit > 0);
  CHECK(lit.size() == all.size() - unlit);
  for (const auto& r : lit) CHECK(r.flags == 0);
}

TEST_CASE("The board's line lies on both planes; its corners project as OpenCV projects them", "[sim][truth]") {
  sim::SimScene s = sim::defaultScene();
  s.apples.clear();
  sim::SimBoard b;
  const Eigen::AngleAxisd tilt(0.3, Eigen::Vector3d(0.2, 1.0, 0.1).normalized());
  b.rotation = tilt.toRotationMatrix();
  b.originMm = Eigen::Vector3d(-180.0, -120.0, 1100.0);
  s.board = b;
  const double slide = 100.0;
  const auto rows = sim::boardLineTruth(s, slide);
  REQUIRE(rows.size() > 100);
  const Eigen::Vector3d nb = b.rotation.col(2);
  for (const auto& r : rows) {
    CHECK(std::abs(nb.dot(r.pointMm - b.originMm)) < 1e-8);
    CHECK(std::abs(s.truth.laser.planeNormal.dot(r.pointMm) - s.truth.laser.planeOffsetAt(slide)) < 1e-8);
    CHECK(r.appleId == -1);
  }
  const auto corners = sim::boardCorners(s);
  REQUIRE(corners.size() == static_cast<size_t>((b.squaresX - 1) * (b.squaresY - 1)));
  std::vector<Eigen::Vector3d> pts;
  for (const auto& c : corners) pts.push_back(c.pointMm);
  const auto px = geometry::projectPoints(s.truth.camera, pts);
  int visible = 0;
  for (size_t i = 0; i < corners.size(); ++i) {
    CHECK(std::abs(px[i].columnPx - corners[i].pixel.x()) < 1e-6);
    CHECK(std::abs(px[i].rowPx - corners[i].pixel.y()) < 1e-6);
    visible += corners[i].visible ? 1 : 0;
  }
  CHECK(visible == static_cast<int>(corners.size()));
}

TEST_CASE("Occlusion share: none, all, and half of the apple", "[sim][truth]") {
  sim::SimScene s = analyticScene(0.0);
  CHECK(sim::occlusionShare(s, s.apples[0]) == 0.0);
  // A plain board covering the left half of the apple's view: its edge at x = 0.
  sim::SimBoard b;
  b.checkerboard = false;
  b.squaresX = 4;
  b.squaresY = 4;
  b.squareMm = 50.0;
  b.marginMm = 0.0;
  b.rotation = Eigen::Matrix3d::Identity();
  b.originMm = Eigen::Vector3d(-200.0, -100.0, 700.0);  // x from -200 to 0 at z = 700
  s.board = b;
  const double half = sim::occlusionShare(s, s.apples[0]);
  CHECK(std::abs(half - 0.5) < 0.04);
  s.board->originMm = Eigen::Vector3d(-100.0, -100.0, 700.0);  // x from -100 to +100: all
  CHECK(sim::occlusionShare(s, s.apples[0]) == 1.0);
}
