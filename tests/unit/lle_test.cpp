#include <catch2/catch.hpp>

#include <random>
#include <vector>

#include "image/lle.h"

using namespace alacs::image;

namespace {
struct Rgb {
  int width, height;
  std::vector<uint8_t> px;
  Rgb(int w, int h, uint8_t fill = 0) : width(w), height(h), px(static_cast<size_t>(w * h * 3), fill) {}
  void setRed(int x, int y, uint8_t v) { px[static_cast<size_t>((y * width + x) * 3)] = v; }
  ImageView view() const { return {px.data(), width, height, static_cast<size_t>(width * 3), PixelFormat::kRgb888}; }
};

// A vertical Gaussian line of `sigma` px centred at column(y) on a dim background.
Rgb lineImage(int w, int h, double (*column)(int), double sigma, double peak, uint8_t bg) {
  Rgb img(w, h, bg);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double d = x - column(y);
      const double v = bg + peak * std::exp(-0.5 * d * d / (sigma * sigma));
      img.setRed(x, y, static_cast<uint8_t>(std::min(255.0, std::round(v))));
    }
  return img;
}
}  // namespace

TEST_CASE("bRCE marks pixels brighter than both neighbours by more than th", "[lle][brce]") {
  const uint8_t red[] = {10, 10, 10, 10, 100, 10, 10, 10, 10};
  uint8_t mask[9];
  brceRow(red, 1, 9, 4, 40, BrceForm::kMeaning, mask);
  CHECK(mask[4] == 1);
  for (int i : {0, 1, 2, 3, 5, 6, 7, 8}) CHECK(mask[i] == 0);
}

TEST_CASE("The literal Algorithm 1 wraps on uint8 and marks dark pixels instead", "[lle][brce]") {
  // Printed form: G1 = R[x-step] - R[x]. On uint8, a bright centre wraps to a large value
  // (10 - 100 = 166), so the literal form fires on the bright pixel for the wrong reason
  // and on a dark dip for the printed one.
  const uint8_t bright[] = {10, 10, 10, 10, 100, 10, 10, 10, 10};
  const uint8_t dip[] = {100, 100, 100, 100, 10, 100, 100, 100, 100};
  uint8_t mask[9];
  brceRow(bright, 1, 9, 4, 40, BrceForm::kLiteral, mask);
  CHECK(mask[4] == 1);
  brceRow(dip, 1, 9, 4, 40, BrceForm::kLiteral, mask);
  CHECK(mask[4] == 1);
  brceRow(dip, 1, 9, 4, 40, BrceForm::kMeaning, mask);
  CHECK(mask[4] == 0);
}

TEST_CASE("Sub-pixel centroid recovers a synthetic line's centre", "[lle]") {
  const Rgb img = lineImage(120, 200, [](int y) { return 50.3 + 0.02 * y; }, 1.3, 150, 30);
  LleWorkspace ws;
  auto line = extractLine(img.view(), {0, 0, 120, 200}, LleParams{}, ws);
  REQUIRE(line.isOk());
  REQUIRE(line->rows.size() == 200);
  double worst = 0;
  for (const auto& r : line->rows) worst = std::max(worst, std::abs(static_cast<double>(r.column) - (50.3 + 0.02 * r.row)));
  CHECK(worst < 0.05);
  REQUIRE(line->valid);
  CHECK(line->columnAt(100) == Approx(52.3).margin(0.02));
}

TEST_CASE("ROI coordinates are reported in full-frame pixels", "[lle]") {
  const Rgb img = lineImage(200, 100, [](int) { return 140.0; }, 1.2, 150, 20);
  LleWorkspace ws;
  auto line = extractLine(img.view(), {100, 10, 80, 50}, LleParams{}, ws);
  REQUIRE(line.isOk());
  REQUIRE(!line->rows.empty());
  CHECK(line->rows.front().row == 10);
  CHECK(line->rows.front().column == Approx(140.0).margin(0.05));
}

TEST_CASE("Edge cases give a result or a clear error, never a crash", "[lle][edge]") {
  LleWorkspace ws;
  LleParams p;
  SECTION("width below 2*step") {
    Rgb img(6, 20, 50);
    auto line = extractLine(img.view(), {0, 0, 6, 20}, p, ws);
    REQUIRE(line.isOk());
    CHECK(line->rows.empty());
  }
  SECTION("one-row ROI") {
    const Rgb img = lineImage(64, 4, [](int) { return 30.0; }, 1.2, 150, 20);
    auto line = extractLine(img.view(), {0, 2, 64, 1}, p, ws);
    REQUIRE(line.isOk());
    CHECK_FALSE(line->valid);
  }
  SECTION("all saturated and all dark") {
    for (uint8_t v : {uint8_t{255}, uint8_t{0}}) {
      Rgb img(64, 32, v);
      auto line = extractLine(img.view(), {0, 0, 64, 32}, p, ws);
      REQUIRE(line.isOk());
      CHECK(line->rows.empty());
    }
  }
  SECTION("a line at the frame border") {
    const Rgb img = lineImage(64, 32, [](int) { return 1.0; }, 1.0, 150, 20);
    auto line = extractLine(img.view(), {0, 0, 64, 32}, p, ws);
    REQUIRE(line.isOk());
  }
  SECTION("bad ROIs and parameters") {
    Rgb img(64, 32, 0);
    CHECK(extractLine(img.view(), {0, 0, 0, 10}, p, ws).status().code() == alacs::Error::kBadInput);
    CHECK(extractLine(img.view(), {60, 0, 10, 10}, p, ws).status().code() == alacs::Error::kBadInput);
    CHECK(extractLine(img.view(), {-1, 0, 10, 10}, p, ws).status().code() == alacs::Error::kBadInput);
    ImageView empty;
    CHECK(extractLine(empty, {0, 0, 1, 1}, p, ws).status().code() == alacs::Error::kBadInput);
    LleParams bad;
    bad.brceStep = 0;
    CHECK(extractLine(img.view(), {0, 0, 10, 10}, bad, ws).status().code() == alacs::Error::kInvalidArgument);
  }
}

TEST_CASE("Random images never crash the extractor", "[lle][edge]") {
  std::mt19937 rng(42);
  LleWorkspace ws;
  for (int i = 0; i < 200; ++i) {
    const int w = 1 + static_cast<int>(rng() % 97);
    const int h = 1 + static_cast<int>(rng() % 41);
    Rgb img(w, h);
    for (auto& v : img.px) v = static_cast<uint8_t>(rng());
    const int x = static_cast<int>(rng() % static_cast<unsigned>(w));
    const int y = static_cast<int>(rng() % static_cast<unsigned>(h));
    LleParams p;
    p.brceStep = 1 + static_cast<int>(rng() % 8);
    auto r = extractLine(img.view(), {x, y, w - x, h - y}, p, ws);
    CHECK(r.isOk());
  }
}
