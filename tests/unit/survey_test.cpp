// Scan-all in logic: the simulator renders a full-stroke sweep over three apples; the
// survey must find each of them, and nothing else (the foliage wall is not a fruit).
#include <catch2/catch.hpp>

#include "sim/renderer.h"
#include "sim/scene.h"
#include "survey/survey.h"

using namespace alacs;

TEST_CASE("Scan-all finds every apple in view and nothing else", "[survey][sim][render]") {
  sim::SimScene scene = sim::defaultScene();
  scene.apples.clear();
  const Eigen::Vector3d centers[] = {{-55, -40, 1150}, {15, 60, 1250}, {75, -10, 1100}};
  for (int i = 0; i < 3; ++i) {
    sim::SimApple a;
    a.id = i + 1;
    a.centerMm = centers[i];
    a.radiusMm = 38.0 + 2.0 * i;
    scene.apples.push_back(a);
  }
  sim::Renderer renderer(scene);
  survey::SurveyParams sp;
  sp.stopSpacingMm = 8.0;
  survey::Survey sv(scene.truth, image::LleParams{}, localize::ScanParams{}, sp);
  image::LleWorkspace ws;
  cv::Mat frame;
  uint64_t k = 0;
  for (double s : survey::surveyStops(200.0, sp)) {
    renderer.render(s, 1.0, k++, frame);
    REQUIRE(sv.addFrame({frame.data, frame.cols, frame.rows, frame.step[0], image::PixelFormat::kBgr888}, s, ws).isOk());
  }
  const auto found = sv.finish();
  REQUIRE(found.size() == 3);
  for (const auto& a : scene.apples) {
    double best = 1e9;
    const localize::AppleEstimate* match = nullptr;
    for (const auto& f : found) {
      const double d = (f.centerMm - a.centerMm).norm();
      if (d < best) {
        best = d;
        match = &f;
      }
    }
    INFO("apple " << a.id << " centre error " << best << " mm");
    CHECK(best < 5.0);
    CHECK(std::abs(match->diameterMm - 2 * a.radiusMm) < 5.0);
  }
}
