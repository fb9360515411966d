// alacs-twin: the digital twin's command line (docs/simulation.md, docs/scan-format.md,
// docs/evaluation.md).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "sim/scan_export.h"
#include "tool_common/cli.h"
#include "twin.h"

namespace alacs::twin {

namespace {

double parseNumber(const std::string& s, bool* ok) {
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  *ok = !s.empty() && *end == '\0' && std::isfinite(v);
  return v;
}

// CLI11 checks of the values: numbers, integers (an integral number), comma lists.
const CLI::Validator kNumberCheck(
    [](std::string& s) {
      bool ok = false;
      parseNumber(s, &ok);
      return ok ? std::string() : "needs a number, got '" + s + "'";
    },
    "NUMBER");
const CLI::Validator kIntegerCheck(
    [](std::string& s) {
      bool ok = false;
      const double v = parseNumber(s, &ok);
      return ok && v == std::floor(v) ? std::string() : "needs an integer, got '" + s + "'";
    },
    "INT");
const CLI::Validator kListCheck(
    [](std::string& s) {
      std::stringstream ss(s);
      bool ok = !s.empty();
      for (std::string part; ok && std::getline(ss, part, ',');) parseNumber(part, &ok);
      return ok ? std::string() : "needs numbers separated by commas, got '" + s + "'";
    },
    "N,N,...");

enum class Kind { kText, kNumber, kInteger, kList, kFlag };

struct OptionSpec {
  const char* name;  // without "--"
  Kind kind;
  const char* help;
};

// One subcommand: its options declared to CLI11, and after the parse the given ones copied
// into the Args its function reads (flags as "1").
struct Subcommand {
  CLI::App* app = nullptr;
  struct Declared {
    std::string name;
    CLI::Option* option;
    bool flag;  // given: "1" (CLI11's own text for a flag varies with its version: "true")
  };
  std::vector<Declared> options;
  std::vector<std::string> positional;
  int (*run)(const Args&) = nullptr;

  Args args() const {
    Args a;
    for (const auto& [name, opt, flag] : options)
      if (opt->count() > 0) a.set(name, flag ? std::string("1") : opt->as<std::string>());
    for (const auto& p : positional) a.addPositional(p);
    return a;
  }
};

Subcommand declare(CLI::App& app, const char* name, const char* help, int (*run)(const Args&),
                   std::initializer_list<OptionSpec> specs) {
  Subcommand sub;
  sub.app = app.add_subcommand(name, help);
  sub.run = run;
  for (const OptionSpec& spec : specs) {
    const std::string flag = std::string("--") + spec.name;
    CLI::Option* opt = nullptr;
    if (spec.kind == Kind::kFlag) {
      opt = sub.app->add_flag(flag, spec.help);
    } else {
      opt = sub.app->add_option(flag, spec.help)->type_size(1)->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
      if (spec.kind == Kind::kNumber) opt->check(kNumberCheck);
      if (spec.kind == Kind::kInteger) opt->check(kIntegerCheck);
      if (spec.kind == Kind::kList) opt->check(kListCheck);
    }
    sub.options.push_back({spec.name, opt, spec.kind == Kind::kFlag});
  }
  return sub;
}

}  // namespace

void Args::set(const std::string& k, const std::string& v) { values_[k] = v; }

void Args::addPositional(const std::string& v) { positional_.push_back(v); }

std::string Args::str(const std::string& k, const std::string& fallback) const {
  used_[k] = true;
  auto it = values_.find(k);
  return it == values_.end() ? fallback : it->second;
}

double Args::num(const std::string& k, double fallback) const {
  used_[k] = true;
  auto it = values_.find(k);
  return it == values_.end() ? fallback : std::strtod(it->second.c_str(), nullptr);
}

int64_t Args::integer(const std::string& k, int64_t fallback) const {
  return static_cast<int64_t>(num(k, static_cast<double>(fallback)));
}

std::vector<double> Args::list(const std::string& k, const std::vector<double>& fallback) const {
  used_[k] = true;
  auto it = values_.find(k);
  if (it == values_.end()) return fallback;
  std::vector<double> out;
  std::stringstream ss(it->second);
  for (std::string part; std::getline(ss, part, ',');) out.push_back(std::strtod(part.c_str(), nullptr));
  return out;
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

Result<MeteringArgs> meteringArgs(const Args& args) {
  MeteringArgs m;
  m.params.enabled = args.integer("metering", 1) != 0;
  m.params.targetDn = static_cast<int>(args.integer("meter-target-dn", m.params.targetDn));
  m.params.subtractAboveDn = static_cast<int>(args.integer("meter-subtract-above-dn", m.params.subtractAboveDn));
  m.params.brightAnalogueGain = args.num("meter-bright-gain", m.params.brightAnalogueGain);
  m.params.secondExposureFactor = args.num("meter-second-exposure", m.params.secondExposureFactor);
  m.maxExposureUs = args.integer("max-exposure-us", m.maxExposureUs);
  if (Status s = m.params.validate(); !s) return s;
  if (m.maxExposureUs < 1) return Status(Error::kInvalidArgument, "--max-exposure-us must be positive");
  return m;
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

tools::Json jsonVec(const Eigen::Vector3d& v) {
  return {tools::jsonNumber(v.x()), tools::jsonNumber(v.y()), tools::jsonNumber(v.z())};
}

// `frames` frames of one request, each with its own noise (seeds frameIndex onwards) and
// the first one's speckle, averaged and rounded to 8 bits (one frame: as rendered); the
// region `roi` (x, y, w, h) only, when given.
cv::Mat renderAveraged(const sim::SimScene& scene, sim::FrameRequest req, const std::vector<double>& roi,
                       int64_t frames) {
  if (frames > 1) req.speckleFrameIndex = static_cast<int64_t>(req.frameIndex);
  sim::Renderer r(scene);
  cv::Mat img;
  cv::Mat sum;
  for (int64_t i = 0; i < frames; ++i) {
    if (roi.empty()) {
      r.render(req, img);
    } else {
      const auto at = [&](size_t k) { return static_cast<int>(roi[k]); };
      r.renderRegion(req, cv::Rect(at(0), at(1), at(2), at(3)), img);
    }
    if (frames == 1) return img;
    if (sum.empty()) sum = cv::Mat::zeros(img.size(), CV_32SC3);
    cv::add(sum, img, sum, cv::noArray(), CV_32SC3);
    ++req.frameIndex;
  }
  sum.convertTo(img, CV_8UC3, 1.0 / static_cast<double>(frames));  // rounds to nearest
  return img;
}

int renderMain(const Args& args) {
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
  if (!roi.empty() && roi.size() != 4) {
    std::fprintf(stderr, "alacs-twin render: --roi wants x,y,w,h\n");
    return 2;
  }
  // --gain-db: the sensor's analogue gain instead of the scene's (the caller scales the
  // exposure to keep the same DN). --average: several frames of the same exposure, each
  // with its own noise (seeds frame, frame + 1, ...) and the first one's speckle (a laser at
  // rest on a still scene keeps its speckle), averaged and rounded to 8 bits, as a stop's
  // frames stacked would be (tools/eval diagnose --stack).
  if (args.has("gain-db")) {
    scene.sensor.gainDb = args.num("gain-db", scene.sensor.gainDb);
    if (Status s = scene.validate(); !s) {
      std::fprintf(stderr, "alacs-twin render: --gain-db: %s\n", s.toString().c_str());
      return 2;
    }
  }
  const int64_t average = args.integer("average", 1);
  if (average < 1 || average > 64) {
    std::fprintf(stderr, "alacs-twin render: --average wants 1..64 frames\n");
    return 2;
  }
  const cv::Mat img = renderAveraged(scene, req, roi, average);
  if (!cv::imwrite(out, img)) {
    std::fprintf(stderr, "alacs-twin: cannot write '%s'\n", out.c_str());
    return 1;
  }
  // The exact laser line at the exposure's middle, as a scan's truth file (sim::exportScan):
  // which slide positions would light a hidden fruit, for diagnosis.
  const std::string truthPath = args.str("truth");
  if (!truthPath.empty()) {
    if (Status s = sim::writeTruthCsv(scene, 0.5 * (req.slideStartMm + req.slideEndMm), truthPath); !s) {
      std::fprintf(stderr, "alacs-twin: %s\n", s.toString().c_str());
      return 1;
    }
  }
  return 0;
}

}  // namespace alacs::twin

int main(int argc, char** argv) {
  using namespace alacs::twin;
  CLI::App app("The digital twin's command line (docs/simulation.md, docs/scan-format.md, docs/evaluation.md).",
               "alacs-twin");
  app.require_subcommand(1);
  Subcommand subs[] = {
      declare(
          app, "generate", "benchmark scan directories DIR/case_NNNN (one JSON line per case on stdout)", generateMain,
          {{"set", Kind::kText, "lle|loc (required)"},
           {"out", Kind::kText, "DIR (required)"},
           {"count", Kind::kInteger, "cases (default lle 320, loc 120)"},
           {"seed", Kind::kInteger, "random seed (default 1)"},
           {"distance-mm", Kind::kList, "Z[,Z..] (default lle 800..1600, loc 1000..1600)"},
           {"occluded", Kind::kText, "0|1|both|mix (default lle mix, loc both)"},
           {"lighting", Kind::kText, "lab|overcast|direct|sun|outdoor|all (default lle outdoor, loc lab; holdout all)"},
           {"world", Kind::kText, "benchmark|benchmark-hard|holdout (default benchmark; docs/evaluation.md)"},
           {"bayer", Kind::kInteger, "0|1 (default 1)"},
           {"jobs", Kind::kInteger, "threads (default 2)"},
           {"motion-mm-s", Kind::kNumber, "slide speed during the exposure (default 0)"},
           {"bandpass-nm", Kind::kNumber, "FWHM of a 635 nm band-pass filter; 0 none (default), else 5..80"},
           {"metering", Kind::kInteger,
            "1: laser-off frames meter the laser frames' exposure, as alacsd (default); 0: off"},
           {"meter-target-dn", Kind::kInteger, "metering.target_dn (default: the daemon's)"},
           {"meter-subtract-above-dn", Kind::kInteger, "metering.subtract_above_dn (default: the daemon's)"},
           {"meter-bright-gain", Kind::kNumber,
            "metering.bright_analogue_gain (default: the daemon's; 0: never changed)"},
           {"meter-second-exposure", Kind::kNumber,
            "metering.second_exposure_factor (default: the daemon's; 0: one exposure per stop)"},
           {"max-exposure-us", Kind::kInteger, "the longest exposure metering may choose: camera.exposure_us (3000)"},
           {"follow-up-unseen-max-stops", Kind::kInteger,
            "ScanParams::followUpUnseenMaxStops for the second pass rendered (default ScanParams')"},
           {"follow-up-far-sigmas", Kind::kNumber, "ScanParams::followUpFarSigmas for the second pass rendered"},
           {"resume", Kind::kFlag, "keep the cases already written"},
           {"only", Kind::kText,
            "NAME[,NAME..]: generate these cases only (the others untouched; to render again the scans a "
            "change moves)"}}),
      declare(app, "calib", "calibration scans: DIR/checkerboard_NN (laser off), DIR/laser_plane_NNNN", calibrationMain,
              {{"out", Kind::kText, "DIR (required)"},
               {"seed", Kind::kInteger, "random seed (default 7)"},
               {"views", Kind::kInteger, "checkerboard views (default 24)"},
               {"world", Kind::kText, "benchmark|tuning|holdout: board, blur, noise, tilt (docs/calibration.md)"},
               {"board", Kind::kText, "SXxSYxMM: squares and square size (default: the world's)"},
               {"margin-mm", Kind::kNumber, "the board's plain margin (default: the world's)"},
               {"tilt-deg", Kind::kNumber, "the views' largest tilt about x and y (default: the world's, 35 or 40)"},
               {"jobs", Kind::kInteger, "threads (default 2)"},
               {"positions", Kind::kList, "slide positions, mm (default 0,25,...,200)"}}),
      declare(app, "process", "runs the pipeline (replay source + localizer) on scan directories; one JSON line each",
              processMain,
              {{"calibration", Kind::kText, "FILE instead of each scan's calibration"},
               {"brce-step", Kind::kInteger, "bRCE step (default LleParams')"},
               {"brce-threshold", Kind::kInteger, "bRCE threshold (default LleParams')"},
               {"lle-smooth-rows", Kind::kInteger, "LleParams::smoothRows (default LleParams')"},
               {"lle-edge-ratio", Kind::kInteger, "LleParams::edgeRatio (default LleParams')"},
               {"lle-weak-line-pct", Kind::kInteger, "LleParams::weakLineThresholdPct (default LleParams')"},
               {"lle-subtracted-line-pct", Kind::kInteger, "LleParams::subtractedLineThresholdPct"},
               {"lle-short-line-pct", Kind::kInteger,
                "LleParams::shortLinePct: a line shorter than this share of the ROI is run again (0: off)"},
               {"lle-subtracted-rows", Kind::kInteger, "LleParams::subtractedRows: 1 (the row alone) or 3"},
               {"lle-rerun-others-firm", Kind::kInteger,
                "LleParams::rerunOthersFirm: 1, a rerun's other segments need the first pass's bar"},
               {"lle-matched-filter", Kind::kInteger,
                "LleParams::matchedFilter: 0, no matched filter for the rows LLE leaves in direct sun (process only)"},
               {"rows", Kind::kFlag, "every frame's rows, kept pixels, sunlit arcs' samples and curve"},
               {"other-object-prior", Kind::kNumber,
                "ScanParams::otherObjectPrior (0: σ and confidence from the fit alone)"},
               {"shape-irregularity-pct", Kind::kNumber,
                "ScanParams::shapeIrregularityPct: the fruit's departure from a spheroid in σ (0: none)"},
               {"fit-when-far-from-rough", Kind::kFlag,
                "ScanParams::roughWhenFarFromRough off: a fit more likely another object goes out (AMBIGUOUS)"},
               {"follow-up-unseen-max-stops", Kind::kInteger,
                "ScanParams::followUpUnseenMaxStops (the scans hold the stops their generation asked for)"},
               {"follow-up-far-sigmas", Kind::kNumber, "ScanParams::followUpFarSigmas (as generate's)"},
               {"weak-arc-min-z", Kind::kNumber, "ScanParams::weakArcMinZ: the sunlit arc search's bar (0: off)"},
               {"leaf-green-ratio", Kind::kNumber,
                "ScanParams::leafGreenRatio: samples this much greener than red in the laser-off frame join no fit (0: "
                "off)"},
               {"metering", Kind::kInteger, "1: meter on the scan's laser-off frames and subtract as alacsd (default)"},
               {"meter-target-dn", Kind::kInteger, "metering.target_dn (default: the daemon's)"},
               {"meter-subtract-above-dn", Kind::kInteger, "metering.subtract_above_dn (default: the daemon's)"},
               {"meter-bright-gain", Kind::kNumber,
                "metering.bright_analogue_gain (default: the daemon's; 0: never changed)"},
               {"meter-second-exposure", Kind::kNumber,
                "metering.second_exposure_factor (default: the daemon's; 0: one exposure per stop)"},
               {"max-exposure-us", Kind::kInteger, "the longest exposure metering may choose (3000, as generate)"},
               {"jobs", Kind::kInteger, "threads (default 2)"}}),
      declare(app, "examples", "example frames of the conditions, for docs/simulation.md", examplesMain,
              {{"out", Kind::kText, "DIR (required)"}}),
      declare(app, "render", "one frame of a scene (default: the built-in scene)", renderMain,
              {{"scene", Kind::kText, "scene FILE (default: the built-in scene)"},
               {"slide", Kind::kNumber, "slide position at the exposure's start, mm (default 100)"},
               {"slide-end", Kind::kNumber, "... at its end (default: --slide)"},
               {"exposure-us", Kind::kInteger, "exposure, us (default: the scene's)"},
               {"laser", Kind::kNumber, "laser on-fraction of the exposure, 0..1 (default 1)"},
               {"roi", Kind::kList, "x,y,w,h: render this region only"},
               {"frame", Kind::kInteger, "frame index (noise seed; default 0)"},
               {"average", Kind::kInteger,
                "N frames (noise seeds frame .. frame+N-1, the first one's speckle) averaged and rounded to 8 bits: a "
                "stop's frames stacked (1..64, default 1)"},
               {"gain-db", Kind::kNumber, "the sensor's analogue gain instead of the scene's, dB (0..48)"},
               {"out", Kind::kText, "PNG (required)"},
               {"truth", Kind::kText,
                "CSV: also the truth rows (at the exposure's middle), as a scan's truth/frame_NNNN.csv"}}),
      declare(app, "reach",
              "the slide positions that light each scan's target on enough visible rows (the truth), and how surely "
              "its rough position names the target among the scene's fruit (one JSON line each)",
              reachMain,
              {{"stroke-mm", Kind::kNumber, "the slide's stroke (default 200)"},
               {"step-mm", Kind::kNumber, "between the positions tried (default 1)"},
               {"min-rows", Kind::kInteger,
                "visible, laser-lit rows a position must light (default 8, as a line in the fit)"},
               {"slides", Kind::kList, "these slide positions, mm, instead of the stroke at the step"},
               {"list", Kind::kFlag, "also each such position and its rows"},
               {"jobs", Kind::kInteger, "threads (default 2)"}}),
  };
  subs[0].app->get_option("--set")->required()->check(CLI::IsMember({"lle", "loc"}));
  subs[0].app->get_option("--out")->required();
  subs[0].app->get_option("--occluded")->check(CLI::IsMember({"0", "1", "both", "mix"}));
  subs[1].app->get_option("--out")->required();
  subs[2].app->add_option("DIR", subs[2].positional, "scan directories")->required();
  subs[3].app->get_option("--out")->required();
  subs[4].app->get_option("--out")->required();
  subs[5].app->add_option("DIR", subs[5].positional, "scan directories")->required();
  if (const int rc = alacs::tools::parseCommandLine(app, argc, argv); rc >= 0) return rc;
  for (const Subcommand& sub : subs)
    if (sub.app->parsed()) return sub.run(sub.args());
  return alacs::tools::kUsageExit;  // require_subcommand(1): not reached
}
