// The whole behaviour of the ALACS node, with no device, thread or clock of its own
// (libcanard's shape, one level up): the event loop hands it CAN frames, the worker's
// events and the time; it answers through the CAN bus port and drives the scan worker
// and the laser guard. The daemon's platforms (hardware, sim, replay) supply the ports;
// the unit tests supply fakes and a virtual clock (tests/unit/app_sensor_test.cpp).
//
// States: BOOT -> HOMING -> IDLE <-> SCANNING; any fault -> FAULT; STOP -> STOPPED;
// CLEAR_FAULT -> IDLE. See docs/daemon.md for the state diagram.
#pragma once

#include <limits>
#include <optional>
#include <string>

#include "app/config.h"
#include "app/laser_guard.h"
#include "app/scan_jobs.h"
#include "geometry/calibration.h"
#include "ports/can_bus.h"
#include "ports/digital_io.h"
#include "protocol/node.h"

namespace alacs::app {

// Told of each scan as it starts and ends (the recorder, the debug timeline).
class ScanObserver {
 public:
  virtual ~ScanObserver() = default;
  virtual void scanStarted(const protocol::LocalizeCommand& /*command*/, const localize::ScanPlan& /*plan*/) {}
  virtual void scanFinished(const WorkerEvent& /*ev*/) {}
};

struct SensorPorts {
  ports::CanBus* can = nullptr;           // required
  ScanJobs* worker = nullptr;             // required
  LaserGuard* laser = nullptr;            // required
  ports::DigitalIn* homeSwitch = nullptr; // optional: shown in the status frame
  ScanObserver* observer = nullptr;       // optional
};

struct SensorVersion {
  int major = 0;
  int minor = 0;
  int patch = 0;
};

class Sensor {
 public:
  // `calibration`: the loaded calibration, or why there is none. Without one the sensor
  // still homes and answers, and NACKs LOCALIZE and SCAN_ALL with NOT_CALIBRATED.
  Sensor(const DaemonConfig& config, const SensorPorts& ports, Result<geometry::Calibration> calibration,
         SensorVersion version = {});

  // Queues the boot-up (the node's first frame) and starts homing.
  void start(TimeNs now);
  // One frame received from the bus.
  void onCanFrame(const ports::CanFrame& frame, TimeNs now);
  // One event posted by the worker.
  void onWorkerEvent(const WorkerEvent& ev, TimeNs now);
  // Time-driven work: the laser's on-time limit, NMT reset, heartbeat and status frames,
  // deferred settings, and transmission. Call at least every 10 ms and at nextDeadline().
  void tick(TimeNs now);
  // Shutdown (SIGTERM): the command in progress is answered as ABORTED, the worker
  // cancelled, the laser off. The caller then ticks until txPending() is 0 (bounded).
  void shutdown(TimeNs now);

  // The CAN loop's receive side, once per wake-up of the event loop whether or not the
  // socket has frames: drains the receive queue into onCanFrame(), at most
  // kMaxFramesPerService frames so that a flood cannot starve the timers. A drain that
  // ends without an error is the CAN loop's receive progress; tick()'s transmit flush is
  // its transmit progress (canLoopDeadlineNs()).
  void serviceCan(TimeNs now);
  static constexpr int kMaxFramesPerService = 256;

  // Whether every part has shown progress within its own deadline (docs/daemon.md,
  // "Watchdog"): the worker (busy without progress beyond workerDeadlineNs()), the frame
  // source (a frame read in flight beyond frameDeadlineNs()) and the CAN loop (no receive
  // drain or transmit flush within canLoopDeadlineNs()). Each miss raises a FAULT whose
  // reason names the part (stallReason()); the daemon pings the systemd watchdog only
  // while this holds.
  bool healthy() const { return !workerStalled_ && stalledReadNs_ == 0 && !canStalled_; }
  // The worker thread may never return (no progress, or a frame read that does not end):
  // it cannot be joined.
  bool workerStuck() const { return workerStalled_ || stalledReadNs_ != 0; }
  // The last missed deadline, naming the part ("scan worker", "frame source", "CAN loop");
  // empty before any.
  const std::string& stallReason() const { return stallReason_; }
  // The longest the worker may go without progress while busy: the longest single
  // phase (homing, or a capture with its retries) plus `slackNs` (setWorkerSlack).
  TimeNs workerDeadlineNs() const;
  // The longest one frame read may take: camera.frame_timeout_ms (the source's own
  // timeout) plus the exposure plus the same slack (a reopen of the camera, a render).
  TimeNs frameDeadlineNs() const;
  // The longest the event loop may go without draining the CAN receive queue and
  // flushing the transmit queue: a STOP waits that long at most.
  static constexpr TimeNs canLoopDeadlineNs() { return kNsPerS; }
  // Extra time for a platform whose frames take long to make (the simulator renders).
  void setWorkerSlack(TimeNs slackNs) { workerSlackNs_ = slackNs; }

  // The next time tick() has something to do (INT64_MAX: nothing scheduled).
  TimeNs nextDeadline() const;
  size_t txPending() const { return node_.txPending(); }
  protocol::State state() const { return state_; }
  uint16_t faults() const { return node_.faults(); }
  const protocol::CanNode& node() const { return node_; }
  const DaemonConfig& config() const { return cfg_; }
  bool calibrated() const { return calibration_.has_value(); }
  const std::string& calibrationRefusal() const { return calibrationRefusal_; }
  // The configuration file was refused (alacsd runs on the built-in defaults): the sensor
  // stays up and answers, CONFIG_INVALID is latched in its faults (CLEAR_FAULT keeps it),
  // and HOME, LOCALIZE and SCAN_ALL are NACKed FAULT_ACTIVE, since the defaults need not
  // match the slide. Call before start().
  void refuseConfig(std::string reason);
  const std::string& configFileRefusal() const { return configFileRefusal_; }
  uint32_t lastLatencyMs() const { return lastLatencyMs_; }

 private:
  enum class CancelCause { kNone, kStop, kFault, kShutdown };
  struct ActiveCommand {
    protocol::Command command;
    WorkerJob::Kind kind = WorkerJob::Kind::kHome;
    TimeNs commandTimeNs = 0;
  };

  void onCommand(const protocol::Command& c, TimeNs now);
  void onStop(const protocol::Command& c);
  void onClearFault(const protocol::Command& c);
  void onHome(const protocol::Command& c, TimeNs now);
  void onLocalize(const protocol::Command& c, TimeNs now);
  void onScanAll(const protocol::Command& c, TimeNs now);
  // Refusal shared by LOCALIZE and SCAN_ALL: the state, calibration and homing checks.
  protocol::NackReason scanRefusal() const;
  void onHomeDone(const WorkerEvent& ev);
  void publishScanResult(const WorkerEvent& ev, TimeNs now);
  // The owed result now, without the worker's event (shutdown, a stalled worker);
  // the worker's own event for it, if it ever comes, is then not published again.
  void answerNow(protocol::ResultStatus status, TimeNs now);
  protocol::NackReason applyConfig(const protocol::SetConfigCommand& s);
  protocol::SetConfigCommand currentConfig() const;
  void pushWorkerSettings();
  void enterFault(uint16_t bit, const Status& why);
  bool startHoming(TimeNs now);
  protocol::StatusReport statusReport();
  void flushTx(TimeNs now);
  void keepHeartbeat(TimeNs now);
  void checkWorkerProgress(TimeNs now);
  void checkFrameRead(TimeNs now);
  void checkCanLoop(TimeNs now);
  // A part missed its deadline: FAULT (`faultBit`) with `why`, kept as stallReason().
  void missDeadline(uint16_t faultBit, const std::string& why);
  void sendProgress(TimeNs now);
  protocol::ResultReason resultReasonOf(const WorkerEvent& ev) const;
  bool submit(const WorkerJob& job);

  DaemonConfig cfg_;
  SensorPorts ports_;
  SensorVersion version_;
  protocol::CanNode node_;
  std::optional<geometry::Calibration> calibration_;
  std::string calibrationRefusal_;
  std::string configFileRefusal_;
  protocol::State state_ = protocol::State::kBoot;
  uint16_t faults_ = 0;
  std::optional<ActiveCommand> active_;
  CancelCause cancelCause_ = CancelCause::kNone;
  Status cancelReason_;
  bool workerSettingsPending_ = false;  // SET_CONFIG/SDO accepted while the worker was busy
  static constexpr TimeNs kNotYet = std::numeric_limits<TimeNs>::min();
  TimeNs bootUpNs_ = kNotYet;      // when the boot-up was written (kNotYet: not since the last start)
  bool heartbeatStarted_ = false;  // the cyclic heartbeat, one period after the boot-up
  TimeNs heartbeatStartNs() const { return bootUpNs_ + node_.heartbeatPeriod(); }
  bool resultOwed_ = false;
  uint16_t faultCause_ = 0;  // the fault bit that cancelled the running job
  struct ConfigRefusal {
    protocol::NackDetail detail = protocol::NackDetail::kNone;
    double value = 0.0;
    double limit = 0.0;
  } configRefusal_;           // why the last SET_CONFIG was refused
  ScanProgress lastProgress_;
  TimeNs lastProgressNs_ = 0;
  bool progressSent_ = false;  // a LOCALIZE or SCAN_ALL was ACKed and its result is not out
  bool workerStalled_ = false;
  TimeNs stalledReadNs_ = 0;  // start of the frame read that missed its deadline (0: none)
  bool canStalled_ = false;
  TimeNs canRxNs_ = -1;  // the CAN loop's last receive drain and transmit flush
  TimeNs canTxNs_ = -1;  // (-1: before start())
  Status canRxError_;    // the last receive error, for the stall's reason
  std::string stallReason_;
  TimeNs submittedNs_ = 0;               // the last job's submission
  TimeNs workerSlackNs_ = 2 * kNsPerS;
  uint16_t measCounter_ = 0;
  uint32_t lastLatencyMs_ = 0;
  uint32_t maxLatencyMs_ = 0;
};

}  // namespace alacs::app
