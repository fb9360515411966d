// LLE in full sun with and without the 635 nm band-pass filter of the twin's camera
// (sim::SimSensor::bandpassFwhmNm; docs/simulation.md "Band-pass filter", docs/lle.md).
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <map>

#include "image/lle.h"
#include "sim/orchard.h"
#include "sim/renderer.h"
#include "sim/truth.h"

using namespace alacs;

namespace {

struct SunResult {
  int visible = 0;
  int found = 0;  // visible truth rows with a valid sample within 1 px
  int64_t exposureUs = 0;
};

SunResult sunCase(double bandpassNm, uint64_t seed) {
  sim::CaseSpec spec;
  spec.lighting = sim::LightingKind::kFullSun;
  spec.distanceMm = 900.0;
  spec.bandpassFwhmNm = bandpassNm;
  Result<sim::OrchardCase> oc = sim::makeOrchardCase(spec, seed);
  REQUIRE(oc.isOk());
  const sim::SimScene& scene = oc->scene;
  const sim::SimApple& target = *scene.apple(oc->targetId);
  const double slide = oc->slideCentreMm;
  const std::vector<sim::RowTruth> truth = sim::laserLineTruthAll(scene, target, slide);
  int r0 = 1 << 30, r1 = -1, c0 = 1 << 30, c1 = -1;
  std::map<int, double> visible;
  for (const auto& t : truth) {
    if (!t.visibleLit()) continue;
    visible[t.row] = t.column;
    r0 = std::min(r0, t.row);
    r1 = std::max(r1, t.row);
    c0 = std::min(c0, static_cast<int>(t.column));
    c1 = std::max(c1, static_cast<int>(t.column));
  }
  REQUIRE(r1 - r0 > 40);
  const cv::Rect rect(c0 - 40, r0 - 10, c1 - c0 + 80, r1 - r0 + 20);
  sim::Renderer renderer(scene);
  sim::FrameRequest req;
  req.slideStartMm = req.slideEndMm = slide;
  cv::Mat crop;
  renderer.renderRegion(req, rect, crop);
  image::LleWorkspace ws;
  image::LaserLine line;
  const image::ImageView view{crop.data, crop.cols, crop.rows, crop.step[0], image::PixelFormat::kBgr888};
  REQUIRE(image::extractLine(view, image::Roi{0, 0, crop.cols, crop.rows}, image::LleParams{}, ws, line).isOk());
  SunResult res;
  res.exposureUs = scene.sensor.exposureUs;
  for (const auto& [row, col] : visible) {
    res.visible += 1;
    for (const auto& s : line.rows)
      if (s.row == row - rect.y && s.valid() && std::abs(s.column + rect.x - col) < 1.0) {
        res.found += 1;
        break;
      }
  }
  return res;
}

}  // namespace

TEST_CASE("The twin's 635 nm band-pass filter: transmissions and auto-exposure", "[sim][lle]") {
  sim::SimSensor s;
  CHECK(s.ambientFilterRgb() == Eigen::Vector3d::Ones());
  CHECK(s.laserFilter(0.0) == 1.0);
  s.bandpassFwhmNm = 10.0;
  const Eigen::Vector3d f = s.ambientFilterRgb();
  CHECK(f.x() == Approx(0.9 * 10.0 / 80.0));   // peak · FWHM / the red channel's 80 nm
  CHECK(f.y() == Approx(0.9 * 10.0 * 0.08 / 100.0));
  CHECK(f.z() == Approx(0.9 * 10.0 * 0.04 / 100.0));
  CHECK(s.laserFilter(0.0) == Approx(0.9));    // 635 nm: 2 nm below the 637 nm centre, in the flat top
  // 30° off axis the centre moves to 637·√(1 − 0.25/4) = 616.8 nm: the laser is blocked.
  CHECK(s.laserFilter(0.25) == 0.0);
  // Half of the peak where the shifted centre is FWHM/2 from 635 nm.
  const double cwl = 635.0 - 5.0;
  const double sin2 = 4.0 * (1.0 - (cwl / 637.0) * (cwl / 637.0));
  CHECK(s.laserFilter(sin2) == Approx(0.45).margin(1e-9));
  sim::SimScene scene = sim::defaultScene();
  scene.lighting.diffuseLux = 9000.0;
  scene.lighting.directLux = 51000.0;
  const int64_t plain = sim::autoExposureUs(scene);
  scene.sensor.bandpassFwhmNm = 10.0;
  const int64_t filtered = sim::autoExposureUs(scene);
  CHECK(static_cast<double>(filtered) == Approx(static_cast<double>(plain) / f.x()).epsilon(0.02));
  scene.sensor.bandpassFwhmNm = 3.0;
  CHECK_FALSE(scene.validate().isOk());
}

TEST_CASE("In full sun most of the line is lost without the band-pass filter and found with it", "[sim][lle]") {
  const SunResult plain = sunCase(0.0, 7);
  const SunResult filtered = sunCase(10.0, 7);
  INFO("visible " << plain.visible << ", found without " << plain.found << ", with " << filtered.found << "; exposure "
                  << plain.exposureUs << " / " << filtered.exposureUs << " us");
  CHECK(filtered.exposureUs > 5 * plain.exposureUs);
  CHECK(plain.found * 2 < plain.visible);             // 0.9 m: none (robustThresholdPct 60: 43 of 158)
  CHECK(filtered.found * 10 > 9 * filtered.visible);  // 148 of 158 (60: 150)
}
