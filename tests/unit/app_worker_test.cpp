// The scan worker and its frame pipeline in virtual time, with the simulated slide
// (counting STEP pulses) and a camera that returns dark frames. The worker's job thread and
// its sweep's step thread take turns on one VirtualTimeline (common/virtual_timeline.h),
// so every time and position below is exact, however loaded the machine; what the tests do
// "during" a move (send a job, cancel) they do from the STEP line, at a given step.
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <catch2/catch.hpp>
#include <functional>
#include <mutex>
#include <vector>

#include "app/frame_pipeline.h"
#include "app/laser_guard.h"
#include "app/scan_worker.h"
#include "common/virtual_timeline.h"
#include "ports/digital_io_fake.h"
#include "ports/frame_slot_source.h"
#include "sim/orchard.h"
#include "sim/scene.h"
#include "sim/sim_camera.h"
#include "sim/sim_slide.h"

using namespace alacs;

namespace {

// Returns dark frames after the exposure time, slept on the worker's sleeper.
class DarkCamera final : public ports::FrameSource {
 public:
  DarkCamera(const Clock& clock, Sleeper& sleeper, int widthPx, int heightPx)
      : clock_(clock), sleeper_(sleeper), frame_(static_cast<size_t>(widthPx) * static_cast<size_t>(heightPx) * 3U, 0) {
    view_ = {frame_.data(), widthPx, heightPx, static_cast<size_t>(widthPx) * 3U, image::PixelFormat::kBgr888};
  }
  const char* name() const override { return "dark"; }
  std::function<void()> onCapture;   // called on the worker thread as each exposure begins
  std::vector<int64_t> requestedUs;  // the exposure of each capture asked for
  int captures = 0;                  // captures asked for, failed ones too
  std::vector<double> requestedGain;  // and its analogue gain (0: the camera's own)
  double ownGain = 0.0;               // the gain reported when none is asked for (0: none reported)
  Status failure;                     // not ok: every capture fails with it, before any exposure
  // The red of every pixel from now on (BGR888: the third byte), whatever the exposure.
  void setRed(uint8_t red) {
    for (size_t i = 2; i < frame_.size(); i += 3) frame_[i] = red;
  }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks) override {
    ++captures;
    if (!failure) return failure;
    if (Status s = hooks.beginNow(); !s) return s;
    if (onCapture) onCapture();
    requestedUs.push_back(r.exposureUs);
    requestedGain.push_back(r.analogueGain);
    const TimeNs startNs = clock_.now();
    sleeper_.sleepUntil(startNs + r.exposureUs * kNsPerUs);
    hooks.endNow();
    ports::CapturedFrame f;
    f.view = view_;
    f.info.exposureStartNs = startNs;
    f.info.exposureUs = r.exposureUs;
    f.info.analogueGain = r.analogueGain > 0.0 ? r.analogueGain : ownGain;
    return f;
  }
  const Clock& clock_;
  Sleeper& sleeper_;
  std::vector<uint8_t> frame_;
  image::ImageView view_;
};

// The slide's STEP input, with a log of where the slide was after each step and when, and
// a hook called on the stepping thread after each step (to act at an exact point of a move).
class LoggedStepLine final : public ports::DigitalOut {
 public:
  struct Step {
    TimeNs timeNs;
    int64_t positionSteps;  // after the step
  };
  LoggedStepLine(sim::SimSlide& slide, const Clock& clock) : slide_(slide), clock_(clock) {}
  std::vector<Step> steps() const {
    std::lock_guard<std::mutex> lock(mu_);
    return steps_;
  }
  // The slide's position at `t` (after the steps at t), from the log; `beforeSteps` before any.
  int64_t positionAt(TimeNs t, int64_t beforeSteps) const {
    int64_t at = beforeSteps;
    for (const Step& s : steps())
      if (s.timeNs <= t) at = s.positionSteps;
    return at;
  }
  std::function<void(int64_t positionSteps)> onStep;  // set before the job starts

 private:
  Status doSet(bool asserted) override {
    Status s = slide_.stepInput().set(asserted);
    if (!s || !asserted) return s;
    const int64_t at = slide_.positionSteps();
    {
      std::lock_guard<std::mutex> lock(mu_);
      steps_.push_back({clock_.now(), at});
    }
    if (onStep) onStep(at);
    return s;
  }
  sim::SimSlide& slide_;
  const Clock& clock_;
  mutable std::mutex mu_;
  std::vector<Step> steps_;
};

// Everything a worker needs, the slide slowed down so that its braking lasts 0.2 s.
struct Rig {
  explicit Rig(double startMm)
      : slide(time, limits().stepsPerMm, limits().strokeMm, startMm),
        step(slide, time),
        laser(laserLine, time, 250 * kNsPerMs) {
    deps.clock = &time;
    deps.sleeper = &time;
    deps.limits = limits();
    deps.stepLines = {&step, &slide.dirInput(), &slide.homeSwitch(), &slide.endSwitch()};
    deps.enable = &slide.enableInput();
    deps.laser = &laser;
    deps.camera = &camera;
    deps.capture.exposureUs = 1000;
    // The tests follow a worker's first scans as they go without the camera's pace learnt
    // at homing (as when the camera failed then): the metering before the first sweep, its
    // pace from the metering frame. The tests of that learning switch it on.
    deps.learnPaceAtHome = false;
    efd = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  }
  ~Rig() { ::close(efd); }
  // A metering that halves `exposureUs` in two laser-off frames: red 200 DN at it, the
  // target 100 DN, and the ambient high enough for the laser-off frame to be subtracted.
  void meterHalving(int64_t exposureUs) {
    deps.capture.exposureUs = exposureUs;
    deps.metering.targetDn = 100;
    deps.metering.subtractAboveDn = 50;
    camera.setRed(200);
  }
  static motion::SlideLimits limits() {
    motion::SlideLimits l;
    l.maxSpeedMmPerS = 100.0;
    l.accelMmPerS2 = 500.0;  // braking from 100 mm/s: 10 mm, 0.2 s
    return l;
  }
  // The worker's next event, as the daemon's loop waits for it: on the eventfd. The limit
  // is in real time and only keeps a broken worker from hanging the test run; nothing
  // here depends on how fast the machine is.
  // Homes `w` (a HOME job, which must succeed); its event.
  std::optional<app::WorkerEvent> home(app::ScanWorker& w);
  std::optional<app::WorkerEvent> next(app::ScanWorker& w, int hangLimitMs = 60000) {
    while (true) {
      if (std::optional<app::WorkerEvent> ev = w.takeEvent()) return ev;
      pollfd p{efd, POLLIN, 0};
      if (::poll(&p, 1, hangLimitMs) != 1) return std::nullopt;
      uint64_t n = 0;
      [[maybe_unused]] ssize_t r = ::read(efd, &n, sizeof n);
    }
  }
  VirtualTimeline time;
  sim::SimSlide slide;
  LoggedStepLine step;
  ports::FakeDigitalOut laserLine{time};
  app::LaserGuard laser;
  DarkCamera camera{time, time, 64, 48};
  app::WorkerDeps deps;
  int efd = -1;
};

app::WorkerJob jobOf(app::WorkerJob::Kind kind, double mm = 0.0) {
  app::WorkerJob j;
  j.kind = kind;
  j.moveToMm = mm;
  return j;
}

// A stop-and-go LOCALIZE at 10 and 20 mm over a 32 px square ROI.
app::WorkerJob twoStopScan() {
  app::WorkerJob scan = jobOf(app::WorkerJob::Kind::kLocalize);
  scan.localize.mode = protocol::ScanMode::kStopAndGo;
  scan.plan.stopsMm = {10.0, 20.0};
  scan.plan.roi = {0, 0, 32, 32};
  return scan;
}

// A continuous LOCALIZE through 20, 25 and 30 mm over a 32 px square ROI.
app::WorkerJob threeStopSweep() {
  app::WorkerJob scan = jobOf(app::WorkerJob::Kind::kLocalize);
  scan.localize.mode = protocol::ScanMode::kContinuous;
  scan.plan.stopsMm = {20.0, 25.0, 30.0};
  scan.plan.roi = {0, 0, 32, 32};
  return scan;
}

std::optional<app::WorkerEvent> Rig::home(app::ScanWorker& w) {
  w.submit(jobOf(app::WorkerJob::Kind::kHome));
  std::optional<app::WorkerEvent> ev = next(w);
  REQUIRE(ev);
  REQUIRE(ev->status.isOk());
  return ev;
}

}  // namespace

TEST_CASE("A continuous scan's result is out while the slide brakes; a job sent then runs once it is at rest",
          "[app][worker]") {
  Rig rig(2.0);
  const motion::SlideLimits lim = Rig::limits();
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  std::optional<app::WorkerEvent> ev = rig.home(worker);
  REQUIRE(rig.slide.positionSteps() == 0);
  const size_t homingSteps = rig.step.steps().size();
  CHECK(homingSteps == static_cast<size_t>(lim.stepsFor(2.0)));

  // Sent from the STEP line while the slide brakes (at 35 mm, past the last stop's 30).
  const int64_t brakingAt = lim.stepsFor(35.0);
  bool sent = false, busyBefore = true, busyAfter = false;
  rig.step.onStep = [&](int64_t at) {
    if (sent || at != brakingAt) return;
    sent = true;
    busyBefore = worker.busy();
    CHECK(worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 10.0)));
    busyAfter = worker.busy();
  };
  const app::WorkerJob scan = threeStopSweep();
  worker.submit(scan);
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kLocalize);
  CHECK(ev->status.isOk());  // dark frames: no object, but the scan worked
  CHECK(!ev->afterResult);
  REQUIRE(ev->exposures.size() == 3);
  // Each exposure is centred on its stop at cruise speed: the slide is at the stop, to
  // a step, half-way through it.
  for (size_t i = 0; i < 3; ++i) {
    const app::ExposureWindow& x = ev->exposures[i];
    CHECK(x.endNs - x.startNs == 1000 * kNsPerUs);
    CHECK(x.endToldNs == x.endNs);  // the fake camera tells the end when it is (virtual time)
    const TimeNs mid = (x.startNs + x.endNs) / 2;
    CHECK(std::llabs(rig.step.positionAt(mid, 0) - lim.stepsFor(scan.plan.stopsMm[i])) <= 1);
  }
  // The result is out the moment the last exposure ends (the image work takes no virtual
  // time), the slide just past the last stop, still at cruise speed: it brakes afterwards.
  CHECK(ev->doneNs == ev->exposures.back().endNs);
  const TimeNs resultNs = ev->doneNs;
  const int64_t atResult = rig.step.positionAt(resultNs, 0);
  CHECK(atResult > lim.stepsFor(30.0));
  CHECK(atResult <= lim.stepsFor(30.0 + 0.05) + 1);  // half an exposure's travel at 100 mm/s

  // The job sent while it braked: the result was out (not busy), then queued (busy); it
  // moved the slide back only once the braking had ended at 30 + 0.1 + 0.5 + 10 mm.
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(sent);
  CHECK(!busyBefore);
  CHECK(busyAfter);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kMoveTo);
  CHECK(ev->status.isOk());
  const std::vector<LoggedStepLine::Step> steps = rig.step.steps();
  size_t peak = homingSteps;
  while (peak + 1 < steps.size() && steps[peak + 1].positionSteps > steps[peak].positionSteps) ++peak;
  CHECK(steps[peak].positionSteps == lim.stepsFor(40.6));
  CHECK(steps[peak].timeNs > resultNs);
  // After the peak, only the move back: every step one down, the first after the last up.
  REQUIRE(peak + 1 < steps.size());
  CHECK(steps[peak + 1].timeNs > steps[peak].timeNs);
  bool onlyBack = true;
  for (size_t k = peak + 1; k < steps.size(); ++k)
    onlyBack = onlyBack && steps[k].positionSteps == steps[k - 1].positionSteps - 1;
  CHECK(onlyBack);
  CHECK(rig.slide.positionSteps() == lim.stepsFor(10.0));
  CHECK(rig.slide.ignoredSteps() == 0);
  CHECK(worker.homed());
  CHECK(!worker.takeEvent());  // no second event: the braking completed
}

TEST_CASE("The worker shows when the frame read in flight began, for the frame source's deadline", "[app][worker]") {
  Rig rig(2.0);
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  std::optional<app::WorkerEvent> ev = rig.home(worker);
  CHECK(worker.frameReadSinceNs() == 0);
  struct Seen {
    TimeNs sinceNs;  // what the sensor would read during the capture
    TimeNs nowNs;    // when the capture began
  };
  std::vector<Seen> seen;
  rig.camera.onCapture = [&] { seen.push_back({worker.frameReadSinceNs(), rig.time.now()}); };
  const app::WorkerJob scan = twoStopScan();
  worker.submit(scan);
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->status.isOk());
  REQUIRE(seen.size() >= 2);  // one read per stop (and per stop of a second pass, if any)
  // One read per stop, and the laser-off frames the exposure was metered on before.
  REQUIRE(seen.size() == ev->exposures.size() + static_cast<size_t>(ev->laserOffFrames));
  for (const Seen& s : seen) {
    CHECK(s.sinceNs > 0);
    CHECK(s.sinceNs == s.nowNs);
  }
  CHECK(seen[1].nowNs > seen[0].nowNs);
  CHECK(worker.frameReadSinceNs() == 0);  // none in flight once the reads returned
}

TEST_CASE(
    "Before the stops, the worker meters the exposure on laser-off frames and hands the pipeline the "
    "laser-off frame to subtract",
    "[app][worker]") {
  Rig rig(2.0);
  rig.deps.metering.targetDn = 100;
  rig.deps.metering.subtractAboveDn = 50;
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  std::optional<app::WorkerEvent> ev = rig.home(worker);
  rig.camera.setRed(200);  // 200 DN at the configured 1000 us: 500 us brings it to 100
  struct Seen {
    bool laser;
    size_t steps;  // STEP pulses so far
  };
  std::vector<Seen> seen;
  rig.camera.requestedUs.clear();
  rig.camera.onCapture = [&] { seen.push_back({rig.laserLine.level(), rig.step.steps().size()}); };
  const size_t stepsBefore = rig.step.steps().size();
  const app::WorkerJob scan = twoStopScan();
  worker.submit(scan);
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->status.isOk());
  CHECK(ev->exposureUs == 500);
  CHECK(ev->laserOffFrames == 2);  // metered at 1000 us, then the laser-off frame at 500 us
  CHECK(ev->laserOffSubtracted);
  REQUIRE(seen.size() == 2 + ev->exposures.size());
  REQUIRE(rig.camera.requestedUs.size() == seen.size());
  // The laser-off frames come first, before the slide moves, with the laser off.
  for (size_t i = 0; i < 2; ++i) {
    CHECK_FALSE(seen[i].laser);
    CHECK(seen[i].steps == stepsBefore);
  }
  CHECK(rig.camera.requestedUs[0] == 1000);
  CHECK(rig.camera.requestedUs[1] == 500);
  // Every stop at the metered exposure, the laser on only during its exposure.
  for (size_t i = 2; i < seen.size(); ++i) {
    CHECK(seen[i].laser);
    CHECK(rig.camera.requestedUs[i] == 500);
  }
  for (const app::ExposureWindow& x : ev->exposures) CHECK(x.endNs - x.startNs == 500 * kNsPerUs);

  // Metering off: the configured exposure, no laser-off frame.
  rig.deps.metering.enabled = false;
  app::ScanWorker plain(rig.deps, loc, rig.efd);
  plain.submit(jobOf(app::WorkerJob::Kind::kHome));
  REQUIRE(rig.next(plain));
  seen.clear();
  plain.submit(scan);
  ev = rig.next(plain);
  REQUIRE(ev);
  CHECK(ev->exposureUs == 0);
  CHECK(ev->laserOffFrames == 0);
  CHECK_FALSE(ev->laserOffSubtracted);
  CHECK(seen.size() == ev->exposures.size());
  for (const Seen& s : seen) CHECK(s.laser);
}

TEST_CASE("No stop finds a line: NOT_FOUND, named BRIGHT_AMBIENT when the metering found the ambient bright",
          "[app][worker]") {
  Rig rig(2.0);
  rig.meterHalving(1000);  // red 200 DN at 1000 us, no laser line anywhere: 200 DN/ms
  // The calibration's frame size: each stop's frame is searched and holds nothing (an
  // empty observation, as a real scan's); the rig's small frames are refused (none).
  DarkCamera full(rig.time, rig.time, 2048, 1536);
  full.setRed(200);
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  // Stop-and-go meters before the first move, a sweep during its run-up.
  for (const app::WorkerJob& scan : {twoStopScan(), threeStopSweep()}) {
    for (const auto& [camera, barDnPerMs] : {std::pair{&rig.camera, 250.0}, std::pair{&rig.camera, 150.0},
                                             std::pair{&full, 250.0}, std::pair{&full, 150.0}}) {
      const bool bright = barDnPerMs < 200.0;
      INFO((camera == &full ? "full frames" : "refused frames")
           << ", bright above " << barDnPerMs << " DN/ms, " << scan.plan.stopsMm.size() << " stops");
      rig.deps.camera = camera;
      rig.deps.metering.brightDnPerMs = barDnPerMs;
      app::ScanWorker worker(rig.deps, loc, rig.efd);
      rig.home(worker);
      worker.submit(scan);
      std::optional<app::WorkerEvent> ev = rig.next(worker);
      REQUIRE(ev);
      CHECK(ev->status.isOk());  // the scan worked; it found nothing
      CHECK(ev->exposures.size() == scan.plan.stopsMm.size());
      CHECK(ev->resultStatus == protocol::ResultStatus::kNotFound);
      CHECK(ev->brightAmbient == bright);
      CHECK(ev->resultReason ==
            (bright ? protocol::ResultReason::kBrightAmbient : protocol::ResultReason::kNoLinesInGate));
    }
  }
}

TEST_CASE("In sun the frame subtracted and the laser frames are taken at the least gain, exposed longer",
          "[app][worker]") {
  Rig rig(2.0);
  rig.meterHalving(1000);  // red 200 DN at 1000 us: 200 DN/ms, bright above 150
  rig.deps.metering.brightDnPerMs = 150.0;
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  // A camera at gain 2 that reports it: the target's 100 DN takes 500 us at gain 2, so
  // 1000 us (the longest) at gain 1. One that does not report its gain keeps it.
  for (const double ownGain : {2.0, 0.0}) {
    INFO("the camera reports gain " << ownGain);
    rig.camera.ownGain = ownGain;
    rig.camera.requestedUs.clear();
    rig.camera.requestedGain.clear();
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    rig.camera.requestedUs.clear();
    rig.camera.requestedGain.clear();
    worker.submit(twoStopScan());
    std::optional<app::WorkerEvent> ev = rig.next(worker);
    REQUIRE(ev);
    CHECK(ev->brightAmbient);
    CHECK(ev->laserOffSubtracted);
    if (ownGain > 0.0) {
      CHECK(ev->analogueGain == 1.0);
      CHECK(ev->exposureUs == 1000);
      // The metering frame at the camera's own gain, then the one to subtract and the two
      // stops' at gain 1.
      CHECK(rig.camera.requestedUs == std::vector<int64_t>{1000, 1000, 1000, 1000});
      CHECK(rig.camera.requestedGain == std::vector<double>{0.0, 1.0, 1.0, 1.0});
    } else {
      CHECK(ev->analogueGain == 0.0);
      CHECK(ev->exposureUs == 500);
      CHECK(rig.camera.requestedUs == std::vector<int64_t>{1000, 500, 500, 500});
      CHECK(rig.camera.requestedGain == std::vector<double>{0.0, 0.0, 0.0, 0.0});
    }
  }
}

TEST_CASE("In sun each stop of a stop-and-go scan is exposed twice: metered, then longer by the factor",
          "[app][worker]") {
  Rig rig(2.0);
  rig.meterHalving(1000);  // red 200 DN at 1000 us: 200 DN/ms, bright above 150; 500 us chosen
  rig.deps.metering.brightDnPerMs = 150.0;
  rig.deps.metering.secondExposureFactor = 2.0;
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  std::vector<bool> seen;  // the laser's level at each capture
  rig.camera.onCapture = [&] { seen.push_back(rig.laserLine.level()); };
  for (const double barDnPerMs : {150.0, 250.0}) {
    const bool bright = barDnPerMs < 200.0;
    INFO((bright ? "sun" : "not bright"));
    rig.deps.metering.brightDnPerMs = barDnPerMs;
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    seen.clear();
    rig.camera.requestedUs.clear();
    worker.submit(twoStopScan());
    std::optional<app::WorkerEvent> ev = rig.next(worker);
    REQUIRE(ev);
    CHECK(ev->status.isOk());
    CHECK(ev->exposureUs == 500);
    REQUIRE(ev->laserOffSubtracted);
    const std::vector<int64_t> want = bright ? std::vector<int64_t>{1000, 500, 1000, 500, 1000, 500, 1000}
                                             // metering, two laser-off, 2 stops × 2
                                             : std::vector<int64_t>{1000, 500, 500, 500};
    CHECK(rig.camera.requestedUs == want);
    CHECK(ev->secondExposureUs == (bright ? 1000 : 0));
    CHECK(ev->laserOffFrames == (bright ? 3 : 2));
    // The laser is on for each laser frame (and only then: LaserGuard), off for the others.
    const size_t offFrames = static_cast<size_t>(ev->laserOffFrames);
    REQUIRE(seen.size() == want.size());
    for (size_t i = 0; i < seen.size(); ++i) CHECK(seen[i] == (i >= offFrames));
    REQUIRE(ev->exposures.size() == want.size() - offFrames);
    for (size_t i = 0; i < ev->exposures.size(); ++i)
      CHECK(ev->exposures[i].endNs - ev->exposures[i].startNs == want[offFrames + i] * kNsPerUs);
    // Progress counts stops, not frames.
    CHECK(worker.progress().stopsDone == 2);
  }
}

TEST_CASE("In sun a sweep takes each stop's second exposure at the next frame, paced for two captures a stop",
          "[app][worker]") {
  Rig rig(2.0);
  rig.meterHalving(1000);  // red 200 DN at 1000 us: 200 DN/ms; 500 us chosen
  rig.deps.metering.secondExposureFactor = 2.0;
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  std::vector<bool> seen;  // the laser's level at each capture
  rig.camera.onCapture = [&] { seen.push_back(rig.laserLine.level()); };
  for (const double barDnPerMs : {250.0, 150.0}) {
    const bool bright = barDnPerMs < 200.0;
    rig.deps.metering.brightDnPerMs = barDnPerMs;
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    // The first sweep meters before it starts; the second while it runs up to its first
    // stop, paced as the first's metering found.
    for (int scan = 0; scan < 2; ++scan) {
      INFO((bright ? "sun" : "not bright") << ", sweep " << scan + 1);
      seen.clear();
      rig.camera.requestedUs.clear();
      worker.submit(threeStopSweep());
      std::optional<app::WorkerEvent> ev = rig.next(worker);
      REQUIRE(ev);
      CHECK(ev->status.isOk());
      CHECK(ev->secondExposureUs == (bright ? 1000 : 0));
      const size_t offFrames = static_cast<size_t>(ev->laserOffFrames);
      std::vector<int64_t> want(rig.camera.requestedUs.begin(),
                                rig.camera.requestedUs.begin() + static_cast<std::ptrdiff_t>(offFrames));
      for (int stop = 0; stop < 3; ++stop) {
        want.push_back(500);
        if (bright) want.push_back(1000);
      }
      CHECK(rig.camera.requestedUs == want);
      REQUIRE(seen.size() == want.size());
      for (size_t i = 0; i < seen.size(); ++i) CHECK(seen[i] == (i >= offFrames));
      CHECK(worker.progress().stopsDone == 3);
      // Each frame placed where the slide was at its mid-exposure: the stops' on them, each
      // second exposure past its stop in the sweep's direction, before the next stop.
      REQUIRE(ev->exposures.size() == want.size() - offFrames);
      const size_t perStop = bright ? 2 : 1;
      const double dir = ev->exposures.back().slideMm > ev->exposures.front().slideMm ? 1.0 : -1.0;
      for (size_t k = 0; k < 3; ++k) {
        const double stopMm = dir > 0 ? 20.0 + 5.0 * static_cast<double>(k) : 30.0 - 5.0 * static_cast<double>(k);
        CHECK(ev->exposures[k * perStop].slideMm == Approx(stopMm).margin(0.1));
        if (!bright) continue;
        const double pastMm = dir * (ev->exposures[k * perStop + 1].slideMm - stopMm);
        CHECK(pastMm > 0.01);
        CHECK(pastMm < 4.9);
      }
    }
  }
  // The sun comes out between two sweeps: the one that finds it meters in its run-up,
  // paced for one capture a stop, and takes no second exposure (and says so); the next does.
  rig.deps.metering.brightDnPerMs = 150.0;
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  rig.home(worker);
  for (const auto& [red, takes] :
       {std::pair{uint8_t{100}, 0}, std::pair{uint8_t{200}, 0}, std::pair{uint8_t{200}, 3}}) {
    rig.camera.setRed(red);  // 100 DN at 1000 us: 100 DN/ms, not bright; 200: bright
    rig.camera.requestedUs.clear();
    worker.submit(threeStopSweep());
    std::optional<app::WorkerEvent> ev = rig.next(worker);
    REQUIRE(ev);
    CHECK(ev->status.isOk());
    CHECK(ev->secondExposureUs == (takes > 0 ? 2 * ev->exposureUs : 0));
    CHECK(ev->exposures.size() == static_cast<size_t>(3 + takes));
  }
}

TEST_CASE("The frame pipeline merges a stop's second exposure into its first, or keeps it as a line of its own",
          "[app][worker]") {
  const int w = 2048, h = 1536;  // the default scene's camera
  std::vector<uint8_t> frame(static_cast<size_t>(w) * h * 3U, 0);
  const image::ImageView view{frame.data(), w, h, static_cast<size_t>(w) * 3U, image::PixelFormat::kBgr888};
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  Result<localize::ScanPlan> plan = loc.plan(sim::defaultScene().apples.front().centerMm, 200.0);
  REQUIRE(plan);
  const double s0 = plan->stopsMm.front();
  using E = app::FramePipeline::Exposure;
  app::FramePipeline pipeline;
  pipeline.setLaserOff(view, plan->roi, true);
  pipeline.setSecondLaserOff(view, plan->roi);
  pipeline.begin(loc, *plan);
  pipeline.push(view, s0);
  pipeline.push(view, s0, 0.0, E::kSecondMerged);        // the same stop: merged
  pipeline.push(view, s0 + 5.0, 0.0, E::kSecondMerged);  // taken elsewhere: a line of its own
  pipeline.push(view, s0 + 2.5, 0.0, E::kSecondLine);    // a sweep's: a line of its own
  const std::vector<localize::LineObservation> lines = pipeline.finish();
  REQUIRE(lines.size() == 3);
  CHECK(lines[0].slideMm == s0);
  CHECK(lines[1].slideMm == s0 + 5.0);
  CHECK(lines[2].slideMm == s0 + 2.5);
}

TEST_CASE("A sweep meters its exposure while the slide runs up to the first stop, or while it is positioned there",
          "[app][worker]") {
  // Long exposures, so that the metering lasts long enough for steps: 20 ms, then the laser-off
  // frame at 10 ms (red 200 DN at 20 ms, the target 100 DN). Stops at 20, 25 and 30 mm. With
  // no metering before it, a sweep meters before it starts; later ones expect the metering
  // to last as long as the last one (30 ms), and from 2 mm the run-up lasts 280 ms.
  struct Case {
    const char* name;
    double fromMm;       // where the slide waits for the scan
    bool movesMetering;  // the slide moves under the first scan's metering
    bool movesNext;      // and under the next one's, from the same place
  };
  for (const Case c : {Case{"runs up from 2 mm", 2.0, false, true},
                       Case{"positioned from 23 mm, inside the span", 23.0, true, true}}) {
    DYNAMIC_SECTION(c.name) {
      Rig rig(2.0);
      rig.meterHalving(20000);
      const motion::SlideLimits lim = Rig::limits();
      const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
      app::ScanWorker worker(rig.deps, loc, rig.efd);
      rig.home(worker);
      const app::WorkerJob scan = threeStopSweep();
      for (const bool moves : {c.movesMetering, c.movesNext}) {
        worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, c.fromMm));
        REQUIRE(rig.next(worker));
        struct Seen {
          bool laser;
          int64_t positionSteps;
        };
        std::vector<Seen> seen;
        rig.camera.onCapture = [&] { seen.push_back({rig.laserLine.level(), rig.slide.positionSteps()}); };
        worker.submit(scan);
        std::optional<app::WorkerEvent> ev = rig.next(worker);
        REQUIRE(ev);
        CHECK(ev->status.isOk());
        REQUIRE(ev->laserOffFrames == 2);
        CHECK(ev->exposureUs == 10000);
        REQUIRE(seen.size() == 2 + ev->exposures.size());
        // The laser-off frames with the laser off; the slide moving under them when the
        // metering overlaps the move (the first frame at the move's start, the second 20 ms
        // later), else at rest.
        CHECK_FALSE(seen[0].laser);
        CHECK_FALSE(seen[1].laser);
        CHECK((seen[1].positionSteps != seen[0].positionSteps) == moves);
        // Each laser frame at the metered exposure, centred on its stop to a step.
        REQUIRE(ev->exposures.size() == 3);
        for (size_t i = 0; i < 3; ++i) {
          const app::ExposureWindow& x = ev->exposures[i];
          CHECK(seen[2 + i].laser);
          CHECK(x.endNs - x.startNs == 10000 * kNsPerUs);
          const TimeNs mid = (x.startNs + x.endNs) / 2;
          CHECK(std::llabs(rig.step.positionAt(mid, 0) - lim.stepsFor(scan.plan.stopsMm[i])) <= 1);
        }
        CHECK(rig.laserLine.level() == false);
        rig.camera.onCapture = nullptr;
        // The slide brakes after the last frame; the next job waits for it.
      }
    }
  }
}

TEST_CASE(
    "A metering longer than the sweep's run-up starts the slide later: the first laser frame at most half a "
    "stop late",
    "[app][worker]") {
  // 80 ms at red 200 DN, then the laser-off frame at 40 ms: the metering lasts 120 ms, and
  // from 19.9 mm the run-up to the first stop (20 mm) lasts 20 ms. Overlapped at once, the
  // first frame would be 191 steps (4.8 mm) past its stop; the worker lets it be late by
  // half a stop's travel at most (2.5 mm at 100 mm/s, 25 ms) and starts the slide that
  // much later (2 steps past: the slide still speeds up).
  Rig rig(2.0);
  rig.meterHalving(80000);
  const motion::SlideLimits lim = Rig::limits();
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  rig.home(worker);
  const app::WorkerJob scan = threeStopSweep();
  for (int n = 0; n < 2; ++n) {  // the first scan meters before its sweep, the second during it
    worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 19.9));
    REQUIRE(rig.next(worker));
    worker.submit(scan);
    std::optional<app::WorkerEvent> ev = rig.next(worker);
    REQUIRE(ev);
    REQUIRE(ev->status.isOk());
    REQUIRE(ev->laserOffFrames == 2);
    REQUIRE(ev->exposures.size() == 3);
    const app::ExposureWindow& x = ev->exposures[0];
    const int64_t pastSteps = rig.step.positionAt((x.startNs + x.endNs) / 2, 0) - lim.stepsFor(scan.plan.stopsMm[0]);
    INFO("scan " << n << ": the first laser frame " << pastSteps << " steps past its stop");
    CHECK(pastSteps >= -1);
    CHECK(pastSteps <= (n == 0 ? 1 : lim.stepsFor(2.5) + 1));
  }
}

TEST_CASE("One job waits behind the running one; cancel() ends both, and a job sent afterwards runs", "[app][worker]") {
  Rig rig(2.0);
  const motion::SlideLimits lim = Rig::limits();
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  std::optional<app::WorkerEvent> ev = rig.home(worker);
  // At 1 mm into a 1.7 s move: one job queued behind it, a second refused, then cancel().
  const int64_t cancelAt = lim.stepsFor(1.0);
  bool acted = false, queued = false, refused = false;
  rig.step.onStep = [&](int64_t at) {
    if (acted || at != cancelAt) return;
    acted = true;
    queued = worker.submit(jobOf(app::WorkerJob::Kind::kHome));    // running: the queue is empty again
    refused = !worker.submit(jobOf(app::WorkerJob::Kind::kHome));  // bounded: one job waits, no more
    worker.cancel();
  };
  REQUIRE(worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 150.0)));
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(acted);
  CHECK(queued);
  CHECK(refused);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kMoveTo);
  CHECK(!ev->status.isOk());
  CHECK(ev->resultStatus == protocol::ResultStatus::kAborted);
  CHECK(rig.slide.positionSteps() == cancelAt);  // not one step after the cancel
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kHome);
  CHECK(!ev->status.isOk());  // queued before the cancel: cancelled too
  CHECK(rig.slide.positionSteps() == cancelAt);
  CHECK(!worker.homed());
  worker.submit(jobOf(app::WorkerJob::Kind::kHome));
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->status.isOk());
  CHECK(worker.homed());
  CHECK(rig.slide.positionSteps() == 0);
}

TEST_CASE("The frame pipeline keeps only the window's pages of a 5 MP frame resident, and frees them at the next scan",
          "[app][memory]") {
  const int w = 2592, h = 1944;
  std::vector<uint8_t> frame(static_cast<size_t>(w) * h * 3U, 0);
  const image::ImageView view{frame.data(), w, h, static_cast<size_t>(w) * 3U, image::PixelFormat::kBgr888};
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  localize::ScanPlan plan;
  plan.stopsMm = {50.0};
  plan.roi = {1000, 600, 200, 100};
  const long page = ::sysconf(_SC_PAGESIZE);
  const auto resident = [&](const image::ImageView& v) {
    const size_t bytes = v.strideBytes * static_cast<size_t>(v.height);
    std::vector<unsigned char> pages((bytes + static_cast<size_t>(page) - 1) / static_cast<size_t>(page));
    REQUIRE(::mincore(const_cast<uint8_t*>(v.data), bytes, pages.data()) == 0);
    size_t n = 0;
    for (unsigned char p : pages) n += p & 1U;
    return n;
  };
  app::FramePipeline pipeline;
  pipeline.begin(loc, plan);
  pipeline.push(view, 50.0);
  (void)pipeline.finish();
  const image::ImageView buffer = pipeline.lastFrame();
  REQUIRE(buffer.data != nullptr);
  REQUIRE(buffer.width == w);
  // 100 rows of 600 bytes, 7776 bytes apart: one or two pages each, of 3690 in the frame.
  const size_t n = resident(buffer);
  CHECK(n >= 100);
  CHECK(n <= 200);
  pipeline.begin(loc, plan);
  CHECK(resident(buffer) == 0);
}

namespace {
// A localize job on the twin's default scene, seen by the simulated camera (it renders the
// plan's window at the slide's position, with the laser as the laser line really was).
struct SceneRun {
  std::optional<app::WorkerEvent> event;
  std::vector<double> planStopsMm;
  std::vector<double> followUpMm;  // what the localizer asks for after the first pass
  std::vector<ports::Edge> laserEdges;
  double finalMm = 0.0;
  int homingCaptures = 0;       // frames the camera gave while the worker homed
  size_t homingLaserEdges = 0;  // the laser's switchings meanwhile
};

// A real sensor's timing: free-running with a frame period (ports::FrameSlotSource), and
// maybe a rolling shutter, which the worker may be told of (WorkerDeps::lineTimeNs).
struct SensorTiming {
  TimeNs framePeriodNs = 0;  // 0: the simulated camera as it is (exposes at once, a global shutter)
  TimeNs lineTimeNs = 0;     // a rolling shutter's
  bool workerToldLineTime = true;
  bool stampsExposureEnd = false;  // the timestamp marks the end of the exposure (Raspberry Pi's pipelines)
  bool workerToldStamp = true;
  ports::LaserTiming laser = ports::LaserTiming::kAtRequest;
  TimeNs laserLeadNs = 0;
  TimeNs stampJitterNs = 0;                // the timestamps scatter by up to this about the sensor's clock
  TimeNs workerJitterNs = 300 * kNsPerUs;  // WorkerDeps::frameClock.maxJitterNs (camera.frame_clock_jitter_us)
  bool learnPaceAtHome = false;            // WorkerDeps::learnPaceAtHome
};

// Counts the frames a source gives.
class CountingSource final : public ports::FrameSource {
 public:
  explicit CountingSource(ports::FrameSource& inner) : inner_(inner) {}
  const char* name() const override { return inner_.name(); }
  std::atomic<int> frames{0};

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks) override {
    Result<ports::CapturedFrame> f = inner_.capture(r, hooks);
    if (f) frames.fetch_add(1);
    return f;
  }
  ports::FrameSource& inner_;
};

// A source whose frame timestamps scatter about the sensor's clock by -1, 0 or +1 times
// `jitterNs`, by the frame's sequence (as a bench's kernel timestamps do under load).
class JitteredStampSource final : public ports::FrameSource {
 public:
  JitteredStampSource(ports::FrameSource& inner, TimeNs jitterNs) : inner_(inner), jitterNs_(jitterNs) {}
  const char* name() const override { return inner_.name(); }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks) override {
    Result<ports::CapturedFrame> f = inner_.capture(r, hooks);
    if (f) f->info.exposureStartNs += jitterNs_ * (static_cast<TimeNs>((f->info.sequence * 2654435761U) >> 7U) % 3 - 1);
    return f;
  }
  ports::FrameSource& inner_;
  TimeNs jitterNs_;
};

// A source whose frame timestamp is the end of the exposure (the start of readout).
class EndStampedSource final : public ports::FrameSource {
 public:
  explicit EndStampedSource(ports::FrameSource& inner) : inner_(inner) {}
  const char* name() const override { return inner_.name(); }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks) override {
    Result<ports::CapturedFrame> f = inner_.capture(r, hooks);
    if (f) f->info.exposureStartNs += f->info.exposureUs * kNsPerUs;
    return f;
  }
  ports::FrameSource& inner_;
};

// With a sensor timing, the slide has the daemon's motor limits (300 mm/s).
SceneRun localizeOnScene(const localize::ScanParams& sp, protocol::ScanMode mode, const SensorTiming& timing = {}) {
  Rig rig(2.0);
  const sim::SimScene scene = sim::defaultScene();
  sim::SimCamera camera(
      scene, rig.time, rig.time, [&] { return rig.laserLine.level(); }, [&] { return rig.slide.positionMm(); });
  camera.setLineTimeNs(timing.lineTimeNs);
  // A rolling shutter's rows are read out as they end (the simulated camera's).
  ports::FrameSlotSource slotted(camera, rig.time, rig.time, timing.framePeriodNs, timing.lineTimeNs == 0, timing.laser,
                                 timing.laserLeadNs, scene.truth.camera.heightPx,
                                 timing.workerToldLineTime ? timing.lineTimeNs : 0);
  EndStampedSource endStamped(slotted);
  JitteredStampSource jittered(slotted, timing.stampJitterNs);
  rig.deps.camera = &camera;
  if (timing.framePeriodNs > 0) {
    rig.deps.camera = timing.stampsExposureEnd ? static_cast<ports::FrameSource*>(&endStamped) : &slotted;
    if (timing.stampJitterNs > 0) rig.deps.camera = &jittered;
    rig.deps.frameClock.maxJitterNs = timing.workerJitterNs;
    rig.deps.limits = motion::SlideLimits{};
    rig.deps.lineTimeNs = timing.workerToldLineTime ? timing.lineTimeNs : 0;
    rig.deps.timestampAtExposureEnd = timing.stampsExposureEnd && timing.workerToldStamp;
    rig.deps.slotLeadNs = app::slotLeadFor(timing.laser == ports::LaserTiming::kFrameClock, timing.laserLeadNs);
  }
  CountingSource counted(*rig.deps.camera);
  rig.deps.camera = &counted;
  rig.deps.learnPaceAtHome = timing.learnPaceAtHome;
  rig.deps.capture.exposureUs = sim::autoExposureUs(scene);
  const localize::Localizer loc(scene.truth, image::LleParams{}, sp);
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  SceneRun run;
  worker.submit(jobOf(app::WorkerJob::Kind::kHome));
  std::optional<app::WorkerEvent> homed = rig.next(worker);
  if (!homed || !homed->status.isOk()) return run;
  run.homingCaptures = counted.frames.load();
  run.homingLaserEdges = rig.laserLine.edges().size();
  const Eigen::Vector3d roughMm = scene.apples[0].centerMm + Eigen::Vector3d(-12, 9, -20);
  Result<localize::ScanPlan> plan = loc.plan(roughMm, rig.limits().strokeMm);
  if (!plan) return run;
  run.planStopsMm = plan->stopsMm;
  app::WorkerJob job = jobOf(app::WorkerJob::Kind::kLocalize);
  job.localize.mode = mode;
  job.plan = *plan;
  rig.laserLine.clearEdges();
  worker.submit(job);
  run.event = rig.next(worker, 600000);  // every frame is rendered: allow a slow machine
  // Let a continuous sweep's braking finish before reading where the slide is.
  worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 100.0));
  (void)rig.next(worker);
  run.laserEdges = rig.laserLine.edges();
  run.finalMm = rig.slide.positionMm();
  return run;
}

// A 30 fps sensor 1536 rows high that reads out over its whole period.
constexpr TimeNs kSensorPeriodNs = 33'333'333;
constexpr TimeNs kSensorLineNs = 21'700;

// A continuous scan of the default scene with this sensor timing: the centre's error.
double sweepCentreErrorMm(const SensorTiming& timing) {
  const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, timing);
  REQUIRE(run.event);
  REQUIRE(run.event->status.isOk());
  REQUIRE(run.event->estimates.size() == 1);
  const sim::SimScene scene = sim::defaultScene();
  return (run.event->estimates[0].centerMm - scene.apples[0].centerMm).norm();
}

// The laser is switched on once per exposure, exactly as it starts, and off exactly as it
// ends (the camera's end-of-exposure callback): never on while the slide moves between stops.
bool laserOnlyDuringExposures(const SceneRun& run) {
  const auto& ex = run.event->exposures;
  std::vector<std::pair<TimeNs, TimeNs>> on;
  for (size_t i = 0; i < run.laserEdges.size(); ++i) {
    if (!run.laserEdges[i].level) continue;
    if (i + 1 >= run.laserEdges.size()) return false;  // left on
    on.emplace_back(run.laserEdges[i].timeNs, run.laserEdges[i + 1].timeNs);
  }
  if (on.size() != ex.size()) return false;
  for (size_t k = 0; k < ex.size(); ++k) {
    if (on[k].first != ex[k].startNs || on[k].second != ex[k].endNs) return false;
  }
  return true;
}
}  // namespace

TEST_CASE("Too few lines on the fruit: the worker takes the localizer's second pass, in both modes",
          "[app][worker][render]") {
  localize::ScanParams sp = localize::ScanParams::paperScan();
  sp.followUpMinLines = 15;  // more than five stops can give: the second pass is always taken
  for (protocol::ScanMode mode : {protocol::ScanMode::kStopAndGo, protocol::ScanMode::kContinuous}) {
    INFO("mode " << static_cast<int>(mode));
    const SceneRun run = localizeOnScene(sp, mode);
    REQUIRE(run.event);
    REQUIRE(run.event->status.isOk());
    REQUIRE(run.planStopsMm.size() == 5);
    // Four stops between the five and one beyond each end.
    CHECK(run.event->followUpStops == 6);
    CHECK(run.event->exposures.size() == 11);
    REQUIRE(run.event->estimates.size() == 1);
    const localize::AppleEstimate& est = run.event->estimates[0];
    const sim::SimScene scene = sim::defaultScene();
    const sim::SimApple& apple = scene.apples[0];
    INFO("lines " << est.linesUsed << ", centre error " << (est.centerMm - apple.centerMm).norm() << " mm");
    // The second pass's lines reached the fit: more lines than the first pass gave it.
    INFO("first pass " << run.event->firstPassLines << " lines");
    CHECK(run.event->firstPassLines >= 1);
    CHECK(est.linesUsed > run.event->firstPassLines);
    // Both modes alike: in virtual time the rendering takes none, so a continuous sweep never
    // passes a stop before its frame is exposed, however slow the machine (under qemu on the
    // wall clock it did: 2 lines then 4, 2.7 mm). Natively both see 4 lines then 8, 0.3 mm.
    CHECK(est.linesUsed > 5);
    CHECK((est.centerMm - apple.centerMm).norm() < 2.0);
    CHECK(laserOnlyDuringExposures(run));
    CHECK(run.finalMm == 100.0);
  }
}

TEST_CASE("A sweep with a sensor that exposes in its frame slots places each frame at its own mid-exposure",
          "[app][worker][render]") {
  // A free-running sensor at 30 fps: an exposure begins up to 33 ms after the request (10 mm
  // of travel at 300 mm/s) and the frame arrives after the window's readout. Placed at the
  // mean of the positions at the request and at the end of the exposure, the frames were
  // up to 5 mm off along the slide, and the centre 12-36 mm off (alacs_cycle --virtual-time).
  constexpr TimeNs kPeriodNs = 33'333'333;
  const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, {kPeriodNs});
  REQUIRE(run.event);
  REQUIRE(run.event->status.isOk());
  REQUIRE(run.event->exposures.size() >= run.planStopsMm.size());
  for (const app::ExposureWindow& ex : run.event->exposures) CHECK(ex.startNs % kPeriodNs == 0);  // the sensor's slots
  // The laser is on for the whole of every exposure (and, with such a sensor, from the request on).
  for (const app::ExposureWindow& ex : run.event->exposures) {
    bool lit = false;
    for (size_t i = 0; i + 1 < run.laserEdges.size(); ++i)
      lit = lit || (run.laserEdges[i].level && run.laserEdges[i].timeNs <= ex.startNs &&
                    run.laserEdges[i + 1].timeNs >= ex.endNs);
    CHECK(lit);
  }
  REQUIRE(run.event->estimates.size() == 1);
  const localize::AppleEstimate& est = run.event->estimates[0];
  const sim::SimScene scene = sim::defaultScene();
  const sim::SimApple& apple = scene.apples[0];
  INFO("lines " << est.linesUsed << ", centre error " << (est.centerMm - apple.centerMm).norm() << " mm");
  CHECK(est.linesUsed >= 3);
  CHECK((est.centerMm - apple.centerMm).norm() < 2.0);
}

// A continuous scan's first-pass stops in the order the slide passed them (its first
// exposures are theirs), the scan having succeeded.
std::vector<double> firstPassStops(const SceneRun& run) {
  REQUIRE(run.event);
  REQUIRE(run.event->status.isOk());
  const std::vector<app::ExposureWindow>& ex = run.event->exposures;
  const size_t n = run.planStopsMm.size();
  REQUIRE(n >= 2);
  REQUIRE(ex.size() >= n);
  std::vector<double> stops = run.planStopsMm;
  std::sort(stops.begin(), stops.end());
  if (ex[n - 1].slideMm < ex[0].slideMm) std::reverse(stops.begin(), stops.end());
  return stops;
}

TEST_CASE("A sweep no faster than the camera takes each frame at its own stop", "[app][worker][render][sweep]") {
  // The worker asks for a stop's frame as the slide passes it and waits for the frame. A
  // 30 fps sensor takes 34-68 ms from request to delivery; at the motor's 300 mm/s that is
  // 10-20 mm of travel, more than the 13.3 mm between stops: the frames fell behind, about
  // 20 mm apart, and the last ones were taken in the braking past the span. The sweep now
  // runs at the pace of the camera's recent captures (motion/sweep_speed.h).
  const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, {kSensorPeriodNs});
  const std::vector<double> stops = firstPassStops(run);
  const std::vector<app::ExposureWindow>& ex = run.event->exposures;
  const size_t n = stops.size();
  const bool forward = ex[n - 1].slideMm > ex[0].slideMm;
  const double v = run.event->sweepSpeedMmPerS;
  INFO("sweep at " << v << " mm/s");
  // A first scan knows one capture (the metering frame): it allows twice that, 135 mm/s here.
  CHECK(v < 300.0);
  CHECK(v > 100.0);
  // Each frame after its stop by at most a frame slot's travel (the sensor's next slot
  // after the request) and the lateness the speed allows (half a gap): never a gap or more.
  // Once the worker knows the sensor's clock it asks for the frame nearest the stop, which
  // may be up to half a slot's travel before it.
  const double gapMm = std::abs(stops[1] - stops[0]);
  const double slotMm = v * 1e-9 * static_cast<double>(kSensorPeriodNs);
  for (size_t i = 0; i < n; ++i) {
    const double lateMm = forward ? ex[i].slideMm - stops[i] : stops[i] - ex[i].slideMm;
    INFO("stop " << stops[i] << " mm, frame at " << ex[i].slideMm << " mm");
    CHECK(lateMm > -0.5 * slotMm - 0.5);
    CHECK(lateMm < std::min(gapMm, 0.5 * gapMm + slotMm));
  }
}

TEST_CASE("Homing learns the camera's pace: the first sweep after a start runs as fast as the camera allows",
          "[app][worker][render][sweep]") {
  // A 30 fps sensor. A worker that has not captured knows one capture when its first sweep
  // starts (the metering frame) and allows it twice that: about 135 mm/s. Homing now takes
  // laser-off frames until the sensor's clock is learnt (four), and the first sweep runs
  // at the pace a worker that has scanned keeps: two frame periods a capture (a frame is
  // delivered a readout after its slot, by when the next slot has begun).
  SensorTiming timing{kSensorPeriodNs};
  const SceneRun first = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, timing);
  timing.learnPaceAtHome = true;
  const SceneRun learnt = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, timing);
  const std::vector<double> stops = firstPassStops(learnt);
  (void)firstPassStops(first);
  const double paced = motion::sweepSpeedMmPerS(motion::SlideLimits{}, stops, 2 * kSensorPeriodNs);
  INFO("first sweep " << first.event->sweepSpeedMmPerS << " mm/s; after the pace learnt at homing "
                      << learnt.event->sweepSpeedMmPerS << " mm/s; two periods a capture allow " << paced << " mm/s");
  CHECK(first.homingCaptures == 0);
  CHECK(learnt.homingCaptures >= FrameClockParams{}.minFrames);
  CHECK(learnt.homingCaptures <= motion::CaptureTimes::kFrames);
  CHECK(learnt.homingLaserEdges == 0);  // laser-off frames: the laser never went on while homing
  CHECK(first.event->sweepSpeedMmPerS < 0.75 * paced);
  CHECK(learnt.event->sweepSpeedMmPerS == Approx(paced).epsilon(0.01));
  // And the frames still at their stops: after each by at most a slot's travel and half a gap.
  const std::vector<app::ExposureWindow>& ex = learnt.event->exposures;
  const bool forward = ex[stops.size() - 1].slideMm > ex[0].slideMm;
  const double slotMm = paced * 1e-9 * static_cast<double>(kSensorPeriodNs);
  for (size_t i = 0; i < stops.size(); ++i) {
    const double lateMm = forward ? ex[i].slideMm - stops[i] : stops[i] - ex[i].slideMm;
    INFO("stop " << stops[i] << " mm, frame at " << ex[i].slideMm << " mm");
    CHECK(lateMm > -0.5 * slotMm - 0.5);
    CHECK(lateMm < 0.5 * std::abs(stops[1] - stops[0]) + slotMm);
  }
  REQUIRE(learnt.event->estimates.size() == 1);
  CHECK((learnt.event->estimates[0].centerMm - sim::defaultScene().apples[0].centerMm).norm() < 2.0);
}

TEST_CASE("A sweep asks for the frame nearest each stop once it knows the sensor's clock",
          "[app][worker][render][sweep]") {
  // A 60 fps sensor, in a first scan (the sweep's pace from the one metering frame: about
  // 200 mm/s). Asked as the slide passes each stop, its frame would come in the next slot,
  // up to a slot's travel (3.3 mm) past the stop; with the sensor's clock learnt (four
  // frames: the metering frame and three stops) the worker asks two leads before the slot
  // nearest the stop, before or after it: within half a slot's travel.
  const TimeNs periodNs = kSensorPeriodNs / 2;
  const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous,
                                       {periodNs, 0, true, false, true, ports::LaserTiming::kFrameClock, kNsPerMs});
  const std::vector<double> stops = firstPassStops(run);
  const std::vector<app::ExposureWindow>& ex = run.event->exposures;
  const size_t n = stops.size();
  REQUIRE(n >= 6);
  const double v = run.event->sweepSpeedMmPerS;
  const double slotMm = v * 1e-9 * static_cast<double>(periodNs);
  double worstMm = 0.0;
  for (size_t i = 3; i < n; ++i) {
    const double offMm = ex[i].slideMm - stops[i];
    INFO("stop " << stops[i] << " mm, frame at " << ex[i].slideMm << " mm");
    CHECK(std::abs(offMm) <= 0.5 * slotMm + 0.2);
    worstMm = std::max(worstMm, std::abs(offMm));
  }
  WARN("the frames from the fourth stop on: at most " << worstMm << " mm from their stops; a slot is " << slotMm
                                                      << " mm");
}

TEST_CASE("A sweep learns a sensor's clock whose timestamps scatter when told how much they may",
          "[app][worker][render][sweep]") {
  // The same 60 fps sensor, its timestamps 0.45 ms off its clock one frame in three either
  // way (vimc's in UML scatter so): with the default 300 us (camera.frame_clock_jitter_us)
  // the worker never learns the clock and asks as the slide passes each stop, its frames up
  // to a slot past the stop; told 1 ms it learns it and asks for the frame nearest each stop.
  const TimeNs periodNs = kSensorPeriodNs / 2;
  SensorTiming timing{periodNs, 0, true, false, true, ports::LaserTiming::kFrameClock, kNsPerMs};
  timing.stampJitterNs = 450 * kNsPerUs;
  const auto worstOffMm = [&](TimeNs workerJitterNs, double* slotMm) {
    timing.workerJitterNs = workerJitterNs;
    const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, timing);
    const std::vector<double> stops = firstPassStops(run);
    const std::vector<app::ExposureWindow>& ex = run.event->exposures;
    *slotMm = run.event->sweepSpeedMmPerS * 1e-9 * static_cast<double>(periodNs);
    double worstMm = 0.0;
    for (size_t i = 3; i < stops.size(); ++i) worstMm = std::max(worstMm, std::abs(ex[i].slideMm - stops[i]));
    return worstMm;
  };
  double toldSlotMm = 0.0;
  double defaultSlotMm = 0.0;
  const double toldMm = worstOffMm(kNsPerMs, &toldSlotMm);
  const double defaultMm = worstOffMm(300 * kNsPerUs, &defaultSlotMm);
  INFO("the frames from the fourth stop on, at most: told 1 ms "
       << toldMm << " mm (a slot " << toldSlotMm << " mm), the default " << defaultMm << " mm (a slot " << defaultSlotMm
       << " mm)");
  CHECK(toldMm <= 0.5 * toldSlotMm + 0.2);
  CHECK(defaultMm > 0.5 * defaultSlotMm + 0.2);
}

TEST_CASE("A sweep with a rolling-shutter sensor gives each row the slide's position at its own exposure",
          "[app][worker][render]") {
  // A 30 fps sensor 1536 rows high, read out over the whole period: row v exposes v × 21.7
  // us after row 0 (the frame's timestamp), so the target's rows in the middle of the frame
  // saw the laser about 5 mm further along a 300 mm/s sweep than row 0 did.
  const double toldMm = sweepCentreErrorMm({kSensorPeriodNs, kSensorLineNs, true});
  const double notToldMm = sweepCentreErrorMm({kSensorPeriodNs, kSensorLineNs, false});
  INFO("centre error: told the line time " << toldMm << " mm, not told " << notToldMm << " mm");
  CHECK(toldMm < 0.6);      // the middle row's position alone (no travel per row) gave 2.1 mm
  CHECK(notToldMm > 10.0);  // what the line time mends (it measured 0.4 and 26 mm)
}

TEST_CASE("A sweep with a sensor that stamps the end of the exposure, as Raspberry Pi's pipelines do",
          "[app][worker][render]") {
  const double toldMm = sweepCentreErrorMm({kSensorPeriodNs, kSensorLineNs, true, true, true});
  const double notToldMm = sweepCentreErrorMm({kSensorPeriodNs, kSensorLineNs, true, true, false});
  INFO("centre error: told " << toldMm << " mm, not told " << notToldMm << " mm");
  CHECK(toldMm < 0.5);
  CHECK(notToldMm > 2.0 * toldMm);
}

// Each interval the laser was on, with the exposures it covered.
struct LaserOn {
  TimeNs onNs;
  TimeNs offNs;
  int exposuresCovered;
};
std::vector<LaserOn> laserIntervals(const SceneRun& run) {
  std::vector<LaserOn> on;
  for (size_t i = 0; i + 1 < run.laserEdges.size(); ++i) {
    if (!run.laserEdges[i].level || run.laserEdges[i + 1].level) continue;
    LaserOn l{run.laserEdges[i].timeNs, run.laserEdges[i + 1].timeNs, 0};
    for (const app::ExposureWindow& ex : run.event->exposures)
      l.exposuresCovered += l.onNs <= ex.startNs && l.offNs >= ex.endNs ? 1 : 0;
    on.push_back(l);
  }
  return on;
}

TEST_CASE("With the sensor's frame clock, the laser is on only around each exposure, not from request to delivery",
          "[app][worker][render]") {
  // libcamera tells the end of an exposure only at the delivery, a readout later: switched
  // from the request to the delivery, the laser is on for up to two frame periods per
  // frame. With the frame clock learnt (drivers/libcamera), the camera switches it on a
  // lead before the window's exposure span (common/frame_clock.h: either meaning of the
  // timestamp, any readout when the line time is not known) and off a lead after it.
  constexpr TimeNs kLeadNs = 1 * kNsPerMs;
  std::vector<TimeNs> shortestNs;
  std::vector<TimeNs> longestNs;
  // A global shutter whose line time is not known (0): the span allows any readout. (A
  // rolling shutter is not tried: the simulated camera renders its rows after the last one
  // is exposed, with the laser as it was at the first and the last row, so the model
  // cannot switch the laser off before the sensor's last row.)
  std::vector<SensorTiming> timings(2, SensorTiming{kSensorPeriodNs});
  timings[1].laser = ports::LaserTiming::kFrameClock;
  timings[1].laserLeadNs = kLeadNs;
  for (const SensorTiming& timing : timings) {
    INFO("laser " << (timing.laser == ports::LaserTiming::kFrameClock ? "on the frame clock" : "from the request")
                  << ", line time " << timing.lineTimeNs << " ns");
    const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kContinuous, timing);
    REQUIRE(run.event);
    REQUIRE(run.event->status.isOk());
    const std::vector<LaserOn> on = laserIntervals(run);
    REQUIRE(on.size() == run.event->exposures.size());
    std::vector<TimeNs> onNs;
    for (const LaserOn& l : on) {
      CHECK(l.exposuresCovered == 1);  // every exposure lit, once
      onNs.push_back(l.offNs - l.onNs);
    }
    shortestNs.push_back(*std::min_element(onNs.begin(), onNs.end()));
    longestNs.push_back(*std::max_element(onNs.begin(), onNs.end()));
    const TimeNs exposureNs = run.event->exposures[0].endNs - run.event->exposures[0].startNs;
    INFO("exposure " << exposureNs / 1000 << " us, laser on " << shortestNs.back() / 1000 << "-"
                     << longestNs.back() / 1000 << " us per frame");
    // On the clock, the span is at most the two meanings' exposures and a period's readout.
    if (timing.laser == ports::LaserTiming::kFrameClock)
      CHECK(longestNs.back() <= 2 * exposureNs + kSensorPeriodNs + 2 * kLeadNs);
    else
      CHECK(shortestNs.back() > kSensorPeriodNs);  // at least the readout
    REQUIRE(run.event->estimates.size() == 1);
    const sim::SimScene scene = sim::defaultScene();
    CHECK((run.event->estimates[0].centerMm - scene.apples[0].centerMm).norm() < 2.0);
  }
  // Never as long on the clock as from the request (26.6 against 45.2-66.7 ms measured).
  CHECK(longestNs[1] < shortestNs[0]);
}

TEST_CASE("Enough lines on the fruit: no second pass", "[app][worker][render]") {
  const SceneRun run = localizeOnScene(localize::ScanParams{}, protocol::ScanMode::kStopAndGo);
  REQUIRE(run.event);
  REQUIRE(run.event->status.isOk());
  CHECK(run.event->followUpStops == 0);
  CHECK(run.event->exposures.size() == run.planStopsMm.size());
  REQUIRE(run.event->estimates.size() == 1);
  CHECK(run.event->estimates[0].linesUsed >= 3);
  const sim::SimScene scene = sim::defaultScene();
  const sim::SimApple& apple = scene.apples[0];
  INFO("lines " << run.event->estimates[0].linesUsed << ", centre error "
                << (run.event->estimates[0].centerMm - apple.centerMm).norm() << " mm");
  CHECK((run.event->estimates[0].centerMm - apple.centerMm).norm() < 5.0);
  CHECK(laserOnlyDuringExposures(run));
}

namespace {
// `scan` with a STOP as its `nth` laser-off frame is taken (the camera returns it; the next
// one is not asked for): ABORTED, that many captures, no laser frame, the laser low.
void stopWhileMetering(Rig& rig, app::ScanWorker& worker, const app::WorkerJob& scan, int nth = 1) {
  int captures = 0;
  rig.camera.onCapture = [&] {
    if (++captures == nth) worker.cancel();
  };
  worker.submit(scan);
  std::optional<app::WorkerEvent> ev = rig.next(worker);
  REQUIRE(ev);
  CHECK_FALSE(ev->status.isOk());
  CHECK(ev->resultStatus == protocol::ResultStatus::kAborted);
  CHECK(captures == nth);
  CHECK(ev->exposures.empty());
  CHECK(rig.laserLine.level() == false);
  rig.camera.onCapture = nullptr;
}
}  // namespace

TEST_CASE("STOP while a sweep meters: ABORTED, no laser frame, the laser low; homed unless the slide had stepped",
          "[app][worker]") {
  Rig rig(2.0);
  rig.meterHalving(20000);  // two laser-off frames: 20 ms, then 10 ms
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  REQUIRE(rig.home(worker));
  // With no metering before it, the first sweep meters before its move: a STOP at the second
  // frame leaves the slide where it was, homed.
  stopWhileMetering(rig, worker, threeStopSweep(), 2);
  CHECK(rig.slide.positionSteps() == 0);
  CHECK(worker.homed());
  // One whole scan, then back to the start: the next sweep meters during its run-up.
  worker.submit(threeStopSweep());
  std::optional<app::WorkerEvent> ev = rig.next(worker);
  REQUIRE(ev);
  REQUIRE(ev->status.isOk());
  worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 0.0));
  REQUIRE(rig.next(worker));
  REQUIRE(rig.slide.positionSteps() == 0);
  // At the first frame, before the run-up's first step: nothing moved, the slide stays homed.
  stopWhileMetering(rig, worker, threeStopSweep());
  CHECK(rig.slide.positionSteps() == 0);
  CHECK(worker.homed());
  // At the second, 20 ms into the run-up: cut short like any move, the position in doubt.
  stopWhileMetering(rig, worker, threeStopSweep(), 2);
  CHECK(rig.slide.positionSteps() > 0);
  CHECK(rig.slide.positionSteps() < Rig::limits().stepsFor(20.0));  // before the first stop
  CHECK_FALSE(worker.homed());
  CHECK(!worker.takeEvent());
}

TEST_CASE(
    "Homing's laser-off frames: as many as the pace needs, none from a simulated camera or a recording, and a camera "
    "fault is the scan's",
    "[app][worker]") {
  Rig rig(2.0);
  rig.deps.learnPaceAtHome = true;
  rig.deps.slotLeadNs = 0;  // a camera that runs free, as alacsd's libcamera one
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  SECTION("a simulated camera that exposes on request (slotLeadNs unknown): none, its first scan paces itself") {
    rig.deps.slotLeadNs = -1;
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    CHECK(worker.homed());
    CHECK(rig.camera.captures == 0);
  }
  SECTION("a free-running camera whose clock is not learnt (no sequence numbers): the captures kept for the pace") {
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    CHECK(worker.homed());
    CHECK(rig.camera.captures == motion::CaptureTimes::kFrames);
    CHECK(rig.camera.requestedUs == std::vector<int64_t>(motion::CaptureTimes::kFrames, 1000));
    CHECK(rig.laserLine.edges().empty());
    // Homing again: the pace is known, no more frames.
    rig.home(worker);
    CHECK(rig.camera.captures == motion::CaptureTimes::kFrames);
  }
  SECTION("a replayed recording: its frames are its stops'") {
    rig.deps.frameSlideMm = [] { return 10.0; };
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    CHECK(rig.camera.captures == 0);
  }
  SECTION("a camera that fails: the slide is homed all the same, and the first scan meets the fault") {
    rig.camera.failure = Status(Error::kTimeout, "no frame");
    app::ScanWorker worker(rig.deps, loc, rig.efd);
    rig.home(worker);
    CHECK(worker.homed());
    CHECK(rig.camera.captures == 1);
    CHECK(rig.laserLine.edges().empty());
    worker.submit(twoStopScan());
    std::optional<app::WorkerEvent> ev = rig.next(worker);
    REQUIRE(ev);
    CHECK_FALSE(ev->status.isOk());
    CHECK(ev->faultBit == protocol::kFaultCameraTimeout);
    CHECK(rig.laserLine.level() == false);
  }
}

TEST_CASE("STOP while metering: the scan ends ABORTED before any move, and the slide stays homed", "[app][worker]") {
  Rig rig(2.0);
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  std::optional<app::WorkerEvent> ev = rig.home(worker);
  REQUIRE(worker.homed());
  const size_t stepsBefore = rig.step.steps().size();
  stopWhileMetering(rig, worker, twoStopScan());
  CHECK(rig.step.steps().size() == stepsBefore);  // not one step
  CHECK(worker.homed());
  // A move cut short, by contrast, leaves the position in doubt.
  rig.step.onStep = [&](int64_t) { worker.cancel(); };
  worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 30.0));
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK_FALSE(ev->status.isOk());
  CHECK_FALSE(worker.homed());
}
