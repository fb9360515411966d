#include "corners_eval.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "geometry/checkerboard_corners.h"
#include "replay/scan_dir.h"

namespace alacs::eval {

namespace fs = std::filesystem;

namespace {

struct TruthView {
  std::string name;
  std::string dir;
  int cols = 0;
  int rows = 0;
  std::vector<Eigen::Vector2d> corners;  // the visible ones
};

// truth/corners.csv: i,j,x_mm,y_mm,z_mm,column_px,row_px,visible (edge/sim/scan_export.cpp).
bool readTruth(const fs::path& dir, TruthView& v) {
  std::ifstream in(dir / "truth" / "corners.csv");
  if (!in) return false;
  std::string line;
  std::getline(in, line);
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::string f[8];
    for (auto& x : f) std::getline(ss, x, ',');
    v.cols = std::max(v.cols, std::atoi(f[0].c_str()));
    v.rows = std::max(v.rows, std::atoi(f[1].c_str()));
    if (f[7] == "1") v.corners.emplace_back(std::atof(f[5].c_str()), std::atof(f[6].c_str()));
  }
  return v.cols > 1 && v.rows > 1;
}

struct MethodStats {
  std::string name;
  int detected = 0;
  std::vector<double> errors;   // every corner (px)
  std::vector<double> viewRms;  // per detected view
  double sumDx = 0.0, sumDy = 0.0;
  double seconds = 0.0;
  std::vector<std::string> misses;  // "view: reason"
};

// Adds one view's detection to `s`: every detected corner against its nearest true corner.
void score(const TruthView& v, const std::vector<Eigen::Vector2d>& found, MethodStats& s) {
  double sum2 = 0.0;
  for (const auto& p : found) {
    double best = std::numeric_limits<double>::infinity();
    Eigen::Vector2d d = Eigen::Vector2d::Zero();
    for (const auto& t : v.corners) {
      const double e = (p - t).norm();
      if (e < best) {
        best = e;
        d = p - t;
      }
    }
    s.errors.push_back(best);
    s.sumDx += d.x();
    s.sumDy += d.y();
    sum2 += best * best;
  }
  ++s.detected;
  s.viewRms.push_back(std::sqrt(sum2 / static_cast<double>(std::max<size_t>(1, found.size()))));
}

double median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

void printTable(const std::vector<MethodStats>& stats, size_t views) {
  std::printf("| detector | views detected | corner RMS | median view RMS | max | mean offset (x, y) | time/view |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- |\n");
  for (const auto& s : stats) {
    if (s.detected == 0 && s.misses.empty()) continue;  // not run (--default-only)
    double sum2 = 0.0, worst = 0.0;
    for (double e : s.errors) {
      sum2 += e * e;
      worst = std::max(worst, e);
    }
    const double n = static_cast<double>(std::max<size_t>(1, s.errors.size()));
    std::printf("| %s | %d / %zu | %.3f px | %.3f px | %.3f px | (%+.3f, %+.3f) px | %.2f s |\n", s.name.c_str(),
                s.detected, views, std::sqrt(sum2 / n), median(s.viewRms), worst, s.sumDx / n, s.sumDy / n,
                s.seconds / static_cast<double>(std::max<size_t>(1, views)));
  }
}

double rmsOf(const MethodStats& s) {
  double sum2 = 0.0;
  for (double e : s.errors) sum2 += e * e;
  return std::sqrt(sum2 / static_cast<double>(std::max<size_t>(1, s.errors.size())));
}

}  // namespace

int cornersEval(const CornersEvalOptions& o) {
  std::vector<fs::path> dirs;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(o.scansDir, ec))
    if (e.is_directory() && fs::exists(e.path() / "manifest.json") && fs::exists(e.path() / "truth" / "corners.csv"))
      dirs.push_back(e.path());
  if (ec || dirs.empty()) {
    std::fprintf(stderr, "corners: no board scans with truth/corners.csv in %s\n", o.scansDir.c_str());
    return 1;
  }
  std::sort(dirs.begin(), dirs.end());
  using geometry::CornerMethod;
  // --default-only: the default detector at its own window.
  const std::vector<double> windowShares =
      o.defaultOnly ? std::vector<double>{geometry::CornerOptions{}.subPixWindowShare} : o.windowShares;
  std::vector<MethodStats> stats;
  auto named = [](const std::string& name) {
    MethodStats s;
    s.name = name;
    return s;
  };
  stats.push_back(named("sb"));
  stats.push_back(named("sb-accuracy"));
  for (double w : windowShares) {
    char name[64];
    std::snprintf(name, sizeof name, "classic-subpix (window %.2f)", w);
    stats.push_back(named(name));
    std::snprintf(name, sizeof name, "sb-subpix (window %.2f)", w);
    stats.push_back(named(name));
  }
  // The default detector's row (with a refinement: at the default window, if among them).
  const geometry::CornerOptions defaults;
  int defaultRow = defaults.method == CornerMethod::kSectorAccuracy ? 1 : 0;
  for (size_t k = 0; k < windowShares.size(); ++k)
    if (std::abs(windowShares[k] - defaults.subPixWindowShare) < 1e-9) {
      if (defaults.method == CornerMethod::kClassicSubPix) defaultRow = static_cast<int>(2 + 2 * k);
      if (defaults.method == CornerMethod::kSectorSubPix) defaultRow = static_cast<int>(3 + 2 * k);
    }
  using Clock = std::chrono::steady_clock;
  auto secondsSince = [](Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); };
  for (const auto& dir : dirs) {
    TruthView v;
    v.name = dir.filename().string();
    if (!readTruth(dir, v)) {
      std::fprintf(stderr, "corners: %s: unreadable truth/corners.csv\n", v.name.c_str());
      return 1;
    }
    Result<replay::ScanManifest> m = replay::readManifest(dir.string());
    if (!m) {
      std::fprintf(stderr, "corners: %s: %s\n", v.name.c_str(), m.status().toString().c_str());
      return 1;
    }
    const auto off = std::find_if(m->frames.begin(), m->frames.end(), [](const auto& f) { return !f.laserOn; });
    if (off == m->frames.end()) continue;
    Result<cv::Mat> bgr = replay::loadFrame(dir.string(), *m, *off);
    if (!bgr) {
      std::fprintf(stderr, "corners: %s: %s\n", v.name.c_str(), bgr.status().toString().c_str());
      return 1;
    }
    cv::Mat gray;
    cv::cvtColor(*bgr, gray, cv::COLOR_BGR2GRAY);
    auto run = [&](MethodStats& s, const Result<std::vector<Eigen::Vector2d>>& r) {
      if (r)
        score(v, *r, s);
      else
        s.misses.push_back(v.name + ": " + r.status().reason());
      if (o.verbose)
        std::printf("  %s %s: %s\n", v.name.c_str(), s.name.c_str(),
                    r ? ("view RMS " + std::to_string(s.viewRms.back()) + " px").c_str() : r.status().reason().c_str());
    };
    auto t0 = Clock::now();
    if (o.defaultOnly) {
      MethodStats& s = stats[static_cast<size_t>(std::max(defaultRow, 0))];
      const auto found = geometry::findCheckerboardCorners(gray, v.cols, v.rows, defaults);
      s.seconds += secondsSince(t0);
      run(s, found);
      continue;
    }
    const auto sb = geometry::findCheckerboardCorners(gray, v.cols, v.rows, {CornerMethod::kSector});
    const double sbSeconds = secondsSince(t0);
    stats[0].seconds += sbSeconds;
    run(stats[0], sb);
    t0 = Clock::now();
    const auto acc = geometry::findCheckerboardCorners(gray, v.cols, v.rows, {CornerMethod::kSectorAccuracy});
    stats[1].seconds += secondsSince(t0);
    run(stats[1], acc);
    for (size_t k = 0; k < windowShares.size(); ++k) {
      t0 = Clock::now();
      const auto classic =
          geometry::findCheckerboardCorners(gray, v.cols, v.rows, {CornerMethod::kClassicSubPix, windowShares[k]});
      stats[2 + 2 * k].seconds += secondsSince(t0);
      run(stats[2 + 2 * k], classic);
      // sb-subpix: the sb detection (timed above) refined, exactly as findCheckerboardCorners does it.
      Result<std::vector<Eigen::Vector2d>> refined = sb;
      t0 = Clock::now();
      if (refined) {
        if (Status st = geometry::refineCheckerboardCorners(gray, v.cols, v.rows, windowShares[k], *refined); !st)
          refined = st;
      }
      stats[3 + 2 * k].seconds += sbSeconds + secondsSince(t0);
      run(stats[3 + 2 * k], refined);
    }
    std::fflush(stdout);
  }
  std::printf("%zu board views (%s)\n\n", dirs.size(), o.scansDir.c_str());
  printTable(stats, dirs.size());
  const MethodStats& chosen = stats[static_cast<size_t>(defaultRow >= 0 ? defaultRow : 0)];
  std::printf("\nviews the default detector (%s) skips, and why:\n", chosen.name.c_str());
  if (chosen.misses.empty()) std::printf("  none\n");
  for (const auto& miss : chosen.misses) std::printf("  %s\n", miss.c_str());
  bool ok = true;
  if (chosen.detected < o.minDetected) {
    std::printf("LIMIT: %d views detected, fewer than %d\n", chosen.detected, o.minDetected);
    ok = false;
  }
  if (o.maxRmsPx > 0.0 && !(rmsOf(chosen) <= o.maxRmsPx)) {
    std::printf("LIMIT: corner RMS %.3f px above %.3f px\n", rmsOf(chosen), o.maxRmsPx);
    ok = false;
  }
  return ok ? 0 : 4;
}

}  // namespace alacs::eval
