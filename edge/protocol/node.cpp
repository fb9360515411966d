#include "protocol/node.h"

extern "C" {
#include "alacs_protocol.h"
}

namespace alacs::protocol {

CanNode::CanNode(const NodeConfig& config) : config_(config) {}

void CanNode::start(TimeNs now) {
  nmt_ = NmtState::kBootUp;
  lastCounter_.reset();
  urgent_.push_back(encodeHeartbeat(config_.nodeId, static_cast<uint8_t>(NmtState::kBootUp)));
  nmt_ = config_.autoStart ? NmtState::kOperational : NmtState::kPreOperational;
  nextHeartbeat_ = now + config_.heartbeatPeriodNs;
  nextStatus_ = now;
}

std::optional<Command> CanNode::push(const ports::CanFrame& frame, TimeNs now) {
  ++counters_.rxFrames;
  if (frame.error) {
    ++counters_.rxErrorFrames;
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
  if (frame.id != alacs_frame_id(ALACS_BASE_ID_COMMAND, config_.nodeId)) {
    ++counters_.rxUnknownId;
    return std::nullopt;
  }
  // Checks in the documented order (docs/can-protocol.md): DLC, checksum, opcode,
  // counter, NMT state, value ranges; the application checks the sensor state.
  const CommandDecode d = decodeCommand(frame);
  const bool structural = !d.ok && d.reason != NackReason::kBadValue;
  if (structural) {
    ++counters_.rxBadFrames;
    nack(d.command.opcode, d.command.counter, d.reason, frame.dlc > 0 ? frame.data[0] : 0);
    return std::nullopt;
  }
  if (lastCounter_.has_value() && *lastCounter_ == d.command.counter &&
      now - lastCounterTimeNs_ < kDuplicateWindowNs) {
    ++counters_.rxBadFrames;
    nack(d.command.opcode, d.command.counter, NackReason::kBadCounter);
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

void CanNode::poll(TimeNs now, const std::function<StatusReport()>& status) {
  if (config_.heartbeatPeriodNs > 0 && now >= nextHeartbeat_) {
    urgent_.push_back(encodeHeartbeat(config_.nodeId, static_cast<uint8_t>(nmt_)));
    // Keep the cadence: schedule from the due time, not from a late poll.
    nextHeartbeat_ += config_.heartbeatPeriodNs;
    if (nextHeartbeat_ <= now) nextHeartbeat_ = now + config_.heartbeatPeriodNs;
  }
  if (nmt_ == NmtState::kOperational && config_.statusPeriodNs > 0 && now >= nextStatus_) {
    if (status_.size() >= config_.statusQueueFrames) {
      status_.pop_front();
      ++counters_.txDroppedStatus;
    }
    StatusReport s = status();
    s.rxErrors = counters_.rxUnknownId + counters_.rxBadFrames + counters_.rxErrorFrames;
    status_.push_back(encodeStatus(config_.nodeId, s));
    nextStatus_ += config_.statusPeriodNs;
    if (nextStatus_ <= now) nextStatus_ = now + config_.statusPeriodNs;
  }
}

TimeNs CanNode::nextDeadline() const {
  TimeNs t = nextStatus_;
  if (config_.heartbeatPeriodNs > 0 && nextHeartbeat_ < t) t = nextHeartbeat_;
  return t;
}

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
  urgent_.push_back(encodeEmcy(config_.nodeId, errorCode, faults, reason));
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
