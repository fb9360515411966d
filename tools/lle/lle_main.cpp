// alacs_lle: Laser Line Extraction on one image or on a scan directory; writes per
// frame a JSON document (every ROI row: row, sub-pixel column in full-frame pixels,
// confidence, validity; the polynomial; segments and coverage) and an overlay PNG.
// See usage() and docs/lle.md.
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "image/lle.h"
#include "lle_output.h"
#ifdef ALACS_LLE_HAVE_REPLAY
#include "replay/scan_dir.h"
#endif

using namespace alacs;
namespace fs = std::filesystem;

namespace {

void usage(FILE* out) {
  std::fprintf(out,
               "usage: alacs_lle IMAGE [--roi X,Y,W,H] [--laser-off IMAGE] [--json FILE] [--overlay FILE.png] [options]\n"
               "       alacs_lle --scan DIR --out DIR [--roi X,Y,W,H] [--subtract-off] [options]\n"
               "\n"
               "IMAGE mode writes FILE (default: IMAGE with .lle.json) and the overlay (default: IMAGE with\n"
               ".lle.png; --overlay none: no overlay). --scan reads a scan directory (manifest.json, or\n"
               "else every *.png in it) and writes one JSON and one overlay per laser-on frame into --out,\n"
               "plus summary.json; the ROI is --roi, else the scan's planned ROI, else the whole frame.\n"
               "--subtract-off subtracts the laser-off frame taken at the same slide position.\n"
               "\n"
               "options: --method robust|paper   --form meaning|literal   --step N (4)   --th N (40)\n"
               "         --theta N (8)   --gamma N (3)   --order N (4)   --outlier PX (2)   --min-rows N (8)\n"
               "         --smooth N (8)   --jump PX (2)   --gap N (3)   --min-segment N (6)   --peaks N (4)\n"
               "         --edge N (3; 0 off: rows at an occluding edge are kept valid)\n"
               "         --robust-pct N (60: the robust method's strong threshold, %% of --th)\n"
               "         --weak-excess DN (a line weaker than this is run again at --weak-pct; 0: off)  --weak-pct N\n"
               "         --only-line (no other segments)   --scalar (scalar kernels)   --reference (float reference)\n"
               "exit status: 0 done, 1 an input or parameter was refused (the reason on stderr), 2 usage\n");
}

struct Options {
  std::string image, laserOff, json, overlay, scan, out;
  bool haveRoi = false;
  image::Roi roi;
  bool subtractOff = false;
  bool reference = false;
  image::LleParams params;
};

bool parseInt(const std::string& s, int& v) {
  char* end = nullptr;
  const long x = std::strtol(s.c_str(), &end, 10);
  if (end == s.c_str() || *end != '\0' || x < -1000000000L || x > 1000000000L) return false;
  v = static_cast<int>(x);
  return true;
}

bool parseDouble(const std::string& s, double& v) {
  char* end = nullptr;
  v = std::strtod(s.c_str(), &end);
  return end != s.c_str() && *end == '\0';
}

bool parseRoi(const std::string& s, image::Roi& r) {
  int v[4];
  size_t at = 0;
  for (int i = 0; i < 4; ++i) {
    const size_t comma = s.find(',', at);
    const std::string part = s.substr(at, comma == std::string::npos ? std::string::npos : comma - at);
    if (!parseInt(part, v[i])) return false;
    if (i < 3 && comma == std::string::npos) return false;
    at = comma + 1;
  }
  r = {v[0], v[1], v[2], v[3]};
  return true;
}

// Returns 0 on success, 2 on a usage error (message printed).
int parseArgs(int argc, char** argv, Options& o) {
  image::LleParams& p = o.params;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](std::string& v) {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "alacs_lle: %s needs a value\n", a.c_str());
        return false;
      }
      v = argv[++i];
      return true;
    };
    std::string v;
    auto intOpt = [&](int& field) {
      if (!value(v)) return false;
      if (!parseInt(v, field)) {
        std::fprintf(stderr, "alacs_lle: %s wants an integer, not '%s'\n", a.c_str(), v.c_str());
        return false;
      }
      return true;
    };
    auto numOpt = [&](double& field) {
      if (!value(v)) return false;
      if (!parseDouble(v, field)) {
        std::fprintf(stderr, "alacs_lle: %s wants a number, not '%s'\n", a.c_str(), v.c_str());
        return false;
      }
      return true;
    };
    bool ok = true;
    if (a == "-h" || a == "--help") {
      usage(stdout);
      std::exit(0);
    } else if (a == "--roi") {
      ok = value(v);
      if (ok && !parseRoi(v, o.roi)) {
        std::fprintf(stderr, "alacs_lle: --roi wants X,Y,W,H (integers), not '%s'\n", v.c_str());
        ok = false;
      }
      o.haveRoi = true;
    } else if (a == "--laser-off") ok = value(o.laserOff);
    else if (a == "--json") ok = value(o.json);
    else if (a == "--overlay") ok = value(o.overlay);
    else if (a == "--scan") ok = value(o.scan);
    else if (a == "--out") ok = value(o.out);
    else if (a == "--subtract-off") o.subtractOff = true;
    else if (a == "--reference") o.reference = true;
    else if (a == "--scalar") p.kernels = image::LleKernels::kScalar;
    else if (a == "--only-line") p.keepOtherSegments = false;
    else if (a == "--method") {
      ok = value(v);
      if (ok && v == "paper") p.method = image::LleMethod::kPaper;
      else if (ok && v == "robust") p.method = image::LleMethod::kRobust;
      else if (ok) {
        std::fprintf(stderr, "alacs_lle: --method is robust or paper, not '%s'\n", v.c_str());
        ok = false;
      }
    } else if (a == "--form") {
      ok = value(v);
      if (ok && v == "literal") p.brceForm = image::BrceForm::kLiteral;
      else if (ok && v == "meaning") p.brceForm = image::BrceForm::kMeaning;
      else if (ok) {
        std::fprintf(stderr, "alacs_lle: --form is meaning or literal, not '%s'\n", v.c_str());
        ok = false;
      }
    } else if (a == "--step") ok = intOpt(p.brceStep);
    else if (a == "--th") ok = intOpt(p.brceThreshold);
    else if (a == "--theta") ok = intOpt(p.noiseTheta);
    else if (a == "--gamma") ok = intOpt(p.noiseGamma);
    else if (a == "--order") ok = intOpt(p.polyOrder);
    else if (a == "--outlier") ok = numOpt(p.outlierPx);
    else if (a == "--min-rows") ok = intOpt(p.minRows);
    else if (a == "--smooth") ok = intOpt(p.smoothRows);
    else if (a == "--edge") ok = intOpt(p.edgeRatio);
    else if (a == "--robust-pct") ok = intOpt(p.robustThresholdPct);
    else if (a == "--weak-excess") ok = intOpt(p.weakLineExcessDn);
    else if (a == "--weak-pct") ok = intOpt(p.weakLineThresholdPct);
    else if (a == "--jump") ok = numOpt(p.maxJumpPx);
    else if (a == "--gap") ok = intOpt(p.maxGapRows);
    else if (a == "--min-segment") ok = intOpt(p.minSegmentRows);
    else if (a == "--peaks") ok = intOpt(p.maxPeaksPerRow);
    else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "alacs_lle: unknown option %s\n", a.c_str());
      ok = false;
    } else if (o.image.empty()) o.image = a;
    else {
      std::fprintf(stderr, "alacs_lle: one IMAGE only ('%s' is extra)\n", a.c_str());
      ok = false;
    }
    if (!ok) return 2;
  }
  if (o.image.empty() == o.scan.empty()) {
    std::fprintf(stderr, "alacs_lle: give either IMAGE or --scan DIR\n");
    return 2;
  }
  if (!o.scan.empty() && o.out.empty()) {
    std::fprintf(stderr, "alacs_lle: --scan needs --out DIR\n");
    return 2;
  }
  return 0;
}

image::ImageView viewOf(const cv::Mat& m) {
  return {m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888};
}

// Reads an 8-bit colour image (BGR). Errors name the file.
Result<cv::Mat> readImage(const std::string& path) {
  if (!fs::exists(path)) return Status(Error::kNotFound, "'" + path + "' does not exist");
  cv::Mat m = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (m.empty()) return Status(Error::kBadInput, "'" + path + "' is not an image OpenCV can read");
  if (m.depth() != CV_8U) return Status(Error::kBadInput, "'" + path + "' is not 8 bits per channel");
  if (m.channels() == 1) cv::cvtColor(m, m, cv::COLOR_GRAY2BGR);
  else if (m.channels() == 4) cv::cvtColor(m, m, cv::COLOR_BGRA2BGR);
  else if (m.channels() != 3) return Status(Error::kBadInput, "'" + path + "' has " + std::to_string(m.channels()) + " channels");
  return m;
}

// Runs LLE on one frame and writes its JSON and overlay. Returns false (reason printed)
// when the library refused the input.
bool processFrame(const Options& o, const std::string& name, const cv::Mat& frame, const cv::Mat* off,
                  const image::Roi& roi, const std::string& jsonPath, const std::string& overlayPath,
                  image::LleWorkspace& ws, image::LaserLine& line, std::string* summary) {
  tools::LleRun run;
  run.image = name;
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
    char buf[512];
    std::snprintf(buf, sizeof buf,
                  "{\"frame\": \"%s\", \"json\": \"%s\", \"line_valid\": %s, \"line_rows\": %d, \"coverage\": %.4f, "
                  "\"segments\": %zu}",
                  name.c_str(), fs::path(jsonPath).filename().c_str(), line.valid ? "true" : "false", line.inliers,
                  line.coverage, line.segments.size());
    *summary += buf;
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
  return processFrame(o, o.image, *frame, o.laserOff.empty() ? nullptr : &off, roi, json, overlay, ws, line, nullptr) ? 0
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
  std::string summary = "{\n  \"scan\": \"" + o.scan + "\",\n  \"frames\": [";
  int done = 0, failed = 0;
  auto sep = [&]() { summary += done + failed > 0 ? ",\n    " : "\n    "; };
#ifdef ALACS_LLE_HAVE_REPLAY
  if (fs::exists(fs::path(o.scan) / "manifest.json")) {
    Result<replay::ScanManifest> m = replay::readManifest(o.scan);
    if (!m) {
      std::fprintf(stderr, "alacs_lle: %s\n", m.status().toString().c_str());
      return 1;
    }
    for (const auto& fr : m->frames) {
      if (!fr.laserOn) continue;
      Result<cv::Mat> img = replay::loadFrame(o.scan, *m, fr);
      if (!img) {
        std::fprintf(stderr, "alacs_lle: %s\n", img.status().toString().c_str());
        ++failed;
        continue;
      }
      cv::Mat off;
      bool haveOff = false;
      if (o.subtractOff) {
        for (const auto& g : m->frames) {
          if (g.laserOn || std::abs(g.slideMm - fr.slideMm) > 1e-6) continue;
          Result<cv::Mat> r = replay::loadFrame(o.scan, *m, g);
          if (r) {
            off = *r;
            haveOff = true;
          }
          break;
        }
      }
      const image::Roi roi = o.haveRoi ? o.roi : m->scan.roiPx ? *m->scan.roiPx : image::Roi{0, 0, img->cols, img->rows};
      char stem[32];
      std::snprintf(stem, sizeof stem, "frame_%04d", fr.index);
      const std::string base = (fs::path(o.out) / stem).string();
      std::string entry;
      const bool ok = processFrame(o, fr.file, *img, haveOff ? &off : nullptr, roi, base + ".json", base + ".png", ws,
                                   line, &entry);
      sep();
      summary += ok ? entry : "{\"frame\": \"" + fr.file + "\", \"error\": true}";
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
      std::string entry;
      const bool ok = processFrame(o, path.filename().string(), *img, nullptr, roi, base + ".json", base + ".png", ws,
                                   line, &entry);
      sep();
      summary += ok ? entry : "{\"frame\": \"" + path.filename().string() + "\", \"error\": true}";
      (ok ? done : failed) += 1;
    }
  }
  summary += "\n  ],\n  \"processed\": " + std::to_string(done) + ", \"failed\": " + std::to_string(failed) + "\n}\n";
  std::ofstream(fs::path(o.out) / "summary.json") << summary;
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
  if (argc < 2) {
    usage(stderr);
    return 2;
  }
  if (const int rc = parseArgs(argc, argv, o); rc != 0) return rc;
  if (Status s = o.params.validate(); !s) {
    std::fprintf(stderr, "alacs_lle: %s\n", s.toString().c_str());
    return 1;
  }
  return o.scan.empty() ? runImage(o) : runScan(o);
}
