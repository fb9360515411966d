// Calibration estimation on synthetic observations: checkerboard corners projected with
// OpenCV through a known camera, laser lines made by intersecting known laser planes with
// a known flat target and projecting them with noise. The estimates must come back to the
// truth within what the noise allows, and the quality gate must name what it refuses.
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <random>

#include "geometry/calibration.h"
#include "geometry/calibration_gate.h"
#include "geometry/calibration_uncertainty.h"
#include "geometry/camera_calibration.h"
#include "geometry/laser_calibration.h"
#include "geometry/triangulation.h"
#include "sim/scene.h"
#include "temp_dir.h"

using namespace alacs;
using namespace alacs::geometry;

namespace {

// A target pose looking back at the camera from `distanceMm`, tilted by (yaw, pitch) deg,
// with its corner grid centred on the optical axis shifted by `offsetMm`.
TargetPose makePose(double distanceMm, double yawDeg, double pitchDeg, const Eigen::Vector2d& offsetMm,
                    const Eigen::Vector2d& gridCentreMm) {
  TargetPose pose;
  pose.rotation = (Eigen::AngleAxisd(yawDeg * M_PI / 180.0, Eigen::Vector3d::UnitY()) *
                   Eigen::AngleAxisd(pitchDeg * M_PI / 180.0, Eigen::Vector3d::UnitX()))
                      .toRotationMatrix();
  const Eigen::Vector3d centreInCamera(offsetMm.x(), offsetMm.y(), distanceMm);
  pose.translationMm = centreInCamera - pose.rotation * Eigen::Vector3d(gridCentreMm.x(), gridCentreMm.y(), 0.0);
  return pose;
}

TargetView viewOf(const CameraIntrinsics& cam, const TargetPose& pose, const std::vector<Eigen::Vector3d>& corners,
                  double noisePx, std::mt19937& rng) {
  std::normal_distribution<double> noise(0.0, noisePx);
  std::vector<Eigen::Vector3d> inCamera;
  for (const auto& c : corners) inCamera.push_back(pose.rotation * c + pose.translationMm);
  const std::vector<PixelPoint> px = projectPoints(cam, inCamera);
  TargetView v;
  for (size_t i = 0; i < px.size(); ++i) {
    if (px[i].columnPx < 0 || px[i].rowPx < 0 || px[i].columnPx > cam.widthPx - 1 || px[i].rowPx > cam.heightPx - 1)
      continue;
    v.objectMm.push_back(corners[i]);
    v.imagePx.emplace_back(px[i].columnPx + noise(rng), px[i].rowPx + noise(rng));
  }
  return v;
}

// The laser line on a flat target: laser plane at `slideMm` ∩ target plane, sampled
// every image row it crosses, projected with distortion, column noise added (the line
// extraction errs along the row). lineOn undistorts them again as the calibrate tool does.
std::vector<PixelPoint> linePixels(const Calibration& truth, const TargetPose& target, double slideMm, double noisePx,
                                   double outlierShare, std::mt19937& rng) {
  const Eigen::Vector3d nl = truth.laser.planeNormal;
  const double dl = truth.laser.planeOffsetAt(slideMm);
  const Eigen::Vector3d nt = target.planeNormal();
  const double dt = target.planeOffsetMm();
  // Line of the two planes: direction and one point.
  const Eigen::Vector3d dir = nl.cross(nt).normalized();
  Eigen::Matrix3d a;
  a.row(0) = nl.transpose();
  a.row(1) = nt.transpose();
  a.row(2) = dir.transpose();
  const Eigen::Vector3d p0 = a.inverse() * Eigen::Vector3d(dl, dt, 0.0);
  std::vector<Eigen::Vector3d> pts;
  for (double t = -300.0; t <= 300.0; t += 0.5) pts.push_back(p0 + t * dir);
  const std::vector<PixelPoint> px = projectPoints(truth.camera, pts);
  std::normal_distribution<double> noise(0.0, noisePx);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  std::vector<PixelPoint> kept;
  int lastRow = -1;
  for (const auto& p : px) {
    const int row = static_cast<int>(std::lround(p.rowPx));
    if (row == lastRow || p.columnPx < 0 || p.columnPx > truth.camera.widthPx - 1 || row < 0 ||
        row > truth.camera.heightPx - 1)
      continue;
    lastRow = row;
    double col = p.columnPx + noise(rng);
    if (u01(rng) < outlierShare) col += 5.0 + 40.0 * u01(rng);  // a reflection beside the line
    kept.push_back({col, p.rowPx});
  }
  return kept;
}

LaserLineSample lineOn(const Calibration& truth, const TargetPose& target, const TargetPose& measuredTarget,
                       int placement, double slideMm, double noisePx, double outlierShare, std::mt19937& rng) {
  LaserLineSample s;
  s.placement = placement;
  s.targetNormal = measuredTarget.planeNormal();
  s.targetOffsetMm = measuredTarget.planeOffsetMm();
  s.slideMm = slideMm;
  s.normalized = undistortPixels(truth.camera, linePixels(truth, target, slideMm, noisePx, outlierShare, rng));
  return s;
}

struct Rig {
  Calibration truth = sim::defaultScene().truth;
  std::vector<Eigen::Vector3d> corners = checkerboardCorners(11, 8, 40.0);
  Eigen::Vector2d gridCentre{200.0, 140.0};
};

std::vector<TargetPose> placements() {
  return {makePose(800, 18, -8, {0, 0}, {200, 140}),   makePose(1000, -15, 10, {-40, 20}, {200, 140}),
          makePose(1200, 22, 6, {30, -30}, {200, 140}),  makePose(1400, -20, -12, {0, 40}, {200, 140}),
          makePose(1600, 12, 15, {-20, 0}, {200, 140}),  makePose(1800, -10, -6, {20, 10}, {200, 140})};
}

// A whole synthetic calibration as alacs_calibrate runs it: checkerboard views plus the
// placements' boards for the camera, then the poses and the laser lines in the estimated
// camera. Noise 0.1 px on corners, 0.15 px on line columns.
struct SyntheticCalibration {
  CameraFit camera;
  LaserFit laser;
  CalibrationObservations observations;
};

SyntheticCalibration calibrateSynthetic(const Rig& rig, unsigned seed, int cameraViews) {
  std::mt19937 rng(seed);
  std::vector<TargetView> views;
  for (int i = 0; i < cameraViews; ++i) {
    const double yaw = -30.0 + 60.0 * (i % 5) / 4.0;
    const double pitch = -25.0 + 50.0 * (i % 3) / 2.0;
    const Eigen::Vector2d off(-150.0 + 300.0 * (i % 4) / 3.0, -100.0 + 200.0 * (i % 2));
    views.push_back(viewOf(rig.truth.camera, makePose(600.0 + 40.0 * i, yaw, pitch, off, rig.gridCentre), rig.corners,
                           0.1, rng));
  }
  const std::vector<TargetPose> poses = placements();
  SyntheticCalibration out;
  for (const auto& pose : poses) {
    out.observations.placementViews.push_back(viewOf(rig.truth.camera, pose, rig.corners, 0.1, rng));
    views.push_back(out.observations.placementViews.back());
  }
  auto cam = calibrateCamera(views, rig.truth.camera.widthPx, rig.truth.camera.heightPx);
  REQUIRE(cam.isOk());
  out.camera = *cam;
  std::vector<LaserLineSample> samples;
  for (size_t p = 0; p < poses.size(); ++p) {
    auto measured = locateTarget(cam->camera, out.observations.placementViews[p]);
    REQUIRE(measured.isOk());
    for (double slide : {0.0, 50.0, 100.0, 150.0, 200.0}) {
      LaserPixelLine line{static_cast<int>(p), slide, linePixels(rig.truth, poses[p], slide, 0.15, 0.0, rng)};
      LaserLineSample s;
      s.placement = static_cast<int>(p);
      s.targetNormal = measured->planeNormal();
      s.targetOffsetMm = measured->planeOffsetMm();
      s.slideMm = slide;
      s.normalized = undistortPixels(cam->camera, line.pixels);
      samples.push_back(std::move(s));
      out.observations.lines.push_back(std::move(line));
    }
  }
  LaserFitOptions lo;
  lo.focalPx = cam->camera.fxPx;
  auto laser = calibrateLaser(samples, lo);
  REQUIRE(laser.isOk());
  out.laser = *laser;
  return out;
}

// RMS depth error of `est` on pixels of points on the true laser planes at depth z
// (check-calibration's grid: the whole stroke, ±0.3·z of height).
double rmsDepthErrorMm(const Calibration& truth, const Calibration& est, double z) {
  const LaserGeometry& t = truth.laser;
  double sum = 0.0;
  int count = 0;
  for (double slide = 0.0; slide <= 200.0; slide += 25.0) {
    for (double y = -0.3 * z; y <= 0.3 * z + 1e-9; y += 0.05 * z) {
      const double x = (t.planeOffsetAt(slide) - t.planeNormal.y() * y - t.planeNormal.z() * z) / t.planeNormal.x();
      const PixelPoint px = projectPoint(truth.camera, Eigen::Vector3d(x, y, z));
      if (px.columnPx < 0 || px.rowPx < 0 || px.columnPx > truth.camera.widthPx - 1 ||
          px.rowPx > truth.camera.heightPx - 1)
        continue;
      const TriangulatedPoint q = triangulate(est.laser, slide, undistortPixels(est.camera, {px})[0]);
      if (!q.valid) continue;
      sum += std::pow(q.pointMm.z() - z, 2);
      ++count;
    }
  }
  return count > 0 ? std::sqrt(sum / count) : 1e9;
}

}  // namespace

TEST_CASE("Camera intrinsics and distortion come back from checkerboard views", "[calibration]") {
  Rig rig;
  std::mt19937 rng(11);
  std::vector<TargetView> views;
  std::vector<TargetPose> poses;
  // Close, tilted views fill the frame (the distortion lives at its edges).
  for (int i = 0; i < 14; ++i) {
    const double yaw = -30.0 + 60.0 * (i % 5) / 4.0;
    const double pitch = -25.0 + 50.0 * (i % 3) / 2.0;
    const Eigen::Vector2d off(-150.0 + 300.0 * (i % 4) / 3.0, -100.0 + 200.0 * (i % 2));
    poses.push_back(makePose(600.0 + 40.0 * i, yaw, pitch, off, rig.gridCentre));
    views.push_back(viewOf(rig.truth.camera, poses.back(), rig.corners, 0.1, rng));
  }
  auto fit = calibrateCamera(views, rig.truth.camera.widthPx, rig.truth.camera.heightPx);
  REQUIRE(fit.isOk());
  const auto& c = fit->camera;
  INFO("fx " << c.fxPx << " fy " << c.fyPx << " cx " << c.cxPx << " cy " << c.cyPx << " rms " << fit->rmsPx);
  INFO("k1 " << c.distortion[0] << " k2 " << c.distortion[1] << " p1 " << c.distortion[2] << " p2 " << c.distortion[3]);
  CHECK(fit->rmsPx < 0.15);
  CHECK(c.fxPx == Approx(rig.truth.camera.fxPx).epsilon(0.002));
  CHECK(c.fyPx == Approx(rig.truth.camera.fyPx).epsilon(0.002));
  CHECK(c.cxPx == Approx(rig.truth.camera.cxPx).margin(3.0));
  CHECK(c.cyPx == Approx(rig.truth.camera.cyPx).margin(3.0));
  CHECK(c.distortion[0] == Approx(rig.truth.camera.distortion[0]).margin(0.01));
  CHECK(c.distortion[1] == Approx(rig.truth.camera.distortion[1]).margin(0.03));
  // The reported σ is honest: the errors are within 4σ.
  CHECK(std::abs(c.fxPx - rig.truth.camera.fxPx) < 4.0 * fit->sigmaPx[0] + 0.5);
  CHECK(fit->sigmaPx[0] > 0.0);
  CHECK(fit->sigmaPx[0] < 4.0);
  CHECK(std::abs(c.cxPx - rig.truth.camera.cxPx) < 4.0 * fit->sigmaPx[2] + 0.2);
  // The lens model: how far each model moves a pixel when it undistorts it (its
  // normalized coordinate against the linear one, K⁻¹·p), compared in pixels. The
  // principal point itself is not compared here: an offset of it within its σ is taken
  // up by the poses (a rotation of ~0.3 mrad), and where the solver settles inside that
  // valley differs between builds (x86 vs aarch64 floating-point contraction).
  for (const auto& [pixel, tolerance] :
       {std::pair{PixelPoint{40.0, 30.0}, 1.0}, std::pair{PixelPoint{700.0, 500.0}, 0.2}}) {
    const PixelPoint px = pixel;  // a copy: clang before 16 cannot capture a structured binding
    const auto shift = [&](const CameraIntrinsics& cam) {
      const Eigen::Vector2d linear((px.columnPx - cam.cxPx) / cam.fxPx, (px.rowPx - cam.cyPx) / cam.fyPx);
      return Eigen::Vector2d(undistortPixels(cam, {px})[0] - linear);
    };
    const Eigen::Vector2d st = shift(rig.truth.camera);
    const Eigen::Vector2d se = shift(c);
    INFO("pixel (" << px.columnPx << ", " << px.rowPx << "): the truth moves it " << st.norm() * rig.truth.camera.fxPx
                   << " px, the estimate " << se.norm() * rig.truth.camera.fxPx << " px");
    CHECK(st.norm() * rig.truth.camera.fxPx > 3.0 * tolerance);  // there is distortion to get right
    CHECK((st - se).norm() * rig.truth.camera.fxPx < tolerance);
  }
  // Poses: every view's plane within a millimetre.
  for (size_t i = 0; i < poses.size(); ++i) {
    CHECK(std::abs(fit->poses[i].planeOffsetMm() - poses[i].planeOffsetMm()) < 1.0);
    CHECK((fit->poses[i].planeNormal() - poses[i].planeNormal()).norm() < 2e-3);
  }
  CHECK(calibrateCamera({views[0], views[1]}, 2048, 1536).status().code() == Error::kBadInput);
}

TEST_CASE("Misplaced corners are left out before the final solve", "[calibration]") {
  Rig rig;
  std::mt19937 rng(12);
  std::vector<TargetView> views;
  for (int i = 0; i < 12; ++i) {
    const double yaw = -30.0 + 60.0 * (i % 5) / 4.0;
    const double pitch = -25.0 + 50.0 * (i % 3) / 2.0;
    const Eigen::Vector2d off(-150.0 + 300.0 * (i % 4) / 3.0, -100.0 + 200.0 * (i % 2));
    views.push_back(
        viewOf(rig.truth.camera, makePose(600.0 + 40.0 * i, yaw, pitch, off, rig.gridCentre), rig.corners, 0.15, rng));
  }
  // What the sector detector does on a blurred view: a few corners 4-6 px off.
  std::vector<TargetView> bad = views;
  const std::vector<std::pair<size_t, size_t>> moved{{0, 3}, {2, 17}, {5, 40}, {5, 41}, {9, 8}, {11, 30}};
  std::uniform_real_distribution<double> angle(0.0, 2.0 * M_PI);
  for (const auto& [v, k] : moved) {
    const double a = angle(rng);
    bad[v].imagePx[k] += (4.0 + static_cast<double>(k % 3)) * Eigen::Vector2d(std::cos(a), std::sin(a));
  }
  const int w = rig.truth.camera.widthPx;
  const int h = rig.truth.camera.heightPx;
  CameraFitOptions keep;
  keep.outlierSigmas = 0.0;
  auto clean = calibrateCamera(views, w, h, keep);
  auto kept = calibrateCamera(bad, w, h, keep);
  auto rejected = calibrateCamera(bad, w, h);  // the default: outliers left out
  REQUIRE(clean.isOk());
  REQUIRE(kept.isOk());
  REQUIRE(rejected.isOk());
  CHECK(kept->outliers.count() == 0);
  // Exactly the moved corners, and no good one (the bound: 1 px, 5 robust sigmas of 0.15 px).
  REQUIRE(rejected->outliers.perView.size() == views.size());
  CHECK(rejected->outliers.count() == moved.size());
  for (const auto& [v, k] : moved) {
    const auto& list = rejected->outliers.perView[v];
    CHECK(std::find(list.begin(), list.end(), k) != list.end());
  }
  CHECK(rejected->outliers.boundPx == Approx(1.0));
  CHECK(rejected->outliers.sigmaPx == Approx(0.15).margin(0.03));
  // Kept, the six corners double the RMS and move the focal length and principal point by
  // more than the clean fit's own error; left out, the fit is the clean one.
  INFO("rms clean " << clean->rmsPx << " kept " << kept->rmsPx << " rejected " << rejected->rmsPx);
  CHECK(kept->rmsPx > 1.5 * clean->rmsPx);
  CHECK(rejected->rmsPx == Approx(clean->rmsPx).margin(0.01));
  const auto err = [&](const CameraFit& f) {
    return std::hypot(f.camera.fxPx - rig.truth.camera.fxPx, f.camera.cxPx - rig.truth.camera.cxPx) +
           std::hypot(f.camera.fyPx - rig.truth.camera.fyPx, f.camera.cyPx - rig.truth.camera.cyPx);
  };
  INFO("intrinsics error clean " << err(*clean) << " kept " << err(*kept) << " rejected " << err(*rejected) << " px");
  CHECK(std::abs(err(*rejected) - err(*clean)) < 0.1 * err(*clean) + 0.05);
  CHECK(rejected->sigmaPx[0] < kept->sigmaPx[0]);
  // The views without them keep their order and every other corner.
  const std::vector<TargetView> without = withoutCorners(bad, rejected->outliers);
  REQUIRE(without.size() == bad.size());
  CHECK(without[5].imagePx.size() == bad[5].imagePx.size() - 2);
  CHECK(without[1].imagePx.size() == bad[1].imagePx.size());
  CHECK(without[5].imagePx[40] == bad[5].imagePx[42]);
}

TEST_CASE("A target's pose in a calibrated camera", "[calibration]") {
  Rig rig;
  std::mt19937 rng(5);
  const TargetPose truth = makePose(1300, 20, -10, {10, 15}, rig.gridCentre);
  const TargetView view = viewOf(rig.truth.camera, truth, rig.corners, 0.1, rng);
  auto pose = locateTarget(rig.truth.camera, view);
  REQUIRE(pose.isOk());
  CHECK(pose->rmsPx < 0.2);
  CHECK((pose->translationMm - truth.translationMm).norm() < 2.0);
  CHECK(std::abs(pose->planeOffsetMm() - truth.planeOffsetMm()) < 0.5);
  CHECK(locateTarget(rig.truth.camera, TargetView{}).status().code() == Error::kBadInput);
}

TEST_CASE("Laser plane and slide come back from lines on a flat target, despite reflections", "[calibration][render]") {
  Rig rig;
  std::mt19937 rng(7);
  std::vector<LaserLineSample> samples;
  const std::vector<TargetPose> poses = placements();
  for (size_t p = 0; p < poses.size(); ++p) {
    // The target's plane as the calibrate tool gets it: from noisy corners.
    auto measured = locateTarget(rig.truth.camera, viewOf(rig.truth.camera, poses[p], rig.corners, 0.1, rng));
    REQUIRE(measured.isOk());
    for (double slide : {0.0, 50.0, 100.0, 150.0, 200.0})
      samples.push_back(lineOn(rig.truth, poses[p], *measured, static_cast<int>(p), slide, 0.15, 0.05, rng));
  }
  LaserFitOptions opt;
  opt.focalPx = rig.truth.camera.fxPx;
  // The drawing's slide axis, a little off the true one: only its component along the
  // normal is observable, and the scale absorbs the difference.
  opt.nominalSlideAxis = Eigen::Vector3d(1.0, 0.0, 0.0);
  auto fit = calibrateLaser(samples, opt);
  REQUIRE(fit.isOk());
  const LaserGeometry& t = rig.truth.laser;
  const LaserGeometry& e = fit->laser;
  INFO("normal " << e.planeNormal.transpose() << " d0 " << e.planeOffsetMm << " scale " << e.slideScale << " rms "
                 << fit->rmsPx << " px, σn " << fit->normalSigmaMrad << " mrad, σd0 " << fit->offsetSigmaMm
                 << " mm, σz(1.6 m) " << fit->depthSigmaMmAt1600 << " mm");
  CHECK(std::acos(std::min(1.0, e.planeNormal.dot(t.planeNormal))) < 0.5e-3);
  for (double s : {0.0, 100.0, 200.0}) CHECK(std::abs(e.planeOffsetAt(s) - t.planeOffsetAt(s)) < 0.3);
  CHECK(fit->rmsPx < 0.25);
  CHECK(static_cast<double>(fit->inliers) / static_cast<double>(fit->points) > 0.9);
  CHECK(fit->placements == 6);
  CHECK(fit->slidePositions == 5);
  CHECK(fit->normalSigmaMrad > 0.0);
  CHECK(fit->depthSigmaMmAt1600 > fit->depthSigmaMmAt1000);
  // What matters: points triangulated with the estimate land where the truth puts them.
  double worst = 0.0;
  for (double z : {1000.0, 1300.0, 1600.0}) {
    for (double slide : {20.0, 100.0, 180.0}) {
      // The point at height 40 mm and depth z that the true plane at `slide` lights.
      const Eigen::Vector3d n = t.planeNormal;
      const double x = (t.planeOffsetAt(slide) - n.y() * 40.0 - n.z() * z) / n.x();
      const Eigen::Vector3d p(x, 40.0, z);
      const auto xn = undistortPixels(rig.truth.camera, {projectPoint(rig.truth.camera, p)})[0];
      const TriangulatedPoint q = triangulate(e, slide, xn);
      INFO("point " << p.transpose() << " slide " << slide);
      REQUIRE(q.valid);
      worst = std::max(worst, (q.pointMm - p).norm());
    }
  }
  INFO("worst triangulation error " << worst << " mm");
  CHECK(worst < 1.0);
  // The reported uncertainty covers the error it predicts (within 4σ).
  const Eigen::Vector3d axisPoint(0.0, 0.0, 1600.0);
  const double s = t.slideForPoint(axisPoint);
  const TriangulatedPoint q = triangulate(e, s, Eigen::Vector2d(0.0, 0.0));
  REQUIRE(q.valid);
  CHECK(std::abs(q.pointMm.z() - 1600.0) < 4.0 * fit->depthSigmaMmAt1600 + 0.05);
}

TEST_CASE("Laser calibration refuses data that cannot determine the plane", "[calibration]") {
  Rig rig;
  std::mt19937 rng(9);
  const std::vector<TargetPose> poses = placements();
  std::vector<LaserLineSample> oneSlide;
  for (size_t p = 0; p < poses.size(); ++p)
    oneSlide.push_back(lineOn(rig.truth, poses[p], poses[p], static_cast<int>(p), 100.0, 0.15, 0.0, rng));
  auto fit = calibrateLaser(oneSlide);
  REQUIRE_FALSE(fit.isOk());
  CHECK(fit.status().reason().find("slide positions") != std::string::npos);
  CHECK(calibrateLaser({}).status().code() == Error::kBadInput);
}

TEST_CASE("The quality gate names every figure it refuses", "[calibration]") {
  CalibrationQuality good;
  good.reprojectionRmsPx = 0.12;
  good.cameraViews = 14;
  good.fxSigmaPx = 0.8;
  good.fySigmaPx = 0.8;
  good.cxSigmaPx = 0.6;
  good.cySigmaPx = 0.6;
  good.laserRmsPx = 0.15;
  good.planeRmsMm = 0.1;
  good.inlierShare = 0.97;
  good.targetPlacements = 6;
  good.slidePositions = 5;
  good.normalSigmaMrad = 0.05;
  good.offsetSigmaMm = 0.05;
  good.scaleSigma = 0.0002;
  good.depthSigmaMmAt1000 = 0.1;
  good.depthSigmaMmAt1600 = 0.2;
  CHECK(checkCalibrationQuality(good).passed());
  CHECK(checkCalibrationQuality(good).status().isOk());

  CalibrationQuality bad = good;
  bad.laserRmsPx = 0.9;
  bad.targetPlacements = 2;
  bad.depthSigmaMmAt1600 = std::nan("");
  const GateVerdict v = checkCalibrationQuality(bad);
  REQUIRE(v.failures.size() == 3);
  const std::string reason = v.status().reason();
  CHECK(reason.find("quality.laser_rms_px 0.9 exceeds 0.5") != std::string::npos);
  CHECK(reason.find("quality.target_placements 2 is below 4") != std::string::npos);
  // A figure its stage could not compute (NaN) is named as such, not as a number.
  CHECK(reason.find("quality.depth_sigma_mm_at_1600 not measured (limit") != std::string::npos);
  CHECK(v.status().code() == Error::kBadInput);

  // Limits from a file; a bad key is named.
  const test::TempDir tmp;
  const std::string path = tmp.file("limits.json");
  std::ofstream(path) << R"({"max_laser_rms_px": 1.0, "min_target_placements": 2})";
  auto limits = CalibrationLimits::load(path);
  REQUIRE(limits.isOk());
  CHECK(checkCalibrationQuality(bad, *limits).failures.size() == 1);
  std::ofstream(path) << R"({"max_laser_rms_px": "big"})";
  CHECK(CalibrationLimits::load(path).status().reason().find("max_laser_rms_px") != std::string::npos);
}

TEST_CASE("Quality figures round-trip; a refused calibration never loads", "[calibration]") {
  Calibration cal = sim::defaultScene().truth;
  cal.quality.fromTruth = false;
  cal.quality.laserRmsPx = 0.17;
  cal.quality.targetPlacements = 6;
  cal.quality.depthSigmaMmAt1600 = 0.31;
  cal.quality.gate = CalibrationQuality::Gate::kPassed;
  const test::TempDir tmp;
  const std::string path = tmp.file("cal_quality.json");
  REQUIRE(saveCalibration(cal, path).isOk());
  auto back = loadCalibration(path);
  REQUIRE(back.isOk());
  CHECK(back->quality.laserRmsPx == Approx(0.17));
  CHECK(back->quality.targetPlacements == 6);
  CHECK(back->quality.depthSigmaMmAt1600 == Approx(0.31));
  CHECK(back->quality.gate == CalibrationQuality::Gate::kPassed);
  CHECK_FALSE(back->quality.fromTruth);

  cal.quality.gate = CalibrationQuality::Gate::kRefused;
  REQUIRE(saveCalibration(cal, path).isOk());
  auto refused = loadCalibration(path);
  REQUIRE_FALSE(refused.isOk());
  CHECK(refused.status().reason().find("quality.gate") != std::string::npos);

  // Inconsistent distortion (the radial model folds the frame) is named.
  cal.quality.gate = CalibrationQuality::Gate::kPassed;
  cal.camera.distortion = {-0.9, 0.0, 0.0, 0.0, 0.0};
  CHECK(validateCalibration(cal).reason().find("camera.distortion") != std::string::npos);
}

TEST_CASE("The intrinsics' full covariance agrees with calib3d's sigma and keeps the fx-fy coupling", "[calibration]") {
  Rig rig;
  const SyntheticCalibration run = calibrateSynthetic(rig, 21, 10);
  const IntrinsicsCovariance& c = run.camera.covariance;
  for (int i = 0; i < 4; ++i) {
    INFO("parameter " << i);
    CHECK(std::sqrt(c(i, i)) == Approx(run.camera.sigmaPx[static_cast<size_t>(i)]).epsilon(0.02));
  }
  CHECK(std::sqrt(c(4, 4)) == Approx(run.camera.sigmaDistortion[0]).epsilon(0.02));
  CHECK(c(8, 8) == 0.0);  // k3 fixed: no variance
  // A common focal error: fx and fy move together.
  CHECK(c(0, 1) / std::sqrt(c(0, 0) * c(1, 1)) > 0.8);
}

TEST_CASE("The total depth sigma includes the intrinsics, grows with depth and predicts the real error",
          "[calibration][slow]") {
  Rig rig;
  double sumZ2 = 0.0;
  int count = 0;
  for (unsigned seed = 1; seed <= 6; ++seed) {
    const SyntheticCalibration run = calibrateSynthetic(rig, seed, 10);
    auto unc = propagateCalibrationUncertainty(run.camera.camera, run.camera.covariance, run.laser, run.observations);
    REQUIRE(unc.isOk());
    REQUIRE(unc->byDepth.size() == 4);
    CHECK(unc->solves == 16);  // ±1σ along 8 free intrinsics
    Calibration est;
    est.camera = run.camera.camera;
    est.laser = run.laser.laser;
    for (size_t d = 0; d < unc->byDepth.size(); ++d) {
      const DepthUncertainty& u = unc->byDepth[d];
      const double err = rmsDepthErrorMm(rig.truth, est, u.depthMm);
      INFO("seed " << seed << " depth " << u.depthMm << ": laser-only " << u.depthSigmaLaserMm << " intrinsics "
                   << u.depthSigmaIntrinsicsMm << " total " << u.depthSigmaTotalMm << " 3D " << u.sigma3dTotalMm
                   << ", real RMS depth error " << err << " mm");
      CHECK(u.points > 50);
      // The intrinsics dominate: the laser-only figure alone is blind to them.
      CHECK(u.depthSigmaIntrinsicsMm > u.depthSigmaLaserMm);
      CHECK(u.depthSigmaTotalMm > u.depthSigmaLaserMm);
      CHECK(u.sigma3dTotalMm >= u.depthSigmaTotalMm);
      if (d > 0) CHECK(u.depthSigmaTotalMm > unc->byDepth[d - 1].depthSigmaTotalMm);
      CHECK(err < 4.0 * u.depthSigmaTotalMm);
      sumZ2 += std::pow(err / u.depthSigmaTotalMm, 2);
      ++count;
    }
    // On the optical axis the old laser-only figure is far below the total.
    CHECK(run.laser.depthSigmaMmAt1600 < unc->byDepth[3].depthSigmaTotalMm);
  }
  // Over the seeds the error is of the order of σ: neither blind (≫ 1) nor vacuous (≪ 1).
  // (calib3d's σ convention is √2 conservative for independent corner noise: expect ~0.7.)
  const double rmsZ = std::sqrt(sumZ2 / count);
  INFO("RMS of error/σ over seeds and depths: " << rmsZ);
  CHECK(rmsZ > 0.25);
  CHECK(rmsZ < 2.0);
}

TEST_CASE("The Monte Carlo of the intrinsics agrees with the linearised total sigma", "[calibration][slow]") {
  Rig rig;
  const SyntheticCalibration run = calibrateSynthetic(rig, 3, 10);
  auto linear = propagateCalibrationUncertainty(run.camera.camera, run.camera.covariance, run.laser, run.observations);
  UncertaintyOptions mc;
  mc.draws = 100;
  mc.seed = 7;
  auto sampled =
      propagateCalibrationUncertainty(run.camera.camera, run.camera.covariance, run.laser, run.observations, mc);
  REQUIRE(linear.isOk());
  REQUIRE(sampled.isOk());
  CHECK(sampled->solves == 100);
  for (size_t d = 0; d < 4; ++d) {
    INFO("depth " << linear->byDepth[d].depthMm << ": linear " << linear->byDepth[d].depthSigmaTotalMm << " Monte Carlo "
                  << sampled->byDepth[d].depthSigmaTotalMm);
    // 100 draws: the sampled σ is good to ~7 % (1σ).
    CHECK(sampled->byDepth[d].depthSigmaTotalMm == Approx(linear->byDepth[d].depthSigmaTotalMm).epsilon(0.25));
  }
}

TEST_CASE("The gate refuses a large total depth sigma and names the field", "[calibration]") {
  CalibrationQuality q;
  q.reprojectionRmsPx = 0.12;
  q.cameraViews = 14;
  q.fxSigmaPx = 2.5;  // inside its own limit (4 px) ...
  q.fySigmaPx = 2.5;
  q.laserRmsPx = 0.15;
  q.planeRmsMm = 0.1;
  q.inlierShare = 0.97;
  q.targetPlacements = 6;
  q.slidePositions = 5;
  q.depthSigmaMmAt1000 = 0.05;  // ... and the laser-only figures look fine,
  q.depthSigmaMmAt1600 = 0.2;
  q.depthSigmaTotalMmAt1000 = 1.1;  // but the total says 1 mm of depth at 1 m
  q.depthSigmaTotalMmAt1600 = 1.7;
  const CalibrationLimits defaults;
  const GateVerdict v = checkCalibrationQuality(q, defaults);
  REQUIRE(v.failures.size() == 2);
  CHECK(v.status().reason().find("quality.depth_sigma_total_mm_at_1000 1.1 exceeds 1") != std::string::npos);
  CHECK(v.status().reason().find("quality.depth_sigma_total_mm_at_1600 1.7 exceeds 1.6") != std::string::npos);
  q.depthSigmaTotalMmAt1000 = 0.5;
  q.depthSigmaTotalMmAt1600 = 0.9;
  CHECK(checkCalibrationQuality(q, defaults).passed());

  const test::TempDir tmp;
  const std::string path = tmp.file("limits_total.json");
  std::ofstream(path) << R"({"max_depth_sigma_total_mm_at_1600": 0.8})";
  auto limits = CalibrationLimits::load(path);
  REQUIRE(limits.isOk());
  CHECK(limits->maxDepthSigmaTotalMmAt1600 == Approx(0.8));
  CHECK(limits->maxDepthSigmaTotalMmAt1000 == Approx(defaults.maxDepthSigmaTotalMmAt1000));
  const GateVerdict tight = checkCalibrationQuality(q, *limits);
  REQUIRE(tight.failures.size() == 1);
  CHECK(tight.failures[0].find("quality.depth_sigma_total_mm_at_1600") == 0);
  std::ofstream(path) << R"({"max_depth_sigma_total_mm_at_1000": -1})";
  CHECK(CalibrationLimits::load(path).status().reason().find("max_depth_sigma_total_mm_at_1000") != std::string::npos);
}

TEST_CASE("The total sigma figures round-trip through calibration.json", "[calibration]") {
  Calibration cal = sim::defaultScene().truth;
  cal.quality.fromTruth = false;
  cal.quality.depthSigmaTotalMmAt1000 = 0.52;
  cal.quality.depthSigmaTotalMmAt1400 = 0.75;
  cal.quality.sigma3dTotalMmAt1600 = 1.43;
  const test::TempDir tmp;
  const std::string path = tmp.file("cal_total_sigma.json");
  REQUIRE(saveCalibration(cal, path).isOk());
  auto back = loadCalibration(path);
  REQUIRE(back.isOk());
  CHECK(back->quality.depthSigmaTotalMmAt1000 == Approx(0.52));
  CHECK(back->quality.depthSigmaTotalMmAt1400 == Approx(0.75));
  CHECK(back->quality.sigma3dTotalMmAt1600 == Approx(1.43));
  cal.quality.depthSigmaTotalMmAt1600 = -1.0;
  CHECK(validateCalibration(cal).reason().find("quality.depth_sigma_total_mm_at_1600") != std::string::npos);
}
