// The spheroid refinement on synthetic lines: an oblate apple (aspect 0.86, stem tilted
// 20°) cut by vertical laser planes, the camera-facing arcs with noise. The sphere fit
// alone is millimetres off; the spheroid comes back to the truth.
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <random>

#include "geometry/sphere_fit.h"
#include "geometry/spheroid_fit.h"
#include "localize/localizer.h"

using namespace alacs;
using namespace alacs::geometry;

namespace {

struct Apple {
  Eigen::Vector3d c{12.0, -25.0, 1250.0};
  double a = 41.0;
  double k = 0.86;
  Eigen::Vector3d s = (Eigen::AngleAxisd(20.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ()) * Eigen::Vector3d(0, -1, 0));
};

// Points of the spheroid's surface on the plane x = xPlane that face the camera (origin).
// `fromMm`..`toMm`: the part of the cut (about the centre's height) that the leaves leave in view.
std::vector<Eigen::Vector3d> cut(const Apple& ap, double xPlane, double noiseMm, std::mt19937& rng,
                                 double fromMm = -60.0, double toMm = 60.0) {
  std::normal_distribution<double> noise(0.0, noiseMm);
  std::vector<Eigen::Vector3d> out;
  const Eigen::Vector3d e1 = ap.s.unitOrthogonal();
  const Eigen::Vector3d e2 = ap.s.cross(e1);
  // March rays in the plane from the camera and intersect the spheroid exactly.
  for (double y = ap.c.y() + fromMm; y <= ap.c.y() + toMm; y += 0.5) {
    const Eigen::Vector3d dir = Eigen::Vector3d(xPlane, y, ap.c.z()).normalized();
    Eigen::Vector3d p;
    Eigen::Vector3d n;
    // spheroidApproach intersects the sight line towards a centre; use a shifted "centre"
    // trick instead: solve the quadratic directly.
    auto form = [&](const Eigen::Vector3d& v, const Eigen::Vector3d& w) {
      const double vs = v.dot(ap.s);
      const double ws = w.dot(ap.s);
      return (v.dot(w) - vs * ws) / (ap.a * ap.a) + vs * ws / (ap.k * ap.a * ap.k * ap.a);
    };
    const double qa = form(dir, dir);
    const double qb = -2.0 * form(dir, ap.c);
    const double qc = form(ap.c, ap.c) - 1.0;
    const double disc = qb * qb - 4.0 * qa * qc;
    if (disc < 0) continue;
    const double t = (-qb - std::sqrt(disc)) / (2.0 * qa);
    p = t * dir;
    (void)n;
    (void)e2;
    out.push_back(p + noise(rng) * dir);
  }
  return out;
}

}  // namespace

TEST_CASE("A spheroid about the stem fits an oblate apple that a sphere cannot", "[geometry][spheroid]") {
  Apple ap;
  std::mt19937 rng(31);
  std::vector<Eigen::Vector3d> pts;
  std::vector<int> lines;
  int id = 0;
  for (double dx : {-30.0, -15.0, 0.0, 15.0, 30.0}) {
    const auto c = cut(ap, ap.c.x() + dx, 0.3, rng);
    pts.insert(pts.end(), c.begin(), c.end());
    lines.insert(lines.end(), c.size(), id++);
  }
  REQUIRE(pts.size() > 500);
  SphereFitParams sp;
  sp.priorRadiusMm = 40.0;
  sp.priorRadiusSigmaMm = 6.0;
  sp.ransacBandMm = 3.0;  // the spheroid departs from any sphere by ~2 mm
  sp.outlierMm = 5.0;
  auto sphere = fitSphere(pts, lines, {}, sp);
  REQUIRE(sphere.isOk());
  Eigen::Vector3d truthApproach;
  Eigen::Vector3d truthNormal;
  REQUIRE(spheroidApproach(ap.c, ap.a, ap.k, ap.s, &truthApproach, &truthNormal));
  const Eigen::Vector3d sphereApproach = sphere->centerMm - sphere->radiusMm * sphere->centerMm.normalized();
  const double sphereCentreErr = (sphere->centerMm - ap.c).norm();

  SpheroidPriors pr;
  pr.pointsPerIndependent = 1.0;
  std::vector<bool> use(pts.size(), true);
  auto fit = refineSpheroid(pts, use, *sphere, pr);
  REQUIRE(fit.isOk());
  Eigen::Vector3d approach;
  Eigen::Vector3d normal;
  REQUIRE(spheroidApproach(fit->centerMm, fit->radiusMm, fit->aspect, fit->stemAxis, &approach, &normal));
  INFO("sphere: centre off " << sphereCentreErr << " mm, d " << 2 * sphere->radiusMm << ", approach off "
                             << (sphereApproach - truthApproach).norm());
  INFO("spheroid: centre off " << (fit->centerMm - ap.c).norm() << " mm, a " << fit->radiusMm << ", k "
                               << fit->aspect << ", approach off " << (approach - truthApproach).norm()
                               << ", σ " << spheroidApproachSigma(*fit));
  CHECK((fit->centerMm - ap.c).norm() < 1.0);
  CHECK((fit->centerMm - ap.c).norm() < 0.5 * sphereCentreErr);
  CHECK(std::abs(fit->radiusMm - ap.a) < 1.0);
  CHECK(std::abs(fit->aspect - ap.k) < 0.04);
  CHECK((approach - truthApproach).norm() < 0.4);
  CHECK(normal.dot(truthNormal) > 0.999);
  CHECK(fit->rmsMm < 0.4);
  const double sigma = spheroidApproachSigma(*fit);
  CHECK(sigma > 0.0);
  CHECK((approach - truthApproach).norm() < 5.0 * sigma + 0.05);
}

TEST_CASE("The approach point is where the sight line to the centre enters the surface", "[geometry][spheroid]") {
  Eigen::Vector3d p;
  Eigen::Vector3d n;
  // A sphere (aspect 1): the point at radius in front of the centre, the normal towards us.
  REQUIRE(spheroidApproach({0.0, 0.0, 1000.0}, 40.0, 1.0, {0, -1, 0}, &p, &n));
  CHECK((p - Eigen::Vector3d(0, 0, 960)).norm() < 1e-9);
  CHECK((n - Eigen::Vector3d(0, 0, -1)).norm() < 1e-9);
  // An oblate spheroid seen along its equator: the equatorial radius in front.
  REQUIRE(spheroidApproach({0.0, 0.0, 1000.0}, 40.0, 0.8, {0, -1, 0}, &p, &n));
  CHECK(p.z() == Approx(960.0));
  // Seen along its stem axis: the polar radius in front.
  REQUIRE(spheroidApproach({0.0, 0.0, 1000.0}, 40.0, 0.8, {0, 0, -1}, &p, &n));
  CHECK(p.z() == Approx(968.0));
  CHECK_FALSE(spheroidApproach({0.0, 0.0, 0.0}, 40.0, 0.8, {0, -1, 0}, &p, &n));
}

namespace {

// The five-cut scan of `ap` (cuts `dxMm` apart about its centre, each in view over
// fromMm..toMm), the sphere fit and its spheroid refinement with the localizer's priors.
struct Refined {
  SphereFit sphere;
  SpheroidFit spheroid;
};

Refined refine(const Apple& ap, std::mt19937& rng, const std::vector<double>& dxMm, double fromMm, double toMm,
               double tiltSigmaRad = SpheroidPriors{}.stemTiltSigmaRad) {
  std::vector<Eigen::Vector3d> pts;
  std::vector<int> lines;
  int id = 0;
  for (double dx : dxMm) {
    const auto c = cut(ap, ap.c.x() + dx, 0.3, rng, fromMm, toMm);
    pts.insert(pts.end(), c.begin(), c.end());
    lines.insert(lines.end(), c.size(), id++);
  }
  SphereFitParams sp;
  sp.priorRadiusMm = 40.0;
  sp.priorRadiusSigmaMm = 6.0;
  sp.pointsPerIndependent = 5.0;
  sp.ransacBandMm = 3.0;
  sp.outlierMm = 5.0;
  auto sphere = fitSphere(pts, lines, {}, sp);
  REQUIRE(sphere.isOk());
  SpheroidPriors pr;  // aspect 0.9 ± 0.1 (the localizer's), tilt ± tiltSigmaRad
  pr.aspectSigma = 0.1;
  pr.stemTiltSigmaRad = tiltSigmaRad;
  pr.pointsPerIndependent = 5.0;
  auto fit = refineSpheroid(pts, std::vector<bool>(pts.size(), true), *sphere, pr);
  REQUIRE(fit.isOk());
  return {*sphere, *fit};
}

}  // namespace

TEST_CASE("Whether the points show a fruit other than round: the spheroid's weight against the sphere",
          "[geometry][spheroid]") {
  SECTION("an oblate fruit in full view is a spheroid beyond doubt") {
    Apple ap;  // aspect 0.86
    std::mt19937 rng(41);
    const Refined r = refine(ap, rng, {-30.0, -15.0, 0.0, 15.0, 30.0}, -60.0, 60.0);
    INFO("χ² sphere " << r.spheroid.sphereChiSquare << ", spheroid " << r.spheroid.chiSquare);
    CHECK(r.spheroid.chiSquare < r.spheroid.sphereChiSquare);
    CHECK(spheroidWeight(r.spheroid) > 0.99);
  }
  SECTION("a round fruit seen through a gap: the sphere keeps its diameter, the aspect prior would bend it") {
    Apple ap;
    ap.k = 1.0;
    ap.a = 36.0;
    // Three cuts, each in view over 30 mm below the centre's height: a small cap.
    double sphereErr = 0.0;
    double spheroidErr = 0.0;
    double blendedErr = 0.0;
    double weight = 0.0;
    constexpr int kSeeds = 8;
    for (int seed = 1; seed <= kSeeds; ++seed) {
      std::mt19937 rng(static_cast<unsigned>(seed));
      const Refined r = refine(ap, rng, {-12.0, 0.0, 12.0}, 0.0, 30.0);
      const double w = spheroidWeight(r.spheroid);
      weight += w / kSeeds;
      sphereErr += std::abs(2.0 * r.sphere.radiusMm - 2.0 * ap.a) / kSeeds;
      spheroidErr += std::abs(2.0 * r.spheroid.radiusMm - 2.0 * ap.a) / kSeeds;
      blendedErr += std::abs(w * 2.0 * r.spheroid.radiusMm + (1.0 - w) * 2.0 * r.sphere.radiusMm - 2.0 * ap.a) / kSeeds;
    }
    INFO("mean weight " << weight << "; diameter error: sphere " << sphereErr << ", spheroid " << spheroidErr
                        << ", weighed " << blendedErr << " mm");
    CHECK(weight < 0.5);
    CHECK(blendedErr < spheroidErr);
  }
}

TEST_CASE("A fruit whose stem leans far from vertical: a wider tilt prior lets the lines set the tilt",
          "[geometry][spheroid]") {
  // An oblate fruit (0.8) whose stem leans 50° towards the camera and sideways (the hard
  // worlds draw leans up to 55-60°), seen on three lines over a 45 mm band, as through a
  // gap in the leaves. At the old ScanParams::stemTiltSigmaDeg, 20° (a 50° lean at 2.5σ),
  // the prior bent the stem back towards vertical and the centre came out 2.7 mm off; at the
  // localizer's 30° the lines set the tilt nearer the truth and the centre is 2.0 mm off,
  // the approach point 1.2 mm off (1.6 at 20°) (docs/geometry.md, "The stem's tilt").
  Apple ap;
  ap.k = 0.8;
  ap.s =
      Eigen::AngleAxisd(50.0 * M_PI / 180.0, Eigen::Vector3d(1.0, 0.0, 1.0).normalized()) * Eigen::Vector3d(0, -1, 0);
  Eigen::Vector3d truthApproach;
  Eigen::Vector3d truthNormal;
  REQUIRE(spheroidApproach(ap.c, ap.a, ap.k, ap.s, &truthApproach, &truthNormal));
  std::mt19937 rngNarrow(5);
  std::mt19937 rngWide(5);  // the same points for both
  const std::vector<double> dx{-20.0, -5.0, 10.0};
  const double wideDeg = localize::ScanParams{}.stemTiltSigmaDeg;
  const Refined narrow = refine(ap, rngNarrow, dx, -25.0, 20.0, 20.0 * M_PI / 180.0);
  const Refined wide = refine(ap, rngWide, dx, -25.0, 20.0, wideDeg * M_PI / 180.0);
  const auto approachErr = [&](const SpheroidFit& f) {
    Eigen::Vector3d p;
    Eigen::Vector3d n;
    REQUIRE(spheroidApproach(f.centerMm, f.radiusMm, f.aspect, f.stemAxis, &p, &n));
    return (p - truthApproach).norm();
  };
  const auto tiltDeg = [](const SpheroidFit& f) { return std::acos(std::abs(f.stemAxis.y())) * 180.0 / M_PI; };
  const double centreNarrow = (narrow.spheroid.centerMm - ap.c).norm();
  const double centreWide = (wide.spheroid.centerMm - ap.c).norm();
  const double approachNarrow = approachErr(narrow.spheroid);
  const double approachWide = approachErr(wide.spheroid);
  const double sigmaWide = spheroidApproachSigma(wide.spheroid);
  INFO("tilt σ 20°: centre off " << centreNarrow << " mm, approach off " << approachNarrow << " mm, σ "
                                 << spheroidApproachSigma(narrow.spheroid) << ", tilt " << tiltDeg(narrow.spheroid));
  INFO("tilt σ " << wideDeg << "°: centre off " << centreWide << " mm, approach off " << approachWide << " mm, σ "
                 << sigmaWide << ", tilt " << tiltDeg(wide.spheroid));
  CHECK(centreNarrow > 2.0);
  CHECK(centreWide < 0.8 * centreNarrow);
  CHECK(approachWide < approachNarrow);
  CHECK(approachWide < sigmaWide);
  CHECK(std::abs(tiltDeg(wide.spheroid) - 50.0) < std::abs(tiltDeg(narrow.spheroid) - 50.0));
}
