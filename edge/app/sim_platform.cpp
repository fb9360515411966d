#include "app/sim_platform.h"

#include "common/log.h"
#include "ports/digital_io_fake.h"
#include "ports/frame_source_fault.h"
#include "replay/replay_source.h"
#include "sim/scene.h"
#include "sim/sim_camera.h"
#include "sim/sim_slide.h"
#ifdef ALACS_HAVE_GPIOD
#include "drivers/gpiod/gpiod_lines.h"
#endif

namespace alacs::app {
namespace {

class SimPlatform final : public Platform {
 public:
  const char* name() const override { return replay_ != nullptr ? "replay" : "sim"; }
  const ports::SensorLines& lines() const override { return lines_; }
  ports::DigitalIn* statusHomeSwitch() const override { return benchHome_ != nullptr ? benchHome_ : lines_.home; }
  ports::FrameSource& camera() override { return faulty_ ? static_cast<ports::FrameSource&>(*faulty_) : *camera_; }
  std::function<double()> frameSlideMm() override {
    if (replay_ == nullptr) return {};
    return [r = replay_] { return r->lastSlideMm(); };
  }
  ScanObserver* observer() override { return timeline_.get(); }
  TimeNs workerSlackNs() const override { return 60 * kNsPerS; }

  // Everything but the camera and the CAN bus: slide, laser, switches, optional bench GPIO.
  Status openCommon(const DaemonConfig& cfg, const SimOptions& opts, const Clock& clock) {
    if (!opts.fault.empty() && opts.fault != "camera-timeout" && opts.fault != "camera-corrupt" &&
        opts.fault != "home-stuck")
      return {Error::kInvalidArgument, "--sim-fault must be camera-timeout|camera-corrupt|home-stuck, got '" + opts.fault + "'"};
    slide_ = std::make_unique<sim::SimSlide>(clock, cfg.motion.stepsPerMm, cfg.motion.strokeMm, opts.startMm);
    laser_ = std::make_unique<ports::FakeDigitalOut>(clock);
    if (Status s = openBenchGpio(cfg); !s) return s;
    if (lines_.step != nullptr) {
      // The bench: real lines, and the simulated slide listens to the same pulses.
      teeStep_ = std::make_unique<ports::TeeDigitalOut>(*lines_.step, slide_->stepInput());
      teeDir_ = std::make_unique<ports::TeeDigitalOut>(*lines_.dir, slide_->dirInput());
      teeEnable_ = std::make_unique<ports::TeeDigitalOut>(*lines_.enable, slide_->enableInput());
      teeLaser_ = std::make_unique<ports::TeeDigitalOut>(*lines_.laser, *laser_);
      benchHome_ = lines_.home;
      lines_ = {teeStep_.get(), teeDir_.get(), teeEnable_.get(), teeLaser_.get(), lines_.home, lines_.end};
    } else {
      lines_ = {&slide_->stepInput(), &slide_->dirInput(), &slide_->enableInput(), laser_.get(), nullptr, nullptr};
    }
    // The simulated slide closes its own switches; a real END line (bench) can close the
    // end switch too, as a limit hit mid-move.
    if (lines_.end != nullptr) {
      endSwitch_ = std::make_unique<ports::AnyOfDigitalIn>(*lines_.end, slide_->endSwitch());
      lines_.end = endSwitch_.get();
    } else {
      lines_.end = &slide_->endSwitch();
    }
    lines_.home = opts.fault == "home-stuck" ? static_cast<ports::DigitalIn*>(&stuckOpenHome_) : &slide_->homeSwitch();
    if (!opts.debugDir.empty()) timeline_ = makeLaserTimelineWriter(opts.debugDir, *laser_, cfg.laserMaxOnMs);
    return Status::ok();
  }

  Status openRenderedCamera(const sim::SimScene& scene, const Clock& clock, Sleeper& sleeper, const DaemonConfig& cfg) {
    ports::FakeDigitalOut* laser = laser_.get();
    sim::SimSlide* slide = slide_.get();
    auto camera = std::make_unique<sim::SimCamera>(
        scene, clock, sleeper, [laser] { return laser->level(); }, [slide] { return slide->positionMm(); });
    // The configured sensor is the simulated one: a rolling shutter, and a timestamp at the
    // end of the exposure, when the config says so.
    camera->setLineTimeNs(static_cast<TimeNs>(std::llround(cfg.lineTimeUs * 1e3)));
    camera->setTimestampAtExposureEnd(cfg.timestampAtExposureEnd);
    camera_ = std::move(camera);
    return Status::ok();
  }

  Status openReplayCamera(const std::string& dir, const Clock& clock) {
    ports::FakeDigitalOut* laser = laser_.get();
    sim::SimSlide* slide = slide_.get();
    Result<std::unique_ptr<replay::ReplaySource>> rs = replay::ReplaySource::open(
        dir, clock, [laser] { return laser->level(); }, [slide] { return slide->positionMm(); });
    if (!rs) return rs.status();
    replay_ = rs->get();
    camera_ = std::move(*rs);
    ALACS_LOG_INFO("replay", "camera: %zu frames of %s", replay_->manifest().frames.size(), dir.c_str());
    return Status::ok();
  }

  void injectCameraFault(const std::string& fault, const Clock& clock, Sleeper& sleeper) {
    if (fault != "camera-timeout" && fault != "camera-corrupt") return;
    faulty_ = std::make_unique<ports::FaultInjectingFrameSource>(*camera_, clock, sleeper);
    faulty_->setFault(fault == "camera-timeout" ? ports::CameraFault::kTimeout : ports::CameraFault::kCorrupt);
  }

  using Platform::openCan;
  using Platform::setCalibration;
  const replay::ScanManifest& replayManifest() const { return replay_->manifest(); }

 private:
  Status openBenchGpio(const DaemonConfig& cfg) {
    if (cfg.gpioChip.empty()) return Status::ok();
#ifdef ALACS_HAVE_GPIOD
    Result<std::unique_ptr<drivers::GpiodLines>> g =
        drivers::GpiodLines::open(cfg.gpioChip, cfg.lines, "alacsd", laserGuardFor(cfg));
    if (!g) return g.status();
    gpio_ = std::move(*g);
    lines_ = gpio_->lines();
    ALACS_LOG_INFO("gpio", "lines requested on %s", gpio_->chipName().c_str());
    return Status::ok();
#else
    return {Error::kUnsupported, "this build has no libgpiod driver (gpio.chip is set)"};
#endif
  }

#ifdef ALACS_HAVE_GPIOD
  std::unique_ptr<drivers::GpiodLines> gpio_;
#endif
  ports::SensorLines lines_;
  std::unique_ptr<sim::SimSlide> slide_;
  std::unique_ptr<ports::FakeDigitalOut> laser_;
  std::unique_ptr<ports::DigitalOut> teeStep_, teeDir_, teeEnable_, teeLaser_;
  std::unique_ptr<ports::AnyOfDigitalIn> endSwitch_;
  ports::FakeDigitalIn stuckOpenHome_{false};
  ports::DigitalIn* benchHome_ = nullptr;  // the bench's real HOME line (status frame only)
  std::unique_ptr<ports::FrameSource> camera_;
  replay::ReplaySource* replay_ = nullptr;  // the camera, when replaying (owned by camera_)
  std::unique_ptr<ports::FaultInjectingFrameSource> faulty_;
  std::unique_ptr<ScanObserver> timeline_;
};

}  // namespace

Result<std::unique_ptr<Platform>> openSimPlatform(const DaemonConfig& cfg, const SimOptions& opts, const Clock& clock,
                                                  Sleeper& sleeper) {
  sim::SimScene scene = sim::defaultScene();
  if (!opts.scenePath.empty()) {
    Result<sim::SimScene> s = sim::loadScene(opts.scenePath);
    if (!s) return s.status();
    scene = *s;
  }
  if (!opts.truthOut.empty()) {
    if (Status s = sim::saveSceneTruth(scene, opts.truthOut); !s) return s;
  }
  auto p = std::make_unique<SimPlatform>();
  if (Status s = p->openCommon(cfg, opts, clock); !s) return s;
  if (opts.calibrationPath.empty()) {
    ALACS_LOG_WARN("cal", "--sim without --calibration: using the simulator's true calibration");
    p->setCalibration(scene.truth);
  } else {
    p->setCalibration(geometry::loadCalibration(opts.calibrationPath));
  }
  if (Status s = p->openRenderedCamera(scene, clock, sleeper, cfg); !s) return s;
  p->injectCameraFault(opts.fault, clock, sleeper);
  if (Status s = p->openCan(cfg); !s) return s;
  return std::unique_ptr<Platform>(std::move(p));
}

Result<std::unique_ptr<Platform>> openReplayPlatform(const DaemonConfig& cfg, const std::string& dir,
                                                     const SimOptions& opts, const Clock& clock, Sleeper& sleeper) {
  auto p = std::make_unique<SimPlatform>();
  if (Status s = p->openCommon(cfg, opts, clock); !s) return s;
  // The manifest first (nothing of a frame is allocated yet), then the calibration it names,
  // inside the scan directory (no symlink out of it), unless --calibration gives one; the
  // CAN bus last, once the scan is known to be usable.
  if (Status s = p->openReplayCamera(dir, clock); !s) return s;
  const replay::ScanManifest& m = p->replayManifest();
  p->setCalibration(opts.calibrationPath.empty() ? replay::loadScanCalibration(dir, m)
                                                 : geometry::loadCalibration(opts.calibrationPath));
  // Frames of another size than the calibration's camera could never be used: refused here,
  // before the first frame buffer is allocated for them.
  if (const auto& cal = p->calibration();
      cal && (m.scan.widthPx != cal->camera.widthPx || m.scan.heightPx != cal->camera.heightPx))
    return Status(Error::kBadInput, "scan '" + dir + "': frames are " + std::to_string(m.scan.widthPx) + "x" +
                                        std::to_string(m.scan.heightPx) + " but the calibration is for " +
                                        std::to_string(cal->camera.widthPx) + "x" +
                                        std::to_string(cal->camera.heightPx));
  p->injectCameraFault(opts.fault, clock, sleeper);
  if (Status s = p->openCan(cfg); !s) return s;
  return std::unique_ptr<Platform>(std::move(p));
}

}  // namespace alacs::app
