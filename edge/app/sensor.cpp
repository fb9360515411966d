#include "app/sensor.h"

#include <algorithm>
#include <string>

#include "common/log.h"

namespace alacs::app {

using protocol::NackReason;
using protocol::Opcode;
using protocol::State;

namespace {

protocol::NodeConfig nodeConfigFor(const DaemonConfig& cfg, bool heartbeatByPort) {
  protocol::NodeConfig nc;
  nc.nodeId = static_cast<uint8_t>(cfg.nodeId);
  nc.heartbeatPeriodNs = cfg.heartbeatMs * kNsPerMs;
  nc.statusPeriodNs = cfg.statusPeriodMs * kNsPerMs;
  nc.heartbeatByPort = heartbeatByPort;
  nc.autoStart = cfg.nmtAutoStart;
  return nc;
}

protocol::NackDetail nackDetailOf(localize::PlanRefusal::Limit limit) {
  switch (limit) {
    case localize::PlanRefusal::Limit::kDepth: return protocol::NackDetail::kDepth;
    case localize::PlanRefusal::Limit::kStroke: return protocol::NackDetail::kStroke;
    case localize::PlanRefusal::Limit::kFrame: return protocol::NackDetail::kFrame;
    case localize::PlanRefusal::Limit::kNone: break;
  }
  return protocol::NackDetail::kNone;
}

protocol::ResultReason faultReasonOf(uint16_t faultBit) {
  switch (faultBit) {
    case protocol::kFaultCameraTimeout:
    case protocol::kFaultCameraCorrupt: return protocol::ResultReason::kCameraFault;
    case protocol::kFaultHomingTimeout:
    case protocol::kFaultLimitHit: return protocol::ResultReason::kMotionFault;
    case protocol::kFaultLaserOvertime: return protocol::ResultReason::kLaserFault;
    default: return protocol::ResultReason::kInternal;
  }
}

bool isBootUp(const ports::CanFrame& f, uint8_t nodeId) {
  return f.id == 0x700U + nodeId && f.dlc == 1 && f.data[0] == static_cast<uint8_t>(protocol::NmtState::kBootUp);
}

}  // namespace

Sensor::Sensor(const DaemonConfig& config, const SensorPorts& ports, Result<geometry::Calibration> calibration,
               SensorVersion version)
    : cfg_(config), ports_(ports), version_(version), node_(nodeConfigFor(config, ports.can->hasCyclic())) {
  if (calibration) {
    calibration_ = *calibration;
  } else {
    calibrationRefusal_ = calibration.status().reason();
    faults_ |= protocol::kFaultNotCalibrated;
    ALACS_LOG_ERROR("cal", "%s: the sensor will refuse to scan (not calibrated)",
                    calibration.status().toString().c_str());
  }
  // SDO objects 0x1017/0x2000/0x2001 read and write the same settings as SET_CONFIG.
  node_.setConfigAccess({[this] { return currentConfig(); },
                         [this](const protocol::SetConfigCommand& s) { return applyConfig(s); }});
  pushWorkerSettings();
}

void Sensor::refuseConfig(std::string reason) {
  configFileRefusal_ = std::move(reason);
  faults_ |= protocol::kFaultConfigInvalid;
  ALACS_LOG_ERROR("config", "%s: running on the built-in defaults; HOME and scans are refused until it is fixed",
                  configFileRefusal_.c_str());
}

void Sensor::start(TimeNs now) {
  (void)ports_.laser->off();
  node_.start(now);
  canRxNs_ = canTxNs_ = now;
  bootUpNs_ = kNotYet;
  heartbeatStarted_ = false;
  // Not calibrated is not a fault state: the sensor still homes and answers. A refused
  // configuration file leaves the slide where it is: the defaults need not fit it.
  state_ = State::kIdle;
  if (configFileRefusal_.empty()) (void)startHoming(now);  // the worker's queue is empty at start
  node_.setFaults(faults_);
}

bool Sensor::submit(const WorkerJob& job) {
  if (!ports_.worker->submit(job)) return false;
  submittedNs_ = job.commandTimeNs;
  return true;
}

TimeNs Sensor::workerDeadlineNs() const {
  const TimeNs homingNs = cfg_.motion.homingTimeoutMs * kNsPerMs;
  const TimeNs captureNs = (cfg_.frameRetries + 1) * static_cast<TimeNs>(cfg_.frameTimeoutMs) * kNsPerMs;
  return std::max(homingNs, captureNs) + workerSlackNs_;
}

TimeNs Sensor::frameDeadlineNs() const {
  return static_cast<TimeNs>(cfg_.frameTimeoutMs) * kNsPerMs + static_cast<TimeNs>(cfg_.exposureUs) * kNsPerUs +
         workerSlackNs_;
}

void Sensor::missDeadline(uint16_t faultBit, const std::string& why) {
  stallReason_ = why;
  enterFault(faultBit, Status(Error::kTimeout, why + "; the watchdog is withheld"));
}

void Sensor::checkWorkerProgress(TimeNs now) {
  if (!ports_.worker->busy()) {
    workerStalled_ = false;
    return;
  }
  const TimeNs sinceNs = now - std::max(ports_.worker->progressNs(), submittedNs_);
  if (workerStalled_ || sinceNs <= workerDeadlineNs()) return;
  workerStalled_ = true;
  missDeadline(protocol::kFaultInternal, "scan worker: no progress for " + std::to_string(sinceNs / kNsPerMs) +
                                             " ms (deadline " + std::to_string(workerDeadlineNs() / kNsPerMs) +
                                             " ms): a frame or a move is stuck");
  // The worker may never come back: the ACKed command is answered now, as failed.
  answerNow(protocol::ResultStatus::kFailed, now);
}

void Sensor::checkFrameRead(TimeNs now) {
  const TimeNs startNs = ports_.worker->busy() ? ports_.worker->frameReadSinceNs() : 0;
  if (startNs != stalledReadNs_) stalledReadNs_ = 0;  // the read that missed has returned
  if (startNs == 0 || stalledReadNs_ != 0 || now - startNs <= frameDeadlineNs()) return;
  stalledReadNs_ = startNs;
  missDeadline(protocol::kFaultCameraTimeout, "frame source: a frame read has not returned for " +
                                                  std::to_string((now - startNs) / kNsPerMs) + " ms (deadline " +
                                                  std::to_string(frameDeadlineNs() / kNsPerMs) +
                                                  " ms: camera.frame_timeout_ms + exposure + slack)");
  // The read may never return, and the worker with it: the owed result is answered now.
  answerNow(protocol::ResultStatus::kFailed, now);
}

void Sensor::checkCanLoop(TimeNs now) {
  if (canRxNs_ < 0) return;  // before start()
  const bool rxLate = now - canRxNs_ > canLoopDeadlineNs();
  const bool txLate = now - canTxNs_ > canLoopDeadlineNs();
  if (!rxLate && !txLate) {
    canStalled_ = false;
    return;
  }
  if (canStalled_) return;
  canStalled_ = true;
  const TimeNs lastNs = rxLate && txLate ? std::min(canRxNs_, canTxNs_) : rxLate ? canRxNs_ : canTxNs_;
  const char* side = rxLate && txLate ? "receive or transmit" : rxLate ? "receive" : "transmit";
  std::string why = std::string("CAN loop: no CAN ") + side + " processing for " +
                    std::to_string((now - lastNs) / kNsPerMs) + " ms (deadline " +
                    std::to_string(canLoopDeadlineNs() / kNsPerMs) + " ms)";
  if (rxLate && !canRxError_) why += ": " + canRxError_.toString();
  missDeadline(protocol::kFaultInternal, why);
}

void Sensor::serviceCan(TimeNs now) {
  checkCanLoop(now);
  ports::CanFrame f;
  for (int k = 0; k < kMaxFramesPerService; ++k) {
    Result<bool> got = ports_.can->receive(&f);
    if (!got) {
      // Not progress: SocketCAN reports a pending socket error once, so a receive that
      // keeps failing is a broken socket, which only a new process opens afresh.
      ALACS_LOG_WARN("can", "%s", got.status().toString().c_str());
      canRxError_ = got.status();
      return;
    }
    if (!*got) break;
    onCanFrame(f, now);
  }
  canRxNs_ = now;
  canRxError_ = Status::ok();
}

bool Sensor::startHoming(TimeNs now) {
  WorkerJob job;
  job.kind = WorkerJob::Kind::kHome;
  job.commandTimeNs = now;
  if (!submit(job)) return false;
  state_ = State::kHoming;
  return true;
}

void Sensor::onCanFrame(const ports::CanFrame& frame, TimeNs now) {
  // Bus-off is the node's: it holds transmission until the controller restarts and
  // latches CAN_BUS_OFF (EMCY 0x8140 once the bus is back); scans go on.
  const bool wasBusOff = node_.busOff();
  if (std::optional<protocol::Command> c = node_.push(frame, now)) onCommand(*c, now);
  if (node_.busOff() != wasBusOff)
    ALACS_LOG_WARN("can", "%s", node_.busOff() ? "bus-off: transmission held until the controller restarts"
                                               : "controller restarted after bus-off");
  node_.setFaults(faults_);
}

void Sensor::onCommand(const protocol::Command& c, TimeNs now) {
  switch (c.opcode) {
    case Opcode::kGetVersion: return node_.queueVersion(c, version_.major, version_.minor, version_.patch);
    case Opcode::kStop: return onStop(c);
    case Opcode::kClearFault: return onClearFault(c);
    case Opcode::kHome: return onHome(c, now);
    case Opcode::kLocalize: return onLocalize(c, now);
    case Opcode::kScanAll: return onScanAll(c, now);
    case Opcode::kSetConfig:
      if (const NackReason r = applyConfig(c.config); r != NackReason::kNone)
        return node_.nack(c.opcode, c.counter, r, configRefusal_.detail, configRefusal_.value, configRefusal_.limit);
      return node_.ack(c, protocol::AckResult::kAck);
    case Opcode::kInvalid: return node_.nack(c.opcode, c.counter, NackReason::kUnknownOpcode);
  }
}

void Sensor::onStop(const protocol::Command& c) {
  // Always executed: abort, laser off, latched STOPPED until CLEAR_FAULT. A STOP whose
  // checksum or counter failed was NACKed by the node for the record, and still counts.
  if (!c.answered) node_.ack(c, protocol::AckResult::kAck);
  if (ports_.worker->busy() && cancelCause_ == CancelCause::kNone) {
    cancelCause_ = CancelCause::kStop;
    cancelReason_ = Status(Error::kFault, "scan stopped by STOP command");
  }
  ports_.worker->cancel();
  (void)ports_.laser->off();
  faults_ |= protocol::kFaultStopRequested;
  state_ = State::kStopped;
}

void Sensor::onClearFault(const protocol::Command& c) {
  // A fault cannot be cleared while the worker it stopped has not let go yet (a stuck
  // frame read): say so, rather than ACK a clear that did not happen.
  if ((state_ == State::kFault || state_ == State::kStopped) && ports_.worker->busy())
    return node_.nack(c.opcode, c.counter, NackReason::kBusy);
  if (state_ == State::kFault || state_ == State::kStopped) {
    faults_ &= static_cast<uint16_t>(protocol::kFaultNotCalibrated | protocol::kFaultConfigInvalid);
    ports_.laser->reset();
    state_ = State::kIdle;
  }
  node_.clearCanFaults();
  node_.ack(c, protocol::AckResult::kAck);
}

void Sensor::onHome(const protocol::Command& c, TimeNs now) {
  if (state_ == State::kFault || state_ == State::kStopped || !configFileRefusal_.empty())
    return node_.nack(c.opcode, c.counter, NackReason::kFaultActive);
  if (ports_.worker->busy() || !startHoming(now)) return node_.nack(c.opcode, c.counter, NackReason::kBusy);
  node_.ack(c, protocol::AckResult::kAck);
  active_ = ActiveCommand{c, WorkerJob::Kind::kHome, now};
}

NackReason Sensor::scanRefusal() const {
  if (state_ == State::kFault || state_ == State::kStopped || !configFileRefusal_.empty())
    return NackReason::kFaultActive;
  if (ports_.worker->busy() || state_ != State::kIdle) return NackReason::kBusy;
  if (!calibration_) return NackReason::kNotCalibrated;
  if (!ports_.worker->homed()) return NackReason::kNotHomed;
  return NackReason::kNone;
}

void Sensor::onLocalize(const protocol::Command& c, TimeNs now) {
  if (const NackReason r = scanRefusal(); r != NackReason::kNone) return node_.nack(c.opcode, c.counter, r);
  localize::PlanRefusal why;
  Result<localize::ScanPlan> plan =
      localize::Localizer(*calibration_, cfg_.lle, cfg_.scan).plan(c.localize.roughMm, cfg_.motion.strokeMm, &why);
  if (!plan) {
    ALACS_LOG_WARN("cmd", "localize refused: %s", plan.status().toString().c_str());
    return node_.nack(c.opcode, c.counter, NackReason::kOutOfRange, nackDetailOf(why.limit), why.value, why.bound);
  }
  WorkerJob job;
  job.kind = WorkerJob::Kind::kLocalize;
  job.localize = c.localize;
  job.plan = *plan;
  job.commandTimeNs = now;
  // The worker's queue is bounded: refused only if a job were already waiting.
  if (!submit(job)) return node_.nack(c.opcode, c.counter, NackReason::kBusy);
  node_.ack(c, protocol::AckResult::kAck);
  active_ = ActiveCommand{c, job.kind, now};
  resultOwed_ = true;
  state_ = State::kScanning;
  if (ports_.observer != nullptr) ports_.observer->scanStarted(c.localize, *plan);
}

void Sensor::onScanAll(const protocol::Command& c, TimeNs now) {
  if (const NackReason r = scanRefusal(); r != NackReason::kNone) return node_.nack(c.opcode, c.counter, r);
  WorkerJob job;
  job.kind = WorkerJob::Kind::kScanAll;
  const survey::SurveyParams sp;
  job.survey.emplace(*calibration_, cfg_.lle, cfg_.scan, sp);
  job.surveyStopsMm = survey::surveyStops(cfg_.motion.strokeMm, sp);
  job.commandTimeNs = now;
  if (!submit(job)) return node_.nack(c.opcode, c.counter, NackReason::kBusy);
  node_.ack(c, protocol::AckResult::kAck);
  active_ = ActiveCommand{c, job.kind, now};
  resultOwed_ = true;
  state_ = State::kScanning;
}

// SET_CONFIG and the SDO server's writes (objects 0x1017, 0x2000, 0x2001): all fields
// valid and applied, or none. Accepted while the worker is busy (homing, scanning): the
// heartbeat period at once, the scan settings from the next job on.
NackReason Sensor::applyConfig(const protocol::SetConfigCommand& s) {
  DaemonConfig next = cfg_;
  if (s.exposureUs) next.exposureUs = *s.exposureUs;
  if (s.brceStep) next.lle.brceStep = *s.brceStep;
  if (s.brceThreshold) next.lle.brceThreshold = *s.brceThreshold;
  if (s.scanStops) next.scan.stops = *s.scanStops;
  if (s.stopSpacingMm) next.scan.stopSpacingMm = *s.stopSpacingMm;
  if (s.heartbeatMs) next.heartbeatMs = *s.heartbeatMs;
  if (Status v = validateConfig(next); !v) {
    ALACS_LOG_WARN("cmd", "set-config refused: %s", v.reason().c_str());
    configRefusal_ = {};
    const double spanMm = (next.scan.stops - 1) * next.scan.stopSpacingMm;
    if (next.scan.stops > 1 && spanMm > next.motion.strokeMm) {
      configRefusal_ = {protocol::NackDetail::kSpacingXStops, spanMm, next.motion.strokeMm};
    } else if (next.exposureUs != cfg_.exposureUs) {
      configRefusal_ = {protocol::NackDetail::kExposure, next.exposureUs / 1000.0, static_cast<double>(next.laserMaxOnMs)};
    } else {
      configRefusal_.detail = protocol::NackDetail::kCrossField;
    }
    return NackReason::kBadValue;
  }
  cfg_ = next;
  node_.setHeartbeatPeriod(cfg_.heartbeatMs * kNsPerMs);
  workerSettingsPending_ = true;
  if (!ports_.worker->busy()) pushWorkerSettings();
  return NackReason::kNone;
}

void Sensor::pushWorkerSettings() {
  ports_.worker->setExposureUs(cfg_.exposureUs);
  if (calibration_) ports_.worker->setLocalizer(localize::Localizer(*calibration_, cfg_.lle, cfg_.scan));
  workerSettingsPending_ = false;
}

protocol::SetConfigCommand Sensor::currentConfig() const {
  protocol::SetConfigCommand s;
  s.exposureUs = static_cast<uint16_t>(cfg_.exposureUs);
  s.brceStep = static_cast<uint8_t>(cfg_.lle.brceStep);
  s.brceThreshold = static_cast<uint8_t>(cfg_.lle.brceThreshold);
  s.scanStops = static_cast<uint8_t>(cfg_.scan.stops);
  s.stopSpacingMm = cfg_.scan.stopSpacingMm;
  s.heartbeatMs = static_cast<uint16_t>(cfg_.heartbeatMs);
  return s;
}

void Sensor::enterFault(uint16_t bit, const Status& why) {
  faults_ |= bit;
  state_ = State::kFault;
  (void)ports_.laser->off();
  if (ports_.worker->busy() && cancelCause_ == CancelCause::kNone) {
    cancelCause_ = CancelCause::kFault;
    faultCause_ = bit;
    cancelReason_ = why;
  }
  ports_.worker->cancel();
  ALACS_LOG_ERROR("fault", "%s", why.toString().c_str());
  // One EMCY per newly raised bit, with its CiA 301 code (protocol::CanNode::setFaults).
  node_.setFaults(faults_);
}

void Sensor::onWorkerEvent(const WorkerEvent& ev, TimeNs now) {
  if (ev.afterResult) {
    // The slide braking after a continuous scan whose result is already published: a
    // fault is raised as any other; a STOP during it only leaves the position in doubt.
    if (ev.faultBit != 0) {
      enterFault(ev.faultBit, ev.status);
    } else {
      ALACS_LOG_WARN("motion", "after the scan: %s (HOME before the next scan)", ev.status.toString().c_str());
    }
  } else {
    if (ev.faultBit != 0) {
      enterFault(ev.faultBit, ev.status);
    } else if (state_ != State::kFault && state_ != State::kStopped) {
      state_ = State::kIdle;
    }
    if (ev.job.kind == WorkerJob::Kind::kHome) {
      onHomeDone(ev);
    } else if (ev.job.kind != WorkerJob::Kind::kMoveTo && resultOwed_) {
      publishScanResult(ev, now);
    }
  }
  if (!ports_.worker->busy()) {
    cancelCause_ = CancelCause::kNone;
    if (workerSettingsPending_) pushWorkerSettings();
  }
  node_.setFaults(faults_);
}

void Sensor::onHomeDone(const WorkerEvent& ev) {
  if (ev.status) {
    ALACS_LOG_INFO("motion", "homed (worst step lateness %.1f us)", static_cast<double>(ev.maxStepLatenessNs) / 1e3);
  }
  if (!active_ || active_->kind != WorkerJob::Kind::kHome) return;
  if (ev.status) {
    node_.ack(active_->command, protocol::AckResult::kDone);
  } else {
    node_.ack(active_->command, protocol::AckResult::kNack,
              ev.faultBit != 0 ? NackReason::kFaultActive : NackReason::kInternal);
  }
  active_.reset();
}

void Sensor::publishScanResult(const WorkerEvent& ev, TimeNs now) {
  const TimeNs cycle = now - ev.job.commandTimeNs;
  lastLatencyMs_ = static_cast<uint32_t>(std::max<TimeNs>(0, cycle) / kNsPerMs);
  maxLatencyMs_ = std::max(maxLatencyMs_, lastLatencyMs_);
  protocol::ResultHeader h;
  h.measCounter = ++measCounter_;
  h.targetId = ev.job.localize.targetId;
  h.status = ev.resultStatus;
  h.reason = resultReasonOf(ev);
  Status why = ev.status;
  // A scan cut short by a fault failed for that fault; only STOP and shutdown abort.
  if (h.status == protocol::ResultStatus::kAborted && cancelCause_ != CancelCause::kNone) {
    why = cancelReason_;
    if (cancelCause_ == CancelCause::kFault) h.status = protocol::ResultStatus::kFailed;
  }
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
    ALACS_LOG_INFO("scan",
                   "%s %u: centre (%.1f, %.1f, %.1f) mm, d %.1f mm, sigma %.2f mm, confidence %.0f %%, %d lines",
                   h.mode == 1 ? "object" : "target", h.mode == 1 ? o.index : h.targetId, e.centerMm.x(),
                   e.centerMm.y(), e.centerMm.z(), e.diameterMm, e.sigmaMm, e.confidencePct, e.linesUsed);
  }
  if (!why) ALACS_LOG_WARN("scan", "target %u: %s", h.targetId, why.toString().c_str());
  h.objectCount = static_cast<uint8_t>(objects.size());
  // What the bus says of it, in the DBC's names: a technician reading the journal sees a
  // ROUGH_ONLY or NOT_FOUND as such, not only the numbers of the line above.
  ALACS_LOG_INFO("scan", "result %u (%s, target %u): %s (%s), %u object(s), cycle %u ms", h.measCounter,
                 protocol::resultModeName(h.mode), h.targetId, protocol::resultStatusName(h.status),
                 protocol::resultReasonName(h.reason), h.objectCount, lastLatencyMs_);
  if (ports_.observer != nullptr) ports_.observer->scanFinished(ev);
  // LOCALIZE is answered by its ACK and then this one result (docs/can-protocol.md).
  node_.publishResult(h, objects);
  active_.reset();
  resultOwed_ = false;
  progressSent_ = false;
}

void Sensor::answerNow(protocol::ResultStatus status, TimeNs now) {
  if (!resultOwed_ || !active_) return;
  WorkerEvent ev;
  ev.job.kind = active_->kind;
  ev.job.localize = active_->command.localize;
  ev.job.commandTimeNs = active_->commandTimeNs;
  ev.status = cancelReason_;
  ev.resultStatus = status;
  publishScanResult(ev, now);
}

protocol::ResultReason Sensor::resultReasonOf(const WorkerEvent& ev) const {
  using protocol::ResultReason;
  if (ev.resultStatus == protocol::ResultStatus::kMeasured)
    return ev.resultReason == ResultReason::kOutsideGate ? ev.resultReason : ResultReason::kNone;
  switch (cancelCause_) {
    case CancelCause::kStop: return ResultReason::kStopped;
    case CancelCause::kShutdown: return ResultReason::kShutdown;
    case CancelCause::kFault: return faultReasonOf(faultCause_);
    case CancelCause::kNone: break;
  }
  if (ev.faultBit != 0) return faultReasonOf(ev.faultBit);
  if (ev.resultReason != ResultReason::kNone) return ev.resultReason;
  return ev.resultStatus == protocol::ResultStatus::kAborted ? ResultReason::kStopped : ResultReason::kInternal;
}

void Sensor::sendProgress(TimeNs now) {
  if (!resultOwed_ || !active_) return;
  const ScanProgress p = ports_.worker->progress();
  // On every change, and at least every 500 ms until the result.
  if (progressSent_ && p == lastProgress_ && now - lastProgressNs_ < 500 * kNsPerMs) return;
  protocol::ProgressReport r;
  r.measCounter = static_cast<uint16_t>(measCounter_ + 1);
  r.counter = active_->command.counter;
  r.mode = active_->kind == WorkerJob::Kind::kScanAll ? 1 : 0;
  r.phase = p.phase;
  r.stopsDone = static_cast<uint32_t>(std::max(0, p.stopsDone));
  r.stopsTotal = static_cast<uint32_t>(std::max(0, p.stopsTotal));
  r.objectsFound = static_cast<uint32_t>(std::max(0, p.objectsFound));
  r.elapsedMs = static_cast<uint32_t>(std::max<TimeNs>(0, now - active_->commandTimeNs) / kNsPerMs);
  node_.publishProgress(r);
  progressSent_ = true;
  lastProgress_ = p;
  lastProgressNs_ = now;
}

void Sensor::shutdown(TimeNs now) {
  (void)ports_.laser->off();
  // The ACKed command gets its answer before the process ends: ABORTED.
  if (resultOwed_) {
    cancelCause_ = CancelCause::kShutdown;
    cancelReason_ = Status(Error::kFault, "sensor shutting down (SIGTERM)");
    answerNow(protocol::ResultStatus::kAborted, now);
  }
  ports_.worker->cancel();
}

protocol::StatusReport Sensor::statusReport() {
  protocol::StatusReport s;
  s.state = state_;
  s.homed = ports_.worker->homed();
  s.laserOn = ports_.laser->isOn();
  s.calibrated = calibration_.has_value();
  if (ports_.homeSwitch != nullptr) {
    Result<bool> h = ports_.homeSwitch->get();
    s.homeSwitch = h.isOk() && *h;
  }
  s.faults = faults_;
  s.lastLatencyMs = lastLatencyMs_;
  s.maxLatencyMs = maxLatencyMs_;
  s.droppedFrames = ports_.worker->droppedFrames();
  return s;
}

void Sensor::tick(TimeNs now) {
  if (ports_.laser->enforce(now))
    enterFault(protocol::kFaultLaserOvertime, Status(Error::kFault, "laser on beyond laser.max_on_ms"));
  if (node_.takeResetRequest()) {
    ALACS_LOG_INFO("can", "NMT reset: restarting the node");
    node_.start(now);
    bootUpNs_ = kNotYet;
    heartbeatStarted_ = false;
  }
  if (workerSettingsPending_ && !ports_.worker->busy()) pushWorkerSettings();
  checkFrameRead(now);
  checkWorkerProgress(now);
  checkCanLoop(now);
  sendProgress(now);
  node_.setFaults(faults_);
  node_.poll(now, [this] { return statusReport(); });
  flushTx(now);
  canTxNs_ = now;
  keepHeartbeat(now);
}

TimeNs Sensor::nextDeadline() const {
  const TimeNs node = node_.nextDeadline();
  if (heartbeatStarted_ || bootUpNs_ == kNotYet || !ports_.can->hasCyclic()) return node;
  return std::min(node, heartbeatStartNs());
}

void Sensor::keepHeartbeat(TimeNs now) {
  if (!ports_.can->hasCyclic()) return;  // the node queues the heartbeat itself (poll)
  // The boot-up is the node's first frame (CiA 301), and the first heartbeat follows it one
  // producer period later, as the node's own timing does on a bus without cyclic sending
  // (the kernel's cyclic job sends at once when started). A master that waits for the boot-up
  // can miss one followed at once by a heartbeat: python-canopen's wait_for_bootup reads the
  // last state received, which the heartbeat has already replaced.
  if (!heartbeatStarted_ && bootUpNs_ != kNotYet && now >= heartbeatStartNs()) heartbeatStarted_ = true;
  const TimeNs period = heartbeatStarted_ ? node_.heartbeatPeriod() : 0;
  if (Status s = ports_.can->keepCyclic(node_.heartbeatFrame(), period, now); !s)
    ALACS_LOG_WARN("can", "heartbeat: %s", s.toString().c_str());
}

void Sensor::flushTx(TimeNs now) {
  // Bounded: at most the queue's length per call, never blocking. A refused write
  // (the queue is full, or the interface is down) leaves the frame queued and the node
  // paces the retries (1, 2, 4 .. 64 ms; nextDeadline() wakes the loop).
  for (size_t budget = node_.txPending(); budget > 0 && node_.canTransmit(now); --budget) {
    const ports::CanFrame* f = node_.peekTx();
    if (f == nullptr) return;
    const Status s = ports_.can->send(*f);
    if (!s) {
      if (s.code() != Error::kBusy && node_.counters().txRetries % 100 == 0)
        ALACS_LOG_WARN("can", "%s", s.toString().c_str());
      node_.onTxRefused(now);
      return;
    }
    if (isBootUp(*f, node_.nodeId())) bootUpNs_ = now;
    node_.popTx();
    node_.onTxDone();
  }
}

}  // namespace alacs::app
