// The SIMD path of LLE (OpenCV universal intrinsics: NEON on aarch64, SSE2, AVX2 and
// AVX-512 on x86-64, each that the CPU runs) against the scalar reference: bit-exact, kernel by kernel and end to end, on
// random data and on the edge cases (odd widths, widths below 2·step, one-row ROIs,
// all-saturated, all-dark, lines at the borders). Under tests/aarch64/run.sh this runs
// the NEON kernels in qemu-aarch64.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "image/lle.h"
#include "image/lle_internal.h"

using namespace alacs::image;
using detail::SimdKernels;

namespace {

std::vector<const SimdKernels*> simdPaths() {
  std::vector<const SimdKernels*> v;
  if (detail::simdKernelsBaseline() != nullptr) v.push_back(detail::simdKernelsBaseline());
  if (detail::simdKernelsAvx2() != nullptr) v.push_back(detail::simdKernelsAvx2());
  if (detail::simdKernelsAvx512() != nullptr) v.push_back(detail::simdKernelsAvx512());
  return v;
}

struct Frame {
  int width, height;
  std::vector<uint8_t> px;
  Frame(int w, int h) : width(w), height(h), px(static_cast<size_t>(w) * static_cast<size_t>(h) * 3U) {}
  uint8_t& red(int x, int y) { return px[(static_cast<size_t>(y) * static_cast<size_t>(width) + static_cast<size_t>(x)) * 3U]; }
  ImageView view() const { return {px.data(), width, height, static_cast<size_t>(width) * 3U, PixelFormat::kRgb888}; }
};

// Adds a Gaussian line of `peak` DN, column c0 + slope·row, to the red channel.
void addSlantedLine(Frame& f, double c0, double slope, double peak) {
  for (int y = 0; y < f.height; ++y)
    for (int x = 0; x < f.width; ++x) {
      const double d = x - (c0 + slope * y);
      f.red(x, y) = static_cast<uint8_t>(std::min(255.0, f.red(x, y) + peak * std::exp(-d * d / 3.0)));
    }
}

void compareLines(const LaserLine& a, const LaserLine& b) {
  REQUIRE(a.rows.size() == b.rows.size());
  for (size_t i = 0; i < a.rows.size(); ++i) {
    INFO("sample " << i << " row " << a.rows[i].row);
    CHECK(a.rows[i].row == b.rows[i].row);
    CHECK(a.rows[i].columnQ8 == b.rows[i].columnQ8);
    CHECK(a.rows[i].centroidQ8 == b.rows[i].centroidQ8);
    CHECK(a.rows[i].confidence == b.rows[i].confidence);
    CHECK(a.rows[i].status == b.rows[i].status);
    CHECK(a.rows[i].segment == b.rows[i].segment);
    CHECK(a.rows[i].saturated == b.rows[i].saturated);
  }
  REQUIRE(a.segments.size() == b.segments.size());
  for (size_t i = 0; i < a.segments.size(); ++i) {
    CHECK(a.segments[i].firstRow == b.segments[i].firstRow);
    CHECK(a.segments[i].lastRow == b.segments[i].lastRow);
    CHECK(a.segments[i].rows == b.segments[i].rows);
    CHECK(a.segments[i].onLine == b.segments[i].onLine);
  }
  CHECK(a.valid == b.valid);
  CHECK(a.order == b.order);
  CHECK(a.coeffs == b.coeffs);
  CHECK(a.inliers == b.inliers);
  CHECK(a.coverage == b.coverage);
}

// Runs the whole extraction with the scalar and with the SIMD kernels (both methods, both
// bRCE forms, with and without a laser-off frame) and requires identical results.
void compareEndToEnd(const Frame& f, const Roi& roi, LleParams p, const Frame* off = nullptr) {
  LleWorkspace ws1, ws2;
  LaserLine a, b;
  const ImageView ov = off != nullptr ? off->view() : ImageView{};
  for (LleMethod m : {LleMethod::kRobust, LleMethod::kPaper}) {
    for (BrceForm form : {BrceForm::kMeaning, BrceForm::kLiteral}) {
      p.method = m;
      p.brceForm = form;
      p.kernels = LleKernels::kScalar;
      REQUIRE(extractLine(f.view(), roi, p, ws1, a, off ? &ov : nullptr).isOk());
      p.kernels = LleKernels::kAuto;
      REQUIRE(extractLine(f.view(), roi, p, ws2, b, off ? &ov : nullptr).isOk());
      compareLines(a, b);
    }
  }
}

}  // namespace

TEST_CASE("This build has SIMD kernels for LLE", "[lle][simd]") {
  INFO("LLE kernels in use: " << lleSimdName());
  // x86-64 always has SSE2 and aarch64 always has NEON: a scalar-only build there is a
  // configuration error, not a slow machine.
#if defined(__x86_64__) || defined(__aarch64__)
  CHECK(detail::simdKernelsBaseline() != nullptr);
  CHECK(std::string(lleSimdName()) != "scalar");
#endif
#if defined(__aarch64__)
  CHECK(std::string(lleSimdName()) == "neon");
#endif
  WARN("LLE SIMD kernels: " << lleSimdName());
}

TEST_CASE("SIMD red extraction is bit-exact with the scalar kernel", "[lle][simd]") {
  std::mt19937 rng(11);
  for (const SimdKernels* k : simdPaths()) {
    INFO("kernels " << k->name);
    for (int w : {1, 2, 3, 15, 16, 17, 31, 32, 33, 63, 64, 65, 100, 127, 255, 1023, 2048, 2049}) {
      std::vector<uint8_t> on(static_cast<size_t>(w) * 3U), off(on.size());
      for (auto& v : on) v = static_cast<uint8_t>(rng());
      for (auto& v : off) v = static_cast<uint8_t>(rng());
      for (int redOffset : {0, 2}) {
        for (bool useOff : {false, true}) {
          std::vector<uint8_t> a(static_cast<size_t>(w) + 64, 0xAA), b(a.size(), 0xAA);
          const auto fa = detail::redRowScalar(on.data(), useOff ? off.data() : nullptr, redOffset, w, a.data());
          const auto fb = k->redRow(on.data(), useOff ? off.data() : nullptr, redOffset, w, b.data());
          INFO("w " << w << " redOffset " << redOffset << " off " << useOff);
          CHECK(a == b);  // including no write past w
          CHECK(fa.first == fb.first);
          CHECK(fa.last == fb.last);
        }
      }
    }
  }
}

TEST_CASE("SIMD red extraction says where the laser frame's red reaches full scale, as the scalar kernel",
          "[lle][simd][saturation]") {
  // The span clippedRunsRow scans: red pixels at 255 anywhere (vector body or scalar
  // tail), never a 255 in another channel nor in the laser-off frame.
  std::mt19937 rng(12);
  for (const SimdKernels* k : simdPaths()) {
    INFO("kernels " << k->name);
    for (int w : {1, 15, 16, 17, 64, 65, 100, 367}) {
      for (int redOffset : {0, 2}) {
        std::vector<uint8_t> on(static_cast<size_t>(w) * 3U), off(on.size(), 255);
        for (auto& v : on) v = static_cast<uint8_t>(rng() % 255);  // 0..254
        std::vector<uint8_t> red(static_cast<size_t>(w) + 64);
        for (const uint8_t* o : {static_cast<const uint8_t*>(nullptr), static_cast<const uint8_t*>(off.data())}) {
          INFO("w " << w << " redOffset " << redOffset << " off " << (o != nullptr));
          CHECK_FALSE(detail::redRowScalar(on.data(), o, redOffset, w, red.data()).any());
          CHECK_FALSE(k->redRow(on.data(), o, redOffset, w, red.data()).any());
          auto& lastRed = on[3U * static_cast<size_t>(w - 1) + static_cast<size_t>(redOffset)];
          for (int x = 0; x < w; ++x) {
            for (int ch = 0; ch < 3; ++ch) {
              auto& v = on[3U * static_cast<size_t>(x) + static_cast<size_t>(ch)];
              const uint8_t keep = v;
              v = 255;
              INFO("x " << x << " channel " << ch);
              const int expect = ch == redOffset ? x : -1;
              for (const auto& s : {detail::redRowScalar(on.data(), o, redOffset, w, red.data()),
                                    k->redRow(on.data(), o, redOffset, w, red.data())}) {
                CHECK(s.first == expect);
                CHECK(s.last == expect);
              }
              // With the last pixel's red at full scale as well: the span reaches it.
              const uint8_t keepLast = lastRed;
              lastRed = 255;
              const int first = ch == redOffset ? x : w - 1;
              for (const auto& s : {detail::redRowScalar(on.data(), o, redOffset, w, red.data()),
                                    k->redRow(on.data(), o, redOffset, w, red.data())}) {
                CHECK(s.first == first);
                CHECK(s.last == w - 1);
              }
              lastRed = keepLast;
              v = keep;
            }
          }
        }
      }
    }
  }
}

TEST_CASE("SIMD averaging of three rows is bit-exact with the scalar kernel", "[lle][simd]") {
  std::mt19937 rng(14);
  for (const SimdKernels* k : simdPaths()) {
    INFO("kernels " << k->name);
    for (int w : {1, 2, 15, 16, 17, 31, 32, 33, 63, 64, 65, 100, 255, 1023, 2049}) {
      for (int kind = 0; kind < 3; ++kind) {
        std::vector<uint8_t> rows(3U * static_cast<size_t>(w));
        for (auto& v : rows) v = kind == 0 ? static_cast<uint8_t>(rng()) : kind == 1 ? uint8_t{255} : uint8_t{0};
        const uint8_t* above = rows.data();
        const uint8_t* mid = above + w;
        const uint8_t* below = mid + w;
        std::vector<uint8_t> a(static_cast<size_t>(w) + 64, 0xAA), b(a.size(), 0xAA);
        detail::averageRowsScalar(above, mid, below, w, a.data());
        k->averageRows(above, mid, below, w, b.data());
        INFO("w " << w << " kind " << kind);
        CHECK(a == b);  // including no write past w
        // The rounding is the documented one: avg(avg(above, below), mid), rounding up.
        for (int x = 0; x < w; ++x) {
          const int outer = (above[x] + below[x] + 1) / 2;
          CHECK(a[static_cast<size_t>(x)] == (outer + mid[x] + 1) / 2);
        }
      }
    }
  }
}

TEST_CASE("SIMD bRCE, candidate bits and column counts are bit-exact with the scalar kernel", "[lle][simd]") {
  // (The column counters are u8, modulo 256; the caller widens them every 255 rows.)
  std::mt19937 rng(12);
  for (const SimdKernels* k : simdPaths()) {
    INFO("kernels " << k->name);
    for (int iter = 0; iter < 400; ++iter) {
      const int w = iter < 130 ? iter + 1 : 1 + static_cast<int>(rng() % 2100);
      const int wv = detail::paddedWidth(w);
      const int step = iter % 7 == 0 ? 64 : 1 + static_cast<int>(rng() % 16);
      const int th = std::vector<int>{0, 1, 40, 127, 200, 254}[static_cast<size_t>(rng() % 6)];
      const BrceForm form = rng() % 2 ? BrceForm::kLiteral : BrceForm::kMeaning;
      std::vector<uint8_t> buf(static_cast<size_t>(wv + 2 * detail::kRedPad), 0);
      uint8_t* red = buf.data() + detail::kRedPad;
      const int kind = static_cast<int>(rng() % 4);
      for (int x = 0; x < w; ++x)
        red[x] = kind == 0 ? static_cast<uint8_t>(rng())                       // noise
                 : kind == 1 ? uint8_t{255}                                   // all saturated
                 : kind == 2 ? uint8_t{0}                                     // all dark
                             : static_cast<uint8_t>(x % 9 == 0 ? 250 : 20);   // lines, incl. x = 0
      std::vector<uint8_t> valid(static_cast<size_t>(wv), 0);
      for (int x = step; x < w - step; ++x) valid[static_cast<size_t>(x)] = 1;
      std::vector<uint8_t> ca(static_cast<size_t>(wv)), cb(ca.size());
      for (size_t i = 0; i < ca.size(); ++i) ca[i] = cb[i] = static_cast<uint8_t>(rng());  // wraps at 255
      std::vector<uint64_t> ba(static_cast<size_t>(wv / 64), ~0ULL), bb(ba.size(), 0x5555ULL);
      const bool anyA = detail::brceRowScalar(red, w, wv, step, th, form, ca.data(), ba.data()) != 0;
      const bool anyB = k->brceRow(red, valid.data(), wv, step, th, form, cb.data(), bb.data()) != 0;
      INFO("w " << w << " step " << step << " th " << th << " kind " << kind);
      CHECK(ca == cb);
      CHECK(ba == bb);
      // Whether the row has a candidate, as both say, is what its bits say.
      CHECK(anyA == std::any_of(ba.begin(), ba.end(), [](uint64_t word) { return word != 0; }));
      CHECK(anyB == anyA);
    }
  }
}

TEST_CASE("The whole extraction is bit-exact between the SIMD and the scalar kernels", "[lle][simd]") {
  std::mt19937 rng(13);
  LleParams p;
  SECTION("random images, ROIs and parameters") {
    for (int iter = 0; iter < 60; ++iter) {
      const int w = 1 + static_cast<int>(rng() % 300);
      const int h = 1 + static_cast<int>(rng() % 80);
      Frame f(w, h);
      for (auto& v : f.px) v = static_cast<uint8_t>(rng());
      const int x = static_cast<int>(rng() % static_cast<unsigned>(w));
      const int y = static_cast<int>(rng() % static_cast<unsigned>(h));
      p.brceStep = 1 + static_cast<int>(rng() % 12);
      p.brceThreshold = static_cast<int>(rng() % 80);
      p.minSegmentRows = 1 + static_cast<int>(rng() % 5);
      INFO("iteration " << iter << " " << w << "x" << h);
      compareEndToEnd(f, {x, y, w - x, h - y}, p);
    }
  }
  SECTION("lines on noise, with a laser-off frame") {
    for (int iter = 0; iter < 20; ++iter) {
      const int w = 33 + static_cast<int>(rng() % 500);
      const int h = 20 + static_cast<int>(rng() % 100);
      Frame off(w, h);
      for (auto& v : off.px) v = static_cast<uint8_t>(30 + rng() % 40);
      Frame on = off;
      addSlantedLine(on, 5.0 + static_cast<double>(rng() % static_cast<unsigned>(w - 10)), 0.1, 180.0);
      compareEndToEnd(on, {0, 0, w, h}, p);
      compareEndToEnd(on, {0, 0, w, h}, p, &off);
    }
  }
  SECTION("faint lines in sunlit noise, with a laser-off frame: the rerun on rows averaged") {
    p.subtractedLineThresholdPct = 15;
    int tall = 0, found = 0;  // frames of 30 rows or more; those whose averaged rerun found the line
    for (int iter = 0; iter < 20; ++iter) {
      const int w = 40 + static_cast<int>(rng() % 400);
      const int h = 1 + static_cast<int>(rng() % 120);
      Frame off(w, h);
      for (auto& v : off.px) v = static_cast<uint8_t>(170 + rng() % 8);
      Frame on = off;
      for (auto& v : on.px) v = static_cast<uint8_t>(170 + rng() % 8);
      addSlantedLine(on, 5.0 + static_cast<double>(rng() % static_cast<unsigned>(w - 10)), 0.3, 12.0);
      for (int rows : {1, 3}) {
        p.subtractedRows = rows;
        INFO("iteration " << iter << " " << w << "x" << h << " rows " << rows);
        compareEndToEnd(on, {0, 0, w, h}, p, &off);
        compareEndToEnd(on, {0, h / 3, w, h - h / 3}, p, &off);
      }
      // The comparison is of lines found, not of two empty results.
      if (h >= 30) {
        LleWorkspace ws;
        LaserLine line;
        const ImageView ov = off.view();
        REQUIRE(extractLine(on.view(), {0, 0, w, h}, p, ws, line, &ov).isOk());
        ++tall;
        found += line.inliers >= h / 2 ? 1 : 0;
      }
    }
    INFO(found << " of " << tall << " frames of 30 rows or more found the line on three rows");
    CHECK(tall >= 10);
    CHECK(found >= tall - 2);
  }
  SECTION("edge cases") {
    // Odd widths, widths below 2·step, one-row ROIs.
    for (int w : {1, 3, 7, 8, 9, 17, 63, 65, 127, 129}) {
      Frame f(w, 9);
      for (auto& v : f.px) v = static_cast<uint8_t>(rng());
      compareEndToEnd(f, {0, 0, w, 9}, p);
      compareEndToEnd(f, {0, 4, w, 1}, p);
    }
    // All saturated, all dark.
    for (uint8_t v : {uint8_t{255}, uint8_t{0}}) {
      Frame f(131, 40);
      std::fill(f.px.begin(), f.px.end(), v);
      compareEndToEnd(f, {0, 0, 131, 40}, p);
    }
    // Lines at the borders: first and last column, first row only, a ROI edge.
    for (int col : {0, 1, 4, 95, 98, 99}) {
      Frame f(100, 30);
      std::fill(f.px.begin(), f.px.end(), uint8_t{20});
      for (int yy = 0; yy < 30; ++yy) f.red(col, yy) = 230;
      compareEndToEnd(f, {0, 0, 100, 30}, p);
      compareEndToEnd(f, {0, 0, 100, 1}, p);
      compareEndToEnd(f, {col > 50 ? 50 : 0, 0, 50, 30}, p);
    }
  }
}
