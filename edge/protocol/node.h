// The sensor's CAN node, libcanard-style: it owns no socket and reads no clock. The
// daemon pushes received frames in, pulls frames to send out, and passes `now`.
// It applies the NMT state machine, the command counter rule, the heartbeat and the
// periodic status, serves SDO, raises EMCY on faults, paces transmission when the bus
// refuses frames or is bus-off, and queues acks and results without ever dropping one
// below its bound. Not thread-safe (event-loop only).
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <optional>
#include <vector>

#include "common/clock.h"
#include "protocol/codec.h"
#include "protocol/sdo.h"

namespace alacs::protocol {

enum class NmtState : uint8_t { kBootUp = 0, kStopped = 4, kOperational = 5, kPreOperational = 127 };

// SocketCAN error-frame classes (CAN_ERR_* in linux/can/error.h) that the CAN port
// reports in CanFrame::errorClass; the SocketCAN driver asserts they match.
constexpr uint32_t kCanErrControllerProblem = 0x004U;
constexpr uint32_t kCanErrBusOff = 0x040U;
constexpr uint32_t kCanErrBusError = 0x080U;
constexpr uint32_t kCanErrRestarted = 0x100U;

// The application's settings as the SDO server sees them (objects 0x1017, 0x2000,
// 0x2001). Writes go through `apply`, the same path as SET_CONFIG, so both are
// validated alike: `apply` returns NackReason::kNone when it applied every field.
struct ConfigAccess {
  std::function<SetConfigCommand()> read;  // every field set
  std::function<NackReason(const SetConfigCommand&)> apply;
};

struct NodeConfig {
  uint8_t nodeId = 0x10;
  TimeNs heartbeatPeriodNs = 1000 * kNsPerMs;  // CANopen 0x1017; 0 disables
  TimeNs statusPeriodNs = 100 * kNsPerMs;
  bool autoStart = true;                       // enter OPERATIONAL after boot-up, as NMT-less buses need
  size_t resultQueueFrames = 1024;             // results and acks are never dropped below this
  size_t statusQueueFrames = 4;                // periodic frames: only the newest few are kept
  uint32_t serialNumber = 0;                   // object 0x1018.4
  // The port sends the periodic heartbeat itself (kernel-timed, CAN_BCM): poll() then
  // queues only the boot-up; the port sends heartbeatFrame() every heartbeatPeriod().
  bool heartbeatByPort = false;
  // Transmit pacing: after a refused write, wait 1, 2, 4 .. txBackoffMaxNs before the
  // next attempt; refused for longer than txStallNs raises CAN_TX_OVERFLOW.
  TimeNs txBackoffMaxNs = 64 * kNsPerMs;
  TimeNs txStallNs = 500 * kNsPerMs;
  // While bus-off, nothing is written until the controller reports its restart; if that
  // report is missed, one probe write is tried every busOffProbeNs.
  TimeNs busOffProbeNs = 1000 * kNsPerMs;
};

struct NodeCounters {
  uint32_t rxFrames = 0;
  uint32_t rxUnknownId = 0;   // ids the sensor does not consume
  uint32_t rxBadFrames = 0;   // bad DLC / checksum / counter / NMT length
  uint32_t rxErrorFrames = 0; // error frames from the controller
  uint32_t txDroppedStatus = 0;  // periodic frames replaced by newer ones (bus unavailable)
  uint32_t txDroppedResult = 0;  // should stay 0: the result queue overflowed
  uint32_t busOffEvents = 0;
  uint32_t txRetries = 0;        // writes refused (ENOBUFS, interface down) and retried later
};

class CanNode {
 public:
  explicit CanNode(const NodeConfig& config);

  // Queues the boot-up message; with autoStart the node is then OPERATIONAL.
  void start(TimeNs now);

  // Handles one received frame. Returns the command when the application must act on
  // it (the node has already checked it; the application acks or nacks it, unless
  // Command::answered: a STOP with a bad checksum or counter, NACKed and still returned).
  std::optional<Command> push(const ports::CanFrame& frame, TimeNs now);

  // Queues the heartbeat and status frames that are due; `status` is called only when
  // a status frame is due (it may read hardware). The node adds its CAN faults and the
  // receive error count to the report.
  void poll(TimeNs now, const std::function<StatusReport()>& status);
  // The next time poll() has something to do, or a held frame may be retried
  // (INT64_MAX: nothing scheduled). Never in the past after a poll(), so a loop that
  // sleeps until it does not spin.
  TimeNs nextDeadline() const;

  // The application's fault word (protocol::FaultBit). Every newly raised bit queues one
  // EMCY with its CiA 301 code; all cleared queues one EMCY NO_ERROR. The node's own CAN
  // faults (bus-off, transmit overflow) are merged in. Call whenever faults may change.
  void setFaults(uint16_t applicationFaults);
  // All active faults: the application's and the node's CAN faults.
  uint16_t faults() const { return static_cast<uint16_t>(appFaults_ | canFaults_); }
  // CLEAR_FAULT: the latched CAN faults are cleared (raised again if still present).
  void clearCanFaults() { canFaults_ = 0; }

  // Serves objects 0x1017, 0x2000 and 0x2001 through the application's settings.
  void setConfigAccess(ConfigAccess access);
  const ObjectDictionary& objectDictionary() const { return od_; }

  void ack(const Command& c, AckResult result, NackReason reason = NackReason::kNone);
  // `rejectedByte0`: byte 0 of a command whose opcode is unknown (sent in RejectedOpcode).
  void nack(Opcode opcode, uint8_t counter, NackReason reason, uint8_t rejectedByte0 = 0);
  // A NACK with its detail: which limit, the value asked for and the limit (docs/can-protocol.md).
  void nack(Opcode opcode, uint8_t counter, NackReason reason, NackDetail detail, double value, double limit);
  // ALACS_Progress of a running scan, queued in order with the acks and results.
  void publishProgress(const ProgressReport& p);
  // A repeated counter within this window is a duplicate (NACK BAD_COUNTER).
  static constexpr TimeNs kDuplicateWindowNs = 1000 * kNsPerMs;
  void queueVersion(const Command& c, int major, int minor, int patch);
  void publishResult(const ResultHeader& header, const std::vector<ResultObject>& objects);
  void emergency(uint16_t errorCode, uint16_t faults, uint8_t reason);

  // Transmit side: the next frame to send, in priority order (heartbeat and EMCY, acks
  // and results in order, then status).
  const ports::CanFrame* peekTx() const;
  void popTx();
  size_t txPending() const { return urgent_.size() + results_.size() + status_.size(); }
  // Whether a write may be tried now: false while backing off after a refused write or
  // while the controller is bus-off (until it restarts, or a probe is due).
  bool canTransmit(TimeNs now) const;
  // The outcome of the write of peekTx(): refused (ENOBUFS, interface down; the frame
  // stays queued) or done (the caller pops it).
  void onTxRefused(TimeNs now);
  void onTxDone();
  bool busOff() const { return busOff_; }

  NmtState nmtState() const { return nmt_; }
  // Set by NMT reset-node / reset-communication; the daemon clears it after resetting.
  bool takeResetRequest();
  const NodeCounters& counters() const { return counters_; }
  uint8_t nodeId() const { return config_.nodeId; }
  // A new period counts from the last heartbeat sent, so it shows at once (CiA 301 0x1017).
  void setHeartbeatPeriod(TimeNs period) {
    config_.heartbeatPeriodNs = period;
    nextHeartbeat_ = lastHeartbeatNs_ + period;
  }
  TimeNs heartbeatPeriod() const { return config_.heartbeatPeriodNs; }
  // The heartbeat as it is now (NMT state), for a port that sends it (heartbeatByPort).
  ports::CanFrame heartbeatFrame() const { return encodeHeartbeat(config_.nodeId, static_cast<uint8_t>(nmt_)); }

 private:
  void queueResult(const ports::CanFrame& f);
  void queueUrgent(const ports::CanFrame& f);
  void onErrorFrame(const ports::CanFrame& f, TimeNs now);
  void raiseCanFault(uint16_t bit);
  static Command failSafeStop(uint8_t counter);
  void bindObjects();
  SdoAbort writeConfig(const SetConfigCommand& c);
  NodeConfig config_;
  NmtState nmt_ = NmtState::kBootUp;
  std::optional<uint8_t> lastCounter_;
  TimeNs lastCounterTimeNs_ = 0;
  TimeNs nextHeartbeat_ = 0;
  TimeNs lastHeartbeatNs_ = 0;
  TimeNs nextStatus_ = 0;
  bool resetRequested_ = false;
  NodeCounters counters_;
  uint16_t appFaults_ = 0;
  uint16_t canFaults_ = 0;
  uint16_t reportedFaults_ = 0;   // the fault word the last EMCY told the bus about
  bool busOff_ = false;
  TimeNs busOffSinceNs_ = 0;
  TimeNs txHoldUntilNs_ = 0;      // back-off after a refused write
  TimeNs txBackoffNs_ = 0;
  TimeNs txRefusedSinceNs_ = -1;  // first refusal of the current run; -1: none
  ObjectDictionary od_;
  ConfigAccess configAccess_;
  std::deque<ports::CanFrame> urgent_;   // heartbeat, boot-up, EMCY
  std::deque<ports::CanFrame> results_;  // acks and results, in order
  std::deque<ports::CanFrame> status_;
};

}  // namespace alacs::protocol
