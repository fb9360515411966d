// The scan worker and its frame pipeline on this machine's clock, with the simulated
// slide (counting STEP pulses) and a camera that returns dark frames at once.
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <thread>
#include <vector>

#include "app/frame_pipeline.h"
#include "app/laser_guard.h"
#include "app/scan_worker.h"
#include "ports/digital_io_fake.h"
#include "sim/orchard.h"
#include "sim/scene.h"
#include "sim/sim_camera.h"
#include "sim/sim_slide.h"

using namespace alacs;

namespace {

class DarkCamera final : public ports::FrameSource {
 public:
  DarkCamera(int widthPx, int heightPx) : frame_(static_cast<size_t>(widthPx) * static_cast<size_t>(heightPx) * 3U, 0) {
    view_ = {frame_.data(), widthPx, heightPx, static_cast<size_t>(widthPx) * 3U, image::PixelFormat::kBgr888};
  }
  const char* name() const override { return "dark"; }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const std::function<void()>& end) override {
    std::this_thread::sleep_for(std::chrono::microseconds(r.exposureUs));
    if (end) end();
    ports::CapturedFrame f;
    f.view = view_;
    f.info.exposureUs = r.exposureUs;
    return f;
  }
  std::vector<uint8_t> frame_;
  image::ImageView view_;
};

// Everything a worker needs, the slide slowed down so that its braking lasts 0.2 s.
struct Rig {
  explicit Rig(double startMm) : slide(clock, limits().stepsPerMm, limits().strokeMm, startMm), laser(laserLine, clock, 250 * kNsPerMs) {
    deps.clock = &clock;
    deps.sleeper = &sleeper;
    deps.limits = limits();
    deps.stepLines = {&slide.stepInput(), &slide.dirInput(), &slide.homeSwitch(), &slide.endSwitch()};
    deps.enable = &slide.enableInput();
    deps.laser = &laser;
    deps.camera = &camera;
    deps.capture.exposureUs = 1000;
    efd = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  }
  ~Rig() { ::close(efd); }
  static motion::SlideLimits limits() {
    motion::SlideLimits l;
    l.maxSpeedMmPerS = 100.0;
    l.accelMmPerS2 = 500.0;  // braking from 100 mm/s: 10 mm, 0.2 s
    return l;
  }
  // The next event, waiting at most 5 s.
  std::optional<app::WorkerEvent> next(app::ScanWorker& w) {
    for (int i = 0; i < 5000; ++i) {
      if (std::optional<app::WorkerEvent> ev = w.takeEvent()) return ev;
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return std::nullopt;
  }
  MonotonicClock clock;
  MonotonicSleeper sleeper;
  sim::SimSlide slide;
  ports::FakeDigitalOut laserLine{clock};
  app::LaserGuard laser;
  DarkCamera camera{64, 48};
  app::WorkerDeps deps;
  int efd = -1;
};

app::WorkerJob jobOf(app::WorkerJob::Kind kind, double mm = 0.0) {
  app::WorkerJob j;
  j.kind = kind;
  j.moveToMm = mm;
  return j;
}

}  // namespace

TEST_CASE("A continuous scan's result is out while the slide brakes; a job sent then runs once it is at rest",
          "[app][worker]") {
  Rig rig(2.0);
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  worker.submit(jobOf(app::WorkerJob::Kind::kHome));
  std::optional<app::WorkerEvent> ev = rig.next(worker);
  REQUIRE(ev);
  REQUIRE(ev->status.isOk());

  app::WorkerJob scan = jobOf(app::WorkerJob::Kind::kLocalize);
  scan.localize.mode = protocol::ScanMode::kContinuous;
  scan.plan.stopsMm = {20.0, 25.0, 30.0};
  scan.plan.roi = {0, 0, 32, 32};
  worker.submit(scan);
  ev = rig.next(worker);
  const double atResultMm = rig.slide.positionMm();
  REQUIRE(ev);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kLocalize);
  CHECK(ev->status.isOk());  // dark frames: no object, but the scan worked
  CHECK(!ev->afterResult);
  CHECK(ev->exposures.size() == 3);
  // Past the last stop, still short of where the braking ends (30 + 0.1 + 0.5 + 10 mm).
  CHECK(atResultMm > 29.0);
  CHECK(atResultMm < 40.0);
  CHECK(!worker.busy());

  // Sent while the slide brakes: queued, it moves the slide back once it is at rest.
  worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 10.0));
  double maxMm = 0.0;
  for (int i = 0; i < 5000 && !(ev = worker.takeEvent()); ++i) {
    maxMm = std::max(maxMm, rig.slide.positionMm());
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  REQUIRE(ev);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kMoveTo);
  CHECK(ev->status.isOk());
  CHECK(maxMm > 40.0);  // the braking ran to its end before the move began
  CHECK(rig.slide.positionMm() == Approx(10.0).margin(0.03));
  CHECK(rig.slide.ignoredSteps() == 0);
  CHECK(worker.homed());
  CHECK(!worker.takeEvent());  // no second event: the braking completed
}

TEST_CASE("One job waits behind the running one; cancel() ends both, and a job sent afterwards runs", "[app][worker]") {
  Rig rig(2.0);
  const localize::Localizer loc(sim::defaultScene().truth, image::LleParams{}, localize::ScanParams{});
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  worker.submit(jobOf(app::WorkerJob::Kind::kHome));
  std::optional<app::WorkerEvent> ev = rig.next(worker);
  REQUIRE(ev);
  REQUIRE(ev->status.isOk());
  REQUIRE(worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 150.0)));  // 1.7 s
  for (int i = 0; i < 2000 && rig.slide.positionMm() < 1.0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  REQUIRE(rig.slide.positionMm() >= 1.0);  // running: the queue is empty again
  REQUIRE(worker.submit(jobOf(app::WorkerJob::Kind::kHome)));
  CHECK(!worker.submit(jobOf(app::WorkerJob::Kind::kHome)));  // bounded: one job waits, no more
  worker.cancel();
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kMoveTo);
  CHECK(!ev->status.isOk());
  CHECK(rig.slide.positionMm() < 150.0);
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->job.kind == app::WorkerJob::Kind::kHome);
  CHECK(!ev->status.isOk());  // queued before the cancel: cancelled too
  CHECK(!worker.homed());
  worker.submit(jobOf(app::WorkerJob::Kind::kHome));
  ev = rig.next(worker);
  REQUIRE(ev);
  CHECK(ev->status.isOk());
  CHECK(worker.homed());
  CHECK(rig.slide.positionMm() == 0.0);
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
};

SceneRun localizeOnScene(const localize::ScanParams& sp, protocol::ScanMode mode) {
  Rig rig(2.0);
  const sim::SimScene scene = sim::defaultScene();
  sim::SimCamera camera(scene, rig.clock, rig.sleeper, [&] { return rig.laserLine.level(); }, [&] { return rig.slide.positionMm(); });
  rig.deps.camera = &camera;
  rig.deps.capture.exposureUs = sim::autoExposureUs(scene);
  const localize::Localizer loc(scene.truth, image::LleParams{}, sp);
  app::ScanWorker worker(rig.deps, loc, rig.efd);
  SceneRun run;
  worker.submit(jobOf(app::WorkerJob::Kind::kHome));
  std::optional<app::WorkerEvent> homed = rig.next(worker);
  if (!homed || !homed->status.isOk()) return run;
  const Eigen::Vector3d roughMm = scene.apples[0].centerMm + Eigen::Vector3d(-12, 9, -20);
  Result<localize::ScanPlan> plan = loc.plan(roughMm, rig.limits().strokeMm);
  if (!plan) return run;
  run.planStopsMm = plan->stopsMm;
  app::WorkerJob job = jobOf(app::WorkerJob::Kind::kLocalize);
  job.localize.mode = mode;
  job.plan = *plan;
  rig.laserLine.clearEdges();
  worker.submit(job);
  for (int i = 0; i < 60000 && !run.event; ++i) {  // up to a minute: every frame is rendered
    run.event = worker.takeEvent();
    if (!run.event) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  // Let a continuous sweep's braking finish before reading where the slide is.
  worker.submit(jobOf(app::WorkerJob::Kind::kMoveTo, 100.0));
  (void)rig.next(worker);
  run.laserEdges = rig.laserLine.edges();
  run.finalMm = rig.slide.positionMm();
  return run;
}

// The laser is switched on once per exposure, before it starts, and off after it ends and
// before the next one starts: never on while the slide moves between stops. (Ordering only:
// how long after an exposure the laser goes off depends on this machine's scheduling.)
bool laserOnlyAroundExposures(const SceneRun& run) {
  const auto& ex = run.event->exposures;
  std::vector<std::pair<TimeNs, TimeNs>> on;
  for (size_t i = 0; i < run.laserEdges.size(); ++i) {
    if (!run.laserEdges[i].level) continue;
    if (i + 1 >= run.laserEdges.size()) return false;  // left on
    on.emplace_back(run.laserEdges[i].timeNs, run.laserEdges[i + 1].timeNs);
  }
  if (on.size() != ex.size()) return false;
  for (size_t k = 0; k < ex.size(); ++k) {
    if (on[k].first > ex[k].startNs || on[k].second < ex[k].endNs) return false;
    if (k + 1 < ex.size() && on[k].second > ex[k + 1].startNs) return false;
  }
  return true;
}
}  // namespace

TEST_CASE("Too few lines on the fruit: the worker takes the localizer's second pass, in both modes", "[app][worker][render]") {
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
    if (mode == protocol::ScanMode::kStopAndGo) {
      CHECK(est.linesUsed > 5);
      CHECK((est.centerMm - apple.centerMm).norm() < 2.0);
    } else {
      // A continuous sweep on a machine too slow for it (qemu renders each simulated frame
      // for seconds) passes stops before their frames are exposed: those frames see the line
      // at a later slide position, often a repeat, which the estimate counts once. Seen under
      // qemu: 2 lines in the first pass, 4 after the second, centre 2.7 mm; natively 4 and 8,
      // 0.3 mm. What is checked then is the product's centre target at 1.0-1.6 m, 4 mm.
      CHECK((est.centerMm - apple.centerMm).norm() < 4.0);
    }
    CHECK(laserOnlyAroundExposures(run));
    CHECK(run.finalMm == Approx(100.0).margin(0.03));
  }
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
  INFO("lines " << run.event->estimates[0].linesUsed << ", centre error " << (run.event->estimates[0].centerMm - apple.centerMm).norm() << " mm");
  CHECK((run.event->estimates[0].centerMm - apple.centerMm).norm() < 5.0);
  CHECK(laserOnlyAroundExposures(run));
}
