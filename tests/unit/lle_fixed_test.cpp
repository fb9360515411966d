// LLE in fixed point against its floating-point reference: the fixed-point curve fit
// (Forsythe's orthogonal polynomials, Q16 data, Q30 recurrence) against exact polynomials, and whole
// extractions against extractLineReference within 1/64 px. (alacs_lle_eval makes the same
// comparison on every case of the twin's benchmark.)
#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <vector>

#include "image/lle.h"
#include "image/lle_fit.h"

using namespace alacs::image;

namespace {

struct Rgb {
  int width, height;
  std::vector<uint8_t> px;
  Rgb(int w, int h, uint8_t fill = 0) : width(w), height(h), px(static_cast<size_t>(w * h * 3), fill) {}
  uint8_t& at(int x, int y, int c) { return px[static_cast<size_t>((y * width + x) * 3 + c)]; }
  ImageView view() const { return {px.data(), width, height, static_cast<size_t>(width * 3), PixelFormat::kRgb888}; }
};

// A realistic line: Gaussian core with speckle (multiplicative noise per pixel), a
// background gradient, shot-like noise, occasional clipping, and a hidden stretch.
Rgb speckledLine(std::mt19937& rng, int w, int h, double c0, double slope, double curve, int hideFrom, int hideTo) {
  Rgb img(w, h);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (int y = 0; y < h; ++y) {
    const double c = c0 + slope * y + curve * (y - h / 2.0) * (y - h / 2.0);
    for (int x = 0; x < w; ++x) {
      const double bg = 30.0 + 0.2 * x + 10.0 * std::sin(0.05 * y);
      const double d = x - c;
      double laser = (y >= hideFrom && y < hideTo) ? 0.0 : 170.0 * std::exp(-0.5 * d * d / 2.2);
      laser *= std::max(0.0, 1.0 + 0.35 * n01(rng));
      const double v = bg + laser + 2.0 * n01(rng);
      img.at(x, y, 0) = static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L));
      img.at(x, y, 1) = static_cast<uint8_t>(std::clamp(std::lround(0.3 * bg + 0.08 * laser), 0L, 255L));
    }
  }
  return img;
}

}  // namespace

TEST_CASE("The fixed-point fit reproduces exact polynomials of every order", "[lle][fixed][fit]") {
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int order = 0; order <= detail::kMaxFitOrder; ++order) {
    for (int trial = 0; trial < 10; ++trial) {
      const int first = static_cast<int>(rng() % 1000);
      const int n = 20 + static_cast<int>(rng() % 500);
      const int last = first + n - 1;
      double coef[detail::kMaxFitOrder + 1] = {};
      coef[0] = 200.0 + 1500.0 * (rng() % 1000) / 1000.0;
      for (int k = 1; k <= order; ++k) coef[k] = u(rng) * 10.0;
      auto truth = [&](int row) {
        const double t = (2.0 * row - first - last) / (last - first);
        double v = 0.0;
        for (int k = order; k >= 0; --k) v = v * t + coef[k];
        return v;
      };
      std::vector<int32_t> rows, y;
      std::vector<uint8_t> use;
      for (int r = first; r <= last; ++r) {
        if (rng() % 5 == 0) continue;  // gaps
        rows.push_back(r);
        y.push_back(static_cast<int32_t>(std::lround(truth(r) * 65536.0)));
        use.push_back(1);
      }
      std::vector<int64_t> scratch(3 * rows.size());
      detail::FitQ fit;
      REQUIRE(detail::fitPolyQ(rows.data(), y.data(), use.data(), static_cast<int>(rows.size()), order, first, last,
                               scratch.data(), fit));
      INFO("order " << order << " trial " << trial << " n " << rows.size());
      CHECK(fit.order == order);
      double worst = 0.0;
      for (int r = first; r <= last; ++r) worst = std::max(worst, std::abs(fit.evalQ16(r) / 65536.0 - truth(r)));
      CHECK(worst <= 4.0 / 65536.0);  // the data's own rounding (Q16) plus the result's
      // The monomial form (LaserLine::coeffs) gives the same curve. (Its high-order
      // coefficients themselves are ill-conditioned: the data's rounding moves them.)
      double mono[detail::kMaxFitOrder + 1];
      fit.monomial(mono);
      double worstMono = 0.0;
      for (int r = first; r <= last; ++r) {
        const double t = (2.0 * r - first - last) / (last - first);
        double v = 0.0;
        for (int k = order; k >= 0; --k) v = v * t + mono[k];
        worstMono = std::max(worstMono, std::abs(v - fit.evalQ16(r) / 65536.0));
      }
      CHECK(worstMono <= 1e-4);
    }
  }
}

TEST_CASE("The fixed-point fit lowers its order when the points cannot support it", "[lle][fixed][fit]") {
  std::vector<int64_t> scratch(30);
  detail::FitQ fit;
  const int32_t rows1[] = {10};
  const int32_t y1[] = {65536 * 5};
  const uint8_t use1[] = {1};
  REQUIRE(detail::fitPolyQ(rows1, y1, use1, 1, 4, 10, 10, scratch.data(), fit));
  CHECK(fit.order == 0);
  CHECK(fit.evalQ16(10) == 65536 * 5);
  const int32_t rows2[] = {10, 20};
  const int32_t y2[] = {65536 * 5, 65536 * 7};
  const uint8_t use2[] = {1, 1};
  REQUIRE(detail::fitPolyQ(rows2, y2, use2, 2, 4, 10, 20, scratch.data(), fit));
  CHECK(fit.order == 1);
  CHECK(fit.evalQ16(15) == 65536 * 6);
  const uint8_t none[] = {0, 0};
  CHECK_FALSE(detail::fitPolyQ(rows2, y2, none, 2, 4, 10, 20, scratch.data(), fit));
}

TEST_CASE("The fit's rounded quotient is the 128-bit one on both sides of its int64 path", "[lle][fixed][fit]") {
  using detail::Int128;
  // The quotient as it was before the int64 path: always in 128 bits.
  const auto longWay = [](Int128 a, Int128 b) { return a >= 0 ? (a + b / 2) / b : -((-a + b / 2) / b); };
  const Int128 edge = Int128{1} << 62;
  std::vector<Int128> as{0,
                         1,
                         -1,
                         2,
                         -2,
                         3,
                         -3,
                         7,
                         -7,
                         edge - 1,
                         -(edge - 1),
                         edge,
                         -edge,
                         edge + 1,
                         -(edge + 1),
                         Int128{INT64_MAX},
                         -Int128{INT64_MAX},
                         Int128{1} << 100,
                         -(Int128{1} << 100)};
  std::vector<Int128> bs{1, 2, 3, 4, 7, edge - 1, edge, edge + 1, Int128{1} << 90};
  std::mt19937_64 rng(21);
  for (int i = 0; i < 2000; ++i) {
    const int shiftA = static_cast<int>(rng() % 120);
    const Int128 a = static_cast<Int128>(rng() >> 1) << (shiftA > 57 ? shiftA - 57 : 0);
    as.push_back(i % 2 != 0 ? a : -a);
    const int shiftB = static_cast<int>(rng() % 63);  // (one draw a statement: the same values on every compiler)
    bs.push_back(1 + static_cast<Int128>(rng() >> shiftB));
  }
  int differ = 0;
  // Every a against the edge divisors (the first nine), and against a sample of the others.
  for (const Int128 a : as)
    for (size_t k = 0; k < bs.size(); k += k < 9 ? 1 : 97)
      differ += detail::divRound(a, bs[k]) != longWay(a, bs[k]) ? 1 : 0;
  for (size_t i = 0; i < bs.size(); ++i)
    differ += detail::divRound(as[i % as.size()], bs[i]) != longWay(as[i % as.size()], bs[i]) ? 1 : 0;
  CHECK(differ == 0);
  // Halves round away from zero on both paths.
  CHECK(detail::divRound(5, 2) == 3);
  CHECK(detail::divRound(-5, 2) == -3);
  CHECK(detail::divRound((edge + 1) * 2 + 1, 2) == edge + 2);
}

TEST_CASE("Fixed point agrees with the floating-point reference within 1/64 px", "[lle][fixed]") {
  std::mt19937 rng(22);
  LleWorkspace ws;
  LaserLine fixed, ref;
  double worstColumn = 0.0, worstCurve = 0.0;
  int samples = 0;
  for (int iter = 0; iter < 40; ++iter) {
    const int w = 80 + static_cast<int>(rng() % 300);
    const int h = 40 + static_cast<int>(rng() % 400);
    const double c0 = 20.0 + static_cast<double>(rng() % static_cast<unsigned>(w - 40));
    const int hide = static_cast<int>(rng() % static_cast<unsigned>(h));
    const Rgb img = speckledLine(rng, w, h, c0, 0.02 * ((rng() % 7) - 3.0), 1e-4 * ((rng() % 5) - 2.0), hide,
                                 hide + h / 5);
    LleParams p;
    p.method = iter % 5 == 4 ? LleMethod::kPaper : LleMethod::kRobust;
    p.smoothOrder = static_cast<int>(rng() % 3);
    const Roi roi{static_cast<int>(rng() % 10), static_cast<int>(rng() % 10), w - 10, h - 10};
    REQUIRE(extractLine(img.view(), roi, p, ws, fixed).isOk());
    REQUIRE(extractLineReference(img.view(), roi, p, ref).isOk());
    // The decisions are the same; only the arithmetic differs.
    REQUIRE(fixed.rows.size() == ref.rows.size());
    REQUIRE(fixed.valid == ref.valid);
    for (size_t i = 0; i < fixed.rows.size(); ++i) {
      const RowSample& a = fixed.rows[i];
      const RowSample& b = ref.rows[i];
      REQUIRE(a.row == b.row);
      REQUIRE(a.status == b.status);
      worstColumn = std::max(worstColumn, std::abs(static_cast<double>(a.column) - static_cast<double>(b.column)));
      if (fixed.valid && a.status == RowStatus::kLine)
        worstCurve = std::max(worstCurve, std::abs(fixed.columnAt(a.row) - ref.columnAt(a.row)));
      ++samples;
    }
  }
  INFO("worst |column| difference " << worstColumn << " px, curve " << worstCurve << " px over " << samples << " samples");
  CHECK(samples > 5000);
  CHECK(worstColumn <= 1.0 / 64.0);
  CHECK(worstCurve <= 1.0 / 64.0);
}
