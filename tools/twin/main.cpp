// alacs-twin: the digital twin's command line (docs/simulation.md, docs/scan-format.md,
// docs/evaluation.md).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "twin.h"

namespace alacs::twin {

namespace {

void usage(FILE* out) {
  std::fprintf(out,
               "usage: alacs-twin COMMAND [options]\n"
               "  generate --set lle|loc --out DIR [--count N] [--seed S] [--distance-mm Z[,Z..]]\n"
               "           [--occluded 0|1|mix] [--lighting lab|overcast|direct|sun|outdoor] [--bayer 0|1]\n"
               "           [--jobs N] [--motion-mm-s V] [--bandpass-nm FWHM (a 635 nm band-pass filter; 0 none)]\n"
               "      benchmark scan directories DIR/case_NNNN (one JSON line per case on stdout)\n"
               "  calib --out DIR [--seed S] [--views N] [--jobs N]\n"
               "      calibration scans: DIR/checkerboard_NN (laser off), DIR/laser_plane_NNNN\n"
               "  process [--calibration FILE] [--brce-step N] [--brce-threshold N] [--rows] [--jobs N] DIR...\n"
               "      runs the pipeline (replay source + localizer) on scan directories; one JSON line each\n"
               "  examples --out DIR\n"
               "      example frames of the conditions, for docs/simulation.md\n"
               "  render [--scene FILE] [--slide MM] [--slide-end MM] [--exposure-us US] [--laser 0|1]\n"
               "         [--roi x,y,w,h] [--frame N] --out PNG\n"
               "      one frame of a scene (default: the built-in scene)\n");
}

}  // namespace

Args::Args(int argc, char** argv, int first) {
  for (int i = first; i < argc; ++i) {
    const std::string a = argv[i];
    if (a.rfind("--", 0) == 0) {
      const std::string key = a.substr(2);
      // Constructed, not assigned from a char*: GCC 12 -O3 warns (-Wrestrict) on the latter.
      const bool hasValue = i + 1 < argc && std::strncmp(argv[i + 1], "--", 2) != 0;
      values_[key] = hasValue ? std::string(argv[++i]) : std::string("1");
    } else {
      positional_.push_back(a);
    }
  }
}

std::string Args::str(const std::string& k, const std::string& fallback) const {
  used_[k] = true;
  auto it = values_.find(k);
  return it == values_.end() ? fallback : it->second;
}

double Args::num(const std::string& k, double fallback) const {
  used_[k] = true;
  auto it = values_.find(k);
  if (it == values_.end()) return fallback;
  char* end = nullptr;
  const double v = std::strtod(it->second.c_str(), &end);
  if (*end != '\0' || !std::isfinite(v)) {
    std::fprintf(stderr, "alacs-twin: --%s needs a number, got '%s'\n", k.c_str(), it->second.c_str());
    std::exit(2);
  }
  return v;
}

int64_t Args::integer(const std::string& k, int64_t fallback) const {
  const double v = num(k, static_cast<double>(fallback));
  if (v != std::floor(v)) {
    std::fprintf(stderr, "alacs-twin: --%s needs an integer\n", k.c_str());
    std::exit(2);
  }
  return static_cast<int64_t>(v);
}

std::vector<double> Args::list(const std::string& k, const std::vector<double>& fallback) const {
  used_[k] = true;
  auto it = values_.find(k);
  if (it == values_.end()) return fallback;
  std::vector<double> out;
  std::stringstream ss(it->second);
  std::string part;
  while (std::getline(ss, part, ',')) {
    char* end = nullptr;
    const double v = std::strtod(part.c_str(), &end);
    if (*end != '\0' || part.empty()) {
      std::fprintf(stderr, "alacs-twin: --%s needs numbers separated by commas\n", k.c_str());
      std::exit(2);
    }
    out.push_back(v);
  }
  return out;
}

Status Args::allow(const std::vector<std::string>& known) const {
  for (const auto& [k, v] : values_) {
    bool ok = false;
    for (const auto& n : known) ok = ok || n == k;
    if (!ok) return {Error::kInvalidArgument, "unknown option --" + k};
  }
  return Status::ok();
}

Status parallelFor(int n, int jobs, const std::function<Status(int)>& work, const std::function<void(int)>& done) {
  std::atomic<int> next{0};
  std::mutex mu;
  Status first = Status::ok();
  auto worker = [&] {
    while (true) {
      const int i = next.fetch_add(1);
      if (i >= n) return;
      Status s = work(i);
      std::lock_guard<std::mutex> lock(mu);
      if (!s && first.isOk()) first = s;
      if (s) done(i);
    }
  };
  std::vector<std::thread> threads;
  for (int j = 1; j < std::max(1, jobs); ++j) threads.emplace_back(worker);
  worker();
  for (auto& t : threads) t.join();
  return first;
}

Result<RenderPlan> renderPlan(const geometry::Calibration& cal, const Eigen::Vector3d& roughMm, int stops) {
  localize::ScanParams sp = localize::ScanParams::paperScan();  // the benchmark's scans are the paper's
  sp.stops = stops;
  const localize::Localizer loc(cal, image::LleParams{}, sp);
  Result<localize::ScanPlan> plan = loc.plan(roughMm, 200.0);
  if (!plan) return plan.status();
  localize::ScanParams wide = sp;
  wide.roiMarginMm += 10.0;
  Result<localize::ScanPlan> widePlan = localize::Localizer(cal, image::LleParams{}, wide).plan(roughMm, 200.0);
  if (!widePlan) return widePlan.status();
  const image::Roi& r = widePlan->roi;
  const cv::Rect frame(0, 0, cal.camera.widthPx, cal.camera.heightPx);
  RenderPlan out;
  out.plan = *plan;
  out.region = cv::Rect(r.x - 8, r.y - 8, r.width + 16, r.height + 16) & frame;
  return out;
}

std::string jsonNum(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.6f", v);
  return buf;
}

std::string jsonVec(const Eigen::Vector3d& v) {
  std::string s = "[";  // appended, not concatenated: GCC 12 -O3 warns (-Wrestrict) on "x" + string
  s += jsonNum(v.x());
  s += ", ";
  s += jsonNum(v.y());
  s += ", ";
  s += jsonNum(v.z());
  s += "]";
  return s;
}

int renderMain(const Args& args) {
  if (Status s = args.allow({"scene", "slide", "slide-end", "exposure-us", "laser", "frame", "roi", "out"}); !s) {
    std::fprintf(stderr, "alacs-twin render: %s\n", s.reason().c_str());
    return 2;
  }
  sim::SimScene scene = sim::defaultScene();
  const std::string scenePath = args.str("scene");
  if (!scenePath.empty()) {
    Result<sim::SimScene> s = sim::loadScene(scenePath);
    if (!s) {
      std::fprintf(stderr, "alacs-twin: %s\n", s.status().toString().c_str());
      return 1;
    }
    scene = *s;
  }
  sim::FrameRequest req;
  req.slideStartMm = args.num("slide", 100.0);
  req.slideEndMm = args.num("slide-end", req.slideStartMm);
  req.exposureUs = args.integer("exposure-us", 0);
  req.laserFraction = args.num("laser", 1.0);
  req.frameIndex = static_cast<uint64_t>(args.integer("frame", 0));
  const std::string out = args.str("out");
  const std::vector<double> roi = args.list("roi", {});
  if (out.empty() || (!roi.empty() && roi.size() != 4)) {
    usage(stderr);
    return 2;
  }
  sim::Renderer r(scene);
  cv::Mat img;
  if (roi.empty()) {
    r.render(req, img);
  } else {
    r.renderRegion(req, cv::Rect(static_cast<int>(roi[0]), static_cast<int>(roi[1]), static_cast<int>(roi[2]), static_cast<int>(roi[3])), img);
  }
  if (!cv::imwrite(out, img)) {
    std::fprintf(stderr, "alacs-twin: cannot write '%s'\n", out.c_str());
    return 1;
  }
  return 0;
}

}  // namespace alacs::twin

int main(int argc, char** argv) {
  using namespace alacs::twin;
  if (argc < 2 || std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0) {
    usage(argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  const std::string cmd = argv[1];
  const Args args(argc, argv, 2);
  int rc = 2;
  if (cmd == "generate") rc = generateMain(args);
  else if (cmd == "calib") rc = calibrationMain(args);
  else if (cmd == "process") rc = processMain(args);
  else if (cmd == "examples") rc = examplesMain(args);
  else if (cmd == "render") rc = renderMain(args);
  else {
    std::fprintf(stderr, "alacs-twin: unknown command '%s'\n", cmd.c_str());
    usage(stderr);
    return 2;
  }
  return rc;
}
