// The localize cycle of the real scan worker, on this machine's clock: the same worker,
// step runner, laser guard and image pipeline as alacsd, driving the simulated slide
// (which counts the STEP pulses) and the simulated camera (windowed render of the
// target's region, standing in for the sensor's readout). For each orchard case the
// slide is first parked within 2 cm of where the scan starts, then the job is timed from
// submission to its result. CAN adds one frame time (< 1 ms at 500 kbit/s) on top.
//
// usage: alacs_cycle [--cases N] [--mode stop-and-go|continuous|both] [--width W --height H]
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "app/laser_guard.h"
#include "app/scan_worker.h"
#include "sim/orchard.h"
#include "sim/sim_camera.h"
#include "sim/sim_slide.h"

using namespace alacs;

namespace {

struct Trial {
  double cycleMs = 0;
  double tailMs = 0;
  double centreErrMm = 0;
  bool ok = false;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

app::WorkerEvent runJob(app::ScanWorker& worker, int efd, const app::WorkerJob& job) {
  worker.submit(job);
  uint64_t n = 0;
  while (true) {
    if (::read(efd, &n, sizeof n) < 0) continue;
    if (std::optional<app::WorkerEvent> ev = worker.takeEvent()) return *ev;
  }
}

}  // namespace

int main(int argc, char** argv) {
  int cases = 10;
  std::string modes = "both";
  int width = 0, height = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--cases" && i + 1 < argc) cases = std::max(1, std::atoi(argv[++i]));
    else if (a == "--mode" && i + 1 < argc) modes = argv[++i];
    else if (a == "--width" && i + 1 < argc) width = std::atoi(argv[++i]);
    else if (a == "--height" && i + 1 < argc) height = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: alacs_cycle [--cases N] [--mode stop-and-go|continuous|both] [--width W --height H]\n");
      return 2;
    }
  }
  MonotonicClock clock;
  MonotonicSleeper sleeper;
  motion::SlideLimits limits;  // the daemon's defaults: docs/daemon.md
  image::LleParams lle;
  localize::ScanParams scanParams;
  std::printf("localize cycle: %d orchard cases (1.0-1.4 m, occluded, overcast), motor %.0f mm/s, %.0f mm/s², "
              "%.0f steps/mm\n", cases, limits.maxSpeedMmPerS, limits.accelMmPerS2, limits.stepsPerMm);
  for (const char* mode : {"stop-and-go", "continuous"}) {
    if (modes != "both" && modes != mode) continue;
    const bool continuous = std::strcmp(mode, "continuous") == 0;
    std::vector<Trial> trials;
    for (int c = 0; c < cases; ++c) {
      sim::CaseSpec spec;
      spec.distanceMm = 1000.0 + 100.0 * (c % 5);
      spec.occluded = true;
      spec.lighting = sim::LightingKind::kOvercast;
      Result<sim::OrchardCase> oc = sim::makeOrchardCase(spec, 1000 + static_cast<uint64_t>(c));
      if (!oc) continue;
      sim::SimScene scene = oc->scene;
      if (width > 0 && height > 0) {
        const double sx = width / static_cast<double>(scene.truth.camera.widthPx);
        auto& cam = scene.truth.camera;
        cam.fxPx *= sx;
        cam.fyPx *= sx;
        cam.cxPx *= sx;
        cam.cyPx *= sx;
        cam.widthPx = width;
        cam.heightPx = height;
      }
      const localize::Localizer loc(scene.truth, lle, scanParams);
      Result<localize::ScanPlan> plan = loc.plan(oc->roughMm, limits.strokeMm);
      if (!plan) continue;
      sim::SimSlide slide(clock, limits.stepsPerMm, limits.strokeMm, 0.0);
      ports::FakeDigitalOut laserLine(clock);
      app::LaserGuard laser(laserLine, clock, 250 * kNsPerMs);
      sim::SimCamera camera(scene, clock, [&] { return laserLine.level(); }, [&] { return slide.positionMm(); });
      app::WorkerDeps deps;
      deps.clock = &clock;
      deps.sleeper = &sleeper;
      deps.limits = limits;
      deps.stepLines = {&slide.stepInput(), &slide.dirInput(), &slide.homeSwitch(), &slide.endSwitch()};
      deps.enable = &slide.enableInput();
      deps.laser = &laser;
      deps.camera = &camera;
      deps.capture.exposureUs = std::min<int64_t>(sim::autoExposureUs(scene), 3000);
      const int efd = ::eventfd(0, EFD_CLOEXEC);
      app::ScanWorker worker(deps, loc, efd);
      app::WorkerJob home;
      home.kind = app::WorkerJob::Kind::kHome;
      (void)runJob(worker, efd, home);
      // Park within 2 cm of the scan's first stop (on the side it starts from).
      app::WorkerJob park;
      park.kind = app::WorkerJob::Kind::kMoveTo;
      park.moveToMm = std::clamp(plan->stopsMm.front() - 5.0 - 15.0 * ((c % 3) / 2.0), 0.0, limits.strokeMm);
      (void)runJob(worker, efd, park);
      app::WorkerJob job;
      job.kind = app::WorkerJob::Kind::kLocalize;
      job.localize.mode = continuous ? protocol::ScanMode::kContinuous : protocol::ScanMode::kStopAndGo;
      job.localize.roughMm = oc->roughMm;
      job.plan = *plan;
      const TimeNs t0 = clock.now();
      job.commandTimeNs = t0;
      const app::WorkerEvent ev = runJob(worker, efd, job);
      Trial t;
      t.cycleMs = static_cast<double>(clock.now() - t0) / 1e6;
      t.tailMs = static_cast<double>(ev.processingTailNs) / 1e6;
      t.ok = !ev.estimates.empty();
      if (t.ok) {
        for (const auto& a : scene.apples)
          if (a.id == oc->targetId) t.centreErrMm = (ev.estimates[0].centerMm - a.centerMm).norm();
      }
      trials.push_back(t);
      ::close(efd);
    }
    std::vector<double> cyc, tail, share, err;
    int found = 0;
    for (const auto& t : trials) {
      cyc.push_back(t.cycleMs);
      tail.push_back(t.tailMs);
      share.push_back(100.0 * t.tailMs / t.cycleMs);
      if (t.ok) {
        err.push_back(t.centreErrMm);
        ++found;
      }
    }
    std::printf("  %-12s cycle median %6.0f ms, max %6.0f ms | processing after the last frame: median %5.1f ms "
                "(%4.1f %% of the cycle) | found %d/%zu, centre error median %.2f mm\n",
                mode, median(cyc), cyc.empty() ? 0.0 : *std::max_element(cyc.begin(), cyc.end()), median(tail),
                median(share), found, trials.size(), median(err));
  }
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  std::printf("  peak resident memory of this process (worker + simulator): %.1f MB\n", static_cast<double>(ru.ru_maxrss) / 1024.0);
  return 0;
}
