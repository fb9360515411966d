// End to end in logic: the simulator renders the five stops, the localizer finds the
// apple. Calibration here is the simulator's truth; calibration estimation is tested
// with the calibration tools.
#include <catch2/catch.hpp>

#include "localize/localizer.h"
#include "sim/renderer.h"
#include "sim/scene.h"

using namespace alacs;

namespace {
image::ImageView viewOf(const cv::Mat& m) {
  return {m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888};
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
  std::vector<localize::LineObservation> lines;
  image::LleWorkspace ws;
  cv::Mat frame;
  for (size_t i = 0; i < plan->stopsMm.size(); ++i) {
    renderer.render(plan->stopsMm[i], 1.0, i, frame);
    auto obs = loc.observe(viewOf(frame), *plan, plan->stopsMm[i], ws);
    REQUIRE(obs.isOk());
    lines.push_back(*obs);
  }
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
