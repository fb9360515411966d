// libFuzzer target: the sensor's CAN node (edge/protocol) under arbitrary traffic.
//
// The input is a sequence of 12-byte records, one received frame each:
//   [0..1] id (11 bits; bit 11 extended, bit 12 RTR, bit 13 error frame, bit 14: aim the
//          id at the node's own block), [2] DLC (any byte; the port clamps to 0..8, the
//          node must cope with what it gets), [3] time step in ms, [4..11] data.
// Every frame also goes through decodeCommand() and serveSdo() directly. Between frames
// the node is polled and its transmit queue drained, with writes refused now and then
// (the fuzzer decides) so the back-off and bus-off paths run too. Invariants checked:
// frames out have DLC <= 8 and an 11-bit id; a decoded command is ok exactly when its
// reason is NONE; no result frame is ever dropped below the bound; after a poll the next
// deadline is in the future; the node's fault word only holds defined bits.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "protocol/codec.h"
#include "protocol/node.h"
#include "protocol/sdo.h"

using namespace alacs;
using namespace alacs::protocol;

namespace {
void require(bool ok) {
  if (!ok) std::abort();
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  NodeConfig cfg;
  cfg.resultQueueFrames = 4096;
  cfg.autoStart = (size > 0 && (data[0] & 1) != 0);
  CanNode node(cfg);
  SetConfigCommand settings;
  settings.exposureUs = 3000;
  settings.brceStep = 4;
  settings.brceThreshold = 40;
  settings.scanStops = 5;
  settings.stopSpacingMm = 20.0;
  settings.heartbeatMs = 1000;
  node.setConfigAccess({[&] { return settings; },
                        [&](const SetConfigCommand& c) {
                          if (c.stopSpacingMm && *c.stopSpacingMm < 0.5) return NackReason::kBadValue;
                          if (c.exposureUs) settings.exposureUs = c.exposureUs;
                          if (c.heartbeatMs) {
                            settings.heartbeatMs = c.heartbeatMs;
                            node.setHeartbeatPeriod(static_cast<TimeNs>(*c.heartbeatMs) * kNsPerMs);
                          }
                          return NackReason::kNone;
                        }});
  const ObjectDictionary od = ObjectDictionary::fromSpec();
  TimeNs now = 0;
  node.start(now);
  uint16_t appFaults = 0;
  constexpr uint16_t kDefinedFaults = 0x07FF;
  for (size_t at = 1; at + 12 <= size; at += 12) {
    const uint8_t* r = data + at;
    const auto word = static_cast<uint16_t>(r[0] | r[1] << 8);
    ports::CanFrame f;
    f.id = word & 0x7FFU;
    if ((word & 0x4000U) != 0) f.id = (f.id & 0x780U) | node.nodeId();
    f.extended = (word & 0x0800U) != 0;
    f.rtr = (word & 0x1000U) != 0;
    f.error = (word & 0x2000U) != 0;
    f.errorClass = f.error ? static_cast<uint32_t>(r[4] | r[5] << 8) : 0;
    f.dlc = r[2];
    for (size_t i = 0; i < 8; ++i) f.data[i] = r[4 + i];
    now += static_cast<TimeNs>(r[3]) * kNsPerMs;

    // The stateless decoders on their own.
    ports::CanFrame clamped = f;
    clamped.dlc = f.dlc > 8 ? 8 : f.dlc;
    const CommandDecode d = decodeCommand(clamped);
    require(d.ok == (d.reason == NackReason::kNone));
    if (const auto answer = serveSdo(0x10, clamped, od)) require(answer->dlc == 8 && answer->id == 0x590);

    if (std::optional<Command> c = node.push(clamped, now)) {
      // Play the application: answer like alacsd does, sometimes with a result.
      require(c->opcode != Opcode::kInvalid);
      node.ack(*c, AckResult::kAck);
      if (c->opcode == Opcode::kLocalize) {
        ResultHeader h;
        h.objectCount = 1;
        h.targetId = c->localize.targetId;
        ResultObject o;
        o.centerMm = c->localize.roughMm;
        node.publishResult(h, {o});
      }
      if (c->opcode == Opcode::kStop) appFaults = static_cast<uint16_t>(appFaults | kFaultStopRequested);
      if (c->opcode == Opcode::kClearFault) {
        appFaults = 0;
        node.clearCanFaults();
      }
    }
    node.setFaults(appFaults);
    node.poll(now, [] { return StatusReport{}; });
    require(node.nextDeadline() > now || node.txPending() > 0);
    require((node.faults() & ~kDefinedFaults) == 0);
    // Drain; the record's last data byte decides how many writes the "bus" refuses.
    unsigned refuse = r[11] & 0x03U;
    for (size_t budget = node.txPending(); budget > 0 && node.canTransmit(now); --budget) {
      const ports::CanFrame* out = node.peekTx();
      require(out != nullptr);
      require(out->dlc <= 8 && out->id <= 0x7FF && !out->extended);
      if (refuse > 0) {
        --refuse;
        node.onTxRefused(now);
        break;
      }
      node.popTx();
      node.onTxDone();
    }
  }
  require(node.counters().txDroppedResult == 0);
  return 0;
}
