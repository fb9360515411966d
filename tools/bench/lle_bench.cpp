// alacs_lle_bench: how fast LLE is, measured against things timed in the same run.
//
// On one full 2048×1536 BGR frame (the twin's default scene, or --image), on one core
// (the process is pinned to one CPU; OpenCV runs single-threaded), it times medians of:
//   memcpy of the frame (the yardstick: the target is LLE ≤ 1.0× memcpy), one read of
//   the frame (a sum over it: the floor for anything that looks at every byte once) and
//   LLE on the full frame (SIMD kernels; per-frame median and p99), these three taken in
//   turn frame by frame, in an order rotated each frame, so that the machine's load
//   falls on each alike (and again in blocks, each alone, as before); scalar kernels,
//   LLE on the localizer's ROI for the target (ROI mode), the paper's method in C++,
//   the ROI with a weak line less a laser-off frame (the subtracted rerun, on the row alone
//   and on three rows averaged; and on the row alone without the matched filter),
//   a plain OpenCV floating-point pipeline of the paper's method,
//   and the numpy reference of the paper's method (tools/paper_lle, in a subprocess),
// and prints the ratios. A benchmark, not a test: it fails only when something cannot run.
//
//   alacs_lle_bench [--frames N] [--image PNG] [--python PATH] [--no-python] [--no-pin] [--profile N]
#include <sched.h>
#include <unistd.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "image/lle.h"
#include "localize/localizer.h"
#include "sim/renderer.h"
#include "sim/scene.h"
#include "tool_common/cli.h"

using namespace alacs;
namespace fs = std::filesystem;

namespace {

struct Stats {
  double median = 0.0;
  double p99 = 0.0;
};

// The median and p99 of samples (sorts them).
Stats statsOf(std::vector<double>& ms) {
  std::sort(ms.begin(), ms.end());
  Stats s;
  s.median = ms[ms.size() / 2];
  s.p99 = ms[std::min(ms.size() - 1, static_cast<size_t>(0.99 * static_cast<double>(ms.size())))];
  return s;
}

Stats timeIt(int n, const std::function<void()>& fn) {
  fn();  // warm-up (allocations, caches, page faults)
  std::vector<double> ms;
  ms.reserve(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    fn();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  return statsOf(ms);
}

// The three yardstick timings, in turn frame by frame (after one warm-up of each), their
// order rotated every frame so that none always follows the same one (each leaves the
// caches as the next finds them): the medians of each, and the medians of the per-frame
// ratios b/a, c/a and c/b.
struct Interleaved {
  Stats a, b, c;
  double bOverA = 0.0;
  double cOverA = 0.0;
  double cOverB = 0.0;
};

Interleaved timeInTurn(int n, const std::function<void()>& a, const std::function<void()>& b,
                       const std::function<void()>& c) {
  a();
  b();
  c();
  std::vector<double> ms[3], ratioBA, ratioCA, ratioCB;
  const std::function<void()>* fns[3] = {&a, &b, &c};
  for (int i = 0; i < n; ++i) {
    double t[3];
    for (int j = 0; j < 3; ++j) {
      const int k = (i + j) % 3;
      const auto t0 = std::chrono::steady_clock::now();
      (*fns[k])();
      t[k] = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    }
    for (int k = 0; k < 3; ++k) ms[k].push_back(t[k]);
    ratioBA.push_back(t[1] / t[0]);
    ratioCA.push_back(t[2] / t[0]);
    ratioCB.push_back(t[2] / t[1]);
  }
  Interleaved r{statsOf(ms[0]), statsOf(ms[1]), statsOf(ms[2])};
  r.bOverA = statsOf(ratioBA).median;
  r.cOverA = statsOf(ratioCA).median;
  r.cOverB = statsOf(ratioCB).median;
  return r;
}

// One read of every byte of the frame: 64-bit words summed (the compiler vectorizes it).
uint64_t readOnce(const uint8_t* data, size_t bytes) {
  uint64_t acc = 0;
  const size_t words = bytes / sizeof(uint64_t);
  for (size_t i = 0; i < words; ++i) {
    uint64_t w;
    std::memcpy(&w, data + i * sizeof(uint64_t), sizeof w);
    acc += w;
  }
  return acc;
}

// The paper's method as one would write it with OpenCV in floating point: bRCE on a
// float red plane, Algorithm 2 with per-band column sums, the mean column of each row,
// a least-squares 4th-order polynomial (QR). Returns the number of rows found.
int opencvFloatPaper(const cv::Mat& bgr, const image::LleParams& p) {
  const int w = bgr.cols, h = bgr.rows, s = p.brceStep;
  cv::Mat red, r;
  cv::extractChannel(bgr, red, 2);
  red.convertTo(r, CV_32F);
  const cv::Mat c = r.colRange(s, w - s);
  const cv::Mat d1 = c - r.colRange(0, w - 2 * s);
  const cv::Mat d2 = c - r.colRange(2 * s, w);
  const cv::Mat inner = (d1 > p.brceThreshold) & (d2 > p.brceThreshold);
  cv::Mat mask = cv::Mat::zeros(h, w, CV_32F);
  inner.convertTo(mask.colRange(s, w - s), CV_32F, 1.0 / 255.0);
  const int ww = w / 4, bh = h / 2;
  for (int band = 0; ww >= 1 && bh >= 1 && band < h / bh; ++band) {
    cv::Mat rows = mask.rowRange(band * bh, band * bh + bh);
    cv::Mat colSum;
    cv::reduce(rows, colSum, 0, cv::REDUCE_SUM, CV_64F);
    std::vector<double> prefix(static_cast<size_t>(w) + 1, 0.0);
    for (int x = 0; x < w; ++x) prefix[static_cast<size_t>(x) + 1] = prefix[static_cast<size_t>(x)] + colSum.at<double>(0, x);
    cv::Mat keep = cv::Mat::ones(1, w, CV_32F);
    for (int i = 0; i < (w - ww) / p.noiseGamma; ++i) {
      const int x0 = i * p.noiseGamma;
      if (prefix[static_cast<size_t>(x0 + ww)] - prefix[static_cast<size_t>(x0)] <= p.noiseTheta)
        keep.colRange(x0, x0 + ww).setTo(0.0F);
    }
    cv::multiply(rows, cv::repeat(keep, bh, 1), rows);
  }
  cv::Mat idx(1, w, CV_32F);
  for (int x = 0; x < w; ++x) idx.at<float>(0, x) = static_cast<float>(x);
  cv::Mat sums, counts;
  cv::reduce(mask.mul(cv::repeat(idx, h, 1)), sums, 1, cv::REDUCE_SUM, CV_64F);
  cv::reduce(mask, counts, 1, cv::REDUCE_SUM, CV_64F);
  std::vector<double> ys, cs;
  for (int y = 0; y < h; ++y)
    if (counts.at<double>(y, 0) > 0) {
      ys.push_back(y);
      cs.push_back(sums.at<double>(y, 0) / counts.at<double>(y, 0));
    }
  if (ys.size() > 5) {
    const double mid = 0.5 * (ys.front() + ys.back()), half = std::max(1.0, 0.5 * (ys.back() - ys.front()));
    cv::Mat a(static_cast<int>(ys.size()), 5, CV_64F), b(static_cast<int>(ys.size()), 1, CV_64F, cs.data()), x;
    for (int i = 0; i < a.rows; ++i) {
      const double t = (ys[static_cast<size_t>(i)] - mid) / half;
      double tk = 1.0;
      for (int k = 0; k < 5; ++k, tk *= t) a.at<double>(i, k) = tk;
    }
    cv::solve(a, b, x, cv::DECOMP_QR);
  }
  return static_cast<int>(ys.size());
}

bool writeNpy(const std::string& path, const cv::Mat& bgr) {
  std::string header = "{'descr': '|u1', 'fortran_order': False, 'shape': (" + std::to_string(bgr.rows) + ", " +
                       std::to_string(bgr.cols) + ", 3), }";
  while ((10 + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::ofstream f(path, std::ios::binary);
  const char magic[] = "\x93NUMPY\x01\x00";
  f.write(magic, 8);
  const auto len = static_cast<uint16_t>(header.size());
  const char lenBytes[2] = {static_cast<char>(len & 0xFF), static_cast<char>(len >> 8)};
  f.write(lenBytes, 2);
  f << header;
  for (int y = 0; y < bgr.rows; ++y) f.write(reinterpret_cast<const char*>(bgr.ptr(y)), static_cast<std::streamsize>(bgr.cols) * 3);
  return static_cast<bool>(f);
}

// Median milliseconds of the numpy paper_lle on `npy` (a subprocess), or < 0.
double numpyMillis(const std::string& python, const std::string& npy, const image::Roi* roi, int repeat) {
  const fs::path pkg = fs::path(ALACS_SOURCE_DIR) / "tools" / "paper_lle";
  std::string cmd = "env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 taskset -c 0 '" +
                    python + "' '" + (pkg / "paper_lle.py").string() + "' --time '" + npy + "' --repeat " +
                    std::to_string(repeat);
  if (roi != nullptr)
    cmd += " --roi " + std::to_string(roi->x) + "," + std::to_string(roi->y) + "," + std::to_string(roi->width) + "," +
           std::to_string(roi->height);
  FILE* p = popen(cmd.c_str(), "r");
  if (p == nullptr) return -1.0;
  char buf[128] = {};
  const bool got = std::fgets(buf, sizeof buf, p) != nullptr;
  const int rc = pclose(p);
  return got && rc == 0 ? std::atof(buf) : -1.0;
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 200;
  std::string imagePath;
  std::string python = fs::path(ALACS_SOURCE_DIR) / ".venv" / "bin" / "python";
  bool runPython = true;
  bool pin = true;
  int profileFrames = 0;  // --profile N: only LLE on the full frame, N times (for perf)
  bool noPython = false, noPin = false;
  CLI::App app("LLE against memcpy of the frame, the paper's method in OpenCV float and in numpy: ratios measured "
               "in the same run (a benchmark, not a test).",
               "alacs_lle_bench");
  app.add_option("--frames", frames, "frames timed (at least 10)")->capture_default_str();
  app.add_option("--image", imagePath, "a PNG frame (default: a rendered one)");
  app.add_option("--python", python, "the Python with numpy for the paper's method")->capture_default_str();
  app.add_flag("--no-python", noPython, "skip the numpy measurement");
  app.add_flag("--no-pin", noPin, "do not pin to CPU 0");
  CLI::Option* profile =
      app.add_option("--profile", profileFrames, "only LLE on the full frame, N times (for perf; at least 1)");
  if (const int rc = tools::parseCommandLine(app, argc, argv); rc >= 0) return rc;
  frames = std::max(10, frames);
  if (profile->count() > 0) profileFrames = std::max(1, profileFrames);
  runPython = !noPython;
  pin = !noPin;
  if (pin) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(0, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0) std::fprintf(stderr, "(could not pin to CPU 0)\n");
  }
  cv::setNumThreads(1);

  // The frame and the target's ROI.
  sim::SimScene scene = sim::defaultScene();
  const sim::SimApple& apple = scene.apples.front();
  const double slide = scene.truth.laser.slideForPoint(apple.centerMm);
  cv::Mat frame;
  if (imagePath.empty()) {
    sim::Renderer(scene).render(slide, 1.0, 0, frame);
  } else {
    frame = cv::imread(imagePath, cv::IMREAD_COLOR);
    if (frame.empty()) {
      std::fprintf(stderr, "alacs_lle_bench: cannot read %s\n", imagePath.c_str());
      return 1;
    }
  }
  const image::ImageView view{frame.data, frame.cols, frame.rows, frame.step[0], image::PixelFormat::kBgr888};
  const image::Roi full{0, 0, frame.cols, frame.rows};
  image::Roi roi = full;
  if (imagePath.empty()) {
    const localize::Localizer loc(scene.truth, image::LleParams{}, localize::ScanParams{});
    if (auto plan = loc.plan(apple.centerMm, 200.0)) roi = plan->roi;
  }
  const size_t bytes = frame.step[0] * static_cast<size_t>(frame.rows);
  std::vector<uint8_t> copy(bytes);

  image::LleParams p;
  image::LleWorkspace ws;
  image::LaserLine line;
  size_t sink = 0;
  if (profileFrames > 0) {
    for (int i = 0; i < profileFrames; ++i)
      if (!image::extractLine(view, full, p, ws, line).isOk()) std::abort();
    std::printf("%d frames, %zu rows\n", profileFrames, line.rows.size());
    return 0;
  }
  const auto copyFrame = [&] {
    std::memcpy(copy.data(), frame.data, bytes);
    sink += copy[bytes / 2];
  };
  const auto lleFullFrame = [&] {
    if (!image::extractLine(view, full, p, ws, line).isOk()) std::abort();
    sink += line.rows.size();
  };
  const Interleaved yard = timeInTurn(
      frames, copyFrame, [&] { sink += readOnce(frame.data, bytes); }, lleFullFrame);
  const Stats& mem = yard.a;
  const Stats& lle = yard.c;
  // The same two timed in blocks, each alone (as this benchmark did before): each then runs
  // with its own data hot in the caches, memcpy both of its buffers (2 × the frame).
  const Stats memAlone = timeIt(frames, copyFrame);
  const Stats lleAlone = timeIt(frames, lleFullFrame);
  const size_t fullRows = line.rows.size();
  const Stats roiStats = timeIt(frames, [&] {
    if (!image::extractLine(view, roi, p, ws, line).isOk()) std::abort();
    sink += line.rows.size();
  });
  const size_t roiRows = line.rows.size();
  // In a window the line is chosen among the grown lines (the centre prior); the strongest's alone.
  image::LleParams strongest = p;
  strongest.centrePriorShare = 0.0;
  const Stats roiStrongest = timeIt(frames, [&] {
    if (!image::extractLine(view, roi, strongest, ws, line).isOk()) std::abort();
    sink += line.rows.size();
  });
  // A weak line less the laser-off frame (sunlit skin at a short exposure): the laser on
  // for 4 % of the exposure, so the first pass finds it weak and the subtracted rerun runs.
  // (2: the row alone without the matched filter for the rows it leaves, LleParams::matchedFilter.)
  Stats subtracted[3];
  size_t subtractedRows[3] = {0, 0, 0};
  const bool rendered = imagePath.empty();
  if (rendered) {
    cv::Mat weak, off;
    sim::Renderer renderer(scene);
    renderer.render(slide, 0.04, 1, weak);
    renderer.render(slide, 0.0, 2, off);
    const image::ImageView weakView{weak.data, weak.cols, weak.rows, weak.step[0], image::PixelFormat::kBgr888};
    const image::ImageView offView{off.data, off.cols, off.rows, off.step[0], image::PixelFormat::kBgr888};
    for (int k = 0; k < 3; ++k) {
      image::LleParams sub = p;
      sub.subtractedRows = k == 1 ? 3 : 1;
      sub.matchedFilter = k != 2;
      subtracted[k] = timeIt(frames, [&] {
        if (!image::extractLine(weakView, roi, sub, ws, line, &offView).isOk()) std::abort();
        sink += line.rows.size();
      });
      subtractedRows[k] = static_cast<size_t>(line.inliers);
    }
  }
  image::LleParams scalar = p;
  scalar.kernels = image::LleKernels::kScalar;
  const Stats lleScalar = timeIt(std::max(10, frames / 4), [&] {
    if (!image::extractLine(view, full, scalar, ws, line).isOk()) std::abort();
  });
  image::LleParams paper = p;
  paper.method = image::LleMethod::kPaper;
  const Stats paperCpp = timeIt(std::max(10, frames / 4), [&] {
    if (!image::extractLine(view, full, paper, ws, line).isOk()) std::abort();
  });
  int ocvRows = 0;
  const Stats ocv = timeIt(std::max(10, frames / 10), [&] { ocvRows = opencvFloatPaper(frame, p); });
  double numpyMs = -1.0;
  if (runPython) {
    const std::string npy = (fs::temp_directory_path() / ("alacs_lle_bench_" + std::to_string(getpid()) + ".npy")).string();
    if (writeNpy(npy, frame)) numpyMs = numpyMillis(python, npy, nullptr, 10);
    fs::remove(npy);
  }

  const double mb = static_cast<double>(bytes) / 1e6;
  std::printf("LLE speed on a %dx%d BGR frame (%.2f MB), one core%s, LLE kernels: %s, medians of %d frames\n", frame.cols,
              frame.rows, mb, pin ? " (pinned to CPU 0)" : "", image::lleSimdName(), frames);
  // In turn: the times' medians, and beside them the medians of the per-frame ratios (which
  // need not equal the ratios of the medians).
  std::printf("  %-44s %8.3f ms  (%.1f GB/s)  [in turn]\n", "memcpy of the frame", mem.median, mb / mem.median);
  std::printf("  %-44s %8.3f ms  per frame %.2f x memcpy (the floor for one look at every byte)\n",
              "one read of the frame (a sum)", yard.b.median, yard.bOverA);
  std::printf("  %-44s %8.3f ms  p99 %7.3f ms  per frame %.2f x memcpy, %.2f x one read  [%zu rows]\n",
              "LLE, full frame (SIMD)", lle.median, lle.p99, yard.cOverA, yard.cOverB, fullRows);
  std::printf("  %-44s %8.3f ms against %.3f ms = %.2f x memcpy\n", "the same in blocks, each alone (LLE, memcpy)",
              lleAlone.median, memAlone.median, lleAlone.median / memAlone.median);
  std::printf("  %-44s %8.3f ms  = %.2f x memcpy in blocks\n", "LLE, full frame (scalar kernels)", lleScalar.median,
              lleScalar.median / memAlone.median);
  char roiName[64];
  std::snprintf(roiName, sizeof roiName, "LLE, ROI mode %dx%d", roi.width, roi.height);
  std::printf("  %-44s %8.3f ms  p99 %7.3f ms  [%zu rows]\n", roiName, roiStats.median, roiStats.p99, roiRows);
  std::printf("  %-44s %8.3f ms  (the centre prior costs %.2f x)\n", "LLE, ROI mode, the strongest line (no prior)",
              roiStrongest.median, roiStats.median / roiStrongest.median);
  if (rendered) {
    std::printf("  %-44s %8.3f ms  [%zu line rows]\n", "LLE, ROI, weak line less laser-off, row alone",
                subtracted[0].median, subtractedRows[0]);
    std::printf("  %-44s %8.3f ms  [%zu line rows]  (three rows cost %.2f x the row alone)\n",
                "LLE, ROI, weak line less laser-off, 3 rows", subtracted[1].median, subtractedRows[1],
                subtracted[1].median / subtracted[0].median);
    std::printf("  %-44s %8.3f ms  [%zu line rows]  (the matched filter costs %.2f x)\n",
                "LLE, ROI, weak line less laser-off, no filter", subtracted[2].median, subtractedRows[2],
                subtracted[0].median / subtracted[2].median);
  }
  std::printf("  %-44s %8.3f ms\n", "paper's method, C++ fixed point (SIMD)", paperCpp.median);
  std::printf("  %-44s %8.3f ms  -> LLE is %.1f x faster  [%d rows]\n", "paper's method, plain OpenCV float pipeline",
              ocv.median, ocv.median / lle.median, ocvRows);
  if (numpyMs > 0)
    std::printf("  %-44s %8.3f ms  -> LLE is %.1f x faster\n", "paper's method, numpy reference (paper_lle)", numpyMs,
                numpyMs / lle.median);
  else if (runPython)
    std::printf("  %-44s (could not run %s tools/paper_lle/paper_lle.py)\n", "paper's method, numpy reference", python.c_str());
  std::printf("per-frame latency, full frame: median %.3f ms, p99 %.3f ms; ROI: median %.3f ms, p99 %.3f ms\n", lle.median,
              lle.p99, roiStats.median, roiStats.p99);
  // No verdict: one run's median moves with the machine's load by more than the target's
  // margin; the brief's target (LLE <= 1.0 x memcpy) is judged on the medians of several runs.
  std::printf(
      "ratio LLE / memcpy = %.2f in turn (median of per-frame ratios), %.2f in blocks; LLE / one read = %.2f in turn "
      "(the brief's target: LLE <= 1.0 x memcpy, over several runs)\n",
      yard.cOverA, lleAlone.median / memAlone.median, yard.cOverB);
  return sink == 0 ? 1 : 0;
}
