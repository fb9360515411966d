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
#include "sim/scene.h"
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
