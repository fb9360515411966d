// alacsd's exit status when it ends for a restart (Platform::restartReason): EX_TEMPFAIL.
inline constexpr int kExitRestart = 75;

// Where the sensor's ports come from, chosen once at start (libcamera's pipeline
// handlers' shape): the hardware platform (libgpiod lines, the libcamera camera), the
// simulated one and the replay one (edge/app/sim_platform.h, only in builds with the
// simulator). Each hands out the slide's and the laser's lines, the camera, the CAN bus
// and the calibration, and owns them for the daemon's lifetime.
#pragma once

#include <functional>
#include <memory>
#include <string>

#include "app/config.h"
#include "app/laser_guard.h"
#include "app/scan_worker.h"
#include "app/sensor.h"
#include "drivers/socketcan/socketcan.h"
#ifdef ALACS_HAVE_GPIOD
#include "drivers/gpiod/gpiod_lines.h"
#endif
#include "geometry/calibration.h"
#include "ports/digital_io.h"
#include "ports/digital_io_fake.h"
#include "ports/frame_source.h"

namespace alacs::app {

class Platform {
 public:
  virtual ~Platform() = default;
  Platform(const Platform&) = delete;
  Platform& operator=(const Platform&) = delete;

  virtual const char* name() const = 0;
  // STEP, DIR, ENABLE, LASER, HOME and (optional) END.
  virtual const ports::SensorLines& lines() const = 0;
  virtual ports::FrameSource& camera() = 0;
  // The home switch the status frame shows: the physical line where there is one (on the
  // bench, the real GPIO line beside the simulated slide's own switch).
  virtual ports::DigitalIn* statusHomeSwitch() const { return lines().home; }
  // The calibration the platform measures with, or why there is none (the sensor then
  // NACKs NOT_CALIBRATED; a platform never substitutes another's data).
  const Result<geometry::Calibration>& calibration() const { return calibration_; }
  // Replay: the slide position each frame was recorded at (empty: the worker's own).
  virtual std::function<double()> frameSlideMm() { return {}; }
  // Extra time the worker may go without progress (Sensor::setWorkerSlack): a simulated
  // camera renders each frame, which takes seconds under emulation.
  virtual TimeNs workerSlackNs() const { return 2 * kNsPerS; }
  // Non-empty when the process must end for the unit to start it afresh: the camera's
  // device went away, which libcamera 0.0.3 cannot recover from in-process.
  virtual std::string restartReason() const { return {}; }
  // For the event loop, at each wake-up: true (and logged) once restartReason() has been
  // set for a second with the worker idle, so that the fault is on the bus meanwhile;
  // the daemon then exits with kExitRestart.
  bool restartDue(bool workerBusy, TimeNs now);
  // The camera is a free-running sensor (libcamera), not one that exposes on request: a
  // sweep may ask for each frame ahead of its stop (WorkerDeps::slotLeadNs).
  virtual bool cameraFreeRuns() const { return false; }
  // Told of each scan (the simulator's laser timeline); may be null.
  virtual ScanObserver* observer() { return nullptr; }

  ports::CanBus& can() { return *can_; }
  int canFd() const { return can_->fd(); }

 protected:
  Platform() = default;
  // Opens the configured CAN interface with the node's kernel filters.
  Status openCan(const DaemonConfig& cfg);
  void setCalibration(Result<geometry::Calibration> c) { calibration_ = std::move(c); }

 private:
  std::unique_ptr<drivers::SocketCanBus> can_;
  TimeNs restartAtNs_ = 0;
  Result<geometry::Calibration> calibration_ = Status(Error::kNotCalibrated, "no calibration loaded");
};

// The board: GPIO through libgpiod (gpio.chip), the libcamera camera, the calibration at
// `calibrationPath` (empty: the config's `calibration`). Errors: a missing GPIO chip, a
// build without those drivers, the CAN interface. A camera that cannot be opened is not
// an error (logged, and tried again at each scan, which fails as a camera fault until it
// opens), nor is a bad calibration: the platform opens and reports why it is not
// calibrated.
// `debugDir` (alacsd --debug-dir): the LASER line's edges as the daemon drives them and
// the exposures of each scan, as laser_timeline.json there (makeLaserTimelineWriter).
Result<std::unique_ptr<Platform>> openHardwarePlatform(const DaemonConfig& cfg, const std::string& calibrationPath,
                                                       const Clock& clock, const std::string& debugDir);

// --debug-dir's laser timeline: after each scan, `laser`'s recorded edges and the scan's
// exposure windows go to DIR/laser_timeline.json (then the edges are cleared).
std::unique_ptr<ScanObserver> makeLaserTimelineWriter(const std::string& dir, ports::FakeDigitalOut& laser,
                                                      int maxOnMs);

// What the scan worker needs from the config and the platform: its lines, `camera`
// (the platform's, or a recorder in front of it), the laser guard, the clock.
WorkerDeps workerDepsFor(const DaemonConfig& cfg, Platform& platform, const Clock& clock, Sleeper& sleeper,
                         LaserGuard& laser, ports::FrameSource& camera, const std::string& debugDir);

// `alacsd --laser-off` (the unit's ExecStopPost): requests the configured chip's LASER
// line (gpio.chip, gpio.laser: the names in force, not a fixed one), drives it off and
// releases it. Errors: no GPIO configured, the chip or line missing, a build without
// libgpiod.
Status driveLaserOff(const DaemonConfig& cfg);

#ifdef ALACS_HAVE_GPIOD
// The LASER line through its guard process (drivers/gpiod/laser_guard.h): this binary
// (/proc/self/exe) serves it, and ends any pulse kLaserGuardMarginMs after
// laser.max_on_ms, so that the daemon's own check (LASER_OVERTIME at max_on_ms) comes
// first and the guard only acts when the daemon cannot.
inline constexpr int kLaserGuardMarginMs = 25;
drivers::LaserGuardOptions laserGuardFor(const DaemonConfig& cfg);
#endif

}  // namespace alacs::app
