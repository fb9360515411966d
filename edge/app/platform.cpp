#include "app/platform.h"

#include <nlohmann/json.hpp>

#include <unistd.h>

#include <array>
#include <atomic>

#include "common/frame_clock.h"
#include "common/log.h"
#ifdef ALACS_HAVE_GPIOD
#include "drivers/gpiod/gpiod_lines.h"
#endif
#ifdef ALACS_HAVE_LIBCAMERA
#include "drivers/libcamera/libcamera_source.h"
#endif

namespace alacs::app {

Status Platform::openCan(const DaemonConfig& cfg) {
  // Kernel filters pass NMT and the node's own id block (every function code + N) but
  // its heartbeat id, which the kernel sends for us (CAN_BCM) and would loop back:
  // frames for other nodes never wake the loop; unknown ids of our block are counted.
  const auto node = static_cast<uint32_t>(cfg.nodeId);
  Result<std::unique_ptr<drivers::SocketCanBus>> can = drivers::SocketCanBus::open(
      cfg.canInterface,
      {{0x000, 0x7FF}, {node, 0x47F}, {0x400U + node, 0x67F}, {0x600U + node, 0x77F}, {0x780U + node, 0x7FF}});
  if (!can) return can.status();
  can_ = std::move(*can);
  if (!can_->hasCyclic()) ALACS_LOG_WARN("can", "no CAN_BCM: the heartbeat is sent by the event loop");
  return Status::ok();
}

bool Platform::restartDue(bool workerBusy, TimeNs now) {
  const std::string why = restartReason();
  if (why.empty() || workerBusy) return false;
  if (restartAtNs_ == 0) restartAtNs_ = now + kNsPerS;
  if (now < restartAtNs_) return false;
  ALACS_LOG_ERROR("main", "%s: exiting (%d) for the unit to start alacsd afresh", why.c_str(), kExitRestart);
  return true;
}

namespace {

// --debug-dir: the laser line's edges and the exposures of the last scan, as JSON.
class LaserTimelineWriter final : public ScanObserver {
 public:
  LaserTimelineWriter(std::string dir, ports::FakeDigitalOut& laser, int maxOnMs)
      : dir_(std::move(dir)), laser_(laser), maxOnMs_(maxOnMs) {}
  void scanFinished(const WorkerEvent& ev) override {
    nlohmann::json j;
    j["laser_max_on_ms"] = maxOnMs_;
    j["edges"] = nlohmann::json::array();
    for (const ports::Edge& e : laser_.edges()) j["edges"].push_back({e.timeNs, e.level ? 1 : 0});
    j["exposures"] = nlohmann::json::array();
    j["exposure_end_told"] = nlohmann::json::array();
    for (const ExposureWindow& w : ev.exposures) {
      j["exposures"].push_back({w.startNs, w.endNs});
      j["exposure_end_told"].push_back(w.endToldNs);
    }
    const std::string path = dir_ + "/laser_timeline.json";
    if (Status w = geometry::writeFileAtomically(path, j.dump(2) + "\n"); !w) {
      ALACS_LOG_WARN("debug", "%s", w.toString().c_str());
      return;
    }
    laser_.clearEdges();
  }

 private:
  std::string dir_;
  ports::FakeDigitalOut& laser_;
  int maxOnMs_;
};

}  // namespace

std::unique_ptr<ScanObserver> makeLaserTimelineWriter(const std::string& dir, ports::FakeDigitalOut& laser,
                                                      int maxOnMs) {
  return std::make_unique<LaserTimelineWriter>(dir, laser, maxOnMs);
}

namespace {

#if defined(ALACS_HAVE_GPIOD) && defined(ALACS_HAVE_LIBCAMERA)
// The board's camera, opened at start and, if that failed (no camera yet, a size it
// cannot give), again at each capture: the daemon stays up and answers on the bus, and a
// scan fails as a camera fault naming the reason, instead of the process exiting and
// systemd restarting it in a loop.
class CameraWhenAvailable final : public ports::FrameSource {
 public:
  explicit CameraWhenAvailable(drivers::LibcameraConfig cfg) : cfg_(std::move(cfg)) { (void)tryOpen(); }
  const char* name() const override { return "libcamera"; }
  const Status& openError() const { return error_; }
  std::string lostReason() const {
    const drivers::LibcameraSource* s = source_.load();
    if (s == nullptr || !s->lost()) return {};  // the event loop asks at every wake-up: no copy
    return "camera " + s->stats().cameraId + " lost (its device was removed)";
  }

 private:
  Status tryOpen() {
    Result<std::unique_ptr<drivers::LibcameraSource>> cam = drivers::LibcameraSource::open(cfg_);
    if (!cam) {
      error_ = cam.status();
      return error_;
    }
    owner_ = std::move(*cam);
    error_ = Status::ok();
    rateLogged_ = false;
    capturesUnlearnt_ = 0;
    missWatch_.reset();
    source_.store(owner_.get());
    return error_;
  }
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks) override {
    if (source_.load() == nullptr) {
      if (Status s = tryOpen(); !s) {
        hooks.endNow();
        return Status(Error::kTimeout, "camera unavailable: " + s.toString());
      }
      ALACS_LOG_INFO("camera", "camera opened");
    }
    Result<ports::CapturedFrame> frame = source_.load()->capture(r, hooks);
    const drivers::LibcameraStats st = source_.load()->stats();
    if (st.reopens != reopensSeen_) {
      // The adapter reopened the camera after a timeout: its rate is learnt, and told, again.
      reopensSeen_ = st.reopens;
      rateLogged_ = false;
      capturesUnlearnt_ = 0;
    }
    if (!rateLogged_) logRate(st);
    if (cfg_.laserOnFrameClock && missWatch_.afterCapture(st.frameClockMisses))
      ALACS_LOG_WARN("camera",
                     "the frame clock missed %d of the last %d captures (a frame later than predicted, or the "
                     "capture's thread woke late): each cost a frame period and a second laser pulse, from the "
                     "request; camera.laser_lead_us %lld, camera.frame_clock_jitter_us %lld (raise them, or set "
                     "camera.laser_on_frame_clock false)",
                     missWatch_.missedInWindow(), FrameClockMissWatch::kCaptures,
                     static_cast<long long>(cfg_.laserLeadNs / kNsPerUs),
                     static_cast<long long>(cfg_.frameClockJitterNs / kNsPerUs));
    return frame;
  }
  static constexpr int kFramesToLearnTheClock = 30;
  // The sensor's rate, once its clock is learnt: the first thing to look at when the cycle
  // is slower than the docs say (docs/daemon.md "Frame rate").
  void logRate(const drivers::LibcameraStats& st) {
    if (st.framePeriodNs <= 0) {
      // Timestamps that never settle on one clock keep the laser on from each request to
      // its delivery: say so once, with what the tolerance would need.
      if (++capturesUnlearnt_ < kFramesToLearnTheClock) return;
      rateLogged_ = true;
      ALACS_LOG_WARN("camera",
                     "no frame clock learnt in %d captures: the frames' timestamps do not keep to one clock within "
                     "camera.frame_clock_jitter_us %lld%s",
                     kFramesToLearnTheClock, static_cast<long long>(cfg_.frameClockJitterNs / kNsPerUs),
                     cfg_.laserOnFrameClock ? "; the laser stays on from each request to its frame" : "");
      return;
    }
    rateLogged_ = true;
    const FrameRateNote note =
        frameRateNote(cfg_.frameDurationNs / kNsPerUs, st.frameDurationControl, st.framePeriodNs);
    if (note.warning)
      ALACS_LOG_WARN("camera", "%s", note.text.c_str());
    else
      ALACS_LOG_INFO("camera", "%s", note.text.c_str());
  }
  void doInterrupt() override {
    if (drivers::LibcameraSource* s = source_.load()) s->interrupt();
  }
  void doResume() override {
    if (drivers::LibcameraSource* s = source_.load()) s->resume();
  }

  drivers::LibcameraConfig cfg_;
  std::unique_ptr<drivers::LibcameraSource> owner_;  // set once, by the worker's thread
  std::atomic<drivers::LibcameraSource*> source_{nullptr};
  Status error_;
  bool rateLogged_ = false;  // the worker's thread
  int capturesUnlearnt_ = 0;
  FrameClockMissWatch missWatch_;  // the worker's thread
  uint64_t reopensSeen_ = 0;
};

class HardwarePlatform final : public Platform {
 public:
  static Result<std::unique_ptr<Platform>> open(const DaemonConfig& cfg, const std::string& calibrationPath,
                                                const Clock& clock, const std::string& debugDir) {
    std::unique_ptr<HardwarePlatform> p(new HardwarePlatform);
    if (cfg.gpioChip.empty()) return Status(Error::kInvalidArgument, "no GPIO chip configured (gpio.chip) and not --sim");
    Result<std::unique_ptr<drivers::GpiodLines>> g =
        drivers::GpiodLines::open(cfg.gpioChip, cfg.lines, "alacsd", laserGuardFor(cfg));
    if (!g) return g.status();
    p->gpio_ = std::move(*g);
    p->lines_ = p->gpio_->lines();
    if (!debugDir.empty()) {
      // --debug-dir: the LASER line's edges as the daemon drives them, beside the exposures.
      p->laserEdges_ = std::make_unique<ports::FakeDigitalOut>(clock);
      p->laserTee_ = std::make_unique<ports::TeeDigitalOut>(*p->lines_.laser, *p->laserEdges_);
      p->lines_.laser = p->laserTee_.get();
      p->timeline_ = makeLaserTimelineWriter(debugDir, *p->laserEdges_, cfg.laserMaxOnMs);
    }
    ALACS_LOG_INFO("gpio", "lines requested on %s", p->gpio_->chipName().c_str());
    p->setCalibration(geometry::loadCalibration(calibrationPath.empty() ? cfg.calibrationPath : calibrationPath));
    drivers::LibcameraConfig lc;
    lc.cameraId = cfg.cameraId;
    lc.laserOnFrameClock = cfg.laserOnFrameClock;
    lc.laserLeadNs = std::llround(cfg.laserLeadUs * 1e3);
    lc.frameClockJitterNs = std::llround(cfg.frameClockJitterUs * 1e3);
    lc.lineTimeNs = std::llround(cfg.lineTimeUs * 1e3);
    lc.globalShutter = cfg.globalShutter;
    lc.frameDurationNs = TimeNs{cfg.frameDurationUs} * kNsPerUs;
    if (p->calibration()) {
      lc.widthPx = p->calibration()->camera.widthPx;
      lc.heightPx = p->calibration()->camera.heightPx;
    }
    p->camera_ = std::make_unique<CameraWhenAvailable>(lc);
    if (const Status& e = p->camera_->openError(); !e)
      ALACS_LOG_ERROR("camera", "%s; the daemon runs on and tries again at each scan", e.toString().c_str());
    if (Status s = p->openCan(cfg); !s) return s;
    return std::unique_ptr<Platform>(std::move(p));
  }
  const char* name() const override { return "hardware"; }
  const ports::SensorLines& lines() const override { return lines_; }
  ports::FrameSource& camera() override { return *camera_; }
  ScanObserver* observer() override { return timeline_.get(); }
  bool cameraFreeRuns() const override { return true; }
  std::string restartReason() const override { return camera_->lostReason(); }

 private:
  HardwarePlatform() = default;
  std::unique_ptr<drivers::GpiodLines> gpio_;
  std::unique_ptr<ports::FakeDigitalOut> laserEdges_;
  std::unique_ptr<ports::TeeDigitalOut> laserTee_;
  std::unique_ptr<ScanObserver> timeline_;
  ports::SensorLines lines_;
  std::unique_ptr<CameraWhenAvailable> camera_;
};
#endif

}  // namespace

WorkerDeps workerDepsFor(const DaemonConfig& cfg, Platform& platform, const Clock& clock, Sleeper& sleeper,
                         LaserGuard& laser, ports::FrameSource& camera, const std::string& debugDir) {
  const ports::SensorLines& lines = platform.lines();
  WorkerDeps deps;
  deps.clock = &clock;
  deps.sleeper = &sleeper;
  deps.limits = cfg.motion;
  deps.stepLines = {lines.step, lines.dir, lines.home, lines.end};
  deps.enable = lines.enable;
  deps.laser = &laser;
  deps.camera = &camera;
  deps.captureRetries = cfg.frameRetries;
  deps.lineTimeNs = static_cast<TimeNs>(std::llround(cfg.lineTimeUs * 1e3));
  deps.timestampAtExposureEnd = cfg.timestampAtExposureEnd;
  deps.frameClock.maxJitterNs = std::llround(cfg.frameClockJitterUs * 1e3);
  if (platform.cameraFreeRuns())
    deps.slotLeadNs = slotLeadFor(cfg.laserOnFrameClock, std::llround(cfg.laserLeadUs * 1e3));
  deps.realtimePriority = cfg.realtimePriority;
  deps.capture.exposureUs = cfg.exposureUs;
  deps.capture.analogueGain = cfg.analogueGain;
  deps.capture.timeoutMs = cfg.frameTimeoutMs;
  deps.metering = cfg.metering;
  deps.debugDir = debugDir;
  deps.frameSlideMm = platform.frameSlideMm();
  return deps;
}

#ifdef ALACS_HAVE_GPIOD
namespace {
// alacs-laser-guard beside this executable (installed with it, laser_guard_main.cpp); when
// it is missing (an alacsd copied alone), alacsd itself, which serves the same call.
std::string laserGuardExe() {
  std::array<char, 4096> self{};
  const ssize_t n = ::readlink("/proc/self/exe", self.data(), self.size() - 1);
  const std::string path(self.data(), n > 0 ? static_cast<size_t>(n) : 0);
  const size_t slash = path.rfind('/');
  if (slash != std::string::npos) {
    const std::string guard = path.substr(0, slash + 1) + "alacs-laser-guard";
    if (::access(guard.c_str(), X_OK) == 0) return guard;
    ALACS_LOG_WARN("gpio", "no %s: alacsd is its own laser guard (slower to start, and it pins all its libraries)",
                   guard.c_str());
  }
  return "/proc/self/exe";
}
}  // namespace

drivers::LaserGuardOptions laserGuardFor(const DaemonConfig& cfg) {
  return {laserGuardExe(), cfg.laserMaxOnMs + kLaserGuardMarginMs};
}
#endif

Status driveLaserOff(const DaemonConfig& cfg) {
#ifdef ALACS_HAVE_GPIOD
  if (cfg.gpioChip.empty()) return {Error::kInvalidArgument, "no GPIO chip configured (gpio.chip)"};
  Result<std::unique_ptr<drivers::GpiodLines>> g = drivers::GpiodLines::open(cfg.gpioChip, cfg.lines, "alacsd-laser-off");
  if (!g) return g.status();
  return (*g)->lines().laser->set(false);
#else
  (void)cfg;
  return {Error::kUnsupported, "this build has no libgpiod driver"};
#endif
}

Result<std::unique_ptr<Platform>> openHardwarePlatform(const DaemonConfig& cfg, const std::string& calibrationPath,
                                                       const Clock& clock, const std::string& debugDir) {
#if defined(ALACS_HAVE_GPIOD) && defined(ALACS_HAVE_LIBCAMERA)
  return HardwarePlatform::open(cfg, calibrationPath, clock, debugDir);
#else
  (void)cfg;
  (void)calibrationPath;
  (void)clock;
  (void)debugDir;
  return Status(Error::kUnsupported, "this build has no libgpiod or no libcamera driver: use --sim or --replay");
#endif
}

}  // namespace alacs::app
