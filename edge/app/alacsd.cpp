// alacsd: the ALACS sensor daemon. Options, the platform chosen once (hardware, sim or
// replay; edge/app/platform.h), and one event loop (epoll over the CAN socket, a 10 ms
// timerfd, the worker's eventfd and a signalfd) that feeds app::Sensor, which holds the
// whole behaviour (edge/app/sensor.h). Everything that blocks runs on the ScanWorker.

#include <signal.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>
#include <sys/timerfd.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <string_view>

#include "alacsd_options.h"  // beside this file: part of the alacsd executable
#include "app/config.h"
#include "app/platform.h"
#include "app/process_memory.h"
#include "app/scan_worker.h"
#include "app/sensor.h"
#include "app/sim_options.h"
#include "common/log.h"
#ifdef ALACS_HAVE_GPIOD
#include "drivers/gpiod/laser_guard.h"
#endif
#include "app/recording_observer.h"
#ifdef ALACS_WITH_SIM
#include "app/sim_platform.h"
#endif
#ifdef ALACS_HAVE_SYSTEMD
#include <systemd/sd-daemon.h>
#endif

namespace alacs::app {
namespace {

constexpr SensorVersion kVersion{ALACS_VERSION_MAJOR, ALACS_VERSION_MINOR, ALACS_VERSION_PATCH};

void notify(const char* what) {
#ifdef ALACS_HAVE_SYSTEMD
  sd_notify(0, what);
#else
  (void)what;
#endif
}

Result<std::unique_ptr<Platform>> openPlatform(const Options& o, const DaemonConfig& cfg, const Clock& clock,
                                               Sleeper& sleeper) {
#ifdef ALACS_WITH_SIM
  SimOptions so = o.simOpts;
  so.calibrationPath = o.calibrationPath;
  if (!o.replayDir.empty()) return openReplayPlatform(cfg, o.replayDir, so, clock, sleeper);
  if (o.sim) return openSimPlatform(cfg, so, clock, sleeper);
#else
  (void)sleeper;
  if (o.sim || !o.replayDir.empty()) return Status(Error::kUnsupported, "this build has no simulator (--sim, --replay)");
#endif
  return openHardwarePlatform(cfg, o.calibrationPath, clock, o.simOpts.debugDir);
}

// The event loop. Returns the process's exit code.
int runDaemon(const Options& o, const DaemonConfig& cfg, const std::string& configRefusal) {
  // Block the signals before any thread starts, so that only the signalfd sees them.
  sigset_t mask;
  sigemptyset(&mask);
  for (int sig : {SIGTERM, SIGINT, SIGHUP}) sigaddset(&mask, sig);
  pthread_sigmask(SIG_BLOCK, &mask, nullptr);
  MonotonicClock clock;
  MonotonicSleeper sleeper;
  Result<std::unique_ptr<Platform>> opened = openPlatform(o, cfg, clock, sleeper);
  if (!opened) {
    ALACS_LOG_ERROR("main", "%s", opened.status().toString().c_str());
    return 1;
  }
  Platform& platform = **opened;
  const ports::SensorLines& lines = platform.lines();
  LaserGuard laser(*lines.laser, clock, cfg.laserMaxOnMs * kNsPerMs);
  (void)laser.off();
  std::unique_ptr<replay::ScanRecorder> recorder;
  std::unique_ptr<replay::RecordingSource> recording;
  std::unique_ptr<ScanWorker> worker;
  if (!o.recordDir.empty()) {
    const Result<geometry::Calibration>& cal = platform.calibration();  // none: LOCALIZE is refused, nothing recorded
    recorder = std::make_unique<replay::ScanRecorder>(o.recordDir, cal ? *cal : geometry::Calibration{}, "alacsd",
                                                      o.recordQuota);
    recording = std::make_unique<replay::RecordingSource>(
        platform.camera(), *recorder, [&worker] { return worker ? worker->positionMm() : 0.0; },
        [&laser] { return laser.isOn(); });
  }
  RecordingObserver observer(recorder.get(), platform.observer());
  const int eventFd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  const WorkerDeps deps = workerDepsFor(cfg, platform, clock, sleeper, laser,
                                        recording ? *recording : platform.camera(), o.simOpts.debugDir);
  worker = std::make_unique<ScanWorker>(deps, eventFd);
  Sensor sensor(cfg, {&platform.can(), worker.get(), &laser, platform.statusHomeSwitch(), &observer}, platform.calibration(), kVersion);
  if (!configRefusal.empty()) sensor.refuseConfig(configRefusal);
  sensor.setWorkerSlack(platform.workerSlackNs());

  const int sfd = signalfd(-1, &mask, SFD_NONBLOCK | SFD_CLOEXEC);
  const int tfd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
  itimerspec tick{};
  tick.it_interval.tv_nsec = tick.it_value.tv_nsec = 10 * kNsPerMs;
  timerfd_settime(tfd, 0, &tick, nullptr);
  const int ep = epoll_create1(EPOLL_CLOEXEC);
  for (int fd : {platform.canFd(), sfd, tfd, eventFd}) {
    epoll_event e{};
    e.events = EPOLLIN;
    e.data.fd = fd;
    epoll_ctl(ep, EPOLL_CTL_ADD, fd, &e);
  }
  sensor.start(clock.now());
  notify("READY=1");
  uint64_t watchdogUs = 0;
#ifdef ALACS_HAVE_SYSTEMD
  if (sd_watchdog_enabled(0, &watchdogUs) <= 0) watchdogUs = 0;
#endif
  TimeNs lastWatchdog = 0;
  ALACS_LOG_INFO("main", "alacsd %d.%d.%d up: node 0x%02x on %s (%s platform)", kVersion.major, kVersion.minor,
                 kVersion.patch, cfg.nodeId, cfg.canInterface.c_str(), platform.name());
  int exitCode = 0;
  for (bool running = true; running;) {
    // Wake for the node's next deadline (heartbeat, status, a paced retry) to the ms.
    const TimeNs untilNs = sensor.nextDeadline() - clock.now();
    const int timeoutMs = untilNs <= 0 ? 0 : static_cast<int>(std::min<TimeNs>(100, (untilNs + kNsPerMs - 1) / kNsPerMs));
    epoll_event events[8];
    const int n = epoll_wait(ep, events, 8, timeoutMs);
    const TimeNs now = clock.now();
    for (int i = 0; i < n; ++i) {
      const int fd = events[i].data.fd;
      uint64_t count = 0;
      if (fd == sfd) {
        signalfd_siginfo si{};
        while (::read(sfd, &si, sizeof si) == sizeof si) {
          // SIGHUP is not a reload: the unit restarts us (exit 1, Restart=on-failure).
          ALACS_LOG_INFO("main", "signal %u: shutting down%s", si.ssi_signo, si.ssi_signo == SIGHUP ? " (exit 1)" : "");
          if (si.ssi_signo == SIGHUP) exitCode = 1;
          running = false;
        }
      } else if (fd == tfd || fd == eventFd) {
        [[maybe_unused]] ssize_t r = ::read(fd, &count, sizeof count);
        while (std::optional<WorkerEvent> ev = worker->takeEvent()) sensor.onWorkerEvent(*ev, now);
      }
      // The CAN socket only wakes the loop: it is drained below, at every wake-up.
    }
    // Every wake-up (10 ms at most apart) drains the CAN socket and flushes the transmit
    // queue: the CAN loop's progress, which its deadline watches.
    sensor.serviceCan(now);
    sensor.tick(now);
    if (platform.restartDue(worker->busy(), now)) {
      exitCode = kExitRestart;
      running = false;
    }
    // The watchdog is fed only while the worker, the frame source and the CAN loop keep
    // their deadlines (Sensor::healthy).
    if (watchdogUs > 0 && sensor.healthy() && now - lastWatchdog > static_cast<TimeNs>(watchdogUs) * kNsPerUs / 2) {
      notify("WATCHDOG=1");
      lastWatchdog = now;
    }
  }
  notify("STOPPING=1");
  sensor.shutdown(clock.now());
  // The answers go out before the process ends, bounded by 200 ms.
  for (const TimeNs until = clock.now() + 200 * kNsPerMs; sensor.txPending() > 0 && clock.now() < until;) {
    sensor.tick(clock.now());
    sleeper.sleepUntil(clock.now() + kNsPerMs);
  }
  (void)laser.off();
  if (sensor.workerStuck()) {
    // A stuck worker (a frame read that never returns) cannot be joined: end the process.
    ALACS_LOG_ERROR("main", "scan worker stuck: exiting without joining it; laser off");
    std::_Exit(1);
  }
  worker.reset();
  for (int fd : {ep, tfd, sfd, eventFd}) ::close(fd);
  ALACS_LOG_INFO("main", "stopped; laser off; peak resident memory %.1f MB", peakResidentMb());
  return exitCode;
}

}  // namespace
}  // namespace alacs::app

int main(int argc, char** argv) {
  using namespace alacs;
#ifdef ALACS_HAVE_GPIOD
  // The laser's guard process (drivers/gpiod/laser_guard.h) is alacs-laser-guard beside
  // alacsd; when that is missing, alacsd serves it itself, started as `alacsd --laser-guard
  // FD CHIP LINE MAX_ON_MS` (app/platform.cpp laserGuardFor). Not an option for people.
  if (const int exit = drivers::runLaserGuardFromArgs(argc, argv); exit >= 0) return exit;
#endif
  app::mapLargeBlocks();
  app::Options o;
  bool laserOff = false;
  if (const int exit = app::parseCommandLine(argc, argv, o, laserOff); exit >= 0) return exit;
  log::Level level = log::Level::kInfo;
  (void)log::parseLevel(o.level.c_str(), &level);
  log::setLevel(level);
  const auto withOptions = [&o](app::DaemonConfig c) -> Result<app::DaemonConfig> {
    if (!o.canInterface.empty()) c.canInterface = o.canInterface;
    if (o.nodeId > 0) c.nodeId = o.nodeId;
    if (!o.gpioChip.empty()) c.gpioChip = o.gpioChip;
    if (Status s = app::validateConfig(c); !s) return s;
    return c;
  };
  Result<app::DaemonConfig> cfg = o.configPath.empty() ? app::DaemonConfig{} : app::loadConfig(o.configPath);
  if (cfg) cfg = withOptions(*cfg);
  // A refused configuration file does not end the daemon (a restart loop would only hide
  // the reason from the bus): it runs on the built-in defaults with the command line's
  // CAN interface, node id and GPIO chip, and reports CONFIG_INVALID (docs/daemon.md).
  std::string configRefusal;
  if (!cfg) {
    configRefusal = cfg.status().toString();
    std::fprintf(stderr, "alacsd: %s; running on the built-in defaults\n", configRefusal.c_str());
    cfg = withOptions(app::DaemonConfig{});
    if (!cfg) {
      std::fprintf(stderr, "alacsd: %s\n", cfg.status().toString().c_str());
      return 2;
    }
  }
  if (laserOff) {
    const Status s = app::driveLaserOff(*cfg);
    std::fprintf(stderr, "alacsd: laser off: %s\n", s.toString().c_str());
    return s ? 0 : 1;
  }
  return app::runDaemon(o, *cfg, configRefusal);
}
