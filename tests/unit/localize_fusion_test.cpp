// Fusion of the lines into an apple estimate, on synthetic 3D lines: the laser plane at
// each stop cut with a known sphere, the camera-facing part kept, depth noise along the
// ray, leaves in front. No rendering here (localize_sim_test.cpp does that end to end).
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <functional>
#include <random>

#include "localize/localizer.h"
#include "sim/scene.h"

using namespace alacs;

namespace {

struct Leaf {
  Eigen::Vector3d centerMm;
  double radiusMm;  // a disc facing the camera
};

// observe() reports rows ascending.
localize::LineObservation sortedByRow(const localize::LineObservation& obs) {
  std::vector<size_t> order(obs.pointsMm.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return obs.pixels[a].rowPx < obs.pixels[b].rowPx; });
  localize::LineObservation sorted = obs;
  for (size_t i = 0; i < order.size(); ++i) {
    sorted.pointsMm[i] = obs.pointsMm[order[i]];
    sorted.pixels[i] = obs.pixels[order[i]];
  }
  return sorted;
}

// The observation of one stop: points of the plane ∩ sphere circle that the camera sees,
// one per image row, with noise along the viewing ray; rows hidden by a leaf become leaf
// points instead.
localize::LineObservation lineOf(const geometry::Calibration& cal, const Eigen::Vector3d& c, double r, double slideMm,
                                 double noiseMm, const std::vector<Leaf>& leaves, std::mt19937& rng) {
  localize::LineObservation obs;
  obs.slideMm = slideMm;
  const Eigen::Vector3d n = cal.laser.planeNormal;
  const double delta = n.dot(c) - cal.laser.planeOffsetAt(slideMm);
  if (std::abs(delta) >= r) return obs;
  const Eigen::Vector3d c0 = c - delta * n;
  const double rho = std::sqrt(r * r - delta * delta);
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  std::normal_distribution<double> noise(0.0, noiseMm);
  int lastRow = -1 << 30;
  for (int i = 0; i < 20000; ++i) {
    const double phi = 2.0 * M_PI * i / 20000.0;
    Eigen::Vector3d p = c0 + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
    if ((p - c).dot(-p) <= 0.0) continue;  // faces away from the camera
    const geometry::PixelPoint px = geometry::projectPoint(cal.camera, p);
    const int row = static_cast<int>(std::lround(px.rowPx));
    if (row == lastRow) continue;
    lastRow = row;
    // A leaf disc in front hides the point; the laser then draws on the leaf.
    for (const Leaf& leaf : leaves) {
      const double t = leaf.centerMm.z() / p.z();
      if ((t * p - leaf.centerMm).norm() < leaf.radiusMm) {
        // The laser plane meets the leaf (z = leaf z) at the same row, roughly.
        const Eigen::Vector3d dir = p.normalized();
        p = p - (p.z() - leaf.centerMm.z()) / dir.z() * dir;
        break;
      }
    }
    p += noise(rng) * p.normalized();
    obs.pointsMm.push_back(p);
    obs.pixels.push_back(geometry::projectPoint(cal.camera, p));
  }
  return sortedByRow(obs);
}

// The fruit's line at each of `stopsMm`, its points kept only at the stops in `seenAt` (a
// leaf hides the fruit at the others: the line lies on the leaf, outside the gate).
std::vector<localize::LineObservation> linesSeenAt(const geometry::Calibration& cal, const Eigen::Vector3d& c, double r,
                                                   const std::vector<double>& stopsMm,
                                                   const std::vector<double>& seenAt, std::mt19937& rng) {
  std::vector<localize::LineObservation> lines;
  for (double s : stopsMm) {
    localize::LineObservation l = lineOf(cal, c, r, s, 0.4, {}, rng);
    if (std::find(seenAt.begin(), seenAt.end(), s) == seenAt.end()) {
      l.pointsMm.clear();
      l.pixels.clear();
    }
    lines.push_back(std::move(l));
  }
  return lines;
}

// One stop's line on a spheroid about a vertical stem (y): equatorial radius a, polar
// a·aspect; the plane's curve sampled along rays from the centre's foot in the plane, the
// camera-facing points kept, one per image row, with noise along the viewing ray.
localize::LineObservation spheroidLineOf(const geometry::Calibration& cal, const Eigen::Vector3d& c, double a,
                                         double aspect, double slideMm, double noiseMm, std::mt19937& rng) {
  localize::LineObservation obs;
  obs.slideMm = slideMm;
  const Eigen::Vector3d n = cal.laser.planeNormal;
  const Eigen::Vector3d c0 = c - (n.dot(c) - cal.laser.planeOffsetAt(slideMm)) * n;
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  const Eigen::Vector3d inv(1.0 / (a * a), 1.0 / (a * a * aspect * aspect), 1.0 / (a * a));  // x, y (stem), z
  const Eigen::Vector3d q = c0 - c;
  const double qc = q.cwiseProduct(q).dot(inv) - 1.0;
  std::normal_distribution<double> noise(0.0, noiseMm);
  int lastRow = -1 << 30;
  for (int i = 0; i < 20000; ++i) {
    const double phi = 2.0 * M_PI * i / 20000.0;
    const Eigen::Vector3d d = std::cos(phi) * e1 + std::sin(phi) * e2;
    const double qa = d.cwiseProduct(d).dot(inv);
    const double qb = 2.0 * q.cwiseProduct(d).dot(inv);
    const double disc = qb * qb - 4.0 * qa * qc;
    if (disc <= 0.0) continue;  // this ray misses the fruit's section
    Eigen::Vector3d p = c0 + (-qb + std::sqrt(disc)) / (2.0 * qa) * d;
    if ((p - c).cwiseProduct(inv).dot(-p) <= 0.0) continue;  // faces away from the camera
    const int row = static_cast<int>(std::lround(geometry::projectPoint(cal.camera, p).rowPx));
    if (row == lastRow) continue;
    lastRow = row;
    p += noise(rng) * p.normalized();
    obs.pointsMm.push_back(p);
    obs.pixels.push_back(geometry::projectPoint(cal.camera, p));
  }
  return sortedByRow(obs);
}

// Each stop's line over two fruit of the same radius: a's (behind `leavesOnA`, if any),
// then b's, in one observation.
std::vector<localize::LineObservation> twoFruitLines(const geometry::Calibration& cal, const localize::ScanPlan& plan,
                                                     const Eigen::Vector3d& a, const Eigen::Vector3d& b, double r,
                                                     double noiseMm, const std::vector<Leaf>& leavesOnA,
                                                     std::mt19937& rng) {
  std::vector<localize::LineObservation> lines;
  for (double s : plan.stopsMm) {
    localize::LineObservation la = lineOf(cal, a, r, s, noiseMm, leavesOnA, rng);
    const localize::LineObservation lb = lineOf(cal, b, r, s, noiseMm, {}, rng);
    la.pointsMm.insert(la.pointsMm.end(), lb.pointsMm.begin(), lb.pointsMm.end());
    la.pixels.insert(la.pixels.end(), lb.pixels.begin(), lb.pixels.end());
    lines.push_back(la);
  }
  return lines;
}

struct Case {
  geometry::Calibration cal = sim::defaultScene().truth;
  localize::ScanParams scan = localize::ScanParams::paperScan();  // the cases were built on it
  Eigen::Vector3d center{15.0, -10.0, 1300.0};
  double radius = 38.0;
};

}  // namespace

TEST_CASE("Sphere fusion of five lines: centre, diameter, approach point, honest σ", "[localize]") {
  Case k;
  std::mt19937 rng(21);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center + Eigen::Vector3d(9, -7, 14), 200.0);
  REQUIRE(plan.isOk());
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng));
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  REQUIRE(est->sphereFit);
  const Eigen::Vector3d approachTruth = k.center - k.radius * k.center.normalized();
  const double centreErr = (est->centerMm - k.center).norm();
  const double approachErr = (est->approachMm - approachTruth).norm();
  INFO("centre " << centreErr << " approach " << approachErr << " d " << est->diameterMm << " σ " << est->sigmaMm
                 << " σc " << est->centerSigmaMm << " conf " << est->confidencePct);
  CHECK(centreErr < 1.0);
  CHECK(approachErr < 0.5);
  CHECK(std::abs(est->diameterMm - 2 * k.radius) < 1.5);
  CHECK(est->linesUsed >= 4);
  CHECK(est->sigmaMm > 0.0);
  CHECK(est->sigmaMm < 1.0);
  CHECK(approachErr < 4.0 * est->sigmaMm);
  CHECK(est->centerSigmaMm > est->sigmaMm);  // the front of the fruit is better known than its centre
  CHECK(est->confidencePct > 90.0);
  CHECK(est->occlusionPct < 10.0);
  // The approach normal points from the fruit towards the sensor.
  CHECK(est->approachNormal.dot(-approachTruth.normalized()) > 0.999);
  // Where the rough position says: the target beyond doubt, σ the fit's own, and with the
  // doubt model off the same numbers.
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kNone);
  CHECK(est->targetPct > 95.0);
  CHECK(est->sigmaMm == Approx(est->fitSigmaMm));
  localize::ScanParams off = k.scan;
  off.otherObjectPrior = 0.0;
  auto plain = localize::Localizer(k.cal, image::LleParams{}, off).estimate(*plan, lines);
  REQUIRE(plain.isOk());
  CHECK(plain->sigmaMm == Approx(est->sigmaMm));
  CHECK(plain->confidencePct == Approx(est->confidencePct).epsilon(0.05));
}

TEST_CASE("A large prolate fruit, whose sphere is larger than any fruit's width, is found", "[localize]") {
  // 104 mm across and 114 mm tall (aspect 1.10, the prior's 2σ; stem up), seen whole on
  // the paper's five lines. The vertical lines cut it along its flatter meridians (c²/a =
  // 62.9 mm at the equator), so the sphere through them comes out above maxRadiusMm
  // (52.5) and was refused as no fruit: one line and the priors spoke for it, its face
  // 15.4 mm off. The search now takes spheres up to sphereMaxRadiusMm (57.75 mm).
  Case k;
  const double a = 52.0;
  const double aspect = 1.10;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center + Eigen::Vector3d(6, -5, 10), 200.0);
  REQUIRE(plan.isOk());
  std::mt19937 rng(5);
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) lines.push_back(spheroidLineOf(k.cal, k.center, a, aspect, s, 0.4, rng));
  CHECK(k.scan.sphereMaxRadiusMm() == Approx(57.75));
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  const Eigen::Vector3d approachTruth = k.center - a * k.center.normalized();  // the face, at the equator
  INFO("approach " << (est->approachMm - approachTruth).norm() << " d " << est->diameterMm << " lines "
                   << est->linesUsed << " σ " << est->sigmaMm << " conf " << est->confidencePct);
  CHECK(est->sphereFit);
  CHECK(est->linesUsed >= 4);
  CHECK((est->approachMm - approachTruth).norm() < 3.0);
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kNone);
}

TEST_CASE("A sphere larger than any fruit goes out at the largest fruit's width, its σ taking the excess",
          "[localize]") {
  // A ball 112 mm across (radius 56: within sphereMaxRadiusMm, beyond maxRadiusMm) on the
  // paper's five lines: the sphere fit takes it, the spheroid refinement (bounded by
  // maxRadiusMm) does not. Its diameter is reported as the largest fruit's, 105 mm, and the
  // 7 mm the sphere said beyond it are in the diameter's σ, so the truth lies within it.
  Case k;
  const double r = 56.0;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center + Eigen::Vector3d(6, -5, 10), 200.0);
  REQUIRE(plan.isOk());
  std::mt19937 rng(8);
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) lines.push_back(lineOf(k.cal, k.center, r, s, 0.4, {}, rng));
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  INFO("d " << est->diameterMm << " σd " << est->diameterSigmaMm << " lines " << est->linesUsed << " sphere weight "
            << est->sphereWeight);
  REQUIRE(est->sphereFit);
  CHECK(est->diameterMm == Approx(2.0 * k.scan.maxRadiusMm));
  CHECK(est->diameterSigmaMm > 2.0 * r - 2.0 * k.scan.maxRadiusMm - 0.5);
  CHECK(std::abs(2.0 * r - est->diameterMm) <= 2.0 * est->diameterSigmaMm);
  // The fitted surface keeps its own radius: what tells points on it from others
  // (the second pass's stops that saw it, other surfaces in the gate).
  CHECK(est->surfaceRadiusMm() == Approx(r).margin(1.0));
  // The position is the sphere's: the face within a millimetre.
  CHECK((est->approachMm - (k.center - r * k.center.normalized())).norm() < 1.0);
}

TEST_CASE("Leaves in front of the fruit: the robust fit keeps to the skin", "[localize]") {
  Case k;
  std::mt19937 rng(22);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center + Eigen::Vector3d(-12, 10, -18), 200.0);
  REQUIRE(plan.isOk());
  // Two leaves 25–40 mm in front of the skin hide about half of the fruit.
  const std::vector<Leaf> leaves{{k.center + Eigen::Vector3d(-20, -15, -k.radius - 25), 28.0},
                                 {k.center + Eigen::Vector3d(25, 20, -k.radius - 40), 20.0}};
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, leaves, rng));
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  REQUIRE(est->sphereFit);
  const Eigen::Vector3d approachTruth = k.center - k.radius * k.center.normalized();
  INFO("centre " << (est->centerMm - k.center).norm() << " approach " << (est->approachMm - approachTruth).norm()
                 << " d " << est->diameterMm << " occlusion " << est->occlusionPct << " conf " << est->confidencePct);
  CHECK((est->centerMm - k.center).norm() < 3.0);
  CHECK((est->approachMm - approachTruth).norm() < 1.5);
  CHECK(std::abs(est->diameterMm - 2 * k.radius) < 4.0);
  CHECK(est->occlusionPct > 15.0);
}

TEST_CASE("A neighbour showing more skin than the occluded target is not taken for it", "[localize]") {
  Case k;
  std::mt19937 rng(25);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  const Eigen::Vector3d neighbour = k.center + Eigen::Vector3d(0.0, 78.0, 10.0);  // the one below it, touching
  // The rough position is 20 mm off, towards the neighbour.
  auto plan = loc.plan(k.center + Eigen::Vector3d(6, 18, -8), 200.0);
  REQUIRE(plan.isOk());
  // A leaf hides half of the target; the neighbour is in full view.
  const std::vector<Leaf> leaves{{k.center + Eigen::Vector3d(0, -12, -k.radius - 20), 27.0}};
  std::vector<localize::LineObservation> lines;
  size_t targetPoints = 0;
  size_t neighbourPoints = 0;
  for (double s : plan->stopsMm) {
    localize::LineObservation l = lineOf(k.cal, k.center, k.radius, s, 0.4, leaves, rng);
    const localize::LineObservation n = lineOf(k.cal, neighbour, k.radius, s, 0.4, {}, rng);
    targetPoints += l.pointsMm.size();
    for (size_t i = 0; i < n.pointsMm.size(); ++i) {
      if ((n.pointsMm[i] - plan->roughMm).norm() > k.scan.gateMm) continue;  // observe()'s gate
      l.pointsMm.push_back(n.pointsMm[i]);
      l.pixels.push_back(n.pixels[i]);
      ++neighbourPoints;
    }
    lines.push_back(l);
  }
  INFO("target points (skin and leaf) " << targetPoints << ", neighbour points in the gate " << neighbourPoints);
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  REQUIRE(est->sphereFit);
  INFO("centre error " << (est->centerMm - k.center).norm() << " est " << est->centerMm.transpose() << " d " << est->diameterMm << " target " << k.center.transpose() << " lines " << est->linesUsed << " pts " << est->pointsUsed);
  CHECK((est->centerMm - k.center).norm() < 4.0);
}

TEST_CASE("One line alone: the paper's single-line estimate", "[localize]") {
  Case k;
  std::mt19937 rng(23);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  const double middle = plan->stopsMm[plan->stopsMm.size() / 2];
  std::vector<localize::LineObservation> lines{lineOf(k.cal, k.center, k.radius, middle, 0.4, {}, rng)};
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  CHECK_FALSE(est->sphereFit);
  CHECK(est->linesUsed == 1);
  const Eigen::Vector3d approachTruth = k.center - k.radius * k.center.normalized();
  // The line through the middle of the fruit: its middle is near the approach point, but
  // not on it (the median row is not the point nearest the sensor): millimetres off.
  CHECK((est->approachMm - approachTruth).norm() < 10.0);
  // One line's σ is what one line misses in practice (13-16 mm on the benchmark), never
  // the few millimetres of its geometry alone.
  CHECK(est->sigmaMm >= 15.0);
  CHECK(est->confidencePct < 60.0);
  CHECK(loc.estimate(*plan, {}).status().code() == Error::kNotFound);
}

TEST_CASE("One line far beyond the rough position's error is not the target", "[localize]") {
  // The target is hidden; the only line lies on a fruit 80 mm to the side (within the
  // 90 mm gate). Its sphere is no estimate of the target: the rough position's own is.
  Case k;
  k.scan.roughSigmaMm = 8.0;  // gate: 32 mm
  std::mt19937 rng(29);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  const Eigen::Vector3d other = k.center + Eigen::Vector3d(80.0, 0.0, 5.0);
  const double slide = k.cal.laser.slideForPoint(other);
  std::vector<localize::LineObservation> lines{lineOf(k.cal, other, 36.0, slide, 0.3, {}, rng)};
  // The localizer without the gate (nor the rough position for a fit that is another
  // object) takes the line's fruit: a one-line sphere, its offset from the line's plane the
  // priors', beyond the gate (36 mm from the target with spheres up to sphereMaxRadiusMm,
  // 42 mm below 52.5; the gate is 32 mm).
  localize::ScanParams open = k.scan;
  open.roughGateSigmas = 0.0;
  open.roughWhenFarFromRough = false;
  auto taken = localize::Localizer(k.cal, image::LleParams{}, open).estimate(*plan, lines);
  REQUIRE(taken.isOk());
  INFO("ungated centre " << taken->centerMm.transpose());
  CHECK((taken->centerMm - k.center).norm() > k.scan.roughGateSigmas * k.scan.roughSigmaMm);
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  CHECK_FALSE(est->sphereFit);
  CHECK(est->linesUsed == 0);
  CHECK((est->centerMm - k.center).norm() < 1e-9);
  CHECK(est->sigmaMm >= std::sqrt(3.0) * k.scan.roughSigmaMm);  // the rough position's error
  CHECK(est->confidencePct < 50.0);
}

TEST_CASE("The paper's candidate score P = w1·N − w2·Δd", "[localize]") {
  std::vector<localize::PaperCandidate> c(3);
  c[0].pixelCount = 300;  // long line far from the expected centre
  c[0].distancePx = 120;
  c[1].pixelCount = 250;  // a bit shorter, close to it
  c[1].distancePx = 10;
  c[2].pixelCount = 40;   // a leaf fragment right on it
  c[2].distancePx = 0;
  CHECK(localize::Localizer::selectCandidate(c, 1.0, 0.0) == 0);   // pixel count only
  CHECK(localize::Localizer::selectCandidate(c, 1.0, 1.0) == 1);
  CHECK(localize::Localizer::selectCandidate(c, 0.0, 1.0) == 2);   // distance only
  CHECK(localize::Localizer::selectCandidate(c, 1.0, 3.0) == 1);

  // On real lines the candidates carry the line's middle and its pixel count.
  Case k;
  std::mt19937 rng(24);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng));
  const auto cands = loc.paperCandidates(*plan, lines);
  REQUIRE(cands.size() >= 3);
  const size_t best = localize::Localizer::selectCandidate(cands, k.scan.paperW1, k.scan.paperW2);
  // The middle stop's line passes closest to the centre and is the longest.
  CHECK(cands[best].line == plan->stopsMm.size() / 2);
}

TEST_CASE("A line seen twice (a replay serving a recorded frame again) counts once", "[localize]") {
  Case k;
  std::mt19937 rng(41);
  const localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  std::vector<localize::LineObservation> lines;
  for (size_t i = 1; i < 3; ++i) lines.push_back(lineOf(k.cal, k.center, k.radius, plan->stopsMm[i], 0.4, {}, rng));
  const Result<localize::AppleEstimate> once = loc.estimate(*plan, lines);
  REQUIRE(once.isOk());
  REQUIRE(once->linesUsed == 2);
  // The same two frames again (0.01 mm apart: the replay's recorded position), interleaved.
  std::vector<localize::LineObservation> twice{lines[0], lines[0], lines[1], lines[1], lines[0]};
  twice[1].slideMm += 0.01;
  const Result<localize::AppleEstimate> again = loc.estimate(*plan, twice);
  REQUIRE(again.isOk());
  CHECK(again->linesUsed == 2);
  CHECK(again->pointsUsed == once->pointsUsed);
  CHECK((again->centerMm - once->centerMm).norm() < 1e-9);
  CHECK(again->sigmaMm == Approx(once->sigmaMm));
  // Two lines: the adaptive scan still asks for its second pass.
  CHECK_FALSE(loc.followUpStops(*plan, twice, again, 200.0).empty());
}

// The paper's scan planned on the Case's fruit (the second pass's tests).
struct PaperScan {
  Case k;
  localize::Localizer loc{k.cal, image::LleParams{}, k.scan};
  localize::ScanPlan plan;
  PaperScan() {
    Result<localize::ScanPlan> p = loc.plan(k.center, 200.0);
    REQUIRE(p.isOk());
    plan = *p;
  }
};

TEST_CASE("The adaptive second pass: denser stops where the first pass saw the fruit, only when it is in doubt",
          "[localize]") {
  // The hidden-fruit case of the paper's scan: a leaf leaves one line on the target.
  const PaperScan c;
  const auto& [k, loc, plan] = c;
  std::mt19937 rng(31);
  REQUIRE(plan.stopsMm.size() == 5);
  const double s0 = plan.stopsMm.front();
  const double middle = plan.stopsMm[2];
  REQUIRE(middle == Approx(s0 + 40.0));
  std::vector<localize::LineObservation> lines{lineOf(k.cal, k.center, k.radius, middle, 0.4, {}, rng)};
  const Result<localize::AppleEstimate> one = loc.estimate(plan, lines);
  REQUIRE(one.isOk());
  REQUIRE(one->linesUsed == 1);
  const std::vector<double> more = loc.followUpStops(plan, lines, one, 200.0);
  // The fruit was seen at the middle stop only: the thirds of the spacing within one
  // spacing of it, none where the first pass's other stops saw nothing; one sweep back
  // from the far end (the first pass went forward).
  const double third = 20.0 / 3.0;
  const std::vector<double> expected{middle + 2 * third, middle + third, middle - third, middle - 2 * third};
  REQUIRE(more.size() == expected.size());
  for (size_t i = 0; i < more.size(); ++i) CHECK(more[i] == Approx(expected[i]).margin(1e-9));
  // Those stops give the fruit the lines it lacked: the estimate now rests on several.
  for (double s : more) lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng));
  const Result<localize::AppleEstimate> all = loc.estimate(plan, lines);
  REQUIRE(all.isOk());
  CHECK(all->sphereFit);
  CHECK(all->linesUsed >= 4);
  CHECK(all->centerSigmaMm < one->centerSigmaMm);
  CHECK((all->centerMm - k.center).norm() < 3.0);
  // Enough lines, the fruit not mostly hidden, no rival: nothing more. No estimate
  // (nothing lit near the rough position): nothing more either. Off: nothing.
  REQUIRE(all->occlusionPct < k.scan.followUpHiddenPct);
  REQUIRE(all->doubt == localize::AppleEstimate::Doubt::kNone);
  CHECK(loc.followUpStops(plan, lines, all, 200.0).empty());
  CHECK(
      loc.followUpStops(plan, lines, Result<localize::AppleEstimate>(Status(Error::kNotFound, "none")), 200.0).empty());
  localize::ScanParams off = k.scan;
  off.followUpMaxStops = 0;
  CHECK(localize::Localizer(k.cal, image::LleParams{}, off).followUpStops(plan, lines, one, 200.0).empty());
  // At most followUpMaxStops, the ones nearest the middle of what was seen.
  localize::ScanParams few = k.scan;
  few.followUpMaxStops = 2;
  const std::vector<double> two =
      localize::Localizer(k.cal, image::LleParams{}, few).followUpStops(plan, {lines[0]}, one, 200.0);
  REQUIRE(two.size() == 2);
  CHECK(two[0] == Approx(middle + third));
  CHECK(two[1] == Approx(middle - third));
}

TEST_CASE("The second pass looks through the gaps the first pass saw the fruit through before the stops between them",
          "[localize]") {
  // The fruit seen at s0 + 20 and s0 + 60, a leaf hiding it at s0 + 40 between them.
  const PaperScan c;
  const auto& [k, loc, plan] = c;
  std::mt19937 rng(43);
  const double third = 20.0 / 3.0;
  const std::vector<localize::LineObservation> lines =
      linesSeenAt(k.cal, k.center, k.radius, plan.stopsMm, {plan.stopsMm[1], plan.stopsMm[3]}, rng);
  const Result<localize::AppleEstimate> est = loc.estimate(plan, lines);
  REQUIRE(est.isOk());
  REQUIRE(est->linesUsed == 2);
  // Room for four: the thirds beside the two stops that saw it, not the four nearest the
  // middle of the two (s0 + 40 ± 6.7 and ± 13.3, where the leaf is).
  localize::ScanParams four = k.scan;
  four.followUpMaxStops = 4;
  const std::vector<double> beside =
      localize::Localizer(k.cal, image::LleParams{}, four).followUpStops(plan, lines, est, 200.0);
  const double s1 = plan.stopsMm[1];
  const double s3 = plan.stopsMm[3];
  const std::vector<double> expected{s3 + third, s3 - third, s1 + third, s1 - third};
  REQUIRE(beside.size() == expected.size());
  for (size_t i = 0; i < beside.size(); ++i) CHECK(beside[i] == Approx(expected[i]).margin(1e-9));
  // Room for six: the two nearest the middle join them.
  const std::vector<double> six = loc.followUpStops(plan, lines, est, 200.0);
  REQUIRE(six.size() == 6);
  CHECK(std::count_if(six.begin(), six.end(), [&](double s) { return std::abs(s - (s1 + 20.0)) < 7.0; }) == 2);
}

TEST_CASE("The second pass's reasons: a mostly hidden fruit, two surfaces, far from the rough position, an unsure size",
          "[localize]") {
  const PaperScan c;
  const auto& [k, loc, plan] = c;
  std::mt19937 rng(37);
  const double s0 = plan.stopsMm.front();
  // Two stops see the fruit (s0 + 20 and s0 + 40), the three others nothing: a leaf.
  std::vector<localize::LineObservation> lines =
      linesSeenAt(k.cal, k.center, k.radius, plan.stopsMm, {plan.stopsMm[1], plan.stopsMm[2]}, rng);
  Result<localize::AppleEstimate> est = loc.estimate(plan, lines);
  REQUIRE(est.isOk());
  REQUIRE(est->linesUsed == 2);
  // Few lines: the thirds from one spacing below the first seen stop to one above the last.
  const std::vector<double> fromTwo = loc.followUpStops(plan, lines, est, 200.0);
  REQUIRE(fromTwo.size() == 6);
  for (double s : fromTwo) {
    CHECK(s > s0 - 1e-9);
    CHECK(s < s0 + 60.0 + 1e-9);
  }
  // Enough lines: a fit that the doubt model or the hidden share puts in doubt still asks.
  localize::AppleEstimate sure = *est;
  sure.linesUsed = 4;
  sure.occlusionPct = k.scan.followUpHiddenPct - 1.0;
  CHECK(loc.followUpStops(plan, lines, sure, 200.0).empty());
  localize::AppleEstimate hidden = sure;
  hidden.occlusionPct = k.scan.followUpHiddenPct;
  CHECK(loc.followUpStops(plan, lines, hidden, 200.0) == fromTwo);
  localize::AppleEstimate rival = sure;
  rival.doubt = localize::AppleEstimate::Doubt::kTwoSurfaces;
  CHECK(loc.followUpStops(plan, lines, rival, 200.0) == fromTwo);
  // A fit more likely a neighbour, away from the rough position: the new stops look for the
  // target across a fruit's width round the rough position, not where the neighbour was seen.
  localize::AppleEstimate far = sure;
  far.doubt = localize::AppleEstimate::Doubt::kFarFromRough;
  const std::vector<double> around = loc.followUpStops(plan, lines, far, 200.0);
  REQUIRE_FALSE(around.empty());
  const Eigen::Vector3d& n = k.cal.laser.planeNormal;
  const double a = k.cal.laser.slideForPoint(plan.roughMm - k.scan.maxAppleRadiusMm * n);
  const double b = k.cal.laser.slideForPoint(plan.roughMm + k.scan.maxAppleRadiusMm * n);
  for (double s : around) {
    CHECK(s >= std::min(a, b) - 1e-9);
    CHECK(s <= std::max(a, b) + 1e-9);
  }
  // A fit the doubt model still takes for the target, but farther from the rough position
  // than followUpFarSigmas of its σ (a touching neighbour's distance): the same stops round
  // the rough position; nearer, none. Off (0), none either way.
  const double farMm = k.scan.followUpFarSigmas * k.scan.roughSigmaMm;
  REQUIRE(farMm > 0.0);
  localize::AppleEstimate distant = sure;
  distant.centerMm = plan.roughMm + (farMm + 1.0) * Eigen::Vector3d::UnitY();
  CHECK(loc.followUpStops(plan, lines, distant, 200.0) == around);
  localize::AppleEstimate within = sure;
  within.centerMm = plan.roughMm + (farMm - 1.0) * Eigen::Vector3d::UnitY();
  CHECK(loc.followUpStops(plan, lines, within, 200.0).empty());
  localize::ScanParams nearOnly = k.scan;
  nearOnly.followUpFarSigmas = 0.0;
  CHECK(localize::Localizer(k.cal, image::LleParams{}, nearOnly).followUpStops(plan, lines, distant, 200.0).empty());
  // Nothing of the target seen: the cap is followUpUnseenMaxStops, so that the thirds
  // across its whole width round the rough position can be taken; where the fruit was
  // seen, followUpMaxStops still holds.
  REQUIRE(around.size() == static_cast<size_t>(k.scan.followUpUnseenMaxStops));
  localize::ScanParams wide = k.scan;
  wide.followUpUnseenMaxStops = 32;
  const localize::Localizer wideLoc(k.cal, image::LleParams{}, wide);
  const std::vector<double> across = wideLoc.followUpStops(plan, lines, far, 200.0);
  CHECK(across.size() > around.size());
  for (double s : around) CHECK(std::count(across.begin(), across.end(), s) == 1);
  for (size_t i = 1; i < across.size(); ++i) CHECK(std::abs(across[i] - across[i - 1]) > 20.0 / 6.0);
  CHECK(wideLoc.followUpStops(plan, lines, est, 200.0) == fromTwo);
  localize::ScanParams notHidden = k.scan;
  notHidden.followUpHiddenPct = 0.0;  // not a reason
  CHECK(localize::Localizer(k.cal, image::LleParams{}, notHidden).followUpStops(plan, lines, hidden, 200.0).empty());
  // Only the size in doubt: the stops whose plane cuts the fruit well inside its limb.
  localize::ScanParams unsure = k.scan;
  unsure.followUpDiameterSigmaMm = 0.01;
  const localize::Localizer sizeLoc(k.cal, image::LleParams{}, unsure);
  REQUIRE(sure.diameterSigmaMm > 0.01);
  const std::vector<double> inside = sizeLoc.followUpStops(plan, lines, sure, 200.0);
  CHECK_FALSE(inside.empty());
  const double centreSlide = k.cal.laser.slideForPoint(sure.centerMm);
  const double limbSlide = 0.8 * 0.5 * sure.diameterMm / std::abs(k.cal.laser.planeNormal.x());
  for (double s : inside) CHECK(std::abs(s - centreSlide) <= limbSlide + 1e-6);
  CHECK(std::is_sorted(inside.rbegin(), inside.rend()));
}

TEST_CASE("A lone line at the pass's edge, the rough position standing in: the second pass looks round both",
          "[localize]") {
  // The rough position is off along the slide by more than the pass allows: the fruit lies
  // beyond the first stop, which alone lights it (a leaf hides it from the others). One
  // line is too little for a fit, and the rough position stands in, FAR_FROM_ROUGH.
  const PaperScan c;
  const auto& [k, loc, plan] = c;
  const Eigen::Vector3d& n = k.cal.laser.planeNormal;
  const double s0 = plan.stopsMm.front();
  const double third = 20.0 / 3.0;
  const Eigen::Vector3d fruit = k.center + (k.cal.laser.planeOffsetAt(s0 - 12.0) - n.dot(k.center)) * n;
  std::mt19937 rng(41);
  std::vector<localize::LineObservation> lines = linesSeenAt(k.cal, fruit, k.radius, plan.stopsMm, {s0}, rng);
  REQUIRE(lines.front().pointsMm.size() >= 3);
  // Built by hand: what estimate() gives when the widened search's fruit lies far off,
  // through points outside the gate (the background, leaves behind), which these lines do
  // not hold: the rough position stands in.
  localize::AppleEstimate rough;
  rough.centerMm = plan.roughMm;
  rough.diameterMm = 2.0 * k.radius;
  rough.doubt = localize::AppleEstimate::Doubt::kFarFromRough;
  CAPTURE((fruit - plan.roughMm).norm());
  const std::vector<double> more = loc.followUpStops(plan, lines, rough, 200.0);
  // The third beyond the first stop, nearest the lone line, is among the new stops (the
  // cap: nothing of the fruit fitted; without the line, those nearest the rough position's
  // slide fill it); none lies beyond one spacing below the line or beyond the span round
  // the rough position.
  REQUIRE(more.size() == static_cast<size_t>(k.scan.followUpUnseenMaxStops));
  const auto taken = [](const std::vector<double>& stops, double at) {
    return std::count_if(stops.begin(), stops.end(), [&](double s) { return std::abs(s - at) < 1e-9; });
  };
  CHECK(taken(more, s0 - third) == 1);
  const double a = k.cal.laser.slideForPoint(plan.roughMm - k.scan.maxAppleRadiusMm * n);
  const double b = k.cal.laser.slideForPoint(plan.roughMm + k.scan.maxAppleRadiusMm * n);
  for (double s : more) {
    CAPTURE(s);
    CHECK(s >= s0 - 20.0 - 1e-9);
    CHECK(s <= std::max(a, b) + 1e-9);
  }
  // Those stops light the fruit again: a fit of it on three lines or more.
  for (double s : more) lines.push_back(lineOf(k.cal, fruit, k.radius, s, 0.4, {}, rng));
  const Result<localize::AppleEstimate> after = loc.estimate(plan, lines);
  REQUIRE(after.isOk());
  CAPTURE(after->linesUsed, after->confidencePct, static_cast<int>(after->doubt));
  CHECK(after->sphereFit);
  CHECK(after->linesUsed >= 3);
  CHECK((after->centerMm - fruit).norm() < 3.0);
  // Two lines that saw something: a fit the rough position was preferred to, so what they
  // saw was likely another object; the new stops stay round the rough position.
  localize::LineObservation second = lineOf(k.cal, fruit, k.radius, s0, 0.4, {}, rng);
  second.slideMm = plan.stopsMm[1];
  std::vector<localize::LineObservation> two{lines.front(), second};
  const std::vector<double> round = loc.followUpStops(plan, two, rough, 200.0);
  REQUIRE_FALSE(round.empty());
  CHECK(taken(round, s0 - third) == 0);
  for (double s : round) {
    CHECK(s >= std::min(a, b) - 1e-9);
    CHECK(s <= std::max(a, b) + 1e-9);
  }
}

TEST_CASE("The second pass at the end of the stroke: clamped, never twice the same stop", "[localize]") {
  const PaperScan c;
  const auto& [k, loc, plan] = c;
  std::mt19937 rng(43);
  localize::ScanPlan atEnd = plan;
  atEnd.stopsMm = {120.0, 140.0, 160.0, 180.0, 200.0};
  // The fruit seen at the last stop only (no fit: the paper's candidate).
  std::vector<localize::LineObservation> lines{lineOf(k.cal, k.center, k.radius, plan.stopsMm[2], 0.4, {}, rng)};
  lines[0].slideMm = 200.0;
  const Result<localize::AppleEstimate> one =
      loc.estimate(plan, {lineOf(k.cal, k.center, k.radius, plan.stopsMm[2], 0.4, {}, rng)});
  REQUIRE(one.isOk());
  const std::vector<double> clamped = loc.followUpStops(atEnd, lines, one, 200.0);
  // 186.7 and 193.3 below it; the two beyond the stroke land on 200 and are dropped.
  REQUIRE(clamped.size() == 2);
  CHECK(clamped[0] == Approx(200.0 - 20.0 / 3.0));
  CHECK(clamped[1] == Approx(200.0 - 40.0 / 3.0));
}

TEST_CASE("Scan parameters are validated", "[localize]") {
  CHECK(localize::ScanParams{}.validate().isOk());
  // Each broken rule is refused naming its key. The fruit model: the prior within its
  // bounds, an aspect the spheroid refinement takes, spreads that are not zero, and the
  // aspect's 2σ below the refinement's largest (sphereMaxRadiusMm follows it).
  using P = localize::ScanParams;
  const std::vector<std::pair<std::function<void(P&)>, std::string>> broken = {
      {[](P& p) { p.paperW1 = p.paperW2 = 0.0; }, "paperW1"},
      {[](P& p) { p.gateMm = 80.0; }, "gate_mm"},
      {[](P& p) { p.roughSigmaMm = 20.0; }, "rough_sigma_mm"},
      {[](P& p) { p.priorRadiusMm = 5.0; }, "prior_radius_mm"},
      {[](P& p) { p.followUpMaxStops = 17; }, "follow_up_max_stops"},
      {[](P& p) { p.followUpUnseenMaxStops = 33; }, "follow_up_unseen_max_stops"},
      {[](P& p) { p.followUpFarSigmas = 0.5; }, "follow_up_far_sigmas"},
      {[](P& p) { p.followUpFarSigmas = 11.0; }, "follow_up_far_sigmas"},
      {[](P& p) { p.followUpHiddenPct = 101.0; }, "follow_up_hidden_pct"},
      {[](P& p) { p.leafGreenRatio = 0.5; }, "leaf_green_ratio"},
      {[](P& p) { p.leafGreenRatio = 1.0; }, "leaf_green_ratio"},
      {[](P& p) { p.followUpDiameterSigmaMm = -1.0; }, "follow_up_diameter_sigma_mm"},
      {[](P& p) { p.followUpMinLines = 0; }, "follow_up_min_lines"},
      {[](P& p) { p.priorRadiusMm = 55.0; }, "prior_radius_mm"},
      {[](P& p) { p.maxRadiusMm = 65.0; }, "max_radius_mm"},
      {[](P& p) { p.priorAspect = 1.3; }, "prior_aspect"},
      {[](P& p) { p.priorAspectSigma = 0.0; }, "prior_aspect_sigma"},
      {[](P& p) { p.priorAspect = 1.05; }, "prior_aspect_sigma"},
      {[](P& p) { p.stemTiltSigmaDeg = 0.0; }, "stem_tilt_sigma_deg"},
  };
  for (const auto& [breakIt, key] : broken) {
    P p;
    breakIt(p);
    INFO(key);
    CHECK(p.validate().reason().find(key) != std::string::npos);
  }
}

namespace {
// What observe() does with the gate: points beyond it (within the search) are kept apart.
void applyGate(localize::LineObservation& l, const Eigen::Vector3d& roughMm, const localize::ScanParams& sp) {
  localize::LineObservation g;
  g.slideMm = l.slideMm;
  for (size_t i = 0; i < l.pointsMm.size(); ++i) {
    const double d = (l.pointsMm[i] - roughMm).norm();
    if (d <= sp.gateMm) {
      g.pointsMm.push_back(l.pointsMm[i]);
      g.pixels.push_back(l.pixels[i]);
    } else if (d <= sp.searchMm) {
      g.outsidePointsMm.push_back(l.pointsMm[i]);
    }
  }
  l = std::move(g);
}

// The fruit's lines at the plan's stops, gated round `roughMm` as observe() gates them, and
// how many points they had before and after the gate.
struct GatedLines {
  std::vector<localize::LineObservation> lines;
  size_t seen = 0;
  size_t inGate = 0;
};
GatedLines gatedLinesOf(const Case& k, const localize::ScanPlan& plan, const Eigen::Vector3d& roughMm,
                        const localize::ScanParams& sp, std::mt19937& rng) {
  GatedLines out;
  for (double s : plan.stopsMm) {
    out.lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng));
    out.seen += out.lines.back().pointsMm.size();
    applyGate(out.lines.back(), roughMm, sp);
    out.inGate += out.lines.back().pointsMm.size();
  }
  return out;
}
}  // namespace

TEST_CASE("Nothing within the gate: the widened search fits the lines the scan saw", "[localize][widened]") {
  Case k;
  std::mt19937 rng(31);
  k.scan.gateMm = 40.0;  // narrow, so that a rough position 60 mm short leaves nothing in it
  const Eigen::Vector3d rough = k.center + Eigen::Vector3d(0.0, 0.0, -k.radius - 60.0);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(rough, 200.0);
  REQUIRE(plan.isOk());
  const std::vector<localize::LineObservation> lines = [&] {
    GatedLines g = gatedLinesOf(k, *plan, rough, k.scan, rng);
    REQUIRE(g.inGate == 0);
    return std::move(g.lines);
  }();

  localize::ScanParams gateOnly = k.scan;
  gateOnly.searchMm = 0.0;
  CHECK(localize::Localizer(k.cal, image::LleParams{}, gateOnly).estimate(*plan, lines).status().code() ==
        Error::kNotFound);

  // The fruit it finds goes out as found, though far beyond the RGB-D camera's error: unlike
  // a fit within the gate (ScanParams::roughWhenFarFromRough), finding what the rough
  // position missed is what the search is for.
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  INFO("centre error " << (est->centerMm - k.center).norm() << " mm, d " << est->diameterMm << ", conf "
                       << est->confidencePct);
  CHECK(est->sphereFit);
  CHECK(est->outsideGate);
  CHECK((est->centerMm - k.center).norm() < 2.0);
  CHECK(std::abs(est->diameterMm - 2 * k.radius) < 2.0);
  CHECK(est->confidencePct <= k.scan.outsideGateConfidencePct);
  // Far beyond the rough position's error: more likely another object than the target, so
  // σ spans the distance to where the rough position says the target is, and the bus says
  // AMBIGUOUS, FAR_FROM_ROUGH.
  const double away = (est->centerMm - rough).norm();
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK(est->targetPct < 50.0);
  CHECK(est->sigmaMm > 0.5 * away);
  CHECK(est->fitSigmaMm < 2.0);
  // Without the doubt model the same fit went out at the fit's own σ, a few tenths of a
  // millimetre, though nothing but the prior said it was the fruit the arm meant.
  localize::ScanParams plainScan = k.scan;
  plainScan.otherObjectPrior = 0.0;
  auto plain = localize::Localizer(k.cal, image::LleParams{}, plainScan).estimate(*plan, lines);
  REQUIRE(plain.isOk());
  CHECK(plain->doubt == localize::AppleEstimate::Doubt::kNone);
  CHECK(plain->sigmaMm < 2.0);
  // The same fruit beyond the gate, but the lines also lit a leaf round the rough position:
  // the target may be behind it, and the far fruit is more likely a neighbour. The rough
  // position goes out (ROUGH_ONLY, FAR_FROM_ROUGH); the fit only with the option off.
  std::vector<localize::LineObservation> leafy = lines;
  for (int i = 0; i < 20; ++i) {
    const Eigen::Vector3d onLeaf = rough + Eigen::Vector3d(0.5 * i - 5.0, 1.5 * i - 15.0, -20.0);
    leafy[2].pointsMm.push_back(onLeaf);
    leafy[2].pixels.push_back(geometry::projectPoint(k.cal.camera, onLeaf));
  }
  auto occupied = loc.estimate(*plan, leafy);
  REQUIRE(occupied.isOk());
  CHECK_FALSE(occupied->sphereFit);
  CHECK(occupied->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK((occupied->centerMm - rough).norm() < 1e-9);
  localize::ScanParams fitOut = k.scan;
  fitOut.roughWhenFarFromRough = false;
  auto asFound = localize::Localizer(k.cal, image::LleParams{}, fitOut).estimate(*plan, leafy);
  REQUIRE(asFound.isOk());
  CHECK(asFound->outsideGate);
  CHECK((asFound->centerMm - k.center).norm() < 2.0);
  // A few rows of a surface in the gate, fewer than a line's worth (a hidden target's skin
  // through a gap), show it occupied as well; two stray samples do not.
  for (const auto& [points, roughOut] : {std::pair{4, true}, std::pair{2, false}}) {
    std::vector<localize::LineObservation> few = lines;
    few[2].pointsMm.assign(leafy[2].pointsMm.end() - points, leafy[2].pointsMm.end());
    few[2].pixels.assign(leafy[2].pixels.end() - points, leafy[2].pixels.end());
    auto e = loc.estimate(*plan, few);
    REQUIRE(e.isOk());
    INFO(points << " points in the gate");
    CHECK(e->outsideGate != roughOut);
    CHECK(e->sphereFit != roughOut);
  }
  // The same leaf told by its colour (ScanParams::leafGreenRatio): its points join no fit,
  // but they still show the gate occupied, so the rough position goes out as before.
  std::vector<localize::LineObservation> toldByColour = lines;
  toldByColour[2].leafPointsMm.assign(leafy[2].pointsMm.end() - 20, leafy[2].pointsMm.end());
  auto stillOccupied = loc.estimate(*plan, toldByColour);
  REQUIRE(stillOccupied.isOk());
  CHECK_FALSE(stillOccupied->sphereFit);
  CHECK(stillOccupied->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK((stillOccupied->centerMm - rough).norm() < 1e-9);
  // A rough position known to be this poor (a less accurate camera: σ 60 mm per axis) lets
  // the fit be the target: MEASURED, OUTSIDE_GATE.
  localize::ScanParams poorRough = k.scan;
  poorRough.roughSigmaMm = 60.0;
  auto believed = localize::Localizer(k.cal, image::LleParams{}, poorRough).estimate(*plan, lines);
  REQUIRE(believed.isOk());
  CHECK(believed->sphereFit);
  CHECK(believed->outsideGate);
  CHECK(believed->doubt == localize::AppleEstimate::Doubt::kNone);
  CHECK((believed->centerMm - k.center).norm() < 2.0);
  // The narrow gate above is no configuration a file may hold (the gate must be at least
  // max_radius_mm + 2 x rough_sigma_mm). One that may: σ 80 mm, the gate 215 mm and the
  // search 450 mm, the rough position 222 mm above the fruit's top (so that every stop
  // still cuts the fruit).
  localize::ScanParams poorValid = k.scan;
  poorValid.roughSigmaMm = 80.0;
  poorValid.gateMm = 215.0;
  poorValid.searchMm = 450.0;
  REQUIRE(poorValid.validate().isOk());
  const Eigen::Vector3d farRough = k.center + Eigen::Vector3d(0.0, -k.radius - 222.0, 0.0);
  localize::Localizer farLoc(k.cal, image::LleParams{}, poorValid);
  auto farPlan = farLoc.plan(farRough, 200.0);
  REQUIRE(farPlan.isOk());
  const GatedLines far = gatedLinesOf(k, *farPlan, farRough, poorValid, rng);
  REQUIRE(far.seen > 100);
  REQUIRE(far.inGate == 0);
  auto farBelieved = farLoc.estimate(*farPlan, far.lines);
  REQUIRE(farBelieved.isOk());
  INFO("lines " << farBelieved->linesUsed << ", chance " << farBelieved->targetPct << " %, "
                << (farBelieved->centerMm - farRough).norm() << " mm from the rough position");
  CHECK(farBelieved->sphereFit);
  CHECK(farBelieved->outsideGate);
  CHECK(farBelieved->doubt == localize::AppleEstimate::Doubt::kNone);
  CHECK((farBelieved->centerMm - k.center).norm() < 2.0);
}

TEST_CASE("Lines in the gate on leaves alone: the rough position, and a second pass between the leaves",
          "[localize][leaf]") {
  // Every stop's line fell on a leaf 20 mm in front of where the target should be, and the
  // laser-off frame told each sample green (ScanParams::leafGreenRatio): nothing in the gate
  // is a fruit's, but the target may be behind the leaf. ROUGH_ONLY goes out, and the
  // second pass looks again (too few lines); with no line in the gate at all, nothing does.
  Case k;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  std::vector<localize::LineObservation> leaves;
  for (double s : plan->stopsMm) {
    localize::LineObservation obs;
    obs.slideMm = s;
    for (int i = 0; i < 20; ++i)
      obs.leafPointsMm.push_back(k.center + Eigen::Vector3d(0.5 * i - 5.0, 1.5 * i - 15.0, -k.radius - 20.0));
    leaves.push_back(obs);
  }
  auto est = loc.estimate(*plan, leaves);
  REQUIRE(est.isOk());
  CHECK_FALSE(est->sphereFit);
  CHECK(est->linesUsed == 0);
  CHECK((est->centerMm - k.center).norm() < 1e-9);
  CHECK(est->confidencePct < 50.0);
  CHECK_FALSE(loc.followUpStops(*plan, leaves, est, 200.0).empty());
  std::vector<localize::LineObservation> empty = leaves;
  for (localize::LineObservation& l : empty) l.leafPointsMm.clear();
  auto none = loc.estimate(*plan, empty);
  CHECK(none.status().code() == Error::kNotFound);
  CHECK(loc.followUpStops(*plan, empty, none, 200.0).empty());
}

TEST_CASE("A neighbour in full view, the target hidden: the rough position, not the neighbour's centre",
          "[localize][doubt]") {
  // Every line lies on a fruit 63 mm below where the rough position says the target is
  // (within the 90 mm gate): a sphere well fitted on five lines, and far more likely a
  // neighbour than the target (the RGB-D error is 15 mm per axis). Its centre would put the
  // arm 63 mm off; the rough position is the better estimate of the target.
  Case k;
  std::mt19937 rng(37);
  const Eigen::Vector3d neighbour = k.center + Eigen::Vector3d(0.0, 62.0, -10.0);
  const double neighbourRadiusMm = 36.0;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(neighbour, 200.0);
  REQUIRE(plan.isOk());
  plan->roughMm = k.center;
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) {
    lines.push_back(lineOf(k.cal, neighbour, neighbourRadiusMm, s, 0.3, {}, rng));
    applyGate(lines.back(), k.center, k.scan);
  }
  auto est = loc.estimate(*plan, lines);
  INFO("centre " << est->centerMm.transpose() << ", lines " << est->linesUsed << ", target " << est->targetPct << " %");
  REQUIRE(est.isOk());
  CHECK_FALSE(est->sphereFit);
  CHECK(est->linesUsed == 0);
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK(est->targetPct < 50.0);
  CHECK((est->centerMm - k.center).norm() < 1e-9);
  CHECK(est->sigmaMm >= std::sqrt(3.0) * k.scan.roughSigmaMm);
  CHECK(est->confidencePct < 50.0);
  // Off, the neighbour's fit goes out (AMBIGUOUS on the bus), its σ spanning the distance.
  localize::ScanParams fitOut = k.scan;
  fitOut.roughWhenFarFromRough = false;
  auto fit = localize::Localizer(k.cal, image::LleParams{}, fitOut).estimate(*plan, lines);
  REQUIRE(fit.isOk());
  CHECK(fit->sphereFit);
  CHECK(fit->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK((fit->centerMm - neighbour).norm() < 3.0);
  CHECK(fit->sigmaMm > 0.5 * (neighbour - k.center).norm());
}

TEST_CASE("The widened search takes no flat surface for a fruit", "[localize][widened]") {
  Case k;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  const Eigen::Vector3d rough = k.center;
  auto plan = loc.plan(rough, 200.0);
  REQUIRE(plan.isOk());
  // A wall 150 mm behind the rough position: each stop's line on it, beyond the gate.
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) {
    localize::LineObservation l;
    l.slideMm = s;
    const double z = rough.z() + 150.0;
    const Eigen::Vector3d n = k.cal.laser.planeNormal;
    for (double y = -60.0; y <= 60.0; y += 1.0) {
      // The laser plane n·p = offset at depth z and height y: solve for x.
      const double x = (k.cal.laser.planeOffsetAt(s) - n.y() * y - n.z() * z) / n.x();
      l.outsidePointsMm.emplace_back(x, y, z);
    }
    lines.push_back(l);
  }
  auto est = loc.estimate(*plan, lines);
  CHECK_FALSE((est.isOk() && est->sphereFit));
}

TEST_CASE("Honest uncertainty: two fruit that explain the lines alike are two surfaces", "[localize][doubt]") {
  // Two equal fruit side by side, the rough position halfway between them: the lines
  // cross both, each sphere explains its own pieces, and nothing says which is meant.
  Case k;
  std::mt19937 rng(47);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  const Eigen::Vector3d a = k.center + Eigen::Vector3d(0.0, -39.0, 0.0);
  const Eigen::Vector3d b = k.center + Eigen::Vector3d(0.0, 39.0, 0.0);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  const std::vector<localize::LineObservation> lines = twoFruitLines(k.cal, *plan, a, b, 38.0, 0.3, {}, rng);
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  REQUIRE(est->sphereFit);
  INFO("centre " << est->centerMm.transpose() << " rival share " << est->rivalShare << " target " << est->targetPct
                 << " % σ " << est->sigmaMm);
  CHECK(std::min((est->centerMm - a).norm(), (est->centerMm - b).norm()) < 3.0);
  CHECK(est->rivalShare > 0.3);
  CHECK((est->rivalCenterMm - est->centerMm).norm() > 60.0);
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kTwoSurfaces);
  CHECK(est->confidencePct < 50.0);
  CHECK(est->sigmaMm > 30.0);  // spans the other fruit
}

TEST_CASE("Two fruit as near the rough position, one mostly hidden: the one in view is not a confident result",
          "[localize][doubt]") {
  // The rough position halfway between two touching fruit, a leaf in front of one: the fit
  // takes the fruit in view, which explains far more of the lines. The support says how
  // much of each the lines saw, not which one the arm meant; the rough position, equally
  // far from both, cannot tell either (on the hard cases' seed 11, d1000_occ1_0028, a
  // neighbour went out 74 mm off at 81 % confidence, σ 30 mm).
  Case k;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  const Eigen::Vector3d hidden = k.center + Eigen::Vector3d(0.0, -39.0, 0.0);
  const Eigen::Vector3d inView = k.center + Eigen::Vector3d(0.0, 39.0, 0.0);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  const std::vector<Leaf> leaves{{hidden + Eigen::Vector3d(0, 8, -k.radius - 20), 30.0}};
  for (const unsigned seed : {3U, 5U, 8U}) {
    std::mt19937 rng(seed);
    const std::vector<localize::LineObservation> lines =
        twoFruitLines(k.cal, *plan, hidden, inView, k.radius, 0.4, leaves, rng);
    auto est = loc.estimate(*plan, lines);
    REQUIRE(est.isOk());
    REQUIRE(est->sphereFit);
    INFO("seed " << seed << " centre " << est->centerMm.transpose() << " rival share " << est->rivalShare
                 << " identity " << est->rivalFruitIdentity << " target " << est->targetPct << " % confidence "
                 << est->confidencePct << " % σ " << est->sigmaMm);
    // Whichever it took, it is one of the two, and it says it may be the other.
    const double toHidden = (est->centerMm - hidden).norm();
    const double toInView = (est->centerMm - inView).norm();
    CHECK(std::min(toHidden, toInView) < 4.0);
    CHECK(est->confidencePct < 60.0);
    CHECK(est->sigmaMm > 0.5 * std::max(toHidden, toInView));  // the other within 2σ
  }
}

TEST_CASE("The confidence never exceeds the chance of the 20 mm tolerance at the σ reported", "[localize][doubt]") {
  // A fruit in full view, the rough position farther and farther above it: past about three
  // of its σ the fit may be another object, and the mixture widens σ towards that distance.
  // The confidence (the chance of the end effector's 20 mm tolerance) follows that σ, not
  // the fit's own: on the hard cases a fit went out at 86 % with σ 16.5 mm and 38.8 mm off,
  // where 16.5 mm leaves the tolerance a chance of 78 % (docs/daemon.md).
  Case k;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  // P(|e| <= 20 mm) for a 3D error of total 1σ `sigmaMm` (Maxwell), written out here apart
  // from the localizer's own.
  const auto toleranceChancePct = [](double sigmaMm) {
    const double u = 20.0 / (sigmaMm / std::sqrt(3.0));
    return 100.0 * (std::erf(u / std::sqrt(2.0)) - std::sqrt(2.0 / M_PI) * u * std::exp(-0.5 * u * u));
  };
  int wideSigmas = 0;
  for (double offMm = 30.0; offMm <= 70.0; offMm += 4.0) {
    std::mt19937 rng(61);
    auto plan = loc.plan(k.center + Eigen::Vector3d(0.0, -offMm, 0.0), 200.0);
    REQUIRE(plan.isOk());
    std::vector<localize::LineObservation> lines;
    for (double s : plan->stopsMm) lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng));
    auto est = loc.estimate(*plan, lines);
    REQUIRE(est.isOk());
    INFO("rough position " << offMm << " mm off: σ " << est->sigmaMm << " mm, confidence " << est->confidencePct
                           << " %, target " << est->targetPct << " %, lines " << est->linesUsed);
    CHECK(est->confidencePct <= toleranceChancePct(est->sigmaMm) + 1e-9);
    if (est->sigmaMm > 16.5) CHECK(est->confidencePct < 80.0);
    // Where the mixture has widened σ past 12 mm and the fit is still likelier the target
    // than not, it is the bound that sets the confidence.
    if (est->sigmaMm > 12.0 && est->targetPct > 50.0) {
      ++wideSigmas;
      CHECK(est->confidencePct == Approx(toleranceChancePct(est->sigmaMm)).epsilon(1e-6));
    }
  }
  CHECK(wideSigmas >= 1);  // the sweep reaches the σ where the bound acts
}

TEST_CASE("What all points share is in σ: the line's bias through the triangulation, the calibration's error",
          "[localize]") {
  Case k;
  const Eigen::Vector3d near(0.0, 0.0, 1000.0);
  const Eigen::Vector3d far(0.0, 0.0, 1600.0);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  const double nearMm = loc.systematicSigmaMm(near);
  const double farMm = loc.systematicSigmaMm(far);
  // 0.1 px across the line: tenths of a millimetre, growing with depth (on the axis the
  // laser plane through the point is farther out on the slide: the baseline grows too).
  CHECK(nearMm > 0.05);
  CHECK(farMm < 1.5);
  CHECK(farMm / nearMm > 1.3);
  CHECK(farMm / nearMm < 2.8);
  // Twice the bias, twice the term; none, none.
  localize::ScanParams twice = k.scan;
  twice.lineBiasPx = 0.2;
  CHECK(localize::Localizer(k.cal, image::LleParams{}, twice).systematicSigmaMm(far) ==
        Approx(2.0 * farMm).epsilon(0.01));
  localize::ScanParams none = k.scan;
  none.lineBiasPx = 0.0;
  CHECK(localize::Localizer(k.cal, image::LleParams{}, none).systematicSigmaMm(far) == 0.0);
  // The calibration's 3D error at the depth, interpolated between its depths, in quadrature.
  geometry::Calibration measured = k.cal;
  measured.quality.sigma3dTotalMmAt1000 = 1.0;
  measured.quality.sigma3dTotalMmAt1200 = 1.5;
  measured.quality.sigma3dTotalMmAt1400 = 2.0;
  measured.quality.sigma3dTotalMmAt1600 = 3.0;
  const localize::Localizer calibrated(measured, image::LleParams{}, none);
  CHECK(calibrated.systematicSigmaMm(Eigen::Vector3d(0, 0, 1300.0)) == Approx(1.75));
  CHECK(calibrated.systematicSigmaMm(Eigen::Vector3d(0, 0, 800.0)) == Approx(1.0));
  CHECK(calibrated.systematicSigmaMm(Eigen::Vector3d(0, 0, 1800.0)) == Approx(3.0));
  // ... and an estimate's σ carries it: the same lines, a wider σ.
  std::mt19937 rngA(5);
  std::mt19937 rngB(5);
  localize::Localizer plain(k.cal, image::LleParams{}, none);
  auto plan = plain.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  std::vector<localize::LineObservation> a;
  std::vector<localize::LineObservation> b;
  for (double s : plan->stopsMm) a.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rngA));
  for (double s : plan->stopsMm) b.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rngB));
  auto fit = plain.estimate(*plan, a);
  auto withCal = localize::Localizer(measured, image::LleParams{}, none).estimate(*plan, b);
  REQUIRE(fit.isOk());
  REQUIRE(withCal.isOk());
  CHECK(withCal->fitSigmaMm > fit->fitSigmaMm);
  CHECK(withCal->fitSigmaMm ==
        Approx(std::hypot(fit->fitSigmaMm, calibrated.systematicSigmaMm(withCal->approachMm))).epsilon(0.05));
}

TEST_CASE(
    "A fruit is not a spheroid: a share of its radius is in σ, the approach point's, the centre's and "
    "twice it in the diameter's",
    "[localize]") {
  // The same lines (one noise draw) fitted with the share at 0, 2 % (the default) and
  // 4 %: the fruit stays where it is, and σ grows by that share of the fitted radius, in
  // quadrature, in the approach point's σ and the centre's alike; the diameter's by twice
  // it (the width departs on either side).
  Case k;
  const auto fitWith = [&](double pct) {
    localize::ScanParams scan = k.scan;
    scan.shapeIrregularityPct = pct;
    localize::Localizer loc(k.cal, image::LleParams{}, scan);
    auto plan = loc.plan(k.center + Eigen::Vector3d(4, -3, 6), 200.0);
    REQUIRE(plan.isOk());
    std::mt19937 rng(17);
    std::vector<localize::LineObservation> lines;
    for (double s : plan->stopsMm) lines.push_back(lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng));
    auto est = loc.estimate(*plan, lines);
    REQUIRE(est.isOk());
    REQUIRE(est->sphereFit);
    return *est;
  };
  const localize::AppleEstimate exact = fitWith(0.0);
  const localize::AppleEstimate two = fitWith(localize::ScanParams{}.shapeIrregularityPct);
  const localize::AppleEstimate four = fitWith(4.0);
  CHECK(localize::ScanParams{}.shapeIrregularityPct == 2.0);
  CHECK((two.centerMm - exact.centerMm).norm() < 1e-9);
  CHECK(two.diameterMm == exact.diameterMm);
  const double twoMm = 0.02 * 0.5 * exact.diameterMm;  // 0.76 mm on this 76 mm fruit
  CHECK(two.fitSigmaMm == Approx(std::hypot(exact.fitSigmaMm, twoMm)).epsilon(1e-6));
  CHECK(two.centerSigmaMm == Approx(std::hypot(exact.centerSigmaMm, twoMm)).epsilon(1e-6));
  CHECK(four.fitSigmaMm == Approx(std::hypot(exact.fitSigmaMm, 2.0 * twoMm)).epsilon(1e-6));
  CHECK(two.sigmaMm > exact.sigmaMm);
  CHECK(two.diameterSigmaMm == Approx(std::hypot(exact.diameterSigmaMm, 2.0 * twoMm)).epsilon(1e-6));
  CHECK(four.diameterSigmaMm == Approx(std::hypot(exact.diameterSigmaMm, 4.0 * twoMm)).epsilon(1e-6));
  // Out of range: refused by name.
  localize::ScanParams bad;
  bad.shapeIrregularityPct = -1.0;
  CHECK(bad.validate().reason().find("scan.shape_irregularity_pct") != std::string::npos);
  bad.shapeIrregularityPct = 25.0;
  CHECK_FALSE(bad.validate().isOk());
}

TEST_CASE("One line of the target in the gate, a neighbour's sphere beyond: the neighbour is not taken for it",
          "[localize][doubt][widened]") {
  // Leaves let one stop light the target; a neighbour beside it is in full view on every
  // stop (60 and 76 mm across, 70 mm apart; the rough position 57 mm from the neighbour's
  // centre, 16 mm from the target's). Within the gate only one line is the target's, so the
  // widened search finds the neighbour's sphere. The target's line lies off that sphere,
  // near the rough position: the gate is occupied, and the neighbour is weighed as a fit
  // within the gate would be (another object that near is likely in a cluster): the rough
  // position goes out, FAR_FROM_ROUGH. Weighed against the whole search's ball, the
  // neighbour went out as the target (the benchmark's widened hard cases, seed 3: 72 and
  // 84 mm misses).
  Case k;
  std::mt19937 rng(53);
  const Eigen::Vector3d neighbour = k.center + Eigen::Vector3d(0.0, 70.0, -5.0);
  const Eigen::Vector3d rough = k.center + Eigen::Vector3d(6.0, 14.0, 5.0);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(rough, 200.0);
  REQUIRE(plan.isOk());
  std::vector<localize::LineObservation> lines;
  const size_t lit = plan->stopsMm.size() / 2;
  for (size_t i = 0; i < plan->stopsMm.size(); ++i) {
    localize::LineObservation l = lineOf(k.cal, neighbour, 38.0, plan->stopsMm[i], 0.3, {}, rng);
    if (i == lit) {
      const localize::LineObservation t = lineOf(k.cal, k.center, 30.0, plan->stopsMm[i], 0.3, {}, rng);
      l.pointsMm.insert(l.pointsMm.end(), t.pointsMm.begin(), t.pointsMm.end());
      l.pixels.insert(l.pixels.end(), t.pixels.begin(), t.pixels.end());
    }
    applyGate(l, rough, k.scan);
    lines.push_back(std::move(l));
  }
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  INFO("centre " << est->centerMm.transpose() << ", lines " << est->linesUsed << ", target " << est->targetPct
                 << " %, sphere " << est->sphereFit);
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK((est->centerMm - rough).norm() < 1e-9);
  CHECK((est->centerMm - neighbour).norm() > 50.0);
  CHECK(est->confidencePct < 50.0);
  // With the rule off, the neighbour's fit goes out, but as what it likely is: another
  // object (AMBIGUOUS on the bus), its σ spanning the distance to the rough position.
  localize::ScanParams fitOut = k.scan;
  fitOut.roughWhenFarFromRough = false;
  auto fit = localize::Localizer(k.cal, image::LleParams{}, fitOut).estimate(*plan, lines);
  REQUIRE(fit.isOk());
  CHECK((fit->centerMm - neighbour).norm() < 3.0);
  CHECK(fit->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK(fit->sigmaMm > 0.5 * (neighbour - rough).norm());
}

TEST_CASE(
    "The fit is a neighbour far from the rough position: the target is looked for beside it before the rough "
    "position stands in",
    "[localize][doubt]") {
  // A cluster: the target (31 mm radius) mostly hidden by a leaf in front of its upper part,
  // a larger neighbour touching it from below in full view, and a second neighbour beside
  // them; the rough position 30 mm off the target, towards the first neighbour (the
  // hard cases' seed 12, d1600_occ1_0033: the rough position then stood in, 33 mm off).
  // The fit takes the neighbour with the most skin, far from the rough position: another
  // object. The points off its surface hold the target on several lines; fitted again round
  // the rough position they give it, likelier the target than not, and it goes out.
  Case k;
  std::mt19937 rng(61);
  const double targetRadiusMm = 31.0;
  const Eigen::Vector3d below = k.center + Eigen::Vector3d(-10.0, 76.0, -12.0);
  const Eigen::Vector3d beside = k.center + Eigen::Vector3d(40.0, -70.0, 10.0);
  const Eigen::Vector3d rough = k.center + Eigen::Vector3d(-4.0, 29.0, 6.0);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(rough, 200.0);
  REQUIRE(plan.isOk());
  const std::vector<Leaf> leaves{{k.center + Eigen::Vector3d(0.0, -14.0, -targetRadiusMm - 25.0), 34.0}};
  // The target's line at stop s joined by both neighbours' lines, then gated.
  auto withNeighbours = [&](localize::LineObservation l, double s) {
    for (const Eigen::Vector3d& c : {below, beside}) {
      const localize::LineObservation n = lineOf(k.cal, c, 46.0, s, 0.3, {}, rng);
      l.pointsMm.insert(l.pointsMm.end(), n.pointsMm.begin(), n.pointsMm.end());
      l.pixels.insert(l.pixels.end(), n.pixels.begin(), n.pixels.end());
    }
    applyGate(l, rough, k.scan);
    return l;
  };
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm)
    lines.push_back(withNeighbours(lineOf(k.cal, k.center, targetRadiusMm, s, 0.3, leaves, rng), s));
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  INFO("centre " << est->centerMm.transpose() << ", off the target " << (est->centerMm - k.center).norm()
                 << " mm, lines " << est->linesUsed << ", target " << est->targetPct << " %, doubt "
                 << static_cast<int>(est->doubt) << ", σ " << est->sigmaMm);
  CHECK(est->sphereFit);
  CHECK(est->linesUsed >= 3);
  CHECK((est->centerMm - k.center).norm() < 6.0);
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kNone);
  CHECK(est->targetPct > 50.0);
  // The fit alone (the rule that lets the rough position stand in, off) is the neighbour.
  localize::ScanParams fitOut = k.scan;
  fitOut.roughWhenFarFromRough = false;
  auto fit = localize::Localizer(k.cal, image::LleParams{}, fitOut).estimate(*plan, lines);
  REQUIRE(fit.isOk());
  INFO("the fit alone " << fit->centerMm.transpose());
  CHECK((fit->centerMm - k.center).norm() > 40.0);
  CHECK(fit->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  // The target at its first two stops only: what remains beside the neighbour is too little
  // for a fruit of its own, and the rough position stands in (with a bar of two lines it
  // stands in too: no fit there is likelier the target).
  std::vector<localize::LineObservation> twoLines;
  int withTarget = 0;
  for (double s : plan->stopsMm) {
    localize::LineObservation l = lineOf(k.cal, k.center, targetRadiusMm, s, 0.3, leaves, rng);
    if (!l.pointsMm.empty() && ++withTarget > 2) {
      l = localize::LineObservation{};
      l.slideMm = s;
    }
    twoLines.push_back(withNeighbours(std::move(l), s));
  }
  REQUIRE(withTarget >= 3);
  auto fewer = loc.estimate(*plan, twoLines);
  REQUIRE(fewer.isOk());
  INFO("two lines of the target: centre " << fewer->centerMm.transpose() << ", lines " << fewer->linesUsed);
  CHECK(fewer->doubt == localize::AppleEstimate::Doubt::kFarFromRough);
  CHECK(fewer->linesUsed == 0);
  CHECK((fewer->centerMm - rough).norm() < 1e-9);
}

TEST_CASE("Of a fit and its rival, the one the doubt model finds likelier the target is reported",
          "[localize][doubt]") {
  Case k;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  auto plan = loc.plan(k.center, 200.0);
  REQUIRE(plan.isOk());
  // The rival's chance, as weighDoubt() reckons the fit's: near the rough position, its share.
  localize::AppleEstimate est;
  est.sphereFit = true;
  est.linesUsed = 4;
  est.centerMm = k.center + Eigen::Vector3d(0.0, 58.0, 0.0);
  est.rivalShare = 0.46;
  est.rivalCenterMm = k.center + Eigen::Vector3d(0.0, -20.0, 10.0);
  const double nearPct = loc.rivalTargetPct(*plan, est);
  CHECK(nearPct > 40.0);
  CHECK(nearPct < 46.0);
  // Farther, less likely; a smaller share, less likely; no rival, none.
  localize::AppleEstimate far = est;
  far.rivalCenterMm = k.center + Eigen::Vector3d(0.0, -70.0, 10.0);
  CHECK(loc.rivalTargetPct(*plan, far) < 0.5 * nearPct);
  localize::AppleEstimate weak = est;
  weak.rivalShare = 0.2;
  CHECK(loc.rivalTargetPct(*plan, weak) == Approx(nearPct * 0.2 / 0.46));
  localize::AppleEstimate none = est;
  none.rivalShare = 0.0;
  CHECK(loc.rivalTargetPct(*plan, none) == 0.0);
  localize::AppleEstimate oneLine = est;
  oneLine.sphereFit = false;
  CHECK(loc.rivalTargetPct(*plan, oneLine) == 0.0);
  localize::ScanParams off = k.scan;
  off.otherObjectPrior = 0.0;
  CHECK(localize::Localizer(k.cal, image::LleParams{}, off).rivalTargetPct(*plan, est) == 0.0);
  // Of every other object the fit found, the likeliest, not the strongest: a second
  // neighbour outscores a hidden target near the rough position (as in a scan of the hard
  // cases' seed 7, where the fit was the widened search's and the rough position went out).
  localize::AppleEstimate three = est;
  three.centerMm = k.center + Eigen::Vector3d(0.0, 62.0, 0.0);
  three.rivalShare = 0.32;
  three.rivalCenterMm = k.center + Eigen::Vector3d(0.0, -100.0, 10.0);
  three.others = {{three.rivalCenterMm, 0.32}, {k.center + Eigen::Vector3d(4.0, 3.0, -2.0), 0.07}};
  const double hidden = loc.rivalTargetPct(*plan, three);
  CHECK(hidden > 5.0);
  CHECK((loc.likeliestOtherMm(*plan, three) - three.others[1].centerMm).norm() < 1e-9);
  localize::AppleEstimate rivalOnly = three;
  rivalOnly.others.resize(1);
  CHECK(loc.rivalTargetPct(*plan, rivalOnly) < 0.1 * hidden);
  CHECK((loc.likeliestOtherMm(*plan, rivalOnly) - three.rivalCenterMm).norm() < 1e-9);
}

TEST_CASE("A neighbour that outscores a hidden target far from the rough position gives way to the target",
          "[localize][doubt]") {
  Case k;
  std::mt19937 rng(31);
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  const Eigen::Vector3d neighbour = k.center + Eigen::Vector3d(0.0, 78.0, 10.0);  // below it, touching
  // The rough position 32 mm off (the RGB-D camera's error is 16-21 mm on average),
  // towards the neighbour, and a leaf hides most of the target: the neighbour's support,
  // weighed by nearness to the rough position as the fit ranks objects, beats the target's
  // by a little. The doubt model, which weighs the distance by the camera's error, finds
  // the target far likelier (without the rule the neighbour went out, AMBIGUOUS, at 43 %;
  // seeds 1-8 alike).
  auto plan = loc.plan(k.center + Eigen::Vector3d(0.0, 32.0, 0.0), 200.0);
  REQUIRE(plan.isOk());
  const std::vector<Leaf> leaves{{k.center + Eigen::Vector3d(0, -12, -k.radius - 20), 33.0}};
  std::vector<localize::LineObservation> lines;
  for (double s : plan->stopsMm) {
    localize::LineObservation l = lineOf(k.cal, k.center, k.radius, s, 0.4, leaves, rng);
    const localize::LineObservation n = lineOf(k.cal, neighbour, k.radius, s, 0.4, {}, rng);
    for (size_t i = 0; i < n.pointsMm.size(); ++i) {
      if ((n.pointsMm[i] - plan->roughMm).norm() > k.scan.gateMm) continue;  // observe()'s gate
      l.pointsMm.push_back(n.pointsMm[i]);
      l.pixels.push_back(n.pixels[i]);
    }
    lines.push_back(l);
  }
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  INFO("est " << est->centerMm.transpose() << " sphere " << est->sphereFit << " target " << est->targetPct << " rival "
              << est->rivalShare << " at " << est->rivalCenterMm.transpose() << " lines " << est->linesUsed);
  CHECK((est->centerMm - k.center).norm() < 6.0);
  CHECK(est->targetPct > 50.0);
  CHECK(est->doubt == localize::AppleEstimate::Doubt::kNone);
}

TEST_CASE("The sunlit arcs join the fit only when the lines alone leave the target unseen", "[localize][weak_arc]") {
  Case k;
  localize::Localizer loc(k.cal, image::LleParams{}, k.scan);
  // The rough position 25 mm off: the target's own points put its centre there.
  auto plan = loc.plan(k.center + Eigen::Vector3d(15, -12, 16), 200.0);
  REQUIRE(plan.isOk());
  std::mt19937 rng(41);
  const Eigen::Vector3d approachTruth = k.center - k.radius * k.center.normalized();
  SECTION("the LLE saw nothing of the target; the arcs saw it") {
    std::vector<localize::LineObservation> lines;
    for (double s : plan->stopsMm) {
      localize::LineObservation seen = lineOf(k.cal, k.center, k.radius, s, 0.5, {}, rng);
      localize::LineObservation l;
      l.slideMm = s;
      l.arcPointsMm = seen.pointsMm;
      l.arcPixels = seen.pixels;
      lines.push_back(l);
    }
    auto est = loc.estimate(*plan, lines);
    REQUIRE(est.isOk());
    INFO("approach off " << (est->approachMm - approachTruth).norm() << " mm on " << est->linesUsed << " lines");
    CHECK(est->fromWeakArcs);
    CHECK(est->linesUsed >= 3);
    CHECK((est->approachMm - approachTruth).norm() < 2.0);
    // Off, the same scan has nothing: no line hit the target.
    localize::ScanParams off = k.scan;
    off.weakArcMinZ = 0.0;
    auto without = localize::Localizer(k.cal, image::LleParams{}, off).estimate(*plan, [&] {
      std::vector<localize::LineObservation> bare = lines;
      for (auto& l : bare) l.arcPointsMm.clear(), l.arcPixels.clear();
      return bare;
    }());
    CHECK_FALSE(without.isOk());
  }
  SECTION("the lines saw the target: an arc elsewhere changes nothing") {
    std::vector<localize::LineObservation> lines;
    for (double s : plan->stopsMm) {
      localize::LineObservation l = lineOf(k.cal, k.center, k.radius, s, 0.4, {}, rng);
      // A false arc: a neighbour's skin 70 mm to the side.
      const localize::LineObservation other =
          lineOf(k.cal, k.center + Eigen::Vector3d(70, 0, 10), k.radius, s, 0.4, {}, rng);
      l.arcPointsMm = other.pointsMm;
      l.arcPixels = other.pixels;
      lines.push_back(l);
    }
    auto est = loc.estimate(*plan, lines);
    REQUIRE(est.isOk());
    CHECK_FALSE(est->fromWeakArcs);
    CHECK((est->approachMm - approachTruth).norm() < 1.0);
  }
}

TEST_CASE("A stop's second exposure fills only the rows its first frame left without a sample, from its line",
          "[localize]") {
  // First frame: rows 10..19 with a sample (row 14 an outlier: no sample), 3D at x = row.
  localize::LineObservation first;
  for (int row = 10; row < 20; ++row) {
    image::RowSample r;
    r.row = row;
    r.status = row == 14 ? image::RowStatus::kOutlier : image::RowStatus::kLine;
    first.line.rows.push_back(r);
    if (row == 14) continue;
    first.pixels.push_back({100.0, static_cast<double>(row)});
    first.pointsMm.emplace_back(row, 0.0, 1000.0);
  }
  // Second frame, longer: its line on rows 12..25, 3D at x = -row so that its samples are
  // told apart; row 23 is another segment's (a neighbour's skin, say), not the line's.
  localize::LineObservation second;
  for (int row = 12; row < 26; ++row) {
    image::RowSample r;
    r.row = row;
    r.column = 101.0F;
    r.inlier = row != 23;
    r.status = row == 23 ? image::RowStatus::kSegment : image::RowStatus::kLine;
    second.line.rows.push_back(r);
    second.pixels.push_back({101.0, static_cast<double>(row)});
    second.pointsMm.emplace_back(-row, 0.0, 1000.0);
  }
  second.arcPointsMm.emplace_back(1.0, 2.0, 3.0);
  second.arcPixels.push_back({5.0, 6.0});
  const size_t joined = localize::Localizer::mergeSecondExposure(first, second);
  CHECK(joined == 6);  // row 14 and rows 20..25 but 23
  REQUIRE(first.pixels.size() == 15);
  REQUIRE(first.pointsMm.size() == first.pixels.size());
  for (size_t i = 0; i < first.pixels.size(); ++i) {
    const int row = 10 + static_cast<int>(i) + (i >= 13 ? 1 : 0);  // row 23 left out
    INFO("row " << row);
    CHECK(first.pixels[i].rowPx == row);  // in row order
    const bool fromSecond = row == 14 || row >= 20;
    CHECK(first.pointsMm[i].x() == (fromSecond ? -row : row));
    CHECK(first.pixels[i].columnPx == (fromSecond ? 101.0 : 100.0));
  }
  // The first had no sunlit arc: the second's is taken; one it has stands.
  REQUIRE(first.arcPointsMm.size() == 1);
  CHECK(first.arcPixels[0].columnPx == 5.0);
  second.arcPixels[0].columnPx = 9.0;
  CHECK(localize::Localizer::mergeSecondExposure(first, second) == 0);  // merged once: every row has its sample
  CHECK(first.pixels.size() == 15);
  CHECK(first.arcPixels[0].columnPx == 5.0);
}
