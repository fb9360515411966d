#include "app/platform.h"

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

namespace {

#if defined(ALACS_HAVE_GPIOD) && defined(ALACS_HAVE_LIBCAMERA)
class HardwarePlatform final : public Platform {
 public:
  static Result<std::unique_ptr<Platform>> open(const DaemonConfig& cfg, const std::string& calibrationPath) {
    std::unique_ptr<HardwarePlatform> p(new HardwarePlatform);
    if (cfg.gpioChip.empty()) return Status(Error::kInvalidArgument, "no GPIO chip configured (gpio.chip) and not --sim");
    Result<std::unique_ptr<drivers::GpiodLines>> g =
        drivers::GpiodLines::open(cfg.gpioChip, cfg.lines, "alacsd", laserGuardFor(cfg));
    if (!g) return g.status();
    p->gpio_ = std::move(*g);
    p->lines_ = p->gpio_->lines();
    ALACS_LOG_INFO("gpio", "lines requested on %s", p->gpio_->chipName().c_str());
    p->setCalibration(geometry::loadCalibration(calibrationPath.empty() ? cfg.calibrationPath : calibrationPath));
    drivers::LibcameraConfig lc;
    lc.cameraId = cfg.cameraId;
    lc.retries = cfg.frameRetries;
    if (p->calibration()) {
      lc.widthPx = p->calibration()->camera.widthPx;
      lc.heightPx = p->calibration()->camera.heightPx;
    }
    Result<std::unique_ptr<drivers::LibcameraSource>> cam = drivers::LibcameraSource::open(lc);
    if (!cam) return cam.status();
    p->camera_ = std::move(*cam);
    if (Status s = p->openCan(cfg); !s) return s;
    return std::unique_ptr<Platform>(std::move(p));
  }
  const char* name() const override { return "hardware"; }
  const ports::SensorLines& lines() const override { return lines_; }
  ports::FrameSource& camera() override { return *camera_; }

 private:
  HardwarePlatform() = default;
  std::unique_ptr<drivers::GpiodLines> gpio_;
  ports::SensorLines lines_;
  std::unique_ptr<drivers::LibcameraSource> camera_;
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
  deps.realtimePriority = cfg.realtimePriority;
  deps.capture.exposureUs = cfg.exposureUs;
  deps.capture.timeoutMs = cfg.frameTimeoutMs;
  deps.debugDir = debugDir;
  deps.frameSlideMm = platform.frameSlideMm();
  return deps;
}

#ifdef ALACS_HAVE_GPIOD
drivers::LaserGuardOptions laserGuardFor(const DaemonConfig& cfg) {
  return {"/proc/self/exe", cfg.laserMaxOnMs + kLaserGuardMarginMs};
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

Result<std::unique_ptr<Platform>> openHardwarePlatform(const DaemonConfig& cfg, const std::string& calibrationPath) {
#if defined(ALACS_HAVE_GPIOD) && defined(ALACS_HAVE_LIBCAMERA)
  return HardwarePlatform::open(cfg, calibrationPath);
#else
  (void)cfg;
  (void)calibrationPath;
  return Status(Error::kUnsupported, "this build has no libgpiod or no libcamera driver: use --sim or --replay");
#endif
}

}  // namespace alacs::app
