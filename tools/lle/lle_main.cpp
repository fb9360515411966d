// alacs_lle: Laser Line Extraction on one image or on a scan directory; writes per
// frame a JSON document (every ROI row: row, sub-pixel column in full-frame pixels,
// confidence, validity; the polynomial; segments and coverage) and an overlay PNG.
// See --help and docs/lle.md.
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "image/lle.h"
#include "lle_output.h"
#include "tool_common/cli.h"
#ifdef ALACS_LLE_HAVE_REPLAY
#include "replay/png_io.h"
#include "replay/scan_dir.h"
#endif

using namespace alacs;
namespace fs = std::filesystem;

namespace {

constexpr const char* kDescription =
    "Laser Line Extraction on one image or on a scan directory (docs/lle.md).\n"
    "  alacs_lle IMAGE [--roi X,Y,W,H] [--laser-off IMAGE] [--json FILE] [--overlay FILE.png] [options]\n"
    "  alacs_lle --scan DIR --out DIR [--roi X,Y,W,H] [--subtract-off] [options]\n"
    "IMAGE mode writes FILE (default: IMAGE with .lle.json) and the overlay (default: IMAGE with\n"
    ".lle.png; --overlay none: no overlay). --scan reads a scan directory (manifest.json, or\n"
    "else every *.png in it) and writes one JSON and one overlay per laser-on frame into --out,\n"
    "plus summary.json; the ROI is --roi, else the scan's planned ROI, else the whole frame.\n"
    "--subtract-off subtracts a laser-off frame of the scan at the laser frame's exposure (within 5 %),\n"
    "the nearest in position (the ambient is the same at every position); none: a warning, no subtraction.\n"
    "Exit status: 0 done, 1 an input or parameter was refused (the reason on stderr), 2 usage.";

struct Options {
  std::string image, laserOff, json, overlay, scan, out;
  bool haveRoi = false;
  image::Roi roi;
  bool subtractOff = false;
  bool reference = false;
  image::LleParams params;
};

// "X,Y,W,H", four integers.
bool parseRoi(const std::string& s, image::Roi& r) {
  int v[4];
  char tail = 0;
  if (std::sscanf(s.c_str(), "%d,%d,%d,%d%c", &v[0], &v[1], &v[2], &v[3], &tail) != 4) return false;
  r = {v[0], v[1], v[2], v[3]};
  return true;
}

// Returns -1 to go on, else the exit status (0 after --help, 2 on a usage error, printed).
int parseArgs(int argc, char** argv, Options& o) {
  image::LleParams& p = o.params;
  CLI::App app(kDescription, "alacs_lle");
  app.add_option("IMAGE", o.image, "the image (PNG: the checked reader of edge/replay; else OpenCV)");
  std::string roi;
  app.add_option("--roi", roi, "the region of interest X,Y,W,H in pixels (default: the whole frame)");
  app.add_option("--laser-off", o.laserOff, "a laser-off image of the same scene, subtracted");
  app.add_option("--json", o.json, "the JSON output (default: IMAGE with .lle.json)");
  app.add_option("--overlay", o.overlay, "the overlay PNG (default: IMAGE with .lle.png; none: no overlay)");
  app.add_option("--scan", o.scan, "a scan directory instead of IMAGE");
  app.add_option("--out", o.out, "the output directory of --scan");
  app.add_flag("--subtract-off", o.subtractOff,
               "--scan: subtract the laser-off frame at the laser frame's exposure (within 5 %)");
  std::string method = "robust", form = "meaning";
  app.add_option("--method", method, "robust|paper")->check(CLI::IsMember({"robust", "paper"}))->capture_default_str();
  app.add_option("--form", form, "meaning|literal")->check(CLI::IsMember({"meaning", "literal"}))->capture_default_str();
  app.add_option("--step", p.brceStep, "bRCE step")->capture_default_str();
  app.add_option("--th", p.brceThreshold, "bRCE threshold")->capture_default_str();
  app.add_option("--theta", p.noiseTheta, "noise removal theta")->capture_default_str();
  app.add_option("--gamma", p.noiseGamma, "noise removal gamma")->capture_default_str();
  app.add_option("--order", p.polyOrder, "polynomial order")->capture_default_str();
  app.add_option("--outlier", p.outlierPx, "outlier distance, px")->capture_default_str();
  app.add_option("--min-rows", p.minRows, "fewest rows of a fit")->capture_default_str();
  app.add_option("--smooth", p.smoothRows, "smoothing rows")->capture_default_str();
  app.add_option("--jump", p.maxJumpPx, "largest jump within a segment, px")->capture_default_str();
  app.add_option("--gap", p.maxGapRows, "largest gap within a segment, rows")->capture_default_str();
  app.add_option("--min-segment", p.minSegmentRows, "shortest segment, rows")->capture_default_str();
  app.add_option("--peaks", p.maxPeaksPerRow, "peaks per row")->capture_default_str();
  app.add_option("--centre-prior", p.centrePriorShare,
                 "the line is the grown line whose rows' strengths, each weighted by the row's distance from the "
                 "ROI's centre (sigma in shares of the ROI), sum largest (0: the strongest)")
      ->capture_default_str();
  app.add_option("--edge", p.edgeRatio, "occluding-edge ratio (0 off: rows at an occluding edge are kept valid)")
      ->capture_default_str();
  app.add_option("--robust-pct", p.robustThresholdPct, "the robust method's strong threshold, % of --th")
      ->capture_default_str();
  app.add_option("--weak-excess", p.weakLineExcessDn, "a line weaker than this is run again at --weak-pct; 0: off")
      ->capture_default_str();
  app.add_option(
         "--short-pct", p.shortLinePct,
         "a line with fewer rows than this share of the ROI's height (%) is run again at --weak-pct too; 0: off")
      ->capture_default_str();
  app.add_option("--weak-pct", p.weakLineThresholdPct, "the threshold of the weak-line rerun, % of --th")
      ->capture_default_str();
  app.add_option("--subtracted-pct", p.subtractedLineThresholdPct,
                 "the weak-line rerun's threshold with --laser-off subtracted, % of --th")
      ->capture_default_str();
  app.add_option("--subtracted-rows", p.subtractedRows,
                 "rows that rerun averages the difference over: 1 (the row alone) or 3 ([1 2 1]/4)")
      ->check(CLI::IsMember({1, 3}))
      ->capture_default_str();
  app.add_flag("--rerun-others-firm", p.rerunOthersFirm,
               "a rerun's segments off the line need the first pass's strong threshold (docs/lle.md)");
  app.add_option("--matched-filter", p.matchedFilter,
                 "1: rows the subtracted rerun leaves are looked for with a filter matched to the line's profile "
                 "(alacsd does so only where its metering found direct sun; 0 reproduces any other frame)")
      ->capture_default_str();
  bool onlyLine = false, scalar = false;
  app.add_flag("--only-line", onlyLine, "no other segments");
  app.add_flag("--scalar", scalar, "scalar kernels");
  app.add_flag("--reference", o.reference, "the float reference");
  if (const int rc = tools::parseCommandLine(app, argc, argv); rc >= 0) return rc;
  p.method = method == "paper" ? image::LleMethod::kPaper : image::LleMethod::kRobust;
  p.brceForm = form == "literal" ? image::BrceForm::kLiteral : image::BrceForm::kMeaning;
  if (onlyLine) p.keepOtherSegments = false;
  if (scalar) p.kernels = image::LleKernels::kScalar;
  if (!roi.empty()) {
    if (!parseRoi(roi, o.roi)) return tools::usageError(app, "--roi wants X,Y,W,H (integers), not '" + roi + "'");
    o.haveRoi = true;
  }
  if (o.image.empty() == o.scan.empty()) return tools::usageError(app, "give either IMAGE or --scan DIR");
  if (!o.scan.empty() && o.out.empty()) return tools::usageError(app, "--scan needs --out DIR");
  return -1;
}

image::ImageView viewOf(const cv::Mat& m) {
  return {m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888};
}

bool isPng(const std::string& path) {
  char sig[8] = {};
  std::ifstream in(path, std::ios::binary);
  return in.read(sig, sizeof sig) && std::memcmp(sig, "\x89PNG\r\n\x1a\n", sizeof sig) == 0;
}

// Reads an 8-bit colour image (BGR). Errors name the file. A PNG goes through the
// replay reader, which checks the header's size before allocating; other formats through
// OpenCV, whose refusals (an exception for a header beyond its own limits) become errors.
Result<cv::Mat> readImage(const std::string& path) {
  if (!fs::exists(path)) return Status(Error::kNotFound, "'" + path + "' does not exist");
#ifdef ALACS_LLE_HAVE_REPLAY
  if (isPng(path)) {
    cv::Mat m;
    if (Status s = replay::readPng(path, m); !s) return s;
    return m;
  }
#endif
  cv::Mat m;
  try {
    m = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    return Status(Error::kBadInput, "'" + path + "': " + e.msg);
  }
  if (m.empty()) return Status(Error::kBadInput, "'" + path + "' is not an image OpenCV can read");
  if (m.depth() != CV_8U) return Status(Error::kBadInput, "'" + path + "' is not 8 bits per channel");
  if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
  else if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2BGR);
  else if (m.channels() != 3) return Status(Error::kBadInput, "'" + path + "' has " + std::to_string(m.channels()) + " channels");
  return m;
}

#ifdef ALACS_LLE_HAVE_REPLAY
// Exposures (us) a laser-off frame may differ from the laser frame's by, as a ratio, and
// still be subtracted: what a camera reports against what was asked.
constexpr double kSameExposureRatio = 1.05;
bool sameExposure(int64_t aUs, int64_t bUs) {
  if (aUs <= 0 || bUs <= 0) return aUs == bUs;
  const double r = static_cast<double>(aUs) / static_cast<double>(bUs);
  return r <= kSameExposureRatio && r >= 1.0 / kSameExposureRatio;
}
#endif

// Runs LLE on one frame and writes its JSON and overlay. Returns false (reason printed)
// when the library refused the input.
bool processFrame(const Options& o, const std::string& name, const cv::Mat& frame, const cv::Mat* off,
                  const std::string& offName, const image::Roi& roi, const std::string& jsonPath,
                  const std::string& overlayPath, image::LleWorkspace& ws, image::LaserLine& line,
                  tools::Json* summary) {
  tools::LleRun run;
  run.image = name;
  run.laserOff = off != nullptr ? offName : std::string();
  run.roi = roi;
  run.params = o.params;
  run.reference = o.reference;
  const image::ImageView fv = viewOf(frame);
  image::ImageView ov;
  if (off != nullptr) ov = viewOf(*off);
  const auto t0 = std::chrono::steady_clock::now();
  const Status st = o.reference ? image::extractLineReference(fv, roi, o.params, line, off ? &ov : nullptr)
                                : image::extractLine(fv, roi, o.params, ws, line, off ? &ov : nullptr);
  run.millis = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (!st) {
    std::fprintf(stderr, "alacs_lle: %s: %s\n", name.c_str(), st.toString().c_str());
    return false;
  }
  std::ofstream js(jsonPath, std::ios::trunc);
  js << tools::lleJson(run, frame.cols, frame.rows, line);
  if (!js) {
    std::fprintf(stderr, "alacs_lle: cannot write %s\n", jsonPath.c_str());
    return false;
  }
  if (overlayPath != "none" && !cv::imwrite(overlayPath, tools::lleOverlay(frame, roi, line))) {
    std::fprintf(stderr, "alacs_lle: cannot write %s\n", overlayPath.c_str());
    return false;
  }
  if (summary != nullptr) {
    *summary = {{"frame", name},
                {"json", fs::path(jsonPath).filename().string()},
                {"line_valid", line.valid},
                {"line_rows", line.inliers},
                {"coverage", tools::jsonNumber(line.coverage, "%.4f")},
                {"segments", line.segments.size()}};
  }
  std::printf("%s: %d line rows, coverage %.3f, %zu segments, curve %s -> %s\n", name.c_str(), line.inliers,
              line.coverage, line.segments.size(), line.valid ? "fitted" : "none", jsonPath.c_str());
  return true;
}

std::string withSuffix(const std::string& path, const std::string& suffix) {
  fs::path p(path);
  return (p.parent_path() / p.stem()).string() + suffix;
}

int runImage(const Options& o) {
  Result<cv::Mat> frame = readImage(o.image);
  if (!frame) {
    std::fprintf(stderr, "alacs_lle: %s\n", frame.status().toString().c_str());
    return 1;
  }
  cv::Mat off;
  if (!o.laserOff.empty()) {
    Result<cv::Mat> r = readImage(o.laserOff);
    if (!r) {
      std::fprintf(stderr, "alacs_lle: %s\n", r.status().toString().c_str());
      return 1;
    }
    off = *r;
  }
  const image::Roi roi = o.haveRoi ? o.roi : image::Roi{0, 0, frame->cols, frame->rows};
  image::LleWorkspace ws;
  image::LaserLine line;
  const std::string json = o.json.empty() ? withSuffix(o.image, ".lle.json") : o.json;
  const std::string overlay = o.overlay.empty() ? withSuffix(o.image, ".lle.png") : o.overlay;
  return processFrame(o, o.image, *frame, o.laserOff.empty() ? nullptr : &off, o.laserOff, roi, json, overlay, ws, line,
                      nullptr)
             ? 0
             : 1;
}

int runScan(const Options& o) {
  std::error_code ec;
  fs::create_directories(o.out, ec);
  if (ec) {
    std::fprintf(stderr, "alacs_lle: cannot create %s: %s\n", o.out.c_str(), ec.message().c_str());
    return 1;
  }
  image::LleWorkspace ws;
  image::LaserLine line;
  tools::Json frames = tools::Json::array();
  int done = 0, failed = 0;
#ifdef ALACS_LLE_HAVE_REPLAY
  if (fs::exists(fs::path(o.scan) / "manifest.json")) {
    Result<replay::ScanManifest> m = replay::readManifest(o.scan);
    if (!m) {
      std::fprintf(stderr, "alacs_lle: %s\n", m.status().toString().c_str());
      return 1;
    }
    cv::Mat off;        // the laser-off frame last decoded,
    int offIndex = -1;  // its index in the manifest
    for (const auto& fr : m->frames) {
      if (!fr.laserOn) continue;
      Result<cv::Mat> img = replay::loadFrame(o.scan, *m, fr);
      if (!img) {
        std::fprintf(stderr, "alacs_lle: %s\n", img.status().toString().c_str());
        ++failed;
        continue;
      }
      std::string offName;
      bool haveOff = false;
      if (o.subtractOff) {
        // The ambient is the same at every slide position: the laser-off frame replay would
        // serve (nearest in exposure, then in position), and only at the laser frame's own
        // exposure, as the daemon subtracts (within kSameExposureRatio: a frame reports the
        // exposure it got).
        const int k = replay::nearestFrame(*m, fr.slideMm, false, fr.exposureUs);
        const replay::FrameRecord* g = k >= 0 ? &m->frames[static_cast<size_t>(k)] : nullptr;
        if (g == nullptr || !sameExposure(g->exposureUs, fr.exposureUs)) {
          std::fprintf(stderr, "alacs_lle: %s: no laser-off frame at its exposure (%lld us): nothing subtracted\n",
                       fr.file.c_str(), static_cast<long long>(fr.exposureUs));
        } else {
          if (k != offIndex) {
            Result<cv::Mat> r = replay::loadFrame(o.scan, *m, *g);
            if (!r) {
              std::fprintf(stderr, "alacs_lle: %s\n", r.status().toString().c_str());
              ++failed;
              continue;
            }
            off = std::move(*r);
            offIndex = k;
          }
          haveOff = true;
          offName = g->file;
        }
      }
      const image::Roi roi = o.haveRoi ? o.roi : m->scan.roiPx ? *m->scan.roiPx : image::Roi{0, 0, img->cols, img->rows};
      char stem[32];
      std::snprintf(stem, sizeof stem, "frame_%04d", fr.index);
      const std::string base = (fs::path(o.out) / stem).string();
      tools::Json entry;
      const bool ok = processFrame(o, fr.file, *img, haveOff ? &off : nullptr, offName, roi, base + ".json",
                                   base + ".png", ws, line, &entry);
      frames.push_back(ok ? entry : tools::Json{{"frame", fr.file}, {"error", true}});
      (ok ? done : failed) += 1;
    }
  } else
#endif
  {
    std::vector<fs::path> pngs;
    for (const auto& e : fs::directory_iterator(o.scan, ec))
      if (e.is_regular_file() && e.path().extension() == ".png") pngs.push_back(e.path());
    if (ec) {
      std::fprintf(stderr, "alacs_lle: cannot read %s: %s\n", o.scan.c_str(), ec.message().c_str());
      return 1;
    }
    std::sort(pngs.begin(), pngs.end());
    for (const auto& path : pngs) {
      Result<cv::Mat> img = readImage(path.string());
      if (!img) {
        std::fprintf(stderr, "alacs_lle: %s\n", img.status().toString().c_str());
        ++failed;
        continue;
      }
      const image::Roi roi = o.haveRoi ? o.roi : image::Roi{0, 0, img->cols, img->rows};
      const std::string base = (fs::path(o.out) / path.stem()).string();
      tools::Json entry;
      const bool ok = processFrame(o, path.filename().string(), *img, nullptr, std::string(), roi, base + ".json",
                                   base + ".png", ws, line, &entry);
      frames.push_back(ok ? entry : tools::Json{{"frame", path.filename().string()}, {"error", true}});
      (ok ? done : failed) += 1;
    }
  }
  const tools::Json summary{
      {"scan", o.scan}, {"frames", std::move(frames)}, {"processed", done}, {"failed", failed}};
  std::ofstream(fs::path(o.out) / "summary.json") << tools::jsonText(summary, 2);
  std::printf("%d frames processed, %d failed; %s\n", done, failed, (fs::path(o.out) / "summary.json").c_str());
  if (done + failed == 0) {
    std::fprintf(stderr, "alacs_lle: no laser-on frames in %s\n", o.scan.c_str());
    return 1;
  }
  return failed == 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (const int rc = parseArgs(argc, argv, o); rc >= 0) return rc;
  if (Status s = o.params.validate(); !s) {
    std::fprintf(stderr, "alacs_lle: %s\n", s.toString().c_str());
    return 1;
  }
  return o.scan.empty() ? runImage(o) : runScan(o);
}
