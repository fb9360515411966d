// alacsd: the ALACS sensor daemon. Wires the drivers to the logic and runs one event
// loop (epoll over the CAN socket, a 10 ms timerfd, the worker's eventfd and a
// signalfd). Everything that blocks runs on the ScanWorker thread.
//
// States: BOOT -> HOMING -> IDLE <-> SCANNING; any fault -> FAULT; CLEAR_FAULT -> IDLE
// (unhomed after a motion fault). See docs/daemon.md for the state diagram.

#include <getopt.h>
#include <signal.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>
#include <sys/timerfd.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>

#include "app/config.h"
#include "app/laser_guard.h"
#include "app/process_memory.h"
#include "app/scan_worker.h"
#include "common/log.h"
#include "drivers/socketcan/socketcan.h"
#include "geometry/calibration.h"
#include "protocol/node.h"
#include "sim/scene.h"
#include "sim/sim_camera.h"
#include "sim/sim_slide.h"
#include "replay/replay_source.h"
#include "replay/scan_recorder.h"
#include "ports/frame_source_fault.h"
#ifdef ALACS_HAVE_GPIOD
#include "drivers/gpiod/gpiod_lines.h"
#endif
#ifdef ALACS_HAVE_LIBCAMERA
#include "drivers/libcamera/libcamera_source.h"
#endif
#ifdef ALACS_HAVE_SYSTEMD
#include <systemd/sd-daemon.h>
#endif

#ifndef ALACS_VERSION_MAJOR
#define ALACS_VERSION_MAJOR 0
#define ALACS_VERSION_MINOR 1
#define ALACS_VERSION_PATCH 0
#endif

namespace alacs::app {
namespace {

struct Options {
  std::string configPath;
  std::string canInterface;
  std::string gpioChip;
  std::string calibrationPath;
  std::string scenePath;
  std::string truthOut;
  std::string debugDir;
  int nodeId = -1;
  bool sim = false;
  double simStartMm = 37.0;
  std::string simFault;  // injected simulated hardware fault (tests): camera-timeout|camera-corrupt|home-stuck
  std::string replayDir;  // --replay: a scan directory as the camera (slide and laser simulated)
  std::string recordDir;  // --record: every scan written as a scan directory here
  log::Level level = log::Level::kInfo;
};

void usage(FILE* out) {
  std::fprintf(out,
               "usage: alacsd [options]\n"
               "  --config FILE        configuration JSON (default: built-in defaults)\n"
               "  --can IFACE          CAN interface (overrides can.interface)\n"
               "  --node-id N          CAN node id 1..127 (overrides can.node_id)\n"
               "  --gpio-chip CHIP     GPIO chip path or label (overrides gpio.chip)\n"
               "  --calibration FILE   calibration JSON (overrides calibration)\n"
               "  --sim                simulated camera and slide (the built-in scene)\n"
               "  --sim-scene FILE     scene JSON for --sim\n"
               "  --sim-truth-out FILE write the simulated scene's truth as JSON\n"
               "  --sim-start-mm MM    where the simulated slide starts (default 37)\n"
               "  --sim-fault FAULT    inject a simulated hardware fault: camera-timeout,\n"
               "                       camera-corrupt or home-stuck (the home switch never closes)\n"
               "  --replay DIR         replay a scan directory as the camera (docs/scan-format.md),\n"
               "                       slide and laser simulated; its calibration unless --calibration\n"
               "  --record DIR         write every scan as a scan directory DIR/scan_NNNN\n"
               "  --debug-dir DIR      write an overlay PNG of the lines found per scan\n"
               "  --log-level LEVEL    error|warning|info|debug\n"
               "  --version            print the version\n");
}

int parseOptions(int argc, char** argv, Options* o) {
  enum { kConfig = 1, kCan, kNode, kGpio, kCal, kSim, kScene, kTruth, kStart, kDebug, kLevel, kVersion, kHelp, kFault, kReplay, kRecord };
  static const option kLong[] = {
      {"config", required_argument, nullptr, kConfig}, {"can", required_argument, nullptr, kCan},
      {"node-id", required_argument, nullptr, kNode},  {"gpio-chip", required_argument, nullptr, kGpio},
      {"calibration", required_argument, nullptr, kCal}, {"sim", no_argument, nullptr, kSim},
      {"sim-scene", required_argument, nullptr, kScene}, {"sim-truth-out", required_argument, nullptr, kTruth},
      {"sim-start-mm", required_argument, nullptr, kStart}, {"debug-dir", required_argument, nullptr, kDebug},
      {"sim-fault", required_argument, nullptr, kFault},
      {"replay", required_argument, nullptr, kReplay}, {"record", required_argument, nullptr, kRecord},
      {"log-level", required_argument, nullptr, kLevel}, {"version", no_argument, nullptr, kVersion},
      {"help", no_argument, nullptr, kHelp},           {nullptr, 0, nullptr, 0}};
  int c = 0;
  while ((c = getopt_long(argc, argv, "", kLong, nullptr)) != -1) {
    char* end = nullptr;
    switch (c) {
      case kConfig: o->configPath = optarg; break;
      case kCan: o->canInterface = optarg; break;
      case kNode:
        o->nodeId = static_cast<int>(std::strtol(optarg, &end, 0));
        if (*end != '\0' || o->nodeId < 1 || o->nodeId > 127) {
          std::fprintf(stderr, "alacsd: --node-id must be 1..127, got '%s'\n", optarg);
          return 2;
        }
        break;
      case kGpio: o->gpioChip = optarg; break;
      case kCal: o->calibrationPath = optarg; break;
      case kSim: o->sim = true; break;
      case kScene: o->scenePath = optarg; break;
      case kReplay:
        o->replayDir = optarg;
        o->sim = true;  // the slide and the laser line are simulated; the camera replays
        break;
      case kRecord: o->recordDir = optarg; break;
      case kTruth: o->truthOut = optarg; break;
      case kStart:
        o->simStartMm = std::strtod(optarg, &end);
        if (*end != '\0' || !std::isfinite(o->simStartMm)) {
          std::fprintf(stderr, "alacsd: --sim-start-mm needs a number, got '%s'\n", optarg);
          return 2;
        }
        break;
      case kDebug: o->debugDir = optarg; break;
      case kFault:
        o->simFault = optarg;
        if (o->simFault != "camera-timeout" && o->simFault != "camera-corrupt" && o->simFault != "home-stuck") {
          std::fprintf(stderr, "alacsd: --sim-fault must be camera-timeout|camera-corrupt|home-stuck, got '%s'\n", optarg);
          return 2;
        }
        break;
      case kLevel:
        if (!log::parseLevel(optarg, &o->level)) {
          std::fprintf(stderr, "alacsd: --log-level must be error|warning|info|debug, got '%s'\n", optarg);
          return 2;
        }
        break;
      case kVersion:
        std::printf("alacsd %d.%d.%d\n", ALACS_VERSION_MAJOR, ALACS_VERSION_MINOR, ALACS_VERSION_PATCH);
        return 1;
      case kHelp: usage(stdout); return 1;
      default: usage(stderr); return 2;
    }
  }
  if (optind < argc) {
    std::fprintf(stderr, "alacsd: unexpected argument '%s'\n", argv[optind]);
    return 2;
  }
  if (!o->replayDir.empty() && o->calibrationPath.empty()) o->calibrationPath = o->replayDir + "/calibration.json";
  if ((!o->scenePath.empty() || !o->simFault.empty()) && !o->sim) {
    std::fprintf(stderr, "alacsd: --sim-scene and --sim-fault need --sim\n");
    return 2;
  }
  return 0;
}

void notify(const char* what) {
#ifdef ALACS_HAVE_SYSTEMD
  sd_notify(0, what);
#else
  (void)what;
#endif
}

class Daemon {
 public:
  Daemon(Options opts, DaemonConfig cfg) : opts_(std::move(opts)), cfg_(std::move(cfg)) {}

  int run();

 private:
  Status setUp();
  void onCommand(const protocol::Command& c, TimeNs now);
  protocol::NackReason applyConfig(const protocol::SetConfigCommand& s);
  protocol::SetConfigCommand currentConfig() const;
  void onWorkerEvent(const WorkerEvent& ev, TimeNs now);
  void flushTx();
  void enterFault(uint16_t bit, const Status& why);
  protocol::StatusReport statusReport();
  bool startHoming();  // false: the worker's queue is full (never after busy() said no)
  // --sim --debug-dir: the laser line's edges and the exposures of the last scan, as JSON.
  void writeLaserTimeline(const WorkerEvent& ev);

  Options opts_;
  DaemonConfig cfg_;
  MonotonicClock clock_;
  MonotonicSleeper sleeper_;
  std::unique_ptr<drivers::SocketCan> can_;
  std::unique_ptr<drivers::CyclicSender> heartbeat_;  // kernel-timed heartbeat (CAN_BCM)
  std::unique_ptr<protocol::CanNode> node_;
  std::unique_ptr<sim::SimSlide> simSlide_;
  std::unique_ptr<ports::FakeDigitalOut> simLaser_;
  std::unique_ptr<ports::DigitalOut> teeStep_, teeDir_, teeEnable_, teeLaser_;
  std::unique_ptr<ports::FakeDigitalOut> nullStep_, nullDir_, nullEnable_;
#ifdef ALACS_HAVE_GPIOD
  std::unique_ptr<drivers::GpiodLines> gpio_;
#endif
  ports::DigitalIn* realHome_ = nullptr;
  std::unique_ptr<ports::FrameSource> camera_;
  std::unique_ptr<ports::FaultInjectingFrameSource> faultyCamera_;
  replay::ReplaySource* replay_ = nullptr;          // --replay: the camera (owned by camera_)
  std::unique_ptr<replay::ScanRecorder> recorder_;  // --record
  std::unique_ptr<ports::AnyOfDigitalIn> endSwitch_;
  ports::FakeDigitalIn stuckOpenHome_{false};
  std::unique_ptr<LaserGuard> laser_;
  std::unique_ptr<ScanWorker> worker_;
  std::optional<geometry::Calibration> calibration_;
  protocol::State state_ = protocol::State::kBoot;
  uint16_t faults_ = 0;
  std::optional<protocol::Command> activeCommand_;
  uint16_t measCounter_ = 0;
  uint32_t lastLatencyMs_ = 0;
  uint32_t maxLatencyMs_ = 0;
  int eventFd_ = -1;
};

Status Daemon::setUp() {
  log::setLevel(opts_.level);
  // Calibration: a bad or missing one is not fatal; the sensor refuses to scan and says why.
  if (opts_.sim && opts_.calibrationPath.empty()) {
    ALACS_LOG_WARN("cal", "--sim without --calibration: using the simulator's true calibration");
  }
  sim::SimScene scene = sim::defaultScene();
  if (opts_.sim && !opts_.scenePath.empty()) {
    Result<sim::SimScene> s = sim::loadScene(opts_.scenePath);
    if (!s) return s.status();
    scene = *s;
  }
  if (opts_.sim && !opts_.truthOut.empty()) {
    if (Status s = sim::saveSceneTruth(scene, opts_.truthOut); !s) return s;
  }
  const std::string calPath = !opts_.calibrationPath.empty() ? opts_.calibrationPath
                              : opts_.sim                   ? std::string()
                                                            : cfg_.calibrationPath;
  if (calPath.empty()) {
    calibration_ = scene.truth;
  } else {
    Result<geometry::Calibration> cal = geometry::loadCalibration(calPath);
    if (cal) {
      calibration_ = *cal;
    } else {
      ALACS_LOG_ERROR("cal", "%s: the sensor will refuse to scan (not calibrated)", cal.status().toString().c_str());
      faults_ |= protocol::kFaultNotCalibrated;
    }
  }

  // CAN: kernel filters pass NMT and the node's own id block (every function code + N)
  // but its heartbeat id, which the kernel sends for us (CAN_BCM) and would loop back:
  // frames for other nodes never wake the loop; unknown ids of our block are counted.
  const auto node = static_cast<uint8_t>(cfg_.nodeId);
  Result<std::unique_ptr<drivers::SocketCan>> can = drivers::SocketCan::open(
      cfg_.canInterface,
      {{0x000, 0x7FF}, {node, 0x47F}, {0x400U + node, 0x67F}, {0x600U + node, 0x77F}, {0x780U + node, 0x7FF}});
  if (!can) return can.status();
  can_ = std::move(*can);
  protocol::NodeConfig nc;
  // The heartbeat is timed by the kernel so that a busy CPU or a flood cannot delay it.
  if (Result<std::unique_ptr<drivers::CyclicSender>> hb = drivers::CyclicSender::open(cfg_.canInterface)) {
    heartbeat_ = std::move(*hb);
    nc.heartbeatByPort = true;
  } else {
    ALACS_LOG_WARN("can", "%s: heartbeat sent by the event loop", hb.status().toString().c_str());
  }
  nc.nodeId = node;
  nc.heartbeatPeriodNs = cfg_.heartbeatMs * kNsPerMs;
  nc.statusPeriodNs = cfg_.statusPeriodMs * kNsPerMs;
  node_ = std::make_unique<protocol::CanNode>(nc);
  // SDO objects 0x1017/0x2000/0x2001 read and write the same settings as SET_CONFIG.
  node_->setConfigAccess({[this] { return currentConfig(); },
                          [this](const protocol::SetConfigCommand& s) { return applyConfig(s); }});

  // Lines: real GPIO when a chip is given; in --sim the simulated slide listens to the
  // same pulses (tee), and its switches close the loop.
  ports::SensorLines lines;
#ifdef ALACS_HAVE_GPIOD
  if (!cfg_.gpioChip.empty()) {
    Result<std::unique_ptr<drivers::GpiodLines>> g = drivers::GpiodLines::open(cfg_.gpioChip, cfg_.lines, "alacsd");
    if (!g) return g.status();
    gpio_ = std::move(*g);
    lines = gpio_->lines();
    realHome_ = lines.home;
    ALACS_LOG_INFO("gpio", "lines requested on %s", gpio_->chipName().c_str());
  }
#else
  if (!cfg_.gpioChip.empty()) return {Error::kUnsupported, "this build has no libgpiod driver"};
#endif
  if (opts_.sim) {
    simSlide_ = std::make_unique<sim::SimSlide>(clock_, cfg_.motion.stepsPerMm, cfg_.motion.strokeMm, opts_.simStartMm);
    simLaser_ = std::make_unique<ports::FakeDigitalOut>(clock_);
    if (lines.step != nullptr) {
      teeStep_ = std::make_unique<ports::TeeDigitalOut>(*lines.step, simSlide_->stepInput());
      teeDir_ = std::make_unique<ports::TeeDigitalOut>(*lines.dir, simSlide_->dirInput());
      teeEnable_ = std::make_unique<ports::TeeDigitalOut>(*lines.enable, simSlide_->enableInput());
      teeLaser_ = std::make_unique<ports::TeeDigitalOut>(*lines.laser, *simLaser_);
      lines.step = teeStep_.get();
      lines.dir = teeDir_.get();
      lines.enable = teeEnable_.get();
      lines.laser = teeLaser_.get();
    } else {
      lines.step = &simSlide_->stepInput();
      lines.dir = &simSlide_->dirInput();
      lines.enable = &simSlide_->enableInput();
      lines.laser = simLaser_.get();
    }
    // The simulated slide closes its own switches; a real END line (bench) can close the
    // end switch too, as a limit hit mid-move.
    if (lines.end != nullptr) {
      endSwitch_ = std::make_unique<ports::AnyOfDigitalIn>(*lines.end, simSlide_->endSwitch());
      lines.end = endSwitch_.get();
    } else {
      lines.end = &simSlide_->endSwitch();
    }
    lines.home = opts_.simFault == "home-stuck" ? static_cast<ports::DigitalIn*>(&stuckOpenHome_)
                                                : &simSlide_->homeSwitch();
    ports::FakeDigitalOut* laserLine = simLaser_.get();
    sim::SimSlide* slide = simSlide_.get();
    // --replay serves recorded frames (below): no renderer, whose ray table alone is 25 MB
    // at 3 MP, counts against the daemon's memory then.
    if (opts_.replayDir.empty())
      camera_ = std::make_unique<sim::SimCamera>(scene, clock_, [laserLine] { return laserLine->level(); },
                                                 [slide] { return slide->positionMm(); });
  } else {
    if (lines.step == nullptr) return {Error::kInvalidArgument, "no GPIO chip configured (gpio.chip) and not --sim"};
#ifdef ALACS_HAVE_LIBCAMERA
    drivers::LibcameraConfig lc;
    lc.cameraId = cfg_.cameraId;
    lc.retries = cfg_.frameRetries;
    if (calibration_) {
      lc.widthPx = calibration_->camera.widthPx;
      lc.heightPx = calibration_->camera.heightPx;
    }
    Result<std::unique_ptr<drivers::LibcameraSource>> cam = drivers::LibcameraSource::open(lc);
    if (!cam) return cam.status();
    camera_ = std::move(*cam);
#else
    return {Error::kUnsupported, "this build has no libcamera driver; use --sim"};
#endif
  }
  if (!opts_.replayDir.empty()) {
    // The recorded frames replace the rendered ones: the worker moves the simulated slide
    // to its stops and the source serves the frame recorded nearest each (docs/scan-format.md).
    ports::FakeDigitalOut* laserLine = simLaser_.get();
    sim::SimSlide* slide = simSlide_.get();
    Result<std::unique_ptr<replay::ReplaySource>> rs = replay::ReplaySource::open(
        opts_.replayDir, clock_, [laserLine] { return laserLine->level(); }, [slide] { return slide->positionMm(); });
    if (!rs) return rs.status();
    replay_ = rs->get();
    camera_ = std::move(*rs);
    ALACS_LOG_INFO("replay", "camera: %zu frames of %s", replay_->manifest().frames.size(), opts_.replayDir.c_str());
  }
  if (!opts_.recordDir.empty()) {
    recorder_ = std::make_unique<replay::ScanRecorder>(opts_.recordDir, calibration_.value_or(scene.truth));
    camera_ = std::make_unique<replay::RecordingSource>(
        std::move(camera_), *recorder_, [this] { return worker_ ? worker_->positionMm() : 0.0; },
        [this] { return laser_ != nullptr && laser_->isOn(); });
  }
  if (opts_.simFault == "camera-timeout" || opts_.simFault == "camera-corrupt") {
    faultyCamera_ = std::make_unique<ports::FaultInjectingFrameSource>(*camera_);
    faultyCamera_->setFault(opts_.simFault == "camera-timeout" ? ports::CameraFault::kTimeout
                                                               : ports::CameraFault::kCorrupt);
  }
  laser_ = std::make_unique<LaserGuard>(*lines.laser, clock_, cfg_.laserMaxOnMs * kNsPerMs);
  (void)laser_->off();

  eventFd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
  if (eventFd_ < 0) return {Error::kIo, "eventfd failed"};
  WorkerDeps deps;
  deps.clock = &clock_;
  deps.sleeper = &sleeper_;
  deps.limits = cfg_.motion;
  deps.stepLines = {lines.step, lines.dir, lines.home, lines.end};
  deps.enable = lines.enable;
  deps.laser = laser_.get();
  deps.camera = faultyCamera_ ? static_cast<ports::FrameSource*>(faultyCamera_.get()) : camera_.get();
  deps.captureRetries = cfg_.frameRetries;
  deps.realtimePriority = cfg_.realtimePriority;
  deps.capture.exposureUs = cfg_.exposureUs;
  deps.capture.timeoutMs = cfg_.frameTimeoutMs;
  deps.debugDir = opts_.debugDir;
  if (replay_ != nullptr) deps.frameSlideMm = [r = replay_] { return r->lastSlideMm(); };
  const geometry::Calibration cal = calibration_.value_or(scene.truth);
  worker_ = std::make_unique<ScanWorker>(deps, localize::Localizer(cal, cfg_.lle, cfg_.scan), eventFd_);
  return Status::ok();
}

protocol::StatusReport Daemon::statusReport() {
  protocol::StatusReport s;
  s.state = state_;
  s.homed = worker_->homed();
  s.laserOn = laser_->isOn();
  s.calibrated = calibration_.has_value();
  if (realHome_ != nullptr) {
    Result<bool> h = realHome_->get();
    s.homeSwitch = h.isOk() && *h;
  } else if (simSlide_) {
    Result<bool> h = simSlide_->homeSwitch().get();
    s.homeSwitch = h.isOk() && *h;
  }
  s.faults = faults_;
  s.lastLatencyMs = lastLatencyMs_;
  s.maxLatencyMs = maxLatencyMs_;
  s.droppedFrames = worker_->droppedFrames();
  return s;
}

void Daemon::enterFault(uint16_t bit, const Status& why) {
  faults_ |= bit;
  state_ = protocol::State::kFault;
  (void)laser_->off();
  worker_->cancel();
  ALACS_LOG_ERROR("fault", "%s", why.toString().c_str());
  // One EMCY per newly raised bit, with its CiA 301 code (protocol::CanNode::setFaults).
  node_->setFaults(faults_);
}

void Daemon::writeLaserTimeline(const WorkerEvent& ev) {
  const std::string path = opts_.debugDir + "/laser_timeline.json";
  FILE* f = std::fopen((path + ".tmp").c_str(), "w");
  if (f == nullptr) {
    ALACS_LOG_WARN("debug", "cannot write %s", path.c_str());
    return;
  }
  std::fprintf(f, "{\n  \"laser_max_on_ms\": %d,\n  \"edges\": [", cfg_.laserMaxOnMs);
  const std::vector<ports::Edge> edges = simLaser_->edges();
  for (size_t i = 0; i < edges.size(); ++i)
    std::fprintf(f, "%s[%lld, %d]", i ? ", " : "", static_cast<long long>(edges[i].timeNs), edges[i].level ? 1 : 0);
  std::fprintf(f, "],\n  \"exposures\": [");
  for (size_t i = 0; i < ev.exposures.size(); ++i)
    std::fprintf(f, "%s[%lld, %lld]", i ? ", " : "", static_cast<long long>(ev.exposures[i].startNs),
                 static_cast<long long>(ev.exposures[i].endNs));
  std::fprintf(f, "]\n}\n");
  std::fclose(f);
  std::rename((path + ".tmp").c_str(), path.c_str());
  simLaser_->clearEdges();
}

bool Daemon::startHoming() {
  WorkerJob job;
  job.kind = WorkerJob::Kind::kHome;
  job.commandTimeNs = clock_.now();
  if (!worker_->submit(job)) return false;
  state_ = protocol::State::kHoming;
  return true;
}

// SET_CONFIG and the SDO server's writes (objects 0x1017, 0x2000, 0x2001): all valid
// fields applied, or none.
protocol::NackReason Daemon::applyConfig(const protocol::SetConfigCommand& s) {
  if (worker_->busy()) return protocol::NackReason::kBusy;
  DaemonConfig next = cfg_;
  if (s.exposureUs) next.exposureUs = *s.exposureUs;
  if (s.brceStep) next.lle.brceStep = *s.brceStep;
  if (s.brceThreshold) next.lle.brceThreshold = *s.brceThreshold;
  if (s.scanStops) next.scan.stops = *s.scanStops;
  if (s.stopSpacingMm) next.scan.stopSpacingMm = *s.stopSpacingMm;
  if (s.heartbeatMs) next.heartbeatMs = *s.heartbeatMs;
  if (Status v = validateConfig(next); !v) {
    ALACS_LOG_WARN("cmd", "set-config refused: %s", v.reason().c_str());
    return protocol::NackReason::kBadValue;
  }
  cfg_ = next;
  node_->setHeartbeatPeriod(cfg_.heartbeatMs * kNsPerMs);
  worker_->setExposureUs(cfg_.exposureUs);
  if (calibration_) worker_->setLocalizer(localize::Localizer(*calibration_, cfg_.lle, cfg_.scan));
  return protocol::NackReason::kNone;
}

protocol::SetConfigCommand Daemon::currentConfig() const {
  protocol::SetConfigCommand s;
  s.exposureUs = static_cast<uint16_t>(cfg_.exposureUs);
  s.brceStep = static_cast<uint8_t>(cfg_.lle.brceStep);
  s.brceThreshold = static_cast<uint8_t>(cfg_.lle.brceThreshold);
  s.scanStops = static_cast<uint8_t>(cfg_.scan.stops);
  s.stopSpacingMm = cfg_.scan.stopSpacingMm;
  s.heartbeatMs = static_cast<uint16_t>(cfg_.heartbeatMs);
  return s;
}

void Daemon::onCommand(const protocol::Command& c, TimeNs now) {
  using protocol::NackReason;
  using protocol::Opcode;
  using protocol::State;
  switch (c.opcode) {
    case Opcode::kGetVersion:
      node_->queueVersion(c, ALACS_VERSION_MAJOR, ALACS_VERSION_MINOR, ALACS_VERSION_PATCH);
      return;
    case Opcode::kStop:
      // Always executed: abort, laser off, latched STOPPED until CLEAR_FAULT.
      node_->ack(c, protocol::AckResult::kAck);
      worker_->cancel();
      (void)laser_->off();
      faults_ |= protocol::kFaultStopRequested;
      state_ = State::kStopped;
      return;
    case Opcode::kClearFault:
      if ((state_ == State::kFault || state_ == State::kStopped) && !worker_->busy()) {
        faults_ &= static_cast<uint16_t>(protocol::kFaultNotCalibrated);
        laser_->reset();
        state_ = State::kIdle;
      }
      node_->clearCanFaults();
      node_->ack(c, protocol::AckResult::kAck);
      return;
    case Opcode::kHome:
      if (state_ == State::kFault || state_ == State::kStopped) return node_->nack(c.opcode, c.counter, NackReason::kFaultActive);
      if (worker_->busy()) return node_->nack(c.opcode, c.counter, NackReason::kBusy);
      if (!startHoming()) return node_->nack(c.opcode, c.counter, NackReason::kBusy);
      node_->ack(c, protocol::AckResult::kAck);
      activeCommand_ = c;
      return;
    case Opcode::kLocalize: {
      if (state_ == State::kFault || state_ == State::kStopped)
        return node_->nack(c.opcode, c.counter, NackReason::kFaultActive);
      if (worker_->busy() || state_ != State::kIdle) return node_->nack(c.opcode, c.counter, NackReason::kBusy);
      if (!calibration_) return node_->nack(c.opcode, c.counter, NackReason::kNotCalibrated);
      if (!worker_->homed()) return node_->nack(c.opcode, c.counter, NackReason::kNotHomed);
      Result<localize::ScanPlan> plan =
          localize::Localizer(*calibration_, cfg_.lle, cfg_.scan).plan(c.localize.roughMm, cfg_.motion.strokeMm);
      if (!plan) {
        ALACS_LOG_WARN("cmd", "localize refused: %s", plan.status().toString().c_str());
        return node_->nack(c.opcode, c.counter, NackReason::kOutOfRange);
      }
      WorkerJob job;
      job.kind = WorkerJob::Kind::kLocalize;
      job.localize = c.localize;
      job.plan = *plan;
      job.commandTimeNs = now;
      // The worker's queue is bounded: refused only if a job were already waiting.
      if (!worker_->submit(job)) return node_->nack(c.opcode, c.counter, NackReason::kBusy);
      node_->ack(c, protocol::AckResult::kAck);
      activeCommand_ = c;
      state_ = State::kScanning;
      if (recorder_) {
        if (Status s = recorder_->begin(c.localize.targetId, c.localize.roughMm, plan->stopsMm, plan->roi); !s)
          ALACS_LOG_WARN("record", "%s", s.toString().c_str());
      }
      return;
    }
    case Opcode::kSetConfig: {
      if (const NackReason r = applyConfig(c.config); r != NackReason::kNone) return node_->nack(c.opcode, c.counter, r);
      node_->ack(c, protocol::AckResult::kAck);
      return;
    }
    case Opcode::kScanAll: {
      if (state_ == State::kFault || state_ == State::kStopped)
        return node_->nack(c.opcode, c.counter, NackReason::kFaultActive);
      if (worker_->busy() || state_ != State::kIdle) return node_->nack(c.opcode, c.counter, NackReason::kBusy);
      if (!calibration_) return node_->nack(c.opcode, c.counter, NackReason::kNotCalibrated);
      if (!worker_->homed()) return node_->nack(c.opcode, c.counter, NackReason::kNotHomed);
      WorkerJob job;
      job.kind = WorkerJob::Kind::kScanAll;
      const survey::SurveyParams sp;
      job.survey.emplace(*calibration_, cfg_.lle, cfg_.scan, sp);
      job.surveyStopsMm = survey::surveyStops(cfg_.motion.strokeMm, sp);
      job.commandTimeNs = now;
      if (!worker_->submit(job)) return node_->nack(c.opcode, c.counter, NackReason::kBusy);
      node_->ack(c, protocol::AckResult::kAck);
      activeCommand_ = c;
      state_ = State::kScanning;
      return;
    }
    case Opcode::kInvalid:
      return node_->nack(c.opcode, c.counter, NackReason::kUnknownOpcode);
  }
}

void Daemon::onWorkerEvent(const WorkerEvent& ev, TimeNs now) {
  if (ev.afterResult) {
    // The slide braking after a continuous scan whose result is already published: a
    // fault is raised as any other; a STOP during it only leaves the position in doubt.
    if (ev.faultBit != 0) {
      enterFault(ev.faultBit, ev.status);
    } else {
      ALACS_LOG_WARN("motion", "after the scan: %s (HOME before the next scan)", ev.status.toString().c_str());
    }
    return;
  }
  const bool isHome = ev.job.kind == WorkerJob::Kind::kHome;
  if (ev.faultBit != 0) {
    enterFault(ev.faultBit, ev.status);
  } else if (state_ != protocol::State::kFault && state_ != protocol::State::kStopped) {
    state_ = protocol::State::kIdle;
  }
  if (isHome) {
    if (ev.status) {
      ALACS_LOG_INFO("motion", "homed (worst step lateness %.1f us)", static_cast<double>(ev.maxStepLatenessNs) / 1e3);
    }
    if (activeCommand_ && activeCommand_->opcode == protocol::Opcode::kHome) {
      if (ev.status) {
        node_->ack(*activeCommand_, protocol::AckResult::kDone);
      } else {
        node_->ack(*activeCommand_, protocol::AckResult::kNack,
                   ev.faultBit != 0 ? protocol::NackReason::kFaultActive : protocol::NackReason::kInternal);
      }
      activeCommand_.reset();
    }
    return;
  }
  const TimeNs cycle = now - ev.job.commandTimeNs;
  lastLatencyMs_ = static_cast<uint32_t>(cycle / kNsPerMs);
  maxLatencyMs_ = std::max(maxLatencyMs_, lastLatencyMs_);
  protocol::ResultHeader h;
  h.measCounter = ++measCounter_;
  h.targetId = ev.job.localize.targetId;
  h.status = ev.resultStatus;
  h.mode = ev.job.kind == WorkerJob::Kind::kScanAll ? 1 : 0;
  h.cycleTimeMs = lastLatencyMs_;
  h.scanAgeMs = ev.lastExposureNs > 0 ? static_cast<uint32_t>((now - ev.lastExposureNs) / kNsPerMs) : 0;
  std::vector<protocol::ResultObject> objects;
  for (const localize::AppleEstimate& e : ev.estimates) {
    protocol::ResultObject o;
    o.index = static_cast<uint8_t>(objects.size());
    o.centerMm = e.centerMm;
    o.approachMm = e.approachMm;
    o.normal = e.approachNormal;
    o.sigmaMm = e.sigmaMm;
    o.confidencePct = e.confidencePct;
    o.diameterMm = e.diameterMm;
    o.occlusionPct = e.occlusionPct;
    o.linesUsed = e.linesUsed;
    o.pointsUsed = e.pointsUsed;
    objects.push_back(o);
    ALACS_LOG_INFO("scan", "%s %u: centre (%.1f, %.1f, %.1f) mm, d %.1f mm, sigma %.2f mm, %d lines, cycle %u ms",
                   h.mode == 1 ? "object" : "target", h.mode == 1 ? o.index : h.targetId, e.centerMm.x(),
                   e.centerMm.y(), e.centerMm.z(), e.diameterMm, e.sigmaMm, e.linesUsed, lastLatencyMs_);
  }
  if (!ev.status) {
    ALACS_LOG_WARN("scan", "target %u: %s", h.targetId, ev.status.toString().c_str());
  }
  h.objectCount = static_cast<uint8_t>(objects.size());
  if (!opts_.debugDir.empty() && simLaser_) writeLaserTimeline(ev);
  // LOCALIZE is answered by its ACK and then this one result (docs/can-protocol.md).
  if (recorder_ && ev.job.kind == WorkerJob::Kind::kLocalize) {
    if (Result<std::string> dir = recorder_->end(); dir) ALACS_LOG_INFO("record", "scan written to %s", dir->c_str());
  }
  node_->publishResult(h, objects);
  activeCommand_.reset();
}

void Daemon::flushTx() {
  // Bounded: at most the queue's length per call, never blocking. A refused write
  // (ENOBUFS: the qdisc is full; or the interface is down) leaves the frame queued and
  // the node paces the retries (1, 2, 4 .. 64 ms; nextDeadline() wakes the loop).
  // EPOLLOUT is no help here: a CAN_RAW socket reports writable while the device queue
  // is full, so waiting on it would spin.
  const TimeNs now = clock_.now();
  for (size_t budget = node_->txPending(); budget > 0 && node_->canTransmit(now); --budget) {
    const ports::CanFrame* f = node_->peekTx();
    if (f == nullptr) return;
    const Status s = can_->write(*f);
    if (!s) {
      if (s.code() != Error::kBusy && node_->counters().txRetries % 100 == 0) ALACS_LOG_WARN("can", "%s", s.toString().c_str());
      node_->onTxRefused(now);
      return;
    }
    node_->popTx();
    node_->onTxDone();
  }
}

int Daemon::run() {
  // Block the signals before any thread starts, so that they all inherit the mask and
  // only the signalfd sees SIGTERM.
  sigset_t mask;
  sigemptyset(&mask);
  sigaddset(&mask, SIGTERM);
  sigaddset(&mask, SIGINT);
  sigaddset(&mask, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &mask, nullptr);
  if (Status s = setUp(); !s) {
    ALACS_LOG_ERROR("main", "%s", s.toString().c_str());
    if (laser_) (void)laser_->off();
    return 1;
  }
  const int sfd = signalfd(-1, &mask, SFD_NONBLOCK | SFD_CLOEXEC);
  const int tfd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
  itimerspec tick{};
  tick.it_interval.tv_nsec = 10 * kNsPerMs;
  tick.it_value.tv_nsec = 10 * kNsPerMs;
  timerfd_settime(tfd, 0, &tick, nullptr);
  const int ep = epoll_create1(EPOLL_CLOEXEC);
  auto add = [&](int fd, uint32_t events) {
    epoll_event e{};
    e.events = events;
    e.data.fd = fd;
    epoll_ctl(ep, EPOLL_CTL_ADD, fd, &e);
  };
  add(can_->fd(), EPOLLIN);
  add(sfd, EPOLLIN);
  add(tfd, EPOLLIN);
  add(eventFd_, EPOLLIN);

  node_->start(clock_.now());
  if (faults_ & protocol::kFaultNotCalibrated) {
    state_ = protocol::State::kIdle;  // not a fault state: the sensor still homes and answers
  }
  (void)startHoming();  // the queue is empty at start
  notify("READY=1");
  uint64_t watchdogUs = 0;
#ifdef ALACS_HAVE_SYSTEMD
  if (sd_watchdog_enabled(0, &watchdogUs) <= 0) watchdogUs = 0;
#endif
  TimeNs lastWatchdog = 0;
  ALACS_LOG_INFO("main", "alacsd %d.%d.%d up: node 0x%02x on %s%s", ALACS_VERSION_MAJOR, ALACS_VERSION_MINOR,
                 ALACS_VERSION_PATCH, cfg_.nodeId, cfg_.canInterface.c_str(), opts_.sim ? " (simulation)" : "");
  bool running = true;
  while (running) {
    epoll_event events[8];
    // Wake for the node's next deadline (heartbeat, status, a paced retry) to the ms, so
    // the heartbeat keeps its period without waiting for the 10 ms tick.
    const TimeNs untilNs = node_->nextDeadline() - clock_.now();
    const int timeoutMs = untilNs <= 0 ? 0 : static_cast<int>(std::min<TimeNs>(100, (untilNs + kNsPerMs - 1) / kNsPerMs));
    const int n = epoll_wait(ep, events, 8, timeoutMs);
    const TimeNs now = clock_.now();
    for (int i = 0; i < n; ++i) {
      const int fd = events[i].data.fd;
      if (fd == sfd) {
        signalfd_siginfo si{};
        while (::read(sfd, &si, sizeof si) == sizeof si) {
          ALACS_LOG_INFO("main", "signal %u: shutting down", si.ssi_signo);
          running = false;
        }
      } else if (fd == tfd) {
        uint64_t ticks = 0;
        [[maybe_unused]] ssize_t r = ::read(tfd, &ticks, sizeof ticks);
      } else if (fd == eventFd_) {
        uint64_t count = 0;
        [[maybe_unused]] ssize_t r = ::read(eventFd_, &count, sizeof count);
        while (std::optional<WorkerEvent> ev = worker_->takeEvent()) onWorkerEvent(*ev, now);
      } else if (fd == can_->fd()) {
        if (events[i].events & EPOLLIN) {
          // Drain, but bounded per wake-up so a flood cannot starve the timers.
          for (int k = 0; k < 256; ++k) {
            ports::CanFrame f;
            Result<bool> got = can_->read(&f);
            if (!got) {
              ALACS_LOG_WARN("can", "%s", got.status().toString().c_str());
              break;
            }
            if (!*got) break;
            // Bus-off is the node's: it holds transmission until the controller restarts
            // and latches CAN_BUS_OFF (EMCY 0x8140 once the bus is back); scans go on.
            const bool wasBusOff = node_->busOff();
            if (std::optional<protocol::Command> c = node_->push(f, now)) onCommand(*c, now);
            if (node_->busOff() != wasBusOff)
              ALACS_LOG_WARN("can", "%s", node_->busOff() ? "bus-off: transmission held until the controller restarts"
                                                          : "controller restarted after bus-off");
          }
        }
      }
    }
    if (laser_->enforce(now)) enterFault(protocol::kFaultLaserOvertime, Status(Error::kFault, "laser on beyond laser.max_on_ms"));
    if (node_->takeResetRequest()) {
      ALACS_LOG_INFO("can", "NMT reset: restarting the node");
      node_->start(now);
    }
    node_->setFaults(faults_);
    node_->poll(now, [this] { return statusReport(); });
    if (heartbeat_) {
      if (Status s = heartbeat_->keep(node_->heartbeatFrame(), node_->heartbeatPeriod(), now); !s)
        ALACS_LOG_WARN("can", "heartbeat: %s", s.toString().c_str());
    }
    flushTx();
    if (watchdogUs > 0 && now - lastWatchdog > static_cast<TimeNs>(watchdogUs) * kNsPerUs / 2) {
      notify("WATCHDOG=1");
      lastWatchdog = now;
    }
  }
  notify("STOPPING=1");
  (void)laser_->off();
  worker_->cancel();
  worker_.reset();
  (void)laser_->off();
  flushTx();
  ::close(ep);
  ::close(tfd);
  ::close(sfd);
  ::close(eventFd_);
  ALACS_LOG_INFO("main", "stopped; laser off; peak resident memory %.1f MB", peakResidentMb());
  return 0;
}

}  // namespace
}  // namespace alacs::app

int main(int argc, char** argv) {
  using namespace alacs;
  app::mapLargeBlocks();
  app::Options opts;
  const int rc = app::parseOptions(argc, argv, &opts);
  if (rc != 0) return rc == 1 ? 0 : rc;
  app::DaemonConfig cfg;
  if (!opts.configPath.empty()) {
    Result<app::DaemonConfig> loaded = app::loadConfig(opts.configPath);
    if (!loaded) {
      std::fprintf(stderr, "alacsd: %s\n", loaded.status().toString().c_str());
      return 2;
    }
    cfg = *loaded;
  }
  if (!opts.canInterface.empty()) cfg.canInterface = opts.canInterface;
  if (opts.nodeId > 0) cfg.nodeId = opts.nodeId;
  if (!opts.gpioChip.empty()) cfg.gpioChip = opts.gpioChip;
  if (Status s = app::validateConfig(cfg); !s) {
    std::fprintf(stderr, "alacsd: %s\n", s.toString().c_str());
    return 2;
  }
  app::Daemon daemon(std::move(opts), std::move(cfg));
  return daemon.run();
}
