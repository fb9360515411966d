// The sensor's CAN node, libcanard-style: it owns no socket and reads no clock. The
// daemon pushes received frames in, pulls frames to send out, and passes `now`.
// It applies the NMT state machine, the command counter rule, the heartbeat and the
// periodic status, and queues acks and results. Not thread-safe (event-loop only).
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <vector>

#include "common/clock.h"
#include "protocol/codec.h"

namespace alacs::protocol {

enum class NmtState : uint8_t { kBootUp = 0, kStopped = 4, kOperational = 5, kPreOperational = 127 };

struct NodeConfig {
  uint8_t nodeId = 0x10;
  TimeNs heartbeatPeriodNs = 1000 * kNsPerMs;  // CANopen 0x1017; 0 disables
  TimeNs statusPeriodNs = 100 * kNsPerMs;
  bool autoStart = true;                       // enter OPERATIONAL after boot-up, as NMT-less buses need
  size_t resultQueueFrames = 1024;             // results and acks are never dropped below this
  size_t statusQueueFrames = 4;                // periodic frames: only the newest few are kept
};

struct NodeCounters {
  uint32_t rxFrames = 0;
  uint32_t rxUnknownId = 0;   // ids the sensor does not consume
  uint32_t rxBadFrames = 0;   // bad DLC / checksum / counter / NMT length
  uint32_t rxErrorFrames = 0; // error frames from the controller
  uint32_t txDroppedStatus = 0;
  uint32_t txDroppedResult = 0;  // should stay 0: the result queue overflowed
};

class CanNode {
 public:
  explicit CanNode(const NodeConfig& config);

  // Queues the boot-up message; with autoStart the node is then OPERATIONAL.
  void start(TimeNs now);

  // Handles one received frame. Returns the command when the application must act on
  // it (the node has already checked it; the application acks or nacks it).
  std::optional<Command> push(const ports::CanFrame& frame, TimeNs now);

  // Queues the heartbeat and status frames that are due; `status` is called only when
  // a status frame is due (it may read hardware).
  void poll(TimeNs now, const std::function<StatusReport()>& status);
  // The next time poll() has something to do.
  TimeNs nextDeadline() const;

  void ack(const Command& c, AckResult result, NackReason reason = NackReason::kNone);
  // `rejectedByte0`: byte 0 of a command whose opcode is unknown (sent in RejectedOpcode).
  void nack(Opcode opcode, uint8_t counter, NackReason reason, uint8_t rejectedByte0 = 0);
  // A repeated counter within this window is a duplicate (NACK BAD_COUNTER).
  static constexpr TimeNs kDuplicateWindowNs = 1000 * kNsPerMs;
  void queueVersion(const Command& c, int major, int minor, int patch);
  void publishResult(const ResultHeader& header, const std::vector<ResultObject>& objects);
  void emergency(uint16_t errorCode, uint16_t faults, uint8_t reason);

  // Transmit side: the next frame to send, in priority order (heartbeat, acks and
  // results in order, then status).
  const ports::CanFrame* peekTx() const;
  void popTx();
  size_t txPending() const { return urgent_.size() + results_.size() + status_.size(); }

  NmtState nmtState() const { return nmt_; }
  // Set by NMT reset-node / reset-communication; the daemon clears it after resetting.
  bool takeResetRequest();
  const NodeCounters& counters() const { return counters_; }
  uint8_t nodeId() const { return config_.nodeId; }
  void setHeartbeatPeriod(TimeNs period) { config_.heartbeatPeriodNs = period; }

 private:
  void queueResult(const ports::CanFrame& f);
  NodeConfig config_;
  NmtState nmt_ = NmtState::kBootUp;
  std::optional<uint8_t> lastCounter_;
  TimeNs lastCounterTimeNs_ = 0;
  TimeNs nextHeartbeat_ = 0;
  TimeNs nextStatus_ = 0;
  bool resetRequested_ = false;
  NodeCounters counters_;
  std::deque<ports::CanFrame> urgent_;   // heartbeat, boot-up, EMCY
  std::deque<ports::CanFrame> results_;  // acks and results, in order
  std::deque<ports::CanFrame> status_;
};

}  // namespace alacs::protocol
