// LLE allocates nothing per frame once its workspace and output have seen a ROI of that
// size: counted with a counting allocator. The counter replaces the global operator new
// of this test binary (it only counts and forwards to malloc); under AddressSanitizer,
// whose allocator must stay in place, it counts through the sanitizer's malloc hooks.
#include <catch2/catch.hpp>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <new>
#include <random>
#include <vector>

#include "image/lle.h"

#if defined(__SANITIZE_ADDRESS__)
#define LLE_ALLOC_VIA_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define LLE_ALLOC_VIA_SANITIZER 1
#endif
#endif

namespace {
std::atomic<long> gAllocations{0};
}  // namespace

#ifdef LLE_ALLOC_VIA_SANITIZER
// From <sanitizer/allocator_interface.h> (not installed with every compiler); provided by
// the ASan runtime.
extern "C" int __sanitizer_install_malloc_and_free_hooks(void (*malloc_hook)(const volatile void*, size_t),
                                                         void (*free_hook)(const volatile void*));
namespace {
void onMalloc(const volatile void*, size_t) { gAllocations.fetch_add(1, std::memory_order_relaxed); }
void onFree(const volatile void*) {}
const bool gHooks = (__sanitizer_install_malloc_and_free_hooks(onMalloc, onFree), true);
}  // namespace
#else
namespace {
void* counted(std::size_t n) {
  gAllocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void* countedAligned(std::size_t n, std::align_val_t a) {
  gAllocations.fetch_add(1, std::memory_order_relaxed);
  const auto al = static_cast<std::size_t>(a);
  if (void* p = std::aligned_alloc(al, (n + al - 1) / al * al)) return p;
  throw std::bad_alloc();
}
}  // namespace
void* operator new(std::size_t n) { return counted(n); }
void* operator new[](std::size_t n) { return counted(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  gAllocations.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(n == 0 ? 1 : n);
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  gAllocations.fetch_add(1, std::memory_order_relaxed);
  return std::malloc(n == 0 ? 1 : n);
}
void* operator new(std::size_t n, std::align_val_t a) { return countedAligned(n, a); }
void* operator new[](std::size_t n, std::align_val_t a) { return countedAligned(n, a); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
#endif

using namespace alacs::image;

namespace {

// A frame with a laser line, a leaf segment, background texture and noise; different
// content for every `seed`.
std::vector<uint8_t> makeFrame(int w, int h, uint32_t seed) {
  std::vector<uint8_t> px(static_cast<size_t>(w) * static_cast<size_t>(h) * 3U);
  std::mt19937 rng(seed);
  const double c0 = 100.0 + static_cast<double>(rng() % static_cast<unsigned>(w - 200));
  for (int y = 0; y < h; ++y) {
    uint8_t* row = px.data() + static_cast<size_t>(y) * static_cast<size_t>(w) * 3U;
    const double c = c0 + 0.05 * (y - h / 2) + ((y / 50) % 3 == 1 ? 40.0 : 0.0);
    for (int x = 0; x < w; ++x) {
      const double d = x - c;
      const double v = 40.0 + 20.0 * std::sin(0.02 * x + seed) + 150.0 * std::exp(-0.5 * d * d / 2.0) + (rng() % 9);
      row[3 * x + 2] = static_cast<uint8_t>(std::min(255.0, v));
      row[3 * x + 1] = static_cast<uint8_t>(rng() % 50);
      row[3 * x + 0] = static_cast<uint8_t>(rng() % 50);
    }
  }
  return px;
}

}  // namespace

TEST_CASE("LLE allocates nothing per frame after warm-up", "[lle][alloc]") {
  const int w = 640, h = 480;
  std::vector<std::vector<uint8_t>> frames;
  for (uint32_t i = 0; i < 8; ++i) frames.push_back(makeFrame(w, h, i + 1));
  const std::vector<uint8_t> off = makeFrame(w, h, 99);
  // Sunlit skin and a faint line (12 DN) on it, and the same skin with the laser off: the
  // first pass finds the line weak and the subtracted rerun averages three rows.
  std::vector<uint8_t> sunOff(static_cast<size_t>(w) * static_cast<size_t>(h) * 3U);
  std::mt19937 rng(5);
  for (auto& v : sunOff) v = static_cast<uint8_t>(175 + rng() % 8);
  std::vector<uint8_t> sunOn = sunOff;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double d = x - (300.0 + 0.1 * y);
      uint8_t& red = sunOn[(static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)) * 3U + 2U];
      red = static_cast<uint8_t>(std::min(255.0, red + 12.0 * std::exp(-0.5 * d * d / 2.0)));
    }
  // A short strong line (40 of 480 rows) and a fainter one beside it: the first pass's line
  // is kept and the rerun's segments join it (LleParams::shortLinePct).
  std::vector<uint8_t> shortOn(static_cast<size_t>(w) * static_cast<size_t>(h) * 3U, 30);
  for (int y = 200; y < 300; ++y)
    for (int x = 0; x < w; ++x) {
      const double dStrong = x - 200.0;
      const double dFaint = x - 260.0;
      const double v = 30.0 + (y < 240 ? 150.0 * std::exp(-0.5 * dStrong * dStrong / 2.0) : 0.0) +
                       (y >= 230 ? 34.0 * std::exp(-0.5 * dFaint * dFaint / 2.0) : 0.0);
      shortOn[(static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)) * 3U + 2U] =
          static_cast<uint8_t>(std::min(255.0, v));
    }
  auto view = [&](const std::vector<uint8_t>& px) {
    return ImageView{px.data(), w, h, static_cast<size_t>(w) * 3U, PixelFormat::kBgr888};
  };
  const ImageView offView = view(off);
  const ImageView sunOffView = view(sunOff);
  for (LleMethod method : {LleMethod::kRobust, LleMethod::kPaper}) {
    for (LleKernels kernels : {LleKernels::kAuto, LleKernels::kScalar}) {
      LleParams p;
      p.method = method;
      p.subtractedRows = 3;  // the sun frame's rerun averages three rows
      p.kernels = kernels;
      LleWorkspace ws;
      LaserLine line;
      const Roi full{0, 0, w, h};
      const Roi roi{100, 60, 301, 250};
      // Warm-up: one frame at the largest ROI.
      REQUIRE(extractLine(view(frames[0]), full, p, ws, line).isOk());
      REQUIRE(extractLine(view(shortOn), full, p, ws, line).isOk());
      if (method == LleMethod::kRobust) REQUIRE(line.segments.size() >= 2);  // the rerun's segment joined
      // No Catch2 assertion inside the counted window: a reporter may allocate per
      // assertion (the JUnit reporter keeps every one), which would be counted here.
      const long before = gAllocations.load();
      size_t rows = 0;
      int failedFrames = 0;
      for (int k = 0; k < 24; ++k) {
        const auto& f = frames[static_cast<size_t>(k) % frames.size()];
        const bool sun = k % 4 == 3;
        const bool shortLine = k % 8 == 2;
        const ImageView* laserOff = sun ? &sunOffView : k % 4 == 1 ? &offView : nullptr;
        const ImageView frame = sun ? view(sunOn) : shortLine ? view(shortOn) : view(f);
        if (!extractLine(frame, k % 3 == 0 ? roi : full, p, ws, line, laserOff).isOk()) ++failedFrames;
        rows += line.rows.size();
      }
      const long during = gAllocations.load() - before;
      REQUIRE(failedFrames == 0);
      INFO("method " << static_cast<int>(method) << ", kernels " << static_cast<int>(kernels) << ": " << during
                     << " allocations in 24 frames (" << rows << " rows extracted)");
      CHECK(rows > 24 * 200);  // the frames had lines: work was done
      CHECK(during == 0);
    }
  }
}

TEST_CASE("The counting allocator counts", "[lle][alloc]") {
  const long before = gAllocations.load();
  auto* v = new std::vector<int>(1000);  // the vector and its buffer
  const long during = gAllocations.load() - before;
  delete v;
  CHECK(during >= 2);
}
