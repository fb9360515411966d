// The localize cycle of the real scan worker, on this machine's clock: the same worker,
// step runner, laser guard and image pipeline as alacsd, driving the simulated slide
// (which counts the STEP pulses) and the simulated camera (windowed render of the
// target's region, standing in for the sensor's readout). For each orchard case the
// slide is first parked within 2 cm of where the scan starts (outside or inside the
// span of the stops), then the job is timed from submission to its result. CAN adds one
// frame time (< 1 ms at 500 kbit/s) on top.
//
// --virtual-time runs the same on a VirtualTimeline (common/virtual_timeline.h) with a
// modelled sensor in place of the render's wall time: a free-running sensor at --fps whose
// exposure starts at its next frame start and which delivers the frame after reading out
// its whole height (ports::FrameSlotSource). The render and the image work take no virtual time (the image work
// overlaps the motion: the wall-clock run shows what is left of it after the last frame). What this measures is the
// sensor's and the slide's time, the same on any machine, whatever the simulator costs (the hard worlds' scenes render
// 3x slower than the benchmark's).
//
// Peak memory with real-size frames: --export writes orchard scans as scan directories
// of full frames (docs/scan-format.md) at --width x --height; --replay runs the same
// worker on them with a replay source as the camera (PNG decode of every full frame, as
// alacsd --replay), in a process that holds no simulator, and prints its peak resident
// memory (VmHWM). docs/daemon.md.
//
// usage: alacs_cycle [--cases N] [--mode stop-and-go|continuous|both] [--width W --height H] [--verbose]
//                    [--log-level debug]
//        alacs_cycle --virtual-time [--fps F] [--world W] ...
//        alacs_cycle --export DIR [--cases N] [--width W --height H]
//        alacs_cycle --replay [--mode stop-and-go|continuous|scan-all|all] [--verbose] DIR...
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "app/laser_guard.h"
#include "app/process_memory.h"
#include "app/scan_worker.h"
#include "common/log.h"
#include "common/virtual_timeline.h"
#include "ports/frame_slot_source.h"
#include "protocol/codec.h"
#include "replay/replay_source.h"
#include "replay/scan_dir.h"
#include "sim/orchard.h"
#include "sim/scan_export.h"
#include "sim/sim_camera.h"
#include "sim/sim_slide.h"
#include "survey/survey.h"
#include "tool_common/cli.h"

using namespace alacs;

namespace {

struct Options {
  int cases = 10;
  std::string modes;
  int widthPx = 0;
  int heightPx = 0;
  bool verbose = false;
  std::string logLevel = "info";          // the worker's log (debug: each frame's rows and points)
  int followUpMaxStops = -1;              // -1: ScanParams' default
  int followUpUnseenMaxStops = -1;        // -1: ScanParams' default
  double followUpDiameterSigmaMm = -1.0;  // -1: ScanParams' default
  int stops = 0;                          // 0: ScanParams' default
  double spacingMm = 0.0;                 // 0: ScanParams' default
  int metering = 1;                       // the exposure metered from laser-off frames (the daemon's default)
  double brightAnalogueGain = -1.0;       // metering.bright_analogue_gain; < 0: the daemon's default
  double secondExposure = -1.0;           // metering.second_exposure_factor; < 0: the daemon's default
  int warmUp = 1;                         // one untimed scan of the case first (the worker's steady state)
  std::string lighting = "overcast";
  std::string world = "benchmark";  // benchmark|benchmark-hard|holdout (sim/orchard.h)
  double exposureX = 1.0;  // the exposure: this × the auto exposure (at most 3000 us)
  bool virtualTime = false;  // a VirtualTimeline and ports::FrameSlotSource, not this machine's clock
  double fps = 30.0;         // --virtual-time: the sensor's free-running frame rate
  double lineTimeUs = 0.0;   // a rolling shutter's line time (0: a global shutter)
  int workerLineTime = 1;    // 1: the worker is told the line time (config camera.line_time_us), 0: not
  int nearestFrame = 1;  // --virtual-time: 1: a sweep asks for the frame nearest each stop (alacsd's), 0: as it passes
  int learnPace = 1;     // 1: homing learns the camera's pace from laser-off frames (alacsd's), 0: the first scan does
  std::string laserTiming = "frame-clock";  // --virtual-time: how the camera switches the laser (ports::LaserTiming)
  double laserLeadUs = 1000.0;
  int globalShutter = 0;  // --virtual-time, frame-clock: the camera is told the sensor has a global shutter
  std::string exportDir;
  bool replay = false;
  std::vector<std::string> dirs;
};

// The localizer's scan parameters: the defaults, with the adaptive second pass as asked.
localize::ScanParams scanParamsOf(const Options& o) {
  localize::ScanParams sp;
  if (o.followUpMaxStops >= 0) sp.followUpMaxStops = o.followUpMaxStops;
  if (o.followUpUnseenMaxStops >= 0) sp.followUpUnseenMaxStops = o.followUpUnseenMaxStops;
  if (o.followUpDiameterSigmaMm >= 0.0) sp.followUpDiameterSigmaMm = o.followUpDiameterSigmaMm;
  if (o.stops > 0) sp.stops = o.stops;
  if (o.spacingMm > 0.0) sp.stopSpacingMm = o.spacingMm;
  return sp;
}

// The simulated camera renders each frame on the worker's thread after its exposure, so
// the render's wall time stands for the sensor's readout inside the cycle. A scene with
// many leaves and neighbours (the hard worlds) renders far slower than a sensor reads out:
// this wrapper measures that time (capture's wall time less the exposure) so that the
// report can say how much of a cycle was the simulator.
class RenderTimedSource final : public ports::FrameSource {
 public:
  RenderTimedSource(ports::FrameSource& inner, const Clock& clock) : inner_(inner), clock_(clock) {}
  const char* name() const override { return inner_.name(); }
  double renderMs() const { return static_cast<double>(renderNs_) / 1e6; }
  int frames() const { return frames_; }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& request,
                                         const ports::ExposureHooks& hooks) override {
    const TimeNs t0 = clock_.now();
    Result<ports::CapturedFrame> f = inner_.capture(request, hooks);
    renderNs_ += std::max<TimeNs>(0, clock_.now() - t0 - request.exposureUs * kNsPerUs);
    ++frames_;
    return f;
  }
  void doInterrupt() override { inner_.interrupt(); }
  void doResume() override { inner_.resume(); }
  ports::FrameSource& inner_;
  const Clock& clock_;
  TimeNs renderNs_ = 0;
  int frames_ = 0;
};

struct Trial {
  double cycleMs = 0;
  double renderMs = 0;  // the simulator's render (standing for the readout) within the cycle
  int frames = 0;
  double lastFrameMs = 0;  // end of the last exposure, after the command
  double tailMs = 0;
  double centreErrMm = 0;
  double approachErrMm = 0;  // the arm's target, as docs/evaluation.md measures the 20 mm
  bool ok = false;
  int followUpStops = 0;  // the adaptive second pass's stops (0: not taken)
  int laserOffFrames = 0;  // metering and the subtracted frame
  double sweepSpeedMmPerS = 0;  // continuous: the slowest sweep's cruise speed (0: none)
  double offStopMm = -1;        // the first pass: its frames' largest distance from their stops (-1: none)
  protocol::ResultStatus status = protocol::ResultStatus::kFailed;  // as the bus would say it
  double confidencePct = 0;                                         // the estimate's, when ok
  double sigmaMm = 0;                                               // its 1σ of the approach point
  int linesUsed = 0;
};

// The bar for honest uncertainty: no result beyond the end-effector's 20 mm at a
// confidence of 80 % or more.
constexpr double kToleranceMm = 20.0;
constexpr double kConfidentPct = 80.0;

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

double maxOf(const std::vector<double>& v) { return v.empty() ? 0.0 : *std::max_element(v.begin(), v.end()); }

app::WorkerEvent runJob(app::ScanWorker& worker, int efd, const app::WorkerJob& job) {
  if (!worker.submit(job)) {
    std::fprintf(stderr, "alacs_cycle: the worker refused a job (its queue is full)\n");
    std::exit(1);
  }
  uint64_t n = 0;
  while (true) {
    if (::read(efd, &n, sizeof n) < 0) continue;
    if (std::optional<app::WorkerEvent> ev = worker.takeEvent()) return *ev;
  }
}

// Home, park at `parkMm`, then run `job` timed from its submission.
// `atStart` (optional) runs just before: homing may take frames (the camera's pace).
Trial timeJob(app::ScanWorker& worker, int efd, const Clock& clock, double parkMm, app::WorkerJob job,
              const sim::SimApple* truth, const std::function<void()>& atStart = {}) {
  app::WorkerJob home;
  home.kind = app::WorkerJob::Kind::kHome;
  (void)runJob(worker, efd, home);
  app::WorkerJob park;
  park.kind = app::WorkerJob::Kind::kMoveTo;
  park.moveToMm = parkMm;
  (void)runJob(worker, efd, park);
  if (atStart) atStart();
  const TimeNs t0 = clock.now();
  job.commandTimeNs = t0;
  const app::WorkerEvent ev = runJob(worker, efd, job);
  // When the worker posted the result (this thread is not on a virtual timeline: reading
  // the clock here would add whatever the braking moved it by since).
  const TimeNs t1 = ev.doneNs;
  // Back to the park position: queued while a continuous scan's slide still brakes, it
  // runs once the slide is at rest.
  (void)runJob(worker, efd, park);
  Trial t;
  t.cycleMs = static_cast<double>(t1 - t0) / 1e6;
  t.lastFrameMs = ev.lastExposureNs > 0 ? static_cast<double>(ev.lastExposureNs - t0) / 1e6 : 0.0;
  t.tailMs = static_cast<double>(ev.processingTailNs) / 1e6;
  t.ok = ev.status.isOk() && !ev.estimates.empty();
  t.status = ev.resultStatus;
  if (t.ok) {
    t.confidencePct = ev.estimates[0].confidencePct;
    t.sigmaMm = ev.estimates[0].sigmaMm;
    t.linesUsed = ev.estimates[0].linesUsed;
  }
  t.followUpStops = ev.followUpStops;
  t.laserOffFrames = ev.laserOffFrames;
  t.sweepSpeedMmPerS = ev.sweepSpeedMmPerS;
  // The first pass's frames against its stops, in the order the slide passed them.
  std::vector<double> stops = job.plan.stopsMm;
  if (!stops.empty() && ev.exposures.size() >= stops.size()) {
    std::sort(stops.begin(), stops.end());
    if (ev.exposures[stops.size() - 1].slideMm < ev.exposures[0].slideMm) std::reverse(stops.begin(), stops.end());
    t.offStopMm = 0.0;
    for (size_t i = 0; i < stops.size(); ++i)
      t.offStopMm = std::max(t.offStopMm, std::abs(ev.exposures[i].slideMm - stops[i]));
  }
  if (t.ok && truth != nullptr && job.kind == app::WorkerJob::Kind::kLocalize) {
    t.centreErrMm = (ev.estimates[0].centerMm - truth->centerMm).norm();
    t.approachErrMm = (ev.estimates[0].approachMm - sim::approachPoint(*truth)).norm();
  }
  return t;
}

void report(const char* mode, const std::vector<Trial>& trials, bool accuracy, bool virtualTime = false) {
  std::vector<double> cyc, last, tail, share, err, approachErr;
  int found = 0;
  for (const auto& t : trials) {
    cyc.push_back(t.cycleMs);
    last.push_back(t.lastFrameMs);
    tail.push_back(t.tailMs);
    share.push_back(100.0 * t.tailMs / t.cycleMs);
    if (t.ok) {
      err.push_back(t.centreErrMm);
      approachErr.push_back(t.approachErrMm);
      ++found;
    }
  }
  std::printf("  %-12s cycle median %6.0f ms, max %6.0f ms | last exposure ends at median %4.0f ms, max %4.0f ms | "
              "processing after the last frame: median %5.1f ms (%4.1f %% of the cycle), max %5.1f ms | found %d/%zu",
              mode, median(cyc), maxOf(cyc), median(last), maxOf(last), median(tail), median(share), maxOf(tail), found,
              trials.size());
  if (accuracy) {
    int beyond = 0, confidentBeyond = 0;
    for (const auto& t : trials) {
      if (!t.ok || t.approachErrMm <= kToleranceMm) continue;
      ++beyond;
      if (t.confidencePct >= kConfidentPct) ++confidentBeyond;
    }
    std::printf(
        ", centre error median %.2f mm, max %.2f mm; approach point's median %.2f mm, max %.2f mm, beyond %.0f mm %d "
        "(at confidence >= %.0f %%: %d)",
        median(err), maxOf(err), median(approachErr), maxOf(approachErr), kToleranceMm, beyond, kConfidentPct,
        confidentBeyond);
  }
  std::printf("\n");
  // The adaptive second pass (too few lines on the fruit) costs those cases a second sweep.
  std::vector<double> second, single;
  for (const auto& t : trials) (t.followUpStops > 0 ? second : single).push_back(t.cycleMs);
  if (!second.empty())
    std::printf("  %-12s second pass on %zu/%zu: their cycle median %6.0f ms, max %6.0f ms; the others' median %6.0f ms, "
                "max %6.0f ms\n",
                "", second.size(), trials.size(), median(second), maxOf(second), median(single), maxOf(single));
  std::vector<double> speed, offStop;
  for (const auto& t : trials) {
    if (t.sweepSpeedMmPerS > 0) speed.push_back(t.sweepSpeedMmPerS);
    if (t.offStopMm >= 0) offStop.push_back(t.offStopMm);
  }
  if (!offStop.empty())
    std::printf("  %-12s first pass: its frames' largest distance from their stops, median %.1f mm, max %.1f mm%s\n",
                "", median(offStop), maxOf(offStop),
                speed.empty() ? ""
                              : (" | sweep speed (the camera's pace, the slower pass): median " +
                                 std::to_string(static_cast<int>(std::lround(median(speed)))) + " mm/s")
                                    .c_str());
  std::vector<double> render, less, frames;
  for (const auto& t : trials) {
    if (t.frames == 0) continue;
    render.push_back(t.renderMs);
    less.push_back(t.cycleMs - t.renderMs);
    frames.push_back(t.frames);
  }
  if (virtualTime && !frames.empty())
    std::printf(
        "  %-12s frames per scan: median %.0f, max %.0f (virtual time: the sensor's frame slots and readout "
        "are in the cycle, the simulator's render is not)\n",
        "", median(frames), maxOf(frames));
  else if (!render.empty())
    std::printf(
        "  %-12s the simulator's render within the cycle: median %6.0f ms, max %6.0f ms over a median of %.0f "
        "frames; the cycle less it: median %6.0f ms, max %6.0f ms (a sensor's readout, a few ms a windowed "
        "frame, overlaps the motion)\n",
        "", median(render), maxOf(render), median(frames), median(less), maxOf(less));
}

// The simulated scene at another sensor size: the same optics scaled (same field of view).
void scaleCamera(sim::SimScene& scene, int widthPx, int heightPx) {
  if (widthPx <= 0 || heightPx <= 0) return;
  auto& cam = scene.truth.camera;
  const double sx = widthPx / static_cast<double>(cam.widthPx);
  cam.fxPx *= sx;
  cam.fyPx *= sx;
  cam.cxPx *= sx;
  cam.cyPx *= sx;
  cam.widthPx = widthPx;
  cam.heightPx = heightPx;
}

double caseDistanceMm(int c) { return 1000.0 + 100.0 * (c % 5); }

Result<sim::OrchardCase> orchardCase(int c, sim::LightingKind lighting = sim::LightingKind::kOvercast,
                                     sim::World world = sim::World::kBenchmark) {
  sim::CaseSpec spec;
  spec.world = world;
  spec.distanceMm = caseDistanceMm(c);
  spec.occluded = true;
  spec.lighting = lighting;
  return sim::makeOrchardCase(spec, 1000 + static_cast<uint64_t>(c));
}

// Where the slide waits for the command: within 2 cm of the end of the stops the scan
// starts from (the nearer one), outside the span or inside it.
double parkFor(int c, const localize::ScanPlan& plan, double strokeMm) {
  static constexpr double kOffsetsMm[] = {-20.0, -5.0, 5.0, 20.0};  // < 0: outside the span
  const double offset = kOffsetsMm[c % 4];
  return std::clamp(plan.stopsMm.front() + offset, 0.0, strokeMm);
}

// The worker on the simulated slide (it counts the STEP pulses) with `camera` as its source.
app::WorkerDeps workerDeps(const Clock& clock, Sleeper& sleeper, const motion::SlideLimits& limits, sim::SimSlide& slide,
                           app::LaserGuard& laser, ports::FrameSource& camera) {
  app::WorkerDeps deps;
  deps.clock = &clock;
  deps.sleeper = &sleeper;
  deps.limits = limits;
  deps.stepLines = {&slide.stepInput(), &slide.dirInput(), &slide.homeSwitch(), &slide.endSwitch()};
  deps.enable = &slide.enableInput();
  deps.laser = &laser;
  deps.camera = &camera;
  return deps;
}

int simulatedCycle(const Options& o) {
  MonotonicClock wallClock;
  MonotonicSleeper wallSleeper;
  VirtualTimeline timeline;
  const Clock& clock = o.virtualTime ? static_cast<const Clock&>(timeline) : wallClock;
  Sleeper& sleeper = o.virtualTime ? static_cast<Sleeper&>(timeline) : wallSleeper;
  motion::SlideLimits limits;  // the daemon's defaults: docs/daemon.md
  image::LleParams lle;
  localize::ScanParams scanParams = scanParamsOf(o);
  Result<sim::LightingKind> lighting = sim::parseLighting(o.lighting);
  if (!lighting) {
    std::fprintf(stderr, "alacs_cycle: --lighting: %s\n", lighting.status().reason().c_str());
    return 2;
  }
  Result<sim::World> world = sim::parseWorld(o.world);
  if (!world) {
    std::fprintf(stderr, "alacs_cycle: --world: %s\n", world.status().reason().c_str());
    return 2;
  }
  std::printf(
      "localize cycle: %d orchard cases of the %s world (1.0-1.4 m, occluded, %s, exposure %.1f × auto), motor %.0f "
      "mm/s, "
      "%.0f mm/s², %.0f steps/mm, slide parked -20/-5/+5/+20 mm from the scan's first stop, metering %s, %s\n",
      o.cases, o.world.c_str(), o.lighting.c_str(), o.exposureX, limits.maxSpeedMmPerS, limits.accelMmPerS2,
      limits.stepsPerMm, o.metering != 0 ? "on" : "off",
      o.warmUp != 0 ? "each after an untimed scan of its case (the worker's steady state)"
                    : "each the worker's first scan (--warm-up 0)");
  if (o.lineTimeUs > 0.0)
    std::printf("  a rolling shutter: row v exposes v × %.1f us after row 0; the worker is %s\n", o.lineTimeUs,
                o.workerLineTime != 0 ? "told (camera.line_time_us): each row its own slide position"
                                      : "not told: one slide position for the frame");
  if (o.virtualTime)
    std::printf(
        "  virtual time: a sensor free-running at %.0f fps (an exposure starts at the next frame start; the "
        "frame is delivered after its whole height is read out, one period); the render and the "
        "image work take no virtual time\n  the laser %s\n",
        o.fps,
        o.laserTiming == "frame-clock"
            ? "on a lead before each frame's start and off a lead after its exposure (the frame clock learnt)"
            : "on from the capture request to the frame's delivery (the frame clock not used)");
  const std::string modes = o.modes.empty() ? "both" : o.modes;
  for (const char* mode : {"stop-and-go", "continuous"}) {
    if (modes != "both" && modes != mode) continue;
    const bool continuous = std::strcmp(mode, "continuous") == 0;
    std::vector<Trial> trials;
    std::vector<double> laserOffFrames;
    std::vector<double> laserOnPerFrameMs;  // each scan's laser-on time over its laser frames
    for (int c = 0; c < o.cases; ++c) {
      Result<sim::OrchardCase> oc = orchardCase(c, *lighting, *world);
      if (!oc) continue;
      sim::SimScene scene = oc->scene;
      scaleCamera(scene, o.widthPx, o.heightPx);
      const localize::Localizer loc(scene.truth, lle, scanParams);
      Result<localize::ScanPlan> plan = loc.plan(oc->roughMm, limits.strokeMm);
      if (!plan) continue;
      sim::SimSlide slide(clock, limits.stepsPerMm, limits.strokeMm, 0.0);
      ports::FakeDigitalOut laserLine(clock);
      app::LaserGuard laser(laserLine, clock, 250 * kNsPerMs);
      sim::SimCamera simCamera(
          scene, clock, sleeper, [&] { return laserLine.level(); }, [&] { return slide.positionMm(); });
      RenderTimedSource rendered(simCamera, clock);
      const auto lineTimeNs = static_cast<TimeNs>(std::llround(o.lineTimeUs * 1e3));
      simCamera.setLineTimeNs(lineTimeNs);
      // A rolling shutter's rows are read out as they end (the simulated camera's); a
      // global one's after the exposure (the slot source's).
      ports::FrameSlotSource sensor(
          rendered, clock, sleeper, static_cast<TimeNs>(std::llround(1e9 / o.fps)), lineTimeNs == 0,
          o.laserTiming == "frame-clock" ? ports::LaserTiming::kFrameClock : ports::LaserTiming::kAtRequest,
          static_cast<TimeNs>(std::llround(o.laserLeadUs * 1e3)), scene.truth.camera.heightPx,
          o.workerLineTime != 0 ? lineTimeNs : 0, o.globalShutter != 0 && lineTimeNs == 0);
      ports::FrameSource& camera = o.virtualTime ? static_cast<ports::FrameSource&>(sensor) : rendered;
      app::WorkerDeps deps = workerDeps(clock, sleeper, limits, slide, laser, camera);
      deps.lineTimeNs = o.workerLineTime != 0 ? lineTimeNs : 0;
      deps.learnPaceAtHome = o.learnPace != 0;
      // The modelled sensor free-runs: the sweep asks for each stop's nearest frame, as
      // alacsd does with libcamera (platform.cpp).
      if (o.virtualTime && o.nearestFrame != 0)
        deps.slotLeadNs = app::slotLeadFor(o.laserTiming == "frame-clock", std::llround(o.laserLeadUs * 1e3));
      deps.capture.exposureUs =
          std::min<int64_t>(std::llround(static_cast<double>(sim::autoExposureUs(scene)) * o.exposureX), 3000);
      deps.metering.enabled = o.metering != 0;
      if (o.brightAnalogueGain >= 0.0) deps.metering.brightAnalogueGain = o.brightAnalogueGain;
      if (o.secondExposure >= 0.0) deps.metering.secondExposureFactor = o.secondExposure;
      const int efd = ::eventfd(0, EFD_CLOEXEC);
      app::ScanWorker worker(deps, loc, efd);
      app::WorkerJob job;
      job.kind = app::WorkerJob::Kind::kLocalize;
      job.localize.mode = continuous ? protocol::ScanMode::kContinuous : protocol::ScanMode::kStopAndGo;
      job.localize.roughMm = oc->roughMm;
      job.plan = *plan;
      const double parkMm = parkFor(c, *plan, limits.strokeMm);
      const sim::SimApple* truth = scene.apple(oc->targetId);
      // A daemon's worker has scanned before: it knows how long its metering takes, and a
      // sweep overlaps the metering with its run-up (ScanWorker::sweepStops).
      if (o.warmUp != 0) (void)timeJob(worker, efd, clock, parkMm, job, nullptr);
      double renderBeforeMs = 0.0;
      int framesBefore = 0;
      TimeNs laserOnBeforeNs = 0;
      Trial t = timeJob(worker, efd, clock, parkMm, job, truth, [&] {
        renderBeforeMs = rendered.renderMs();
        framesBefore = rendered.frames();
        laserOnBeforeNs = laser.totalOnNs();
      });
      const TimeNs laserOnNs = laser.totalOnNs() - laserOnBeforeNs;
      // What the camera rendered from the job's start on was the job's (homing's frames, the
      // camera's pace, come before).
      t.renderMs = rendered.renderMs() - renderBeforeMs;
      t.frames = rendered.frames() - framesBefore;
      if (o.verbose)
        std::printf(
            "    %s case %2d: %4.0f mm away, parked %+5.1f mm from the first stop: cycle %4.0f ms, last exposure "
            "ends %4.0f ms, tail %5.1f ms, %s (%s, confidence %.0f %%, sigma %.1f mm, %d lines), centre error %.2f mm, "
            "approach point's %.2f mm, stops %.1f-%.1f mm, second pass %d stops, first pass's frames at most %.1f mm "
            "off their stops, "
            "sweep %.0f mm/s\n",
            mode, c, caseDistanceMm(c), parkMm - plan->stopsMm.front(), t.cycleMs, t.lastFrameMs, t.tailMs,
            t.ok ? "found" : "not found", protocol::resultStatusName(t.status), t.confidencePct, t.sigmaMm, t.linesUsed,
            t.centreErrMm, t.approachErrMm, plan->stopsMm.front(), plan->stopsMm.back(), t.followUpStops, t.offStopMm,
            t.sweepSpeedMmPerS);
      trials.push_back(t);
      laserOffFrames.push_back(t.laserOffFrames);
      if (t.frames > t.laserOffFrames)
        laserOnPerFrameMs.push_back(static_cast<double>(laserOnNs) / 1e6 / (t.frames - t.laserOffFrames));
      ::close(efd);
    }
    report(mode, trials, true, o.virtualTime);
    if (!laserOffFrames.empty())
      std::printf("    laser-off frames (metering and the subtracted one) per scan: median %.0f, max %.0f\n",
                  median(laserOffFrames), *std::max_element(laserOffFrames.begin(), laserOffFrames.end()));
    if (!laserOnPerFrameMs.empty())
      std::printf("    laser on per laser frame (each scan's mean): median %.2f ms, max %.2f ms\n",
                  median(laserOnPerFrameMs), *std::max_element(laserOnPerFrameMs.begin(), laserOnPerFrameMs.end()));
  }
  std::printf("  peak resident memory of this process (worker + simulator): %.1f MB\n", app::peakResidentMb());
  return 0;
}


// Orchard scans as scan directories of full frames (the twin's renderer at the scaled
// sensor size): DIR/case_NN, the five planned stops each, laser on, at rest.
int exportScans(const Options& o) {
  motion::SlideLimits limits;
  image::LleParams lle;
  localize::ScanParams scanParams = scanParamsOf(o);
  std::shared_ptr<const sim::RayTable> rays;
  for (int c = 0; c < o.cases; ++c) {
    Result<sim::OrchardCase> oc = orchardCase(c);
    if (!oc) {
      std::fprintf(stderr, "alacs_cycle: case %d: %s\n", c, oc.status().toString().c_str());
      return 1;
    }
    sim::SimScene scene = oc->scene;
    scaleCamera(scene, o.widthPx, o.heightPx);
    if (!rays) rays = std::make_shared<const sim::RayTable>(scene.truth.camera);
    Result<localize::ScanPlan> plan = localize::Localizer(scene.truth, lle, scanParams).plan(oc->roughMm, limits.strokeMm);
    if (!plan) {
      std::fprintf(stderr, "alacs_cycle: case %d: %s\n", c, plan.status().toString().c_str());
      return 1;
    }
    replay::ScanInfo info;
    info.kind = "localize";
    info.targetId = oc->targetId;
    info.roughMm = oc->roughMm;
    info.stopsMm = plan->stopsMm;
    info.roiPx = plan->roi;
    info.note = oc->description;
    const int64_t exposureUs = std::min<int64_t>(sim::autoExposureUs(scene), 3000);
    std::vector<sim::ExportFrame> frames;
    double t = 0.0;
    for (double s : plan->stopsMm) {
      frames.push_back({s, s, true, exposureUs, t, "stop"});
      t += 0.25;
    }
    char name[32];
    std::snprintf(name, sizeof name, "/case_%02d", c);
    const std::string dir = o.exportDir + name;
    if (Status s = sim::exportScan(scene, rays, dir, info, frames); !s) {
      std::fprintf(stderr, "alacs_cycle: %s: %s\n", dir.c_str(), s.toString().c_str());
      return 1;
    }
    std::printf("%s: %d x %d, %zu frames\n", dir.c_str(), scene.truth.camera.widthPx, scene.truth.camera.heightPx,
                frames.size());
    std::fflush(stdout);
  }
  return 0;
}

// The worker on scan directories, the camera a ReplaySource (as alacsd --replay): the
// cycle (dominated here by the PNG decode of every full frame on the worker thread) and
// the peak resident memory of the process, which holds no simulator.
int replayCycle(const Options& o) {
  MonotonicClock clock;
  MonotonicSleeper sleeper;
  motion::SlideLimits limits;
  image::LleParams lle;
  localize::ScanParams scanParams = scanParamsOf(o);
  const std::string modes = o.modes.empty() ? "stop-and-go" : o.modes;
  const double startMb = app::peakResidentMb();
  int widthPx = 0, heightPx = 0;
  double setupMb = 0.0;
  for (const char* mode : {"stop-and-go", "continuous", "scan-all"}) {
    if (modes != "all" && modes != mode && !(modes == "both" && std::strcmp(mode, "scan-all") != 0)) continue;
    std::vector<Trial> trials;
    for (size_t d = 0; d < o.dirs.size(); ++d) {
      const std::string& dir = o.dirs[d];
      Result<replay::ScanManifest> m = replay::readManifest(dir);
      if (!m) {
        std::fprintf(stderr, "alacs_cycle: %s\n", m.status().toString().c_str());
        return 1;
      }
      Result<geometry::Calibration> cal = replay::loadScanCalibration(dir, *m);
      if (!cal || !m->scan.roughMm) {
        std::fprintf(stderr, "alacs_cycle: %s: %s\n", dir.c_str(),
                     cal ? "the manifest has no rough position" : cal.status().toString().c_str());
        return 1;
      }
      widthPx = m->scan.widthPx;
      heightPx = m->scan.heightPx;
      std::optional<sim::SimApple> truth;
      if (!m->scan.truthFile.empty()) {
        if (Result<sim::SimScene> scene = sim::loadScene(dir + "/" + m->scan.truthFile)) {
          if (const sim::SimApple* a = scene->apple(m->scan.targetId)) truth = *a;
        }
      }
      const localize::Localizer loc(*cal, lle, scanParams);
      Result<localize::ScanPlan> plan = loc.plan(*m->scan.roughMm, limits.strokeMm);
      if (!plan) continue;
      sim::SimSlide slide(clock, limits.stepsPerMm, limits.strokeMm, 0.0);
      ports::FakeDigitalOut laserLine(clock);
      app::LaserGuard laser(laserLine, clock, 250 * kNsPerMs);
      Result<std::unique_ptr<replay::ReplaySource>> source = replay::ReplaySource::open(
          dir, clock, [&] { return laserLine.level(); }, [&] { return slide.positionMm(); });
      if (!source) {
        std::fprintf(stderr, "alacs_cycle: %s\n", source.status().toString().c_str());
        return 1;
      }
      replay::ReplaySource* rs = source->get();
      app::WorkerDeps deps = workerDeps(clock, sleeper, limits, slide, laser, *rs);
      deps.capture.exposureUs = m->frames.front().exposureUs;
      deps.frameSlideMm = [rs] { return rs->lastSlideMm(); };
      const int efd = ::eventfd(0, EFD_CLOEXEC);
      app::ScanWorker worker(deps, loc, efd);
      if (setupMb == 0.0) setupMb = app::peakResidentMb();
      app::WorkerJob job;
      if (std::strcmp(mode, "scan-all") == 0) {
        const survey::SurveyParams sp;
        job.kind = app::WorkerJob::Kind::kScanAll;
        job.survey.emplace(*cal, lle, scanParams, sp);
        job.surveyStopsMm = survey::surveyStops(limits.strokeMm, sp);
      } else {
        job.kind = app::WorkerJob::Kind::kLocalize;
        job.localize.mode = std::strcmp(mode, "continuous") == 0 ? protocol::ScanMode::kContinuous
                                                                  : protocol::ScanMode::kStopAndGo;
        job.localize.roughMm = *m->scan.roughMm;
        job.plan = *plan;
      }
      const int c = static_cast<int>(d);
      const double parkMm = parkFor(c, *plan, limits.strokeMm);
      const Trial t = timeJob(worker, efd, clock, parkMm, job, truth ? &*truth : nullptr);
      if (o.verbose)
        std::printf("    %s %s: cycle %4.0f ms, tail %5.1f ms, %s, centre error %.2f mm, peak so far %.1f MB\n", mode,
                    dir.c_str(), t.cycleMs, t.tailMs, t.ok ? "found" : "not found", t.centreErrMm, app::peakResidentMb());
      trials.push_back(t);
      ::close(efd);
    }
    report(mode, trials, std::strcmp(mode, "scan-all") != 0);
  }
  std::printf("  frames %d x %d (%.1f MP, %.1f MB as BGR8) | peak resident memory (VmHWM) %.1f MB: %.1f MB at start, "
              "%.1f MB with the worker set up; resident now %.1f MB\n",
              widthPx, heightPx, widthPx * static_cast<double>(heightPx) / 1e6,
              3.0 * widthPx * static_cast<double>(heightPx) / (1024.0 * 1024.0), app::peakResidentMb(), startMb, setupMb,
              app::residentMb());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  app::mapLargeBlocks();  // as alacsd
  Options o;
  CLI::App app("The localize cycle of the real scan worker on this machine's clock; --export and --replay measure "
               "the peak memory with real-size frames (docs/daemon.md).\n"
               "  alacs_cycle [--cases N] [--mode stop-and-go|continuous|both] [--width W --height H] [--verbose]\n"
               "  alacs_cycle --export DIR [--cases N] [--width W --height H]\n"
               "  alacs_cycle --replay [--mode stop-and-go|continuous|scan-all|both|all] [--verbose] DIR...",
               "alacs_cycle");
  app.add_option("--cases", o.cases, "orchard cases (at least 1)")->capture_default_str();
  app.add_option("--mode", o.modes, "stop-and-go|continuous|both, with --replay also scan-all|all (default: both; with --replay stop-and-go)")
      ->check(CLI::IsMember({"stop-and-go", "continuous", "both", "scan-all", "all"}));
  app.add_option("--width", o.widthPx, "frame width, px (with --height)");
  app.add_option("--height", o.heightPx, "frame height, px (with --width)");
  app.add_flag("--verbose", o.verbose, "every trial");
  app.add_option("--log-level", o.logLevel, "the worker's log, as alacsd's (debug: each frame's rows and points)")
      ->check(CLI::IsMember({"error", "warning", "info", "debug"}))
      ->capture_default_str();
  app.add_option("--follow-up-max-stops", o.followUpMaxStops, "0: no second pass (default: ScanParams')");
  app.add_option("--follow-up-unseen-max-stops", o.followUpUnseenMaxStops,
                 "the second pass's cap when the first saw nothing of the fruit (default: ScanParams')");
  app.add_option("--follow-up-diameter-sigma-mm", o.followUpDiameterSigmaMm, "0: lines only (default: ScanParams')");
  app.add_option("--stops", o.stops, "stops of the first pass (default: ScanParams')");
  app.add_option("--spacing-mm", o.spacingMm, "spacing of the first pass's stops (default: ScanParams')");
  app.add_option("--warm-up", o.warmUp,
                 "1: one untimed scan of each case before the timed one (the worker's steady state: a sweep then "
                 "meters during its run-up), 0: each timed scan the worker's first")
      ->capture_default_str();
  app.add_option("--metering", o.metering, "1: meter the exposure from laser-off frames (the daemon's default), 0: off")
      ->capture_default_str();
  app.add_option("--bright-analogue-gain", o.brightAnalogueGain,
                 "metering.bright_analogue_gain: the laser frames' gain in sun (0: never changed; default: the "
                 "daemon's)")
      ->check(CLI::Range(0.0, 64.0));
  app.add_option("--second-exposure", o.secondExposure,
                 "metering.second_exposure_factor: in sun each stop exposed again this much longer (0: never; "
                 "default: the daemon's)")
      ->check(CLI::Range(0.0, 8.0));
  app.add_option("--lighting", o.lighting, "lab|overcast|direct|sun")->capture_default_str();
  app.add_option("--world", o.world, "benchmark|benchmark-hard|holdout: whose orchard cases")->capture_default_str();
  app.add_option("--exposure-x", o.exposureX,
                 "the exposure: this × the auto exposure, at most 3000 us (the hard "
                 "worlds fix it at 1.6-2.6 × in sun)")
      ->capture_default_str();
  app.add_flag("--virtual-time", o.virtualTime,
               "virtual time with a modelled sensor (--fps) in place of the simulator's render: the cycle of the "
               "sensor and the slide, whatever the simulator costs");
  app.add_option("--fps", o.fps, "--virtual-time: the sensor's free-running frame rate")
      ->capture_default_str()
      ->check(CLI::Range(1.0, 1000.0));
  app.add_option("--line-time-us", o.lineTimeUs,
                 "a rolling shutter: the sensor's line time (0: a global shutter; a 30 fps sensor 1536 rows high: "
                 "21.7)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 1000.0));
  app.add_option("--worker-line-time", o.workerLineTime,
                 "1: the worker is told the line time, 0: not (to see the error)")
      ->capture_default_str();
  app.add_option("--nearest-frame", o.nearestFrame,
                 "--virtual-time: 1: a sweep asks for the sensor's frame nearest each stop, once it knows the sensor's "
                 "clock (alacsd's way), 0: for the next frame as the slide passes each stop (to compare)")
      ->capture_default_str();
  app.add_option("--learn-pace", o.learnPace,
                 "1: homing takes laser-off frames until the camera's pace is known, as alacsd does (default); 0: the "
                 "first scan after a start paces itself on its own metering frame")
      ->capture_default_str()
      ->check(CLI::Range(0, 1));
  app.add_option("--laser-timing", o.laserTiming,
                 "--virtual-time: frame-clock (the daemon's default: the laser just around each frame) or request "
                 "(on from the request to the delivery)")
      ->check(CLI::IsMember({"frame-clock", "request"}))
      ->capture_default_str();
  app.add_option("--laser-lead-us", o.laserLeadUs, "--virtual-time, frame-clock: the laser's lead before and after")
      ->check(CLI::Range(0.0, 10000.0))
      ->capture_default_str();
  app.add_option("--global-shutter", o.globalShutter,
                 "--virtual-time, frame-clock: 1: the camera is told the sensor has a global shutter "
                 "(camera.global_shutter); 0: not (the laser covers any readout)")
      ->check(CLI::Range(0, 1))
      ->capture_default_str();
  app.add_option("--export", o.exportDir, "write the orchard scans as scan directories into DIR");
  app.add_flag("--replay", o.replay, "run the worker on the scan directories DIR...");
  app.add_option("DIR", o.dirs, "scan directories (--replay)");
  if (const int rc = tools::parseCommandLine(app, argc, argv); rc >= 0) return rc;
  o.cases = std::max(1, o.cases);
  if ((o.widthPx > 0) != (o.heightPx > 0)) return tools::usageError(app, "--width and --height go together");
  if (o.brightAnalogueGain > 0.0 && o.brightAnalogueGain < 1.0)
    return tools::usageError(app, "--bright-analogue-gain: 0 (never changed) or 1..64 (1: the sensor's least)");
  if (o.secondExposure > 0.0 && o.secondExposure < 1.25)
    return tools::usageError(app, "--second-exposure: 0 (never) or 1.25..8");
  if (o.replay && o.dirs.empty()) return tools::usageError(app, "--replay needs DIR...");
  if (o.replay && !o.exportDir.empty()) return tools::usageError(app, "--replay and --export exclude each other");
  if (!o.replay && !o.dirs.empty()) return tools::usageError(app, "DIR... only with --replay");
  if (o.virtualTime && (o.replay || !o.exportDir.empty()))
    return tools::usageError(app, "--virtual-time is for the simulated cycle (not --replay or --export)");
  log::Level level = log::Level::kInfo;
  (void)log::parseLevel(o.logLevel.c_str(), &level);
  log::setLevel(level);
  if (!o.exportDir.empty()) return exportScans(o);
  if (o.replay) return replayCycle(o);
  return simulatedCycle(o);
}
