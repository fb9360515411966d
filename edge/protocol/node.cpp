#include "protocol/node.h"

#include <algorithm>
#include <cmath>
#include <limits>

extern "C" {
#include "alacs_protocol.h"
}

namespace alacs::protocol {

CanNode::CanNode(const NodeConfig& config) : config_(config), od_(ObjectDictionary::fromSpec()) { bindObjects(); }

void CanNode::start(TimeNs now) {
  nmt_ = NmtState::kBootUp;
  lastCounter_.reset();
  urgent_.push_back(encodeHeartbeat(config_.nodeId, static_cast<uint8_t>(NmtState::kBootUp)));
  nmt_ = config_.autoStart ? NmtState::kOperational : NmtState::kPreOperational;
  lastHeartbeatNs_ = now;
  nextHeartbeat_ = now + config_.heartbeatPeriodNs;
  nextStatus_ = now;
  // After a reset the master has forgotten our faults: tell it again.
  reportedFaults_ = 0;
}

void CanNode::bindObjects() {
  od_.bindRead(ALACS_OD_ERROR_REGISTER_INDEX, ALACS_OD_ERROR_REGISTER_SUB, [this] { return errorRegister(faults()); });
  od_.bindRead(ALACS_OD_IDENTITY_SERIAL_INDEX, ALACS_OD_IDENTITY_SERIAL_SUB, [this] { return config_.serialNumber; });
  od_.bindRead(ALACS_OD_PRODUCER_HEARTBEAT_TIME_INDEX, ALACS_OD_PRODUCER_HEARTBEAT_TIME_SUB,
               [this] { return static_cast<uint32_t>(config_.heartbeatPeriodNs / kNsPerMs); });
  od_.bindWrite(ALACS_OD_PRODUCER_HEARTBEAT_TIME_INDEX, ALACS_OD_PRODUCER_HEARTBEAT_TIME_SUB, [this](uint32_t v) {
    SetConfigCommand c;
    c.page = 1;
    c.heartbeatMs = static_cast<uint16_t>(v);
    return writeConfig(c);
  });
  auto counter = [this](uint16_t index, uint8_t sub, const uint32_t NodeCounters::*field) {
    od_.bindRead(index, sub, [this, field] { return counters_.*field; });
  };
  counter(ALACS_OD_DIAG_RX_FRAMES_INDEX, ALACS_OD_DIAG_RX_FRAMES_SUB, &NodeCounters::rxFrames);
  counter(ALACS_OD_DIAG_RX_UNKNOWN_ID_INDEX, ALACS_OD_DIAG_RX_UNKNOWN_ID_SUB, &NodeCounters::rxUnknownId);
  counter(ALACS_OD_DIAG_RX_BAD_FRAMES_INDEX, ALACS_OD_DIAG_RX_BAD_FRAMES_SUB, &NodeCounters::rxBadFrames);
  counter(ALACS_OD_DIAG_RX_ERROR_FRAMES_INDEX, ALACS_OD_DIAG_RX_ERROR_FRAMES_SUB, &NodeCounters::rxErrorFrames);
  counter(ALACS_OD_DIAG_BUS_OFF_COUNT_INDEX, ALACS_OD_DIAG_BUS_OFF_COUNT_SUB, &NodeCounters::busOffEvents);
  counter(ALACS_OD_DIAG_TX_RETRIES_INDEX, ALACS_OD_DIAG_TX_RETRIES_SUB, &NodeCounters::txRetries);
  counter(ALACS_OD_DIAG_TX_DROPPED_STATUS_INDEX, ALACS_OD_DIAG_TX_DROPPED_STATUS_SUB, &NodeCounters::txDroppedStatus);
  counter(ALACS_OD_DIAG_TX_DROPPED_RESULT_INDEX, ALACS_OD_DIAG_TX_DROPPED_RESULT_SUB, &NodeCounters::txDroppedResult);
}

void CanNode::setConfigAccess(ConfigAccess access) {
  configAccess_ = std::move(access);
  if (!configAccess_.read || !configAccess_.apply) return;
  auto get = [this] { return configAccess_.read(); };
  od_.bindRead(ALACS_OD_PRODUCER_HEARTBEAT_TIME_INDEX, ALACS_OD_PRODUCER_HEARTBEAT_TIME_SUB,
               [get] { return static_cast<uint32_t>(get().heartbeatMs.value_or(0)); });
  od_.bindRead(ALACS_OD_CFG_EXPOSURE_US_INDEX, ALACS_OD_CFG_EXPOSURE_US_SUB,
               [get] { return static_cast<uint32_t>(get().exposureUs.value_or(0)); });
  od_.bindRead(ALACS_OD_CFG_BRCE_STEP_INDEX, ALACS_OD_CFG_BRCE_STEP_SUB,
               [get] { return static_cast<uint32_t>(get().brceStep.value_or(0)); });
  od_.bindRead(ALACS_OD_CFG_BRCE_THRESHOLD_INDEX, ALACS_OD_CFG_BRCE_THRESHOLD_SUB,
               [get] { return static_cast<uint32_t>(get().brceThreshold.value_or(0)); });
  od_.bindRead(ALACS_OD_CFG_SCAN_STOPS_INDEX, ALACS_OD_CFG_SCAN_STOPS_SUB,
               [get] { return static_cast<uint32_t>(get().scanStops.value_or(0)); });
  od_.bindRead(ALACS_OD_CFG_STOP_SPACING_INDEX, ALACS_OD_CFG_STOP_SPACING_SUB, [get] {
    // Object unit: 0.1 mm.
    return static_cast<uint32_t>(std::lround(get().stopSpacingMm.value_or(0.0) * 10.0));
  });
  auto bind = [this](uint16_t index, uint8_t sub, uint8_t page, auto set) {
    od_.bindWrite(index, sub, [this, page, set](uint32_t v) {
      SetConfigCommand c;
      c.page = page;
      set(c, v);
      return writeConfig(c);
    });
  };
  bind(ALACS_OD_CFG_EXPOSURE_US_INDEX, ALACS_OD_CFG_EXPOSURE_US_SUB, 0,
       [](SetConfigCommand& c, uint32_t v) { c.exposureUs = static_cast<uint16_t>(v); });
  bind(ALACS_OD_CFG_BRCE_STEP_INDEX, ALACS_OD_CFG_BRCE_STEP_SUB, 0,
       [](SetConfigCommand& c, uint32_t v) { c.brceStep = static_cast<uint8_t>(v); });
  bind(ALACS_OD_CFG_BRCE_THRESHOLD_INDEX, ALACS_OD_CFG_BRCE_THRESHOLD_SUB, 0,
       [](SetConfigCommand& c, uint32_t v) { c.brceThreshold = static_cast<uint8_t>(v); });
  bind(ALACS_OD_CFG_SCAN_STOPS_INDEX, ALACS_OD_CFG_SCAN_STOPS_SUB, 1,
       [](SetConfigCommand& c, uint32_t v) { c.scanStops = static_cast<uint8_t>(v); });
  bind(ALACS_OD_CFG_STOP_SPACING_INDEX, ALACS_OD_CFG_STOP_SPACING_SUB, 1,
       [](SetConfigCommand& c, uint32_t v) { c.stopSpacingMm = static_cast<double>(v) / 10.0; });
}

SdoAbort CanNode::writeConfig(const SetConfigCommand& c) {
  if (!configAccess_.apply) {
    // No application behind the node (tests, fuzzing): only the heartbeat is the node's.
    if (!c.heartbeatMs) return SdoAbort::kUnsupportedAccess;
    setHeartbeatPeriod(static_cast<TimeNs>(*c.heartbeatMs) * kNsPerMs);
    return SdoAbort::kNone;
  }
  switch (configAccess_.apply(c)) {
    case NackReason::kNone: return SdoAbort::kNone;
    case NackReason::kBusy: return SdoAbort::kDeviceState;
    case NackReason::kBadValue:
    case NackReason::kOutOfRange: return SdoAbort::kValueRange;
    case NackReason::kBadDlc:
    case NackReason::kBadChecksum:
    case NackReason::kBadCounter:
    case NackReason::kUnknownOpcode:
    case NackReason::kNotHomed:
    case NackReason::kNotCalibrated:
    case NackReason::kFaultActive:
    case NackReason::kNmtNotOperational:
    case NackReason::kInternal: break;
  }
  return SdoAbort::kGeneral;
}

void CanNode::onErrorFrame(const ports::CanFrame& frame, TimeNs now) {
  ++counters_.rxErrorFrames;
  if ((frame.errorClass & kCanErrBusOff) != 0 && !busOff_) {
    busOff_ = true;
    busOffSinceNs_ = now;
    ++counters_.busOffEvents;
    // Raised now, told once the bus is back: its EMCY code means "recovered from bus-off".
    raiseCanFault(kFaultCanBusOff);
  }
  if ((frame.errorClass & kCanErrRestarted) != 0 && busOff_) {
    busOff_ = false;
    txHoldUntilNs_ = now;
    txBackoffNs_ = 0;
  }
}

void CanNode::raiseCanFault(uint16_t bit) { canFaults_ = static_cast<uint16_t>(canFaults_ | bit); }

std::optional<Command> CanNode::push(const ports::CanFrame& frame, TimeNs now) {
  ++counters_.rxFrames;
  if (frame.error) {
    onErrorFrame(frame, now);
    return std::nullopt;
  }
  if (frame.extended || frame.rtr) {
    ++counters_.rxUnknownId;
    return std::nullopt;
  }
  if (frame.id == ALACS_BASE_ID_NMT) {
    if (frame.dlc != 2) {
      ++counters_.rxBadFrames;
      return std::nullopt;
    }
    if (frame.data[1] != 0 && frame.data[1] != config_.nodeId) return std::nullopt;
    switch (frame.data[0]) {
      case 1: nmt_ = NmtState::kOperational; break;
      case 2: nmt_ = NmtState::kStopped; break;
      case 128: nmt_ = NmtState::kPreOperational; break;
      case 129:
      case 130: resetRequested_ = true; break;
      default: ++counters_.rxBadFrames; break;
    }
    return std::nullopt;
  }
  if (frame.id == alacs_frame_id(ALACS_BASE_ID_SDO_RX, config_.nodeId)) {
    // CiA 301: no SDO in STOPPED.
    if (nmt_ == NmtState::kStopped) return std::nullopt;
    if (std::optional<ports::CanFrame> answer = serveSdo(config_.nodeId, frame, od_)) {
      queueResult(*answer);
    } else if (frame.dlc != 8) {
      ++counters_.rxBadFrames;
    }
    return std::nullopt;
  }
  if (frame.id != alacs_frame_id(ALACS_BASE_ID_COMMAND, config_.nodeId)) {
    ++counters_.rxUnknownId;
    return std::nullopt;
  }
  // Checks in the documented order (docs/can-protocol.md): DLC, checksum, opcode,
  // counter, NMT state, value ranges; the application checks the sensor state.
  const CommandDecode d = decodeCommand(frame);
  const bool structural = !d.ok && d.reason != NackReason::kBadValue;
  // STOP is fail-safe: a frame of the command id and length whose byte 0 says STOP is
  // executed whatever its checksum and counter, and NACKed for the record.
  const bool stopFrame = frame.dlc == ALACS_COMMAND_DLC && frame.data[0] == static_cast<uint8_t>(Opcode::kStop);
  if (structural) {
    ++counters_.rxBadFrames;
    nack(d.command.opcode, d.command.counter, d.reason, frame.dlc > 0 ? frame.data[0] : 0);
    if (stopFrame) return failSafeStop(d.command.counter);
    return std::nullopt;
  }
  if (lastCounter_.has_value() && *lastCounter_ == d.command.counter &&
      now - lastCounterTimeNs_ < kDuplicateWindowNs) {
    ++counters_.rxBadFrames;
    nack(d.command.opcode, d.command.counter, NackReason::kBadCounter);
    if (stopFrame) return failSafeStop(d.command.counter);
    return std::nullopt;
  }
  const bool anyNmtState = d.command.opcode == Opcode::kStop || d.command.opcode == Opcode::kGetVersion;
  if (nmt_ != NmtState::kOperational && !anyNmtState) {
    nack(d.command.opcode, d.command.counter, NackReason::kNmtNotOperational);
    return std::nullopt;
  }
  if (!d.ok) {
    ++counters_.rxBadFrames;
    nack(d.command.opcode, d.command.counter, d.reason);
    return std::nullopt;
  }
  lastCounter_ = d.command.counter;
  lastCounterTimeNs_ = now;
  return d.command;
}

Command CanNode::failSafeStop(uint8_t counter) {
  Command c;
  c.opcode = Opcode::kStop;
  c.counter = counter;
  c.answered = true;
  return c;
}

void CanNode::setFaults(uint16_t applicationFaults) {
  appFaults_ = applicationFaults;
  const uint16_t now = faults();
  const auto raised = static_cast<uint16_t>(now & ~reportedFaults_);
  // CiA 301: no EMCY in STOPPED; the faults are told when the node is started again.
  if (nmt_ == NmtState::kStopped) return;
  for (uint16_t i = 0; i < 16; ++i) {
    const auto bit = static_cast<uint16_t>(1U << i);
    if ((raised & bit) != 0) queueUrgent(encodeEmcy(config_.nodeId, emcyErrorCode(bit), now, static_cast<uint8_t>(i + 1)));
  }
  if (now == 0 && reportedFaults_ != 0) queueUrgent(encodeEmcy(config_.nodeId, 0, 0, 0));
  reportedFaults_ = now;
}

void CanNode::poll(TimeNs now, const std::function<StatusReport()>& status) {
  if (txRefusedSinceNs_ >= 0 && !busOff_ && now - txRefusedSinceNs_ >= config_.txStallNs) {
    raiseCanFault(kFaultCanTxOverflow);
  }
  if (counters_.txDroppedResult > 0) raiseCanFault(kFaultCanTxOverflow);
  if (canFaults_ & ~reportedFaults_) setFaults(appFaults_);
  if (config_.heartbeatPeriodNs > 0 && !config_.heartbeatByPort && now >= nextHeartbeat_) {
    // A heartbeat still waiting (bus unavailable) is stale: the new one replaces it.
    const uint32_t hbId = alacs_frame_id(ALACS_BASE_ID_HEARTBEAT, config_.nodeId);
    const auto stale = std::remove_if(urgent_.begin(), urgent_.end(),
                                      [&](const ports::CanFrame& f) { return f.id == hbId && f.data[0] != 0; });
    counters_.txDroppedStatus += static_cast<uint32_t>(std::distance(stale, urgent_.end()));
    urgent_.erase(stale, urgent_.end());
    urgent_.push_back(encodeHeartbeat(config_.nodeId, static_cast<uint8_t>(nmt_)));
    lastHeartbeatNs_ = nextHeartbeat_;
    // Keep the cadence: schedule from the due time, not from a late poll.
    nextHeartbeat_ += config_.heartbeatPeriodNs;
    if (nextHeartbeat_ <= now) nextHeartbeat_ = now + config_.heartbeatPeriodNs;
  }
  if (config_.statusPeriodNs > 0 && now >= nextStatus_) {
    // Like a TPDO, but also in PRE_OPERATIONAL (docs/can-protocol.md): a sensor waiting
    // for NMT START still says why it cannot scan. Not in STOPPED.
    if (nmt_ == NmtState::kOperational || nmt_ == NmtState::kPreOperational) {
      if (status_.size() >= config_.statusQueueFrames) {
        status_.pop_front();
        ++counters_.txDroppedStatus;
      }
      StatusReport s = status();
      s.faults = static_cast<uint16_t>(s.faults | canFaults_);
      s.rxErrors = counters_.rxUnknownId + counters_.rxBadFrames + counters_.rxErrorFrames;
      status_.push_back(encodeStatus(config_.nodeId, s));
    }
    nextStatus_ += config_.statusPeriodNs;
    if (nextStatus_ <= now) nextStatus_ = now + config_.statusPeriodNs;
  }
}

TimeNs CanNode::nextDeadline() const {
  TimeNs t = std::numeric_limits<TimeNs>::max();
  if (config_.statusPeriodNs > 0) t = nextStatus_;
  if (config_.heartbeatPeriodNs > 0 && !config_.heartbeatByPort && nextHeartbeat_ < t) t = nextHeartbeat_;
  if (txPending() > 0) {
    const TimeNs retry = busOff_ ? busOffSinceNs_ + config_.busOffProbeNs : txHoldUntilNs_;
    t = std::min(t, retry);
  }
  return t;
}

bool CanNode::canTransmit(TimeNs now) const {
  if (busOff_) return now >= busOffSinceNs_ + config_.busOffProbeNs && now >= txHoldUntilNs_;
  return now >= txHoldUntilNs_;
}

void CanNode::onTxRefused(TimeNs now) {
  ++counters_.txRetries;
  if (txRefusedSinceNs_ < 0) txRefusedSinceNs_ = now;
  txBackoffNs_ = txBackoffNs_ == 0 ? kNsPerMs : std::min(2 * txBackoffNs_, config_.txBackoffMaxNs);
  txHoldUntilNs_ = now + txBackoffNs_;
  // A bus-off probe that failed: wait a whole probe period again.
  if (busOff_) busOffSinceNs_ = now;
}

void CanNode::onTxDone() {
  txBackoffNs_ = 0;
  txRefusedSinceNs_ = -1;
  // A write went through: the controller is back even if we missed its restart report.
  busOff_ = false;
}

void CanNode::queueUrgent(const ports::CanFrame& f) { urgent_.push_back(f); }

void CanNode::queueResult(const ports::CanFrame& f) {
  if (results_.size() >= config_.resultQueueFrames) {
    ++counters_.txDroppedResult;
    return;
  }
  results_.push_back(f);
}

void CanNode::ack(const Command& c, AckResult result, NackReason reason) {
  queueResult(encodeAck(config_.nodeId, {c.opcode, c.counter, result, reason}));
}

void CanNode::nack(Opcode opcode, uint8_t counter, NackReason reason, uint8_t rejectedByte0) {
  queueResult(encodeAck(config_.nodeId, {opcode, counter, AckResult::kNack, reason,
                                         opcode == Opcode::kInvalid ? rejectedByte0 : uint8_t{0}}));
}

void CanNode::nack(Opcode opcode, uint8_t counter, NackReason reason, NackDetail detail, double value, double limit) {
  Ack a{opcode, counter, AckResult::kNack, reason};
  a.detail = detail;
  a.nackValue = value;
  a.nackLimit = limit;
  queueResult(encodeAck(config_.nodeId, a));
}

void CanNode::publishProgress(const ProgressReport& p) { queueResult(encodeProgress(config_.nodeId, p)); }

void CanNode::queueVersion(const Command& c, int major, int minor, int patch) {
  queueResult(encodeVersionAck(config_.nodeId, c.counter, major, minor, patch));
}

void CanNode::publishResult(const ResultHeader& header, const std::vector<ResultObject>& objects) {
  queueResult(encodeResultHeader(config_.nodeId, header));
  for (const auto& o : objects) {
    ports::CanFrame pages[4];
    encodeResultObject(config_.nodeId, header.measCounter, o, pages);
    for (const auto& p : pages) queueResult(p);
  }
}

void CanNode::emergency(uint16_t errorCode, uint16_t faults, uint8_t reason) {
  queueUrgent(encodeEmcy(config_.nodeId, errorCode, faults, reason));
}

const ports::CanFrame* CanNode::peekTx() const {
  if (!urgent_.empty()) return &urgent_.front();
  if (!results_.empty()) return &results_.front();
  if (!status_.empty()) return &status_.front();
  return nullptr;
}

void CanNode::popTx() {
  if (!urgent_.empty()) urgent_.pop_front();
  else if (!results_.empty()) results_.pop_front();
  else if (!status_.empty()) status_.pop_front();
}

bool CanNode::takeResetRequest() {
  const bool r = resetRequested_;
  resetRequested_ = false;
  return r;
}

}  // namespace alacs::protocol
