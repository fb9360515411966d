// The twin's renderer: deterministic, a region render equals the full frame's crop, the
// laser line lands where the truth says and is about 4 px wide at 0.8-1.6 m (the paper),
// exposure and light scale the signal until it clips, a moving slide smears the line,
// 635 nm light lands in the red channel.
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <memory>

#include "sim/orchard.h"
#include "sim/renderer.h"
#include "sim/scene.h"
#include "sim/truth.h"

using namespace alacs;

namespace {

std::shared_ptr<const sim::RayTable> fullRays() {
  static const auto table = std::make_shared<const sim::RayTable>(sim::defaultScene().truth.camera);
  return table;
}

// A small camera (320×240) with the default's field of view and distortion, and a
// scene with every kind of object, for whole-frame comparisons that stay fast.
sim::SimScene smallScene(bool bayer) {
  sim::SimScene s = sim::defaultScene();
  auto& cam = s.truth.camera;
  cam.widthPx = 320;
  cam.heightPx = 240;
  cam.fxPx = 375.0;
  cam.fyPx = 375.3;
  cam.cxPx = 160.2;
  cam.cyPx = 119.7;
  s.sensor.bayer = bayer;
  s.background.kind = sim::SimBackground::Kind::kFoliage;
  s.background.skyShare = 0.2;
  s.lighting.directLux = 3000.0;
  s.lighting.diffuseLux = 1500.0;
  sim::SimLeaf leaf;
  leaf.centerMm = Eigen::Vector3d(-60.0, -40.0, 1050.0);
  leaf.normal = Eigen::Vector3d(0.3, 0.2, -1.0).normalized();
  leaf.axis = leaf.normal.unitOrthogonal();
  s.leaves.push_back(leaf);
  sim::SimBranch br;
  s.branches.push_back(br);
  return s;
}

cv::Mat red(const cv::Mat& bgr) {
  cv::Mat ch[3];
  cv::split(bgr, ch);
  cv::Mat r;
  ch[2].convertTo(r, CV_64F);
  return r;
}

struct LineStats {
  double meanOffsetPx = 0;  // mean |peak centroid - truth column|
  double medianWidthPx = 0; // median full width at half maximum of the red excess
  int rows = 0;
};

// Renders the apple's region with and without the laser (same noise seed) and measures
// the red excess row by row over the central half of the true line.
LineStats measureLine(const sim::SimScene& scene, const sim::FrameRequest& on) {
  sim::Renderer r(scene, fullRays());
  const auto& apple = scene.apples[0];
  const auto truth = sim::laserLineTruth(scene, apple, 0.5 * (on.slideStartMm + on.slideEndMm));
  REQUIRE(truth.size() > 20);
  int minRow = truth.front().row, maxRow = truth.back().row;
  int minCol = 1 << 30, maxCol = -(1 << 30);
  for (const auto& t : truth) {
    minCol = std::min(minCol, static_cast<int>(t.column));
    maxCol = std::max(maxCol, static_cast<int>(t.column));
  }
  const cv::Rect roi(minCol - 30, minRow, maxCol - minCol + 60, maxRow - minRow + 1);
  cv::Mat a, b;
  r.renderRegion(on, roi, a);
  sim::FrameRequest off = on;
  off.laserFraction = 0.0;
  r.renderRegion(off, roi, b);
  const cv::Mat excess = red(a) - red(b);
  std::vector<double> widths;
  double sumOff = 0;
  int n = 0;
  const size_t lo = truth.size() / 4, hi = truth.size() - truth.size() / 4;
  for (size_t i = lo; i < hi; ++i) {
    const auto& t = truth[i];
    const int y = t.row - roi.y;
    const double* e = excess.ptr<double>(y);
    const int c0 = static_cast<int>(std::lround(t.column)) - roi.x;
    int peak = c0;
    for (int c = c0 - 4; c <= c0 + 4; ++c)
      if (e[c] > e[peak]) peak = c;
    const double half = 0.5 * e[peak];
    if (half < 5) continue;
    double left = peak, right = peak;
    for (int c = peak; c > 0; --c)
      if (e[c - 1] < half) {
        left = c - (half - e[c - 1]) / (e[c] - e[c - 1]);
        break;
      }
    for (int c = peak; c + 1 < roi.width; ++c)
      if (e[c + 1] < half) {
        right = c + (e[c] - half) / (e[c] - e[c + 1]);
        break;
      }
    widths.push_back(right - left);
    double sw = 0, swx = 0;
    for (int c = peak - 4; c <= peak + 4; ++c) {
      const double w = std::max(0.0, e[c]);
      sw += w;
      swx += w * c;
    }
    sumOff += std::abs(swx / sw + roi.x - t.column);
    ++n;
  }
  LineStats st;
  st.rows = n;
  if (n == 0) return st;
  std::sort(widths.begin(), widths.end());
  st.medianWidthPx = widths[widths.size() / 2];
  st.meanOffsetPx = sumOff / n;
  return st;
}

sim::SimScene appleAt(double z) {
  sim::SimScene s = sim::defaultScene();
  s.apples[0].centerMm = Eigen::Vector3d(10.0, -20.0, z);
  return s;
}

}  // namespace

TEST_CASE("A region render is exactly the crop of the full frame", "[sim][render]") {
  for (bool bayer : {false, true}) {
    const sim::SimScene s = smallScene(bayer);
    sim::Renderer r(s);
    sim::FrameRequest req;
    req.slideStartMm = 95.0;
    req.slideEndMm = 97.0;  // moving, so the smear path is covered too
    req.frameIndex = 3;
    cv::Mat full, crop;
    r.render(req, full);
    for (const cv::Rect roi : {cv::Rect(101, 57, 90, 71), cv::Rect(0, 0, 40, 30), cv::Rect(250, 190, 70, 50)}) {
      r.renderRegion(req, roi, crop);
      REQUIRE(crop.size() == roi.size());
      INFO("bayer " << bayer << " roi " << roi);
      CHECK(cv::norm(crop, full(roi), cv::NORM_INF) == 0.0);
    }
  }
}

TEST_CASE("Rendering is deterministic per frame index; another frame has other noise", "[sim][render]") {
  const sim::SimScene s = smallScene(false);
  sim::Renderer r1(s), r2(s);
  cv::Mat a, b, c;
  sim::FrameRequest req;
  req.slideStartMm = req.slideEndMm = 100.0;
  req.frameIndex = 7;
  r1.render(req, a);
  r2.render(req, b);
  CHECK(cv::norm(a, b, cv::NORM_INF) == 0.0);
  req.frameIndex = 8;
  r1.render(req, c);
  CHECK(cv::norm(a, c, cv::NORM_L1) > 1000.0);
}

TEST_CASE("The laser line lies on the truth and is about 4 px wide from 0.8 to 1.6 m", "[sim][render]") {
  for (double z : {800.0, 1200.0, 1600.0}) {
    sim::SimScene s = appleAt(z);
    s.laser.speckleContrast = 0.0;
    const double slide = s.truth.laser.slideForPoint(s.apples[0].centerMm + Eigen::Vector3d(8.0, 0, 0));
    sim::FrameRequest req;
    req.slideStartMm = req.slideEndMm = slide;
    req.exposureUs = static_cast<int64_t>(300.0 * (z / 1200.0) * (z / 1200.0));  // keep the peak unsaturated
    const LineStats st = measureLine(s, req);
    INFO("z " << z << " mm: width " << st.medianWidthPx << " px, offset " << st.meanOffsetPx << " px over " << st.rows << " rows");
    REQUIRE(st.rows > 20);
    CHECK(st.medianWidthPx > 3.0);
    CHECK(st.medianWidthPx < 5.0);
    CHECK(st.meanOffsetPx < 0.35);
  }
}

TEST_CASE("A slide moving during the exposure smears the line over its travel", "[sim][render]") {
  sim::SimScene s = appleAt(1200.0);
  s.laser.speckleContrast = 0.0;
  const double slide = s.truth.laser.slideForPoint(s.apples[0].centerMm);
  sim::FrameRequest still;
  still.slideStartMm = still.slideEndMm = slide;
  still.exposureUs = 300;
  sim::FrameRequest moving = still;
  moving.slideStartMm = slide - 1.5;
  moving.slideEndMm = slide + 1.5;  // 3 mm of travel: about 6 px at 1.2 m
  const LineStats a = measureLine(s, still);
  const LineStats b = measureLine(s, moving);
  // The line's travel in the image: the plane moves 3·(n·a)·scale mm along its normal.
  const auto& las = s.truth.laser;
  const double travelMm = 3.0 * las.slideScale * las.planeNormal.dot(las.slideAxis);
  const double travelPx = travelMm / las.planeNormal.x() * s.truth.camera.fxPx / (s.apples[0].centerMm.z() - 30.0);
  INFO("still " << a.medianWidthPx << " px, moving " << b.medianWidthPx << " px, travel " << travelPx << " px");
  CHECK(b.medianWidthPx > 0.9 * travelPx);
  CHECK(b.medianWidthPx > a.medianWidthPx + 1.5);
  CHECK(b.meanOffsetPx < 0.6);  // centred on the mid-exposure position
}

TEST_CASE("Ambient signal scales with exposure and clips at 255; laser light is red", "[sim][render]") {
  sim::SimScene s = sim::defaultScene();
  s.laser.speckleContrast = 0.0;
  sim::Renderer r(s, fullRays());
  const cv::Rect patch(995, 690, 30, 30);  // on the apple, away from the line and the highlight
  auto meanRed = [&](int64_t us, double laser, double slide) {
    sim::FrameRequest req;
    req.slideStartMm = req.slideEndMm = slide;
    req.exposureUs = us;
    req.laserFraction = laser;
    cv::Mat m;
    r.renderRegion(req, patch, m);
    return cv::mean(m);
  };
  const cv::Scalar one = meanRed(1000, 0.0, 0.0);
  const cv::Scalar two = meanRed(2000, 0.0, 0.0);
  CHECK(one[2] > 10.0);
  CHECK(std::abs(two[2] / one[2] - 2.0) < 0.1);
  const cv::Scalar lots = meanRed(200000, 0.0, 0.0);
  CHECK(lots[2] == 255.0);
  // The analogue gain: the default scene's 6 dB is twice 0 dB; half the gain at twice the
  // exposure gives the same level (and, with twice the light, less noise).
  {
    sim::FrameRequest req;
    req.exposureUs = 2000;
    req.analogueGain = s.sensor.analogueGain() / 2.0;
    cv::Mat m;
    r.renderRegion(req, patch, m);
    CHECK(std::abs(cv::mean(m)[2] / one[2] - 1.0) < 0.05);
  }

  // Laser only (difference of on and off, same noise seed): mostly red.
  const double slide = s.truth.laser.slideForPoint(s.apples[0].centerMm);
  const auto truth = sim::laserLineTruth(s, s.apples[0], slide);
  const auto& mid = truth[truth.size() / 2];
  const cv::Rect line(static_cast<int>(mid.column) - 3, mid.row - 10, 7, 20);
  sim::FrameRequest on;
  on.slideStartMm = on.slideEndMm = slide;
  on.exposureUs = 400;
  sim::FrameRequest off = on;
  off.laserFraction = 0.0;
  cv::Mat a, b;
  r.renderRegion(on, line, a);
  r.renderRegion(off, line, b);
  const cv::Scalar ea = cv::mean(a), eb = cv::mean(b);
  const double dr = ea[2] - eb[2], dg = ea[1] - eb[1], db = ea[0] - eb[0];
  INFO("laser excess R " << dr << " G " << dg << " B " << db);
  CHECK(dr > 20.0);
  CHECK(dg / dr < 0.15);
  CHECK(db / dr < 0.1);
}

TEST_CASE("Full sun saturates a 3 ms exposure; the auto exposure does not", "[sim][render]") {
  sim::SimScene s = sim::defaultScene();
  s.lighting.directLux = 70000.0;
  s.lighting.diffuseLux = 10000.0;
  sim::Renderer r(s, fullRays());
  const cv::Rect patch(900, 600, 60, 60);
  sim::FrameRequest req;
  req.exposureUs = 3000;
  req.laserFraction = 0.0;
  cv::Mat m;
  r.renderRegion(req, patch, m);
  CHECK(cv::mean(m)[2] > 250.0);
  req.exposureUs = sim::autoExposureUs(s);
  r.renderRegion(req, patch, m);
  INFO("auto exposure " << req.exposureUs << " us");
  CHECK(req.exposureUs < 100);
  CHECK(cv::mean(m)[2] < 200.0);
}

TEST_CASE("With the laser off there is no line", "[sim][render]") {
  sim::SimScene s = sim::defaultScene();
  sim::Renderer r(s, fullRays());
  const double slide = s.truth.laser.slideForPoint(s.apples[0].centerMm);
  const auto truth = sim::laserLineTruth(s, s.apples[0], slide);
  const auto& mid = truth[truth.size() / 2];
  const cv::Rect around(static_cast<int>(mid.column) - 20, mid.row - 20, 41, 41);
  sim::FrameRequest req;
  req.slideStartMm = req.slideEndMm = slide;
  req.laserFraction = 0.0;
  cv::Mat m;
  r.renderRegion(req, around, m);
  req.laserFraction = 1.0;
  cv::Mat l;
  r.renderRegion(req, around, l);
  // Red on the true line's column against 8 px to either side, over 41 rows.
  auto contrast = [&](const cv::Mat& img) {
    const cv::Mat rr = red(img);
    const int c = static_cast<int>(std::lround(mid.column)) - around.x;
    return cv::mean(rr.col(c))[0] - 0.5 * (cv::mean(rr.col(c - 8))[0] + cv::mean(rr.col(c + 8))[0]);
  };
  INFO("contrast off " << contrast(m) << " on " << contrast(l));
  CHECK(std::abs(contrast(m)) < 10.0);
  CHECK(contrast(l) > 100.0);
}
