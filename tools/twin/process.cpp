// alacs-twin process: the pipeline on scan directories, exactly as the scan worker runs
// it live: the localizer plans the stops from the scan's rough position, the exposure is
// metered from the scan's laser-off frames (and a laser-off frame kept for subtraction
// when the meter asks for it), a ReplaySource serves the frame recorded nearest each stop
// and its recorded position, the localizer observes each frame and fuses the lines, and
// takes the adaptive second pass where it asks for one (twoPassScan). One JSON line per scan on stdout:
//   {"scan", "kind", "roi", "frames": [{"slide_mm", "valid", "rows"?, "kept"?, "arc"?, "curve"?}],
//    (--rows: "rows" [row, column, inlier 0|1, image::RowStatus], "kept" [row, column],
//    "kept_from_rough_mm" [each kept sample's 3D distance from the rough position],
//    "arc" [row, column]: the sunlit arcs' gated samples, used only where the lines leave
//    the target unseen),
//    "multi": estimate (both passes), "first_pass": estimate, "follow_up_stops",
//    "follow_up_missing" (second-pass stops the scan holds no frame for),
//    "single": estimate (the stop nearest the rough position only)}
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "localize/exposure.h"
#include "replay/replay_source.h"
#include "twin.h"

namespace alacs::twin {

namespace {

// Pixels as [[row, column], ...].
tools::Json pixelsJson(const std::vector<geometry::PixelPoint>& pixels) {
  tools::Json out = tools::Json::array();
  for (const auto& px : pixels) out.push_back({tools::jsonNumber(px.rowPx), tools::jsonNumber(px.columnPx)});
  return out;
}

tools::Json estimateJson(const Result<localize::AppleEstimate>& e) {
  if (!e) return {{"ok", false}, {"error", errorName(e.status().code())}};
  return {{"ok", true},
          {"center_mm", jsonVec(e->centerMm)},
          {"approach_mm", jsonVec(e->approachMm)},
          {"diameter_mm", tools::jsonNumber(e->diameterMm)},
          {"sigma_mm", tools::jsonNumber(e->sigmaMm)},
          {"center_sigma_mm", tools::jsonNumber(e->centerSigmaMm)},
          {"diameter_sigma_mm", tools::jsonNumber(e->diameterSigmaMm)},
          {"rms_mm", tools::jsonNumber(e->rmsMm)},
          {"outside_gate", e->outsideGate},
          {"fit_sigma_mm", tools::jsonNumber(e->fitSigmaMm)},
          {"target_pct", tools::jsonNumber(e->targetPct)},
          {"rival_share", tools::jsonNumber(e->rivalShare)},
          {"rival_center_mm", jsonVec(e->rivalCenterMm)},
          {"doubt", e->doubt == localize::AppleEstimate::Doubt::kTwoSurfaces    ? "TWO_SURFACES"
                    : e->doubt == localize::AppleEstimate::Doubt::kFarFromRough ? "FAR_FROM_ROUGH"
                                                                                : "NONE"},
          {"confidence_pct", tools::jsonNumber(e->confidencePct)},
          {"occlusion_pct", tools::jsonNumber(e->occlusionPct)},
          {"lines_used", e->linesUsed},
          {"points_used", e->pointsUsed},
          {"sphere_fit", e->sphereFit}};
}

// What the scan worker does before the stops (app/scan_worker.cpp, meterExposure), on a
// replayed scan: laser-off frames from the recorded ones, metered by the same
// ExposureMeter, starting at the exposure of the scan's first laser-off frame, choosing at
// most `maxExposureUs` (the daemon's configured exposure, as the scan was generated with). A scan
// without laser-off frames (recorded before metering) is processed as recorded, without
// subtraction, and says so.
struct Metering {
  localize::MeteringDecision decision;
  int laserOffFrames = 0;
  cv::Mat laserOff;  // the frame to subtract (full frame; its ROI valid), empty: none
  // The laser-off frame at the stops' second exposure (decision.secondExposureUs), empty: none.
  cv::Mat secondLaserOff;
  std::string note;
};

Metering meterReplay(replay::ReplaySource& src, bool& laser, const image::Roi& roi,
                     const localize::MeteringParams& params, int64_t maxExposureUs) {
  Metering out;
  const auto& frames = src.manifest().frames;
  const auto firstOff =
      std::find_if(frames.begin(), frames.end(), [](const replay::FrameRecord& f) { return !f.laserOn; });
  if (firstOff == frames.end() || !params.enabled) {
    out.note = params.enabled ? "no laser-off frame: not metered" : "metering off";
    out.decision.exposureUs = 0;
    return out;
  }
  laser = false;
  const localize::MeteringRun run =
      localize::runMetering(params, firstOff->exposureUs, maxExposureUs, roi,
                            [&](int64_t us, double gain, localize::LaserOffUse) -> Result<localize::LaserOffFrame> {
                              ports::CaptureRequest req;
                              req.exposureUs = us;
                              req.analogueGain = gain;
                              Result<ports::CapturedFrame> f = src.capture(req, {});
                              if (!f) return f.status();
                              return localize::LaserOffFrame{f->view, f->info.exposureUs, f->info.analogueGain};
                            });
  out.decision = run.decision;
  out.laserOffFrames = run.frames;
  if (!run.status) out.note = "metering: " + run.status.reason();
  // A scan recorded at one gain replays at it (ReplaySource::gainLowered).
  const bool oneGain = !src.gainLowered() && params.brightAnalogueGain > 0.0;
  if (run.status && oneGain && run.decision.bright) out.note = "bright, recorded at one gain: replayed at it";
  if (run.status && src.gainLowered() && run.decision.analogueGain == 0.0)
    out.note = "recorded at a lowered gain, replayed without it";
  const auto copy = [](const image::ImageView& v) {
    return cv::Mat(v.height, v.width, CV_8UC3, const_cast<uint8_t*>(v.data), v.strideBytes).clone();
  };
  if (run.hasLaserOff) out.laserOff = copy(run.laserOff.view);
  if (run.hasLaserOff && run.decision.secondExposureUs > 0) {
    // The second exposure's own laser-off frame, as the scan worker takes it after metering.
    ports::CaptureRequest req;
    req.exposureUs = run.decision.secondExposureUs;
    req.analogueGain = run.decision.analogueGain;
    Result<ports::CapturedFrame> f = src.capture(req, {});
    if (f && f->info.exposureUs == req.exposureUs) {
      out.secondLaserOff = copy(f->view);
      ++out.laserOffFrames;
    } else {
      out.note = "no laser-off frame at the second exposure: one exposure per stop";
      out.decision.secondExposureUs = 0;
    }
  }
  laser = true;
  return out;
}

}  // namespace

int processMain(const Args& args) {
  const std::vector<std::string>& dirs = args.positional();
  if (dirs.empty()) {
    std::fprintf(stderr, "alacs-twin process: give scan directories\n");
    return 2;
  }
  std::optional<geometry::Calibration> override;
  const std::string calPath = args.str("calibration");
  if (!calPath.empty()) {
    Result<geometry::Calibration> c = geometry::loadCalibration(calPath);
    if (!c) {
      std::fprintf(stderr, "alacs-twin process: %s\n", c.status().toString().c_str());
      return 1;
    }
    override = *c;
  }
  image::LleParams lle;
  lle.brceStep = static_cast<int>(args.integer("brce-step", lle.brceStep));
  lle.brceThreshold = static_cast<int>(args.integer("brce-threshold", lle.brceThreshold));
  lle.smoothRows = static_cast<int>(args.integer("lle-smooth-rows", lle.smoothRows));
  lle.edgeRatio = static_cast<int>(args.integer("lle-edge-ratio", lle.edgeRatio));
  lle.weakLineThresholdPct = static_cast<int>(args.integer("lle-weak-line-pct", lle.weakLineThresholdPct));
  lle.shortLinePct = static_cast<int>(args.integer("lle-short-line-pct", lle.shortLinePct));
  lle.subtractedLineThresholdPct =
      static_cast<int>(args.integer("lle-subtracted-line-pct", lle.subtractedLineThresholdPct));
  lle.subtractedRows = static_cast<int>(args.integer("lle-subtracted-rows", lle.subtractedRows));
  lle.rerunOthersFirm = args.integer("lle-rerun-others-firm", lle.rerunOthersFirm ? 1 : 0) != 0;
  lle.matchedFilter = args.integer("lle-matched-filter", lle.matchedFilter ? 1 : 0) != 0;
  if (Status s = lle.validate(); !s) {
    std::fprintf(stderr, "alacs-twin process: %s\n", s.reason().c_str());
    return 2;
  }
  localize::ScanParams scan;
  scan.otherObjectPrior = args.num("other-object-prior", scan.otherObjectPrior);
  if (args.has("fit-when-far-from-rough")) scan.roughWhenFarFromRough = false;
  scan.weakArcMinZ = args.num("weak-arc-min-z", scan.weakArcMinZ);
  scan.leafGreenRatio = args.num("leaf-green-ratio", scan.leafGreenRatio);
  scan.shapeIrregularityPct = args.num("shape-irregularity-pct", scan.shapeIrregularityPct);
  scan.followUpUnseenMaxStops =
      static_cast<int>(args.integer("follow-up-unseen-max-stops", scan.followUpUnseenMaxStops));
  scan.followUpFarSigmas = args.num("follow-up-far-sigmas", scan.followUpFarSigmas);
  if (Status s = scan.validate(); !s) {
    std::fprintf(stderr, "alacs-twin process: %s\n", s.reason().c_str());
    return 2;
  }
  // The daemon's metering (metering.* in its config); its defaults unless overridden.
  const Result<MeteringArgs> meteringOrError = meteringArgs(args);
  if (!meteringOrError) {
    std::fprintf(stderr, "alacs-twin process: %s\n", meteringOrError.status().reason().c_str());
    return 2;
  }
  const localize::MeteringParams& metering = meteringOrError->params;
  const int64_t maxExposureUs = meteringOrError->maxExposureUs;
  const bool wantRows = args.has("rows");
  const int jobs = static_cast<int>(args.integer("jobs", 2));
  std::vector<std::string> lines(dirs.size());

  const Status st = parallelFor(
      static_cast<int>(dirs.size()), jobs,
      [&](int i) -> Status {
        const std::string& dir = dirs[static_cast<size_t>(i)];
        VirtualClock clock;
        double slide = 0.0;
        bool laser = true;
        Result<std::unique_ptr<replay::ReplaySource>> src = replay::ReplaySource::open(
            dir, clock, [&] { return laser; }, [&] { return slide; });
        tools::Json o;
        o["scan"] = dir;
        if (!src) {
          o["error"] = src.status().reason();
          lines[static_cast<size_t>(i)] = tools::jsonText(o);
          return Status::ok();
        }
        const replay::ScanManifest& m = (*src)->manifest();
        geometry::Calibration cal;
        if (override) {
          cal = *override;
        } else {
          Result<geometry::Calibration> c = replay::loadScanCalibration(dir, m);
          if (!c) return Status(c.status().code(), dir + ": " + c.status().reason());
          cal = *c;
        }
        const localize::Localizer loc(cal, lle, scan);
        o["kind"] = m.scan.kind;
        if (!m.scan.roughMm) {
          o["error"] = "no rough position";
          lines[static_cast<size_t>(i)] = tools::jsonText(o);
          return Status::ok();
        }
        Result<localize::ScanPlan> plan = loc.plan(*m.scan.roughMm, 200.0);
        if (!plan) {
          o["error"] = "plan: " + plan.status().reason();
          lines[static_cast<size_t>(i)] = tools::jsonText(o);
          return Status::ok();
        }
        // The recorded stops (the LLE set has one; the benchmark's scans the paper's five),
        // not the plan's, which with today's defaults may be denser than the recording.
        const std::vector<double> stops = m.scan.stopsMm.empty() ? plan->stopsMm : m.scan.stopsMm;
        const double centreStop = cal.laser.slideForPoint(*m.scan.roughMm);
        o["roi"] = {plan->roi.x, plan->roi.y, plan->roi.width, plan->roi.height};
        const Metering metered = meterReplay(**src, laser, plan->roi, metering, maxExposureUs);
        o["exposure_us"] = metered.decision.exposureUs;
        if (metered.decision.analogueGain > 0.0)
          o["analogue_gain"] = tools::jsonNumber(metered.decision.analogueGain, "%.3f");
        o["laser_off_frames"] = metered.laserOffFrames;
        o["laser_off_subtracted"] = !metered.laserOff.empty();
        o["bright_ambient"] = metered.decision.bright;  // what names a scan with no line BRIGHT_AMBIENT
        if (!metered.note.empty()) o["metering"] = metered.note;
        const image::ImageView laserOffView{metered.laserOff.data, metered.laserOff.cols, metered.laserOff.rows,
                                            metered.laserOff.step[0], image::PixelFormat::kBgr888};
        const image::ImageView* laserOff = metered.laserOff.empty() ? nullptr : &laserOffView;
        const image::ImageView secondOffView{metered.secondLaserOff.data, metered.secondLaserOff.cols,
                                             metered.secondLaserOff.rows, metered.secondLaserOff.step[0],
                                             image::PixelFormat::kBgr888};
        const int64_t secondUs = metered.decision.secondExposureUs;
        if (secondUs > 0) o["second_exposure_us"] = secondUs;
        image::LleWorkspace ws;
        double observeMs = 0.0;
        // One frame through the camera port and the localizer, as the scan worker does.
        tools::Json frameJson = tools::Json::array();
        auto run = [&](double at) -> Result<localize::LineObservation> {
          slide = at;
          ports::CaptureRequest req;
          if (metered.decision.exposureUs > 0) req.exposureUs = metered.decision.exposureUs;
          req.analogueGain = metered.decision.analogueGain;
          Result<ports::CapturedFrame> f = (*src)->capture(req, {});
          if (!f) {
            frameJson.push_back({{"slide_mm", tools::jsonNumber(at)}, {"valid", false}, {"error", f.status().reason()}});
            return f.status();
          }
          tools::Json fo;
          const double recorded = (*src)->lastSlideMm();
          const auto t0 = std::chrono::steady_clock::now();
          Result<localize::LineObservation> ob =
              loc.observe(f->view, *plan, recorded, ws, laserOff, 0.0, metered.decision.bright);
          observeMs += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
          fo["slide_mm"] = tools::jsonNumber(recorded);
          fo["frame"] = (*src)->lastFrame();
          fo["tag"] = m.frames[static_cast<size_t>((*src)->lastFrame())].tag;
          if (!ob) {
            fo["valid"] = false;
            fo["error"] = ob.status().reason();
            frameJson.push_back(std::move(fo));
            return ob;
          }
          if (secondUs > 0) {
            // The stop's second exposure, as the scan worker takes it: its rows join where
            // the first frame's LLE found none (`rows` and `curve` below are the first's).
            req.exposureUs = secondUs;
            Result<ports::CapturedFrame> f2 = (*src)->capture(req, {});
            if (!f2 || f2->info.exposureUs != secondUs || std::abs((*src)->lastSlideMm() - recorded) > 0.05) {
              fo["second_error"] =
                  f2 ? "the scan holds no laser frame at the second exposure here" : f2.status().reason();
            } else {
              Result<localize::LineObservation> ob2 =
                  loc.observe(f2->view, *plan, (*src)->lastSlideMm(), ws, &secondOffView, 0.0, true);
              if (ob2) {
                fo["second_frame"] = (*src)->lastFrame();
                fo["second_joined"] = localize::Localizer::mergeSecondExposure(*ob, *ob2);
              }
            }
          }
          const image::LaserLine& line = ob->line;
          fo["valid"] = line.valid;
          fo["points"] = ob->pointsMm.size();
          if (wantRows) {
            tools::Json rows = tools::Json::array();
            for (const auto& r : line.rows)
              rows.push_back({r.row, tools::jsonNumber(r.column), r.inlier ? 1 : 0, static_cast<int>(r.status)});
            fo["rows"] = std::move(rows);
            // What the localizer keeps of the frame: the samples gated in 3D around the target,
            // and the sunlit arcs' samples within the gate (ScanParams::gateMm; the search's bar
            // is ScanParams::weakArcMinZ).
            fo["kept"] = pixelsJson(ob->pixels);
            // Each kept sample's distance from the rough position (same order): where a row
            // keeps two, the evaluation can read the one nearer the target's prior.
            tools::Json fromRough = tools::Json::array();
            for (const Eigen::Vector3d& p : ob->pointsMm)
              fromRough.push_back(tools::jsonNumber((p - plan->roughMm).norm()));
            fo["kept_from_rough_mm"] = std::move(fromRough);
            fo["arc"] = pixelsJson(ob->arcPixels);
            if (line.valid) {
              fo["curve_first_row"] = plan->roi.y;
              tools::Json curve = tools::Json::array();
              for (int r = 0; r < plan->roi.height; ++r) curve.push_back(tools::jsonNumber(line.columnAt(plan->roi.y + r)));
              fo["curve"] = std::move(curve);
            }
          }
          frameJson.push_back(std::move(fo));
          return ob;
        };
        int aimed = -1;
        for (size_t k = 0; k < m.frames.size(); ++k)
          if (m.frames[k].tag == "aimed" && m.frames[k].laserOn) aimed = static_cast<int>(k);
        // The recorded first pass, then the second pass the localizer asks for: the
        // generator rendered its frames for the same decision (a stop the scan holds no
        // frame for gets the nearest one, already seen, and counts as missing).
        localize::ScanPlan recorded = *plan;
        recorded.stopsMm = stops;
        int missing = 0;
        const TwoPassScan scanned = twoPassScan(loc, recorded, 200.0, m.scan.kind != "lle", [&](double at, int pass) {
          Result<localize::LineObservation> ob = run(at);
          if (pass == 2 && std::abs((*src)->lastSlideMm() - at) > 0.05) ++missing;
          return ob;
        });
        const std::vector<localize::LineObservation>& obs = scanned.lines;
        // The single line: the frame aimed at the marker if the scan has one, else the stop
        // nearest the rough position.
        std::optional<localize::LineObservation> single;
        std::string singleSource = "centre_stop";
        if (aimed >= 0) {
          Result<localize::LineObservation> ob = run(m.frames[static_cast<size_t>(aimed)].slideMm);
          if (ob) single = std::move(*ob);
          singleSource = "aimed";
        } else {
          for (const auto& l : obs)
            if (!single || std::abs(l.slideMm - centreStop) < std::abs(single->slideMm - centreStop)) single = l;
        }
        o["frames"] = std::move(frameJson);
        o["observe_ms"] = tools::jsonNumber(observeMs);
        if (m.scan.kind != "lle") {
          o["multi"] = estimateJson(scanned.estimate);
          o["first_pass"] = estimateJson(scanned.firstPass);
          o["follow_up_stops"] = scanned.followUpMm.size();
          o["follow_up_missing"] = missing;
          o["single_source"] = singleSource;
          if (single) {
            o["single_slide_mm"] = tools::jsonNumber(single->slideMm);
            o["single"] = estimateJson(loc.estimate(*plan, {*single}));
          }
        }
        lines[static_cast<size_t>(i)] = tools::jsonText(o);
        return Status::ok();
      },
      [&](int i) {
        std::printf("%s", lines[static_cast<size_t>(i)].c_str());
        std::fflush(stdout);
      });
  if (!st) {
    std::fprintf(stderr, "alacs-twin process: %s\n", st.toString().c_str());
    return 1;
  }
  return 0;
}

}  // namespace alacs::twin
