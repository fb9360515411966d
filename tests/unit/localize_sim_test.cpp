// End to end in logic: the simulator renders the five stops, the localizer finds the
// apple. Calibration here is the simulator's truth; calibration estimation is tested
// with the calibration tools.
#include <catch2/catch.hpp>

#include <algorithm>
#include <chrono>

#include "localize/localizer.h"
#include "sim/renderer.h"
#include "sim/scene.h"

using namespace alacs;

namespace {
image::ImageView viewOf(const cv::Mat& m) {
  return {m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888};
}

// Renders each planned stop with the laser on and observes it.
std::vector<localize::LineObservation> scanLines(sim::Renderer& renderer, const localize::Localizer& loc,
                                                 const localize::ScanPlan& plan) {
  std::vector<localize::LineObservation> lines;
  image::LleWorkspace ws;
  cv::Mat frame;
  for (size_t i = 0; i < plan.stopsMm.size(); ++i) {
    renderer.render(plan.stopsMm[i], 1.0, i, frame);
    auto obs = loc.observe(viewOf(frame), plan, plan.stopsMm[i], ws);
    REQUIRE(obs.isOk());
    lines.push_back(*obs);
  }
  return lines;
}
}  // namespace

TEST_CASE("LLE on a simulated frame follows the true laser line to a tenth of a pixel", "[sim][lle][render]") {
  sim::SimScene scene = sim::defaultScene();
  sim::Renderer renderer(scene);
  localize::Localizer loc(scene.truth, image::LleParams{}, localize::ScanParams{});
  const auto plan = loc.plan(scene.apples[0].centerMm + Eigen::Vector3d(8, -6, 15), 200.0);
  REQUIRE(plan.isOk());
  const double slide = plan->stopsMm[2];
  cv::Mat frame;
  renderer.render(slide, 1.0, 0, frame);
  image::LleWorkspace ws;
  auto line = image::extractLine(viewOf(frame), plan->roi, image::LleParams{}, ws);
  REQUIRE(line.isOk());
  const auto truth = sim::laserLineTruth(scene, scene.apples[0], slide);
  REQUIRE(truth.size() > 50);
  // The paper's metric: the central 80 % of the line.
  const size_t first = truth.size() / 10;
  const size_t last = truth.size() - truth.size() / 10;
  double sumAbs = 0;
  int matched = 0;
  size_t j = 0;
  for (size_t i = first; i < last; ++i) {
    const auto& t = truth[i];
    while (j < line->rows.size() && line->rows[j].row < t.row) ++j;
    if (j < line->rows.size() && line->rows[j].row == t.row) {
      sumAbs += std::abs(static_cast<double>(line->rows[j].column) - t.column);
      ++matched;
    }
  }
  REQUIRE(matched >= static_cast<int>(0.95 * static_cast<double>(last - first)));
  const double meanAbs = sumAbs / matched;
  INFO("mean |column error| " << meanAbs << " px over " << matched << " rows");
  CHECK(meanAbs < 0.25);
}

TEST_CASE("Five-stop scan localizes the simulated apple within 5 mm", "[sim][localize][render]") {
  sim::SimScene scene = sim::defaultScene();
  sim::Renderer renderer(scene);
  localize::Localizer loc(scene.truth, image::LleParams{}, localize::ScanParams::paperScan());
  const sim::SimApple& apple = scene.apples[0];
  auto plan = loc.plan(apple.centerMm + Eigen::Vector3d(-12, 9, -20), 200.0);
  REQUIRE(plan.isOk());
  REQUIRE(plan->stopsMm.size() == 5);
  const std::vector<localize::LineObservation> lines = scanLines(renderer, loc, *plan);
  auto est = loc.estimate(*plan, lines);
  REQUIRE(est.isOk());
  CHECK(est->sphereFit);
  const double centerErr = (est->centerMm - apple.centerMm).norm();
  const double approachErr = (est->approachMm - sim::approachPoint(apple)).norm();
  INFO("centre error " << centerErr << " mm, approach error " << approachErr << " mm, diameter "
                       << est->diameterMm);
  CHECK(centerErr < 5.0);
  CHECK(approachErr < 5.0);
  CHECK(std::abs(est->diameterMm - 2 * apple.radiusMm) < 5.0);
  CHECK(est->linesUsed >= 3);
}

TEST_CASE("A frame with the laser off yields no line", "[sim][lle][render]") {
  sim::SimScene scene = sim::defaultScene();
  sim::Renderer renderer(scene);
  localize::Localizer loc(scene.truth, image::LleParams{}, localize::ScanParams{});
  auto plan = loc.plan(scene.apples[0].centerMm, 200.0);
  REQUIRE(plan.isOk());
  cv::Mat frame;
  renderer.render(plan->stopsMm[2], 0.0, 0, frame);
  image::LleWorkspace ws;
  auto obs = loc.observe(viewOf(frame), *plan, plan->stopsMm[2], ws);
  REQUIRE(obs.isOk());
  CHECK(obs->pointsMm.size() < 10);
  CHECK_FALSE(obs->line.valid);
}

// A rolling shutter in a sweep: each row of a frame was lit where the slide was at that
// row's exposure. The renderer draws such a frame (FrameRequest::slideMmPerRow); observe()
// triangulates each row on its own slide position and lands on the fruit's surface, where
// one position for the whole frame puts the rows off it by up to the travel across the ROI.
TEST_CASE("A rolling-shutter frame: each row is triangulated at its own slide position", "[sim][localize][render]") {
  const sim::SimScene scene = sim::defaultScene();
  sim::Renderer renderer(scene);
  const sim::SimApple& apple = scene.apples[0];
  const localize::Localizer loc(scene.truth, image::LleParams{}, localize::ScanParams{});
  auto plan = loc.plan(apple.centerMm, 200.0);
  REQUIRE(plan.isOk());
  // 300 mm/s and 21.7 us a row: 6.5 um a row, 2.4 mm across the ROI.
  constexpr double kMmPerRow = 300.0 * 21.7e-6;
  const double middleRow = plan->roi.y + 0.5 * plan->roi.height;
  const double slideMm = plan->stopsMm[3];  // at the ROI's middle row
  sim::FrameRequest r;
  r.slideStartMm = r.slideEndMm = slideMm - middleRow * kMmPerRow;  // row 0's
  r.slideMmPerRow = kMmPerRow;
  cv::Mat frame;
  renderer.render(r, frame);
  image::LleWorkspace ws;
  const auto offSurfaceMm = [&](double perRow) {
    auto obs = loc.observe(viewOf(frame), *plan, slideMm, ws, nullptr, perRow);
    REQUIRE(obs.isOk());
    std::vector<double> off;
    for (const Eigen::Vector3d& p : obs->pointsMm) {
      const double d = std::abs((p - apple.centerMm).norm() - apple.radiusMm);
      if (d < 20.0) off.push_back(d);  // the fruit's rows (not a leaf's, not the wall's)
    }
    REQUIRE(off.size() > 100);
    std::sort(off.begin(), off.end());
    return off[off.size() * 9 / 10];
  };
  const double eachRow = offSurfaceMm(kMmPerRow);
  const double oneForAll = offSurfaceMm(0.0);
  INFO("90th percentile off the sphere: each row its own position " << eachRow << " mm, one for the frame " << oneForAll
                                                                    << " mm");
  CHECK(eachRow < 1.0);
  CHECK(oneForAll > 2.0 * eachRow);
}

// Issue 16, item 1: the apple at (10, -20, 1200), the rough position (0, 0, 1100), 100 mm
// short in depth. Thirteen lines lit the fruit, but the 3D gate around the rough position
// refused them all and the rough position came back with the default diameter. The
// widened search fits the lines the scan saw to the fruit model.
TEST_CASE("A rough position 100 mm short: the widened search finds the apple, flagged as outside the gate",
          "[sim][localize][render][widened]") {
  sim::SimScene scene = sim::defaultScene();
  sim::Renderer renderer(scene);
  const sim::SimApple& apple = scene.apples[0];
  const Eigen::Vector3d rough(0.0, 0.0, 1100.0);
  // One scan, observed as the sensor does (the gate's points and those beyond it up to the
  // search); the gate alone is the same lines without the latter.
  localize::Localizer wideLoc(scene.truth, image::LleParams{}, localize::ScanParams{});
  localize::ScanParams narrow;
  narrow.searchMm = 0.0;  // the gate alone, as before
  localize::Localizer gateLoc(scene.truth, image::LleParams{}, narrow);
  auto plan = wideLoc.plan(rough, 200.0);
  REQUIRE(plan.isOk());
  const std::vector<localize::LineObservation> lines = scanLines(renderer, wideLoc, *plan);
  std::vector<localize::LineObservation> gateLines = lines;
  for (auto& l : gateLines) l.outsidePointsMm.clear();
  // What the fusion costs (printed, not asserted: a measurement, median of 9).
  auto medianMs = [](const localize::Localizer& loc, const localize::ScanPlan& p,
                     const std::vector<localize::LineObservation>& ls) {
    std::vector<double> ms;
    for (int rep = 0; rep < 9; ++rep) {
      const auto t0 = std::chrono::steady_clock::now();
      (void)loc.estimate(p, ls);
      ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    std::nth_element(ms.begin(), ms.begin() + 4, ms.end());
    return ms[4];
  };
  const std::vector<double> estimateMs{medianMs(gateLoc, *plan, gateLines), medianMs(wideLoc, *plan, lines)};
  const auto gated = gateLoc.estimate(*plan, gateLines);
  const bool gatedMeasured = gated.isOk() && gated->sphereFit && (gated->centerMm - apple.centerMm).norm() < 10.0;
  INFO("gate alone: " << (gated.isOk() ? "an estimate" : gated.status().reason()));
  CHECK_FALSE(gatedMeasured);

  const auto wide = wideLoc.estimate(*plan, lines);
  REQUIRE(wide.isOk());
  const double centerErr = (wide->centerMm - apple.centerMm).norm();
  INFO("widened: centre error " << centerErr << " mm, diameter " << wide->diameterMm << " mm, lines "
                                << wide->linesUsed << ", confidence " << wide->confidencePct << " %");
  CHECK(wide->sphereFit);
  CHECK(wide->outsideGate);
  CHECK(centerErr < 5.0);
  CHECK(std::abs(wide->diameterMm - 2 * apple.radiusMm) < 5.0);
  // Found away from where the arm said: never reported as sure.
  CHECK(wide->confidencePct < 80.0);
  WARN("estimate(), median of 9: gate alone " << estimateMs[0] << " ms (nothing found), widened " << estimateMs[1]
                                              << " ms: the widened search costs " << estimateMs[1] - estimateMs[0]
                                              << " ms, on scans the gate left empty only");
}
