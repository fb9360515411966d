// alacs-twin generate: benchmark scan directories.
//   --set loc: per (distance, occlusion) cell, `count` five-stop scans planned from the
//              RGB-D camera's rough position, as the paper's localization experiments.
//   --set lle: `count` single frames with the laser somewhere on the target, over
//              distances and the paper's outdoor light, as its LLE evaluation.
//   --world benchmark|benchmark-hard|holdout: the world tuned on, its hard cases (also
//              tuned on), or the second world that no parameter choice may look at
//              (sim/orchard.h, docs/evaluation.md).
//   --metering 0|1 (1), --meter-target-dn, --meter-subtract-above-dn: the daemon's exposure
//              metering from laser-off frames (localize/exposure.h), which every scan
//              follows: laser-off frames first, then the laser frames at the chosen exposure.
//   The localize scans take the daemon's adaptive second pass (Localizer::followUpStops,
//              its default parameters; --follow-up-unseen-max-stops to compare one): the first pass is observed as
//              `process` will, and the frames of the second pass it asks for are rendered too (tag "follow_up").
//   --only NAME[,NAME..]: those cases alone, the others untouched (to render again only the
//              scans whose second pass a change moves).
#include <sys/stat.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <optional>
#include <sstream>

#include "localize/exposure.h"
#include "localize/localizer.h"
#include "sim/orchard.h"
#include "sim/renderer.h"
#include "sim/scan_export.h"
#include "twin.h"

namespace alacs::twin {

namespace {

uint64_t mixSeed(uint64_t a, uint64_t b) {
  uint64_t z = a * 0x9E3779B97F4A7C15ULL + b + 0x632BE59BD9B4E019ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

struct CaseJob {
  std::string name;
  sim::CaseSpec spec;
  uint64_t seed = 0;
  bool single = false;  // one frame (LLE set) instead of the planned stops
};

bool exists(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0;
}

// Noise seeds of the laser-off frames, apart from the stops' (0, 1, ...), so that a scene
// whose exposure metering leaves as it was renders its stops exactly as before.
constexpr uint64_t kLaserOffFrameIndex = 1000;
// The noise seeds of the stops' second exposures: apart from the first's, so that a scan
// with them has the same first frames as one without.
constexpr uint64_t kSecondExposureFrameIndex = 2000;
constexpr double kFrameIntervalS = 0.05;

struct Metered {
  std::vector<sim::ExportFrame> laserOff;  // in the order taken, before the stops
  std::vector<cv::Mat> rendered;           // theirs
  std::vector<uint64_t> frameIndices;      // their noise seeds
  localize::MeteringDecision decision;
  cv::Mat subtract;  // the render region of the frame to subtract (empty: none)
  // ... and of the one at the stops' second exposure (decision.secondExposureUs; empty: none)
  cv::Mat secondSubtract;
};

// The daemon's acquisition (app/scan_worker.cpp, meterExposure): laser-off frames of the
// ROI from the scene's (fixed) exposure on, metered by the same ExposureMeter, which may
// choose up to `maxExposureUs` (the daemon's configured exposure); then,
// when it asks for subtraction and no metering frame was taken at the exposure it chose,
// one more laser-off frame at that exposure. Rendered here (the meter needs their pixels)
// and written as rendered.
Metered meterScene(const sim::SimScene& scene, const std::shared_ptr<const sim::RayTable>& rays, const cv::Rect& region,
                   const image::Roi& roi, double slideMm, const localize::MeteringParams& params,
                   int64_t maxExposureUs) {
  Metered out;
  sim::Renderer renderer(scene, rays);
  // The meter reads the render region as a frame of its own: the ROI moves with it.
  const image::Roi local{roi.x - region.x, roi.y - region.y, roi.width, roi.height};
  const auto render = [&](int64_t exposureUs, double analogueGain, const char* tag) {
    sim::ExportFrame f;
    f.slideStartMm = f.slideEndMm = slideMm;
    f.laserOn = false;
    f.exposureUs = exposureUs;
    f.analogueGain = analogueGain > 0.0 ? analogueGain : scene.sensor.analogueGain();
    f.timestampS = kFrameIntervalS * static_cast<double>(out.laserOff.size());
    f.tag = tag;
    sim::FrameRequest req;
    req.slideStartMm = req.slideEndMm = slideMm;
    req.laserFraction = 0.0;
    req.exposureUs = exposureUs;
    req.analogueGain = f.analogueGain;
    req.frameIndex = kLaserOffFrameIndex + out.laserOff.size();
    out.laserOff.push_back(f);
    out.frameIndices.push_back(req.frameIndex);
    out.rendered.emplace_back();
    renderer.renderRegion(req, region, out.rendered.back());
    const cv::Mat& m = out.rendered.back();
    return image::ImageView{m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888};
  };
  const localize::MeteringRun run = localize::runMetering(
      params, scene.sensor.exposureUs, maxExposureUs, local,
      [&](int64_t us, double gain, localize::LaserOffUse use) -> Result<localize::LaserOffFrame> {
        const image::ImageView v = render(us, gain, use == localize::LaserOffUse::kMetering ? "meter" : "ambient");
        return localize::LaserOffFrame{v, us, out.laserOff.back().analogueGain};
      });
  out.decision = run.decision;  // (a render cannot fail, nor can add(): the ROI is inside the region)
  if (run.hasLaserOff) out.subtract = out.rendered.back();  // the last frame taken (MeteringRun)
  // The second exposure's laser-off frame, as the scan worker takes it after metering.
  if (run.hasLaserOff && out.decision.secondExposureUs > 0) {
    render(out.decision.secondExposureUs, out.decision.analogueGain, "ambient");
    out.secondSubtract = out.rendered.back();
  }
  return out;
}

// A laser frame a pass takes, appended by the caller to the scan's frames: its manifest
// entry and noise seed.
struct FrameTaken {
  sim::ExportFrame frame;
  uint64_t frameIndex = 0;
};

image::ImageView viewOf(const cv::Mat& m) { return {m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888}; }

// The daemon's two passes (twoPassScan, the localizer's defaults) on the scene, so that the
// scan holds the second pass's frames where the localizer asks for them: each laser frame
// the passes take is rendered (the render region) and observed as `process` will read it
// back (a frame zero outside the region, the laser-off frame subtracted when metering kept
// one; a stop's second exposure, when `take` gives one, merged as the scan worker merges
// it). Returns the renders in the order taken, for exportScan.
std::vector<cv::Mat> scanTwoPasses(const sim::SimScene& scene, const std::shared_ptr<const sim::RayTable>& rays,
                                   const RenderPlan& rp, const Metered& metered, const localize::ScanParams& scan,
                                   const std::function<std::vector<FrameTaken>(double slideMm, int pass)>& take) {
  std::vector<cv::Mat> renders;
  const localize::Localizer loc(scene.truth, image::LleParams{}, scan);
  Result<localize::ScanPlan> plan = loc.plan(rp.plan.roughMm, 200.0);
  if (!plan) {
    // (The paper's plan was made; the default one differs only in its stops.)
    plan = rp.plan;
  }
  plan->stopsMm = rp.plan.stopsMm;
  sim::Renderer renderer(scene, rays);
  const cv::Mat blank(scene.truth.camera.heightPx, scene.truth.camera.widthPx, CV_8UC3, cv::Scalar::all(0));
  cv::Mat full = blank.clone();
  // The laser-off frames as `process` reads them back: zero outside the render region.
  const auto fullFrame = [&](const cv::Mat& region) {
    cv::Mat m;
    if (region.empty()) return m;
    m = blank.clone();
    region.copyTo(m(rp.region));
    return m;
  };
  const cv::Mat off = fullFrame(metered.subtract);
  const cv::Mat secondOff = fullFrame(metered.secondSubtract);
  const image::ImageView offView = viewOf(off);
  const image::ImageView secondOffView = viewOf(secondOff);
  const bool bright = metered.decision.bright;
  image::LleWorkspace ws;
  twoPassScan(loc, *plan, 200.0, true, [&](double slideMm, int pass) -> Result<localize::LineObservation> {
    const std::vector<FrameTaken> frames = take(slideMm, pass);
    std::optional<Result<localize::LineObservation>> first;
    for (const FrameTaken& f : frames) {
      sim::FrameRequest req;
      req.slideStartMm = f.frame.slideStartMm;
      req.slideEndMm = f.frame.slideEndMm;
      req.laserFraction = 1.0;
      req.exposureUs = f.frame.exposureUs > 0 ? f.frame.exposureUs : scene.sensor.exposureUs;
      req.analogueGain = f.frame.analogueGain;
      req.frameIndex = f.frameIndex;
      renders.emplace_back();
      renderer.renderRegion(req, rp.region, renders.back());
      renders.back().copyTo(full(rp.region));
      const double recordedMm = 0.5 * (f.frame.slideStartMm + f.frame.slideEndMm);
      if (!first) {
        first = loc.observe(viewOf(full), *plan, recordedMm, ws, off.empty() ? nullptr : &offView, 0.0, bright);
      } else if (first->isOk() && !secondOff.empty()) {
        Result<localize::LineObservation> second =
            loc.observe(viewOf(full), *plan, recordedMm, ws, &secondOffView, 0.0, bright);
        if (second) localize::Localizer::mergeSecondExposure(first->value(), *second);
      }
    }
    return std::move(*first);
  });
  return renders;
}

// One line of a set's index: the case it records ("case"; empty when none), the case's
// seed ("seed"; 0 when none) and the line as written.
struct IndexLine {
  std::string name;
  uint64_t seed = 0;
  std::string text;
};

std::vector<IndexLine> indexLines(const std::string& path) {
  std::vector<IndexLine> out;
  std::ifstream in(path);
  for (std::string line; std::getline(in, line);) {
    const tools::Json j = tools::Json::parse(line, nullptr, false);
    IndexLine l;
    if (j.is_object() && j.contains("case") && j["case"].is_string()) l.name = j["case"].get<std::string>();
    if (j.is_object() && j.contains("seed") && j["seed"].is_number_unsigned()) l.seed = j["seed"].get<uint64_t>();
    l.text = line + "\n";
    out.push_back(std::move(l));
  }
  return out;
}

// --only: the named cases of `cases`, each once. A case the set's index already records
// under another seed (the set was generated with other --seed, --world or distances) is
// refused: its new scan would not be the set's. With --resume a named case already written
// would be kept, so the two do not go together.
Result<std::vector<CaseJob>> pickCases(const std::vector<CaseJob>& cases, const std::string& only,
                                       const std::string& indexPath, bool resume) {
  if (resume) return Status(Error::kInvalidArgument, "does not go with --resume (it would keep the named cases)");
  const auto stored = indexLines(indexPath);
  std::vector<CaseJob> picked;
  std::stringstream names(only);
  for (std::string name; std::getline(names, name, ',');) {
    const auto it = std::find_if(cases.begin(), cases.end(), [&](const CaseJob& j) { return j.name == name; });
    if (it == cases.end()) return Status(Error::kInvalidArgument, "no case '" + name + "' in this set");
    if (std::any_of(picked.begin(), picked.end(), [&](const CaseJob& j) { return j.name == name; }))
      return Status(Error::kInvalidArgument, "case " + name + " named twice");
    for (const IndexLine& l : stored)
      if (l.name == name && l.seed != 0 && l.seed != it->seed)
        return Status(Error::kInvalidArgument, "case " + name + " in " + indexPath +
                                                   " has another seed: generate it with the set's own --seed, "
                                                   "--world, --distance-mm and --occluded");
    picked.push_back(*it);
  }
  if (picked.empty()) return Status(Error::kInvalidArgument, "no case named");
  return picked;
}

// The lines of the index at `path` (if any) with those of `cases` replaced by `fresh` (one
// per case, same order), and the cases it did not hold appended.
std::vector<std::string> mergedIndex(const std::string& path, const std::vector<CaseJob>& cases,
                                     std::vector<std::string> fresh) {
  std::vector<std::string> merged;
  std::vector<bool> placed(cases.size(), false);
  for (const IndexLine& l : indexLines(path)) {
    const auto it = std::find_if(cases.begin(), cases.end(), [&](const CaseJob& c) { return c.name == l.name; });
    if (it == cases.end()) {
      if (!l.name.empty()) merged.push_back(l.text);
      continue;
    }
    const size_t k = static_cast<size_t>(it - cases.begin());
    merged.push_back(fresh[k]);
    placed[k] = true;
  }
  for (size_t k = 0; k < cases.size(); ++k)
    if (!placed[k]) merged.push_back(fresh[k]);
  return merged;
}

}  // namespace

int generateMain(const Args& args) {
  const std::string set = args.str("set");
  const std::string out = args.str("out");
  if ((set != "loc" && set != "lle") || out.empty()) {
    std::fprintf(stderr, "alacs-twin generate: needs --set loc|lle and --out DIR\n");
    return 2;
  }
  const bool lle = set == "lle";
  const int count = static_cast<int>(args.integer("count", lle ? 320 : 120));
  const uint64_t seed = static_cast<uint64_t>(args.integer("seed", 1));
  const std::vector<double> distances =
      args.list("distance-mm", lle ? std::vector<double>{800, 1000, 1200, 1400, 1600} : std::vector<double>{1000, 1200, 1400, 1600});
  const std::string occ = args.str("occluded", lle ? "mix" : "both");
  Result<sim::World> world = sim::parseWorld(args.str("world", "benchmark"));
  if (!world) {
    std::fprintf(stderr, "alacs-twin generate: --%s\n", world.status().reason().c_str());
    return 2;
  }
  const bool hard = *world != sim::World::kBenchmark;
  // The hard worlds mix every light by default, sun at a fixed exposure included.
  const std::string lightingArg = args.str("lighting", hard ? "all" : lle ? "outdoor" : "lab");
  const bool bayer = args.integer("bayer", 1) != 0;
  const int jobs = static_cast<int>(args.integer("jobs", 2));
  const double motionMmS = args.num("motion-mm-s", 0.0);
  // A 635 nm band-pass filter in front of the lens (its FWHM in nm; 0: none), as a
  // laser-line sensor in sunlight has (docs/simulation.md, "Band-pass filter").
  const double bandpassNm = args.num("bandpass-nm", 0.0);
  if (!(bandpassNm == 0.0 || (bandpassNm >= 5.0 && bandpassNm <= 80.0))) {
    std::fprintf(stderr, "alacs-twin generate: --bandpass-nm must be 0 or in 5..80\n");
    return 2;
  }
  const bool resume = args.has("resume") && args.integer("resume", 1) != 0;
  // The second pass as the daemon takes it: ScanParams' defaults, unless overridden to
  // compare a setting (alacs-eval diagnose --follow-up-unseen-max-stops).
  localize::ScanParams scanParams;
  scanParams.followUpUnseenMaxStops =
      static_cast<int>(args.integer("follow-up-unseen-max-stops", scanParams.followUpUnseenMaxStops));
  scanParams.followUpFarSigmas = args.num("follow-up-far-sigmas", scanParams.followUpFarSigmas);
  if (Status s = scanParams.validate(); !s) {
    std::fprintf(stderr, "alacs-twin generate: %s\n", s.reason().c_str());
    return 2;
  }
  // The daemon's metering (metering.* in its config); its defaults unless overridden.
  const Result<MeteringArgs> meteringOrError = meteringArgs(args);
  if (!meteringOrError) {
    std::fprintf(stderr, "alacs-twin generate: %s\n", meteringOrError.status().reason().c_str());
    return 2;
  }
  const localize::MeteringParams& metering = meteringOrError->params;
  const int64_t maxExposureUs = meteringOrError->maxExposureUs;
  if (occ != "0" && occ != "1" && occ != "both" && occ != "mix") {
    std::fprintf(stderr, "alacs-twin generate: --occluded must be 0, 1, both or mix\n");
    return 2;
  }
  std::vector<sim::LightingKind> lights;
  if (lightingArg == "outdoor") {
    lights = {sim::LightingKind::kOvercast, sim::LightingKind::kDirect};
  } else if (lightingArg == "all") {
    lights = {sim::LightingKind::kLab, sim::LightingKind::kOvercast, sim::LightingKind::kDirect,
              sim::LightingKind::kFullSun};
  } else {
    Result<sim::LightingKind> l = sim::parseLighting(lightingArg);
    if (!l) {
      std::fprintf(stderr, "alacs-twin generate: %s (or outdoor, all)\n", l.status().reason().c_str());
      return 2;
    }
    lights = {*l};
  }
  if (Status s = replay::makeDirectories(out); !s) {
    std::fprintf(stderr, "alacs-twin generate: %s\n", s.reason().c_str());
    return 1;
  }

  std::vector<CaseJob> cases;
  if (lle) {
    // Distances, light and occlusion cycle so every mix is even.
    for (int i = 0; i < count; ++i) {
      CaseJob j;
      char name[64];
      std::snprintf(name, sizeof name, "lle_%04d", i);
      j.name = name;
      j.spec.distanceMm = distances[static_cast<size_t>(i) % distances.size()];
      j.spec.lighting = lights[static_cast<size_t>(i / static_cast<int>(distances.size())) % lights.size()];
      j.spec.occluded = occ == "1" || (occ == "mix" && (i / static_cast<int>(distances.size() * lights.size())) % 2 == 1);
      j.spec.bayer = bayer;
      j.spec.bandpassFwhmNm = bandpassNm;
      j.spec.world = *world;
      j.seed = mixSeed(seed, 0x11EULL * 1000003ULL + static_cast<uint64_t>(i));
      j.single = true;
      cases.push_back(j);
    }
  } else {
    std::vector<int> occs;
    if (occ == "0" || occ == "both") occs.push_back(0);
    if (occ == "1" || occ == "both") occs.push_back(1);
    if (occ == "mix") occs = {0, 1};
    for (double d : distances)
      for (int o : occs)
        for (int i = 0; i < count; ++i) {
          CaseJob j;
          char name[64];
          std::snprintf(name, sizeof name, "d%04d_occ%d_%04d", static_cast<int>(d), o, i);
          j.name = name;
          j.spec.distanceMm = d;
          j.spec.occluded = o == 1;
          j.spec.lighting = lights[static_cast<size_t>(i) % lights.size()];
          j.spec.bayer = bayer;
          j.spec.bandpassFwhmNm = bandpassNm;
          j.spec.world = *world;
          j.seed = mixSeed(seed, static_cast<uint64_t>(d) * 10 + static_cast<uint64_t>(o) + static_cast<uint64_t>(i) * 100003ULL);
          cases.push_back(j);
        }
  }

  // --only: the named cases alone (each name once, each one of the set's).
  if (args.has("only")) {
    Result<std::vector<CaseJob>> picked = pickCases(cases, args.str("only"), out + "/set.jsonl", resume);
    if (!picked) {
      std::fprintf(stderr, "alacs-twin generate: --only: %s\n", picked.status().reason().c_str());
      return 2;
    }
    cases = std::move(*picked);
  }

  const auto rays = std::make_shared<const sim::RayTable>(sim::defaultScene().truth.camera);
  std::vector<std::string> lines(cases.size());
  const Status st = parallelFor(
      static_cast<int>(cases.size()), jobs,
      [&](int i) -> Status {
        const CaseJob& job = cases[static_cast<size_t>(i)];
        const std::string dir = out + "/" + job.name;
        Result<sim::OrchardCase> oc = sim::makeOrchardCase(job.spec, job.seed);
        if (!oc) return Status(oc.status().code(), job.name + ": " + oc.status().reason());
        const sim::SimScene& scene = oc->scene;
        const sim::SimApple& target = *scene.apple(oc->targetId);
        Result<RenderPlan> rp = renderPlan(scene.truth, oc->roughMm);
        if (!rp) return Status(rp.status().code(), job.name + ": " + rp.status().reason());
        replay::ScanInfo info;
        info.kind = job.single ? "lle" : "localize";
        info.targetId = oc->targetId;
        info.roughMm = oc->roughMm;
        info.roiPx = rp->plan.roi;
        info.note = oc->description;
        // Laser-off frames first (metering, and the one to subtract), then the laser frames
        // at the exposure chosen.
        const Metered metered =
            meterScene(scene, rays, rp->region, rp->plan.roi, rp->plan.stopsMm.front(), metering, maxExposureUs);
        std::vector<sim::ExportFrame> frames = metered.laserOff;
        std::vector<uint64_t> frameIndices = metered.frameIndices;
        const int64_t exposureUs = metered.decision.exposureUs;
        const double smearMm = motionMmS * static_cast<double>(exposureUs) * 1e-6;
        double t = kFrameIntervalS * static_cast<double>(frames.size());
        uint64_t index = 0;  // the stops' noise seeds, as without metering
        uint64_t secondIndex = kSecondExposureFrameIndex;
        const auto laserFrame = [&](double startMm, double endMm, const char* tag, int64_t us, bool second = false) {
          sim::ExportFrame f;
          f.slideStartMm = startMm;
          f.slideEndMm = endMm;
          f.laserOn = true;
          f.exposureUs = us;
          f.analogueGain = metered.decision.analogueGain;  // 0: the scene's, as metered
          f.timestampS = t;
          f.tag = tag;
          frames.push_back(f);
          frameIndices.push_back(second ? secondIndex++ : index++);
        };
        std::vector<cv::Mat> laserRenders;  // the passes' frames, rendered to observe them
        int followUpFrames = 0;
        if (job.single) {
          // The laser somewhere across the target's central 60 %.
          sim::CaseRng rng(job.seed ^ 0x5EEDULL);
          const double off = rng.uniform(-0.6, 0.6) * target.radiusMm;
          const double s = scene.truth.laser.slideForPoint(target.centerMm + off * scene.truth.laser.planeNormal);
          info.stopsMm = {s};
          laserFrame(s - 0.5 * smearMm, s + 0.5 * smearMm, "stop", exposureUs);
        } else {
          info.stopsMm = rp->plan.stopsMm;
          // The first pass at the plan's stops, then the second pass where the localizer
          // asks for one (tag "follow_up"), as the daemon scans.
          // A stop's second exposure (metering.second_exposure_factor) right after its
          // first, at the same position (tag "second").
          const int64_t secondUs = metered.secondSubtract.empty() ? 0 : metered.decision.secondExposureUs;
          laserRenders = scanTwoPasses(scene, rays, *rp, metered, scanParams, [&](double s, int pass) {
            std::vector<FrameTaken> taken;
            laserFrame(s - 0.5 * smearMm, s + 0.5 * smearMm, pass == 1 ? "stop" : "follow_up", exposureUs);
            taken.push_back({frames.back(), frameIndices.back()});
            if (secondUs > 0) {
              t += kFrameIntervalS;
              const double secondSmearMm = motionMmS * static_cast<double>(secondUs) * 1e-6;
              laserFrame(s - 0.5 * secondSmearMm, s + 0.5 * secondSmearMm, "second", secondUs, true);
              taken.push_back({frames.back(), frameIndices.back()});
            }
            followUpFrames += pass == 2 ? 1 : 0;
            t += 0.25;  // a stop every 250 ms (move, settle, expose)
            return taken;
          });
          // The paper's single-line experiment: the laser aimed at the marker on the
          // apple's face (the truth's approach point), not planned from the rough position.
          const double aimed = scene.truth.laser.slideForPoint(sim::approachPoint(target));
          if (aimed >= 0.0 && aimed <= 200.0) laserFrame(aimed, aimed, "aimed", exposureUs);
        }
        if (!(resume && exists(dir + "/manifest.json"))) {
          sim::ExportOptions opt;
          opt.renderRegion = rp->region;
          opt.frameIndices = frameIndices;
          opt.rendered = metered.rendered;
          opt.rendered.insert(opt.rendered.end(), laserRenders.begin(), laserRenders.end());
          opt.rendered.resize(frames.size());  // the others are rendered by exportScan
          if (Status s = sim::exportScan(scene, rays, dir, info, frames, opt); !s)
            return Status(s.code(), job.name + ": " + s.reason());
        }
        const tools::Json record{
            {"case", job.name},
            {"dir", dir},
            {"set", set},
            {"distance_mm", tools::jsonNumber(job.spec.distanceMm, "%.0f")},
            {"occluded", job.spec.occluded ? 1 : 0},
            {"lighting", sim::lightingName(job.spec.lighting)},
            {"lux", tools::jsonNumber(oc->lux, "%.0f")},
            {"occlusion_share", tools::jsonNumber(oc->occlusionShare, "%.4f")},
            {"exposure_us", static_cast<long long>(scene.sensor.exposureUs)},
            {"laser_exposure_us", static_cast<long long>(exposureUs)},
            {"laser_analogue_gain",
             tools::jsonNumber(
                 metered.decision.analogueGain > 0.0 ? metered.decision.analogueGain : scene.sensor.analogueGain(),
                 "%.3f")},
            {"laser_off_frames", metered.laserOff.size()},
            {"laser_off_subtracted", metered.decision.subtract},
            {"follow_up_frames", followUpFrames},
            {"second_exposure_us",
             static_cast<long long>(metered.secondSubtract.empty() ? 0 : metered.decision.secondExposureUs)},
            {"bandpass_nm", tools::jsonNumber(scene.sensor.bandpassFwhmNm, "%.0f")},
            {"diameter_mm", tools::jsonNumber(2.0 * target.radiusMm, "%.2f")},
            {"world", sim::worldName(job.spec.world)},
            {"shape", oc->shape},
            {"aspect", tools::jsonNumber(target.aspect, "%.3f")},
            {"laser_mw", tools::jsonNumber(scene.laser.powerMw, "%.1f")},
            {"background_mm", tools::jsonNumber(scene.background.depthMm - target.centerMm.z(), "%.0f")},
            {"neighbours", scene.apples.size() - 1},
            {"leaves", scene.leaves.size()},
            {"seed", static_cast<unsigned long long>(job.seed)}};
        lines[static_cast<size_t>(i)] = tools::jsonText(record);
        return Status::ok();
      },
      [&](int i) {
        std::printf("%s", lines[static_cast<size_t>(i)].c_str());
        std::fflush(stdout);
      });
  if (!st) {
    std::fprintf(stderr, "alacs-twin generate: %s\n", st.toString().c_str());
    return 1;
  }
  // The set's index, in case order; with --only, the index already there keeps its other
  // cases' lines (in their order) and takes the new ones in place of theirs.
  const std::string indexPath = out + "/set.jsonl";
  if (args.has("only")) lines = mergedIndex(indexPath, cases, std::move(lines));
  // Written beside it and renamed over it: an index that held other cases' lines is not
  // lost to a failed write.
  const std::string partPath = indexPath + ".part";
  FILE* f = std::fopen(partPath.c_str(), "w");
  bool written = f != nullptr;
  for (const auto& l : lines) written = written && std::fputs(l.c_str(), f) >= 0;
  if (f != nullptr) written = std::fclose(f) == 0 && written;
  if (!written || std::rename(partPath.c_str(), indexPath.c_str()) != 0) {
    std::fprintf(stderr, "alacs-twin generate: cannot write %s\n", indexPath.c_str());
    return 1;
  }
  return 0;
}

}  // namespace alacs::twin
