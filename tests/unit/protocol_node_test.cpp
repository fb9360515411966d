// CanNode: EMCY per fault, error register, bus-off hold and restart, transmit back-off.
#include <catch2/catch.hpp>

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "protocol/node.h"

// The node's error classes are the SocketCAN ones the driver passes through.
#include <linux/can/error.h>
static_assert(alacs::protocol::kCanErrBusOff == CAN_ERR_BUSOFF);
static_assert(alacs::protocol::kCanErrRestarted == CAN_ERR_RESTARTED);
static_assert(alacs::protocol::kCanErrControllerProblem == CAN_ERR_CRTL);
static_assert(alacs::protocol::kCanErrBusError == CAN_ERR_BUSERROR);

using namespace alacs;
using namespace alacs::protocol;

namespace {
std::vector<ports::CanFrame> drain(CanNode& node, TimeNs now) {
  std::vector<ports::CanFrame> out;
  while (node.canTransmit(now)) {
    const ports::CanFrame* f = node.peekTx();
    if (f == nullptr) break;
    out.push_back(*f);
    node.popTx();
    node.onTxDone();
  }
  return out;
}
std::vector<ports::CanFrame> withId(const std::vector<ports::CanFrame>& frames, uint32_t id) {
  std::vector<ports::CanFrame> out;
  for (const auto& f : frames)
    if (f.id == id) out.push_back(f);
  return out;
}
ports::CanFrame errorFrame(uint32_t cls) {
  ports::CanFrame f;
  f.error = true;
  f.errorClass = cls;
  f.dlc = 8;
  return f;
}
uint16_t u16(const ports::CanFrame& f, size_t at) { return static_cast<uint16_t>(f.data[at] | f.data[at + 1] << 8); }
}  // namespace

TEST_CASE("EMCY per fault matches the golden vectors (code, register, bits, reason)", "[protocol][node][golden]") {
  cv::FileStorage fs(std::string(ALACS_SOURCE_DIR) + "/can_protocol/vectors/golden.json",
                     cv::FileStorage::READ | cv::FileStorage::FORMAT_JSON);
  REQUIRE(fs.isOpened());
  int checked = 0;
  for (const auto& v : fs["vectors"]) {
    if (static_cast<std::string>(v["message"]) != "EMCY") continue;
    const cv::FileNode s = v["signals"];
    const auto bits = static_cast<uint16_t>(static_cast<int>(s["EmcyFaultBits"]["raw"]));
    const auto reason = static_cast<uint8_t>(static_cast<int>(s["EmcyReason"]["raw"]));
    INFO(static_cast<std::string>(v["name"]));
    if (reason != 0) CHECK(emcyErrorCode(bits) == static_cast<int>(s["EmcyErrorCode"]["raw"]));
    CHECK(errorRegister(bits) == static_cast<int>(s["EmcyErrorRegister"]["raw"]));
    const ports::CanFrame f = encodeEmcy(0x10, static_cast<uint16_t>(static_cast<int>(s["EmcyErrorCode"]["raw"])), bits, reason);
    char hex[17] = {};
    for (size_t i = 0; i < 8; ++i) std::snprintf(hex + 2 * i, 3, "%02X", f.data[i]);
    CHECK(std::string(hex) == static_cast<std::string>(v["data"]));
    ++checked;
  }
  CHECK(checked == 12);
}

TEST_CASE("CAN node: one EMCY per raised fault, NO_ERROR when all clear", "[protocol][node]") {
  CanNode node(NodeConfig{});
  node.start(0);
  drain(node, 0);
  node.setFaults(kFaultCameraTimeout);
  node.setFaults(kFaultCameraTimeout);  // unchanged: nothing new
  node.setFaults(kFaultCameraTimeout | kFaultLimitHit);
  auto emcy = withId(drain(node, 0), 0x090);
  REQUIRE(emcy.size() == 2);
  CHECK(u16(emcy[0], 0) == 0x5000);
  CHECK(emcy[0].data[5] == 3);  // reason CAMERA_TIMEOUT
  CHECK(u16(emcy[1], 0) == 0xFF00);
  CHECK(u16(emcy[1], 3) == (kFaultCameraTimeout | kFaultLimitHit));
  node.setFaults(0);
  emcy = withId(drain(node, 0), 0x090);
  REQUIRE(emcy.size() == 1);
  CHECK(u16(emcy[0], 0) == 0);
  CHECK(emcy[0].data[2] == 0);
  node.setFaults(0);
  CHECK(withId(drain(node, 0), 0x090).empty());
}

TEST_CASE("CAN node: bus-off holds transmission until restart, then EMCY 0x8140 and the held result", "[protocol][node]") {
  NodeConfig cfg;
  cfg.busOffProbeNs = 1000 * kNsPerMs;
  CanNode node(cfg);
  node.start(0);
  drain(node, 0);
  const StatusReport idle;
  node.push(errorFrame(kCanErrBusOff | kCanErrControllerProblem), 10 * kNsPerMs);
  CHECK(node.busOff());
  CHECK(node.counters().busOffEvents == 1);
  node.publishResult(ResultHeader{}, {ResultObject{}});
  node.poll(20 * kNsPerMs, [&] { return idle; });
  CHECK_FALSE(node.canTransmit(20 * kNsPerMs));
  CHECK(node.txPending() >= 5);
  CHECK(node.nextDeadline() <= 1010 * kNsPerMs);  // a probe is scheduled
  // The restart report ends the hold at once.
  node.push(errorFrame(kCanErrRestarted), 300 * kNsPerMs);
  CHECK_FALSE(node.busOff());
  node.poll(300 * kNsPerMs, [&] { return idle; });
  const auto sent = drain(node, 300 * kNsPerMs);
  const auto emcy = withId(sent, 0x090);
  REQUIRE(emcy.size() == 1);
  CHECK(u16(emcy[0], 0) == 0x8140);
  CHECK(emcy[0].data[2] == 0x11);  // error register: generic + communication
  CHECK(withId(sent, 0x290).size() == 1);
  CHECK(withId(sent, 0x390).size() == 4);
  const auto status = withId(sent, 0x490);
  REQUIRE_FALSE(status.empty());
  CHECK((status.back().data[1] & 0x10) != 0);  // FaultCanBusOff (bit 12)
  // Latched until CLEAR_FAULT, then NO_ERROR.
  node.clearCanFaults();
  node.setFaults(0);
  const auto cleared = withId(drain(node, 300 * kNsPerMs), 0x090);
  REQUIRE(cleared.size() == 1);
  CHECK(u16(cleared[0], 0) == 0);
}

TEST_CASE("CAN node: a missed restart report is recovered by a probe write", "[protocol][node]") {
  CanNode node(NodeConfig{});
  node.start(0);
  drain(node, 0);
  node.push(errorFrame(kCanErrBusOff), 0);
  node.publishResult(ResultHeader{}, {});
  CHECK_FALSE(node.canTransmit(999 * kNsPerMs));
  CHECK(node.canTransmit(1000 * kNsPerMs));
  node.onTxRefused(1000 * kNsPerMs);  // still bus-off: wait another probe period
  CHECK_FALSE(node.canTransmit(1500 * kNsPerMs));
  CHECK(node.canTransmit(2000 * kNsPerMs));
  node.popTx();
  node.onTxDone();
  CHECK_FALSE(node.busOff());
}

TEST_CASE("CAN node: refused writes back off 1, 2, 4 .. 64 ms; a long stall raises CAN_TX_OVERFLOW", "[protocol][node]") {
  CanNode node(NodeConfig{});
  node.start(0);
  TimeNs t = 0;
  std::vector<TimeNs> gaps;
  TimeNs last = 0;
  int attempts = 0;
  const StatusReport idle;
  // Refuse every write for 600 ms, polling every 0.5 ms: attempts are paced, not spun.
  for (; t <= 600 * kNsPerMs; t += kNsPerMs / 2) {
    node.poll(t, [&] { return idle; });
    if (node.peekTx() != nullptr && node.canTransmit(t)) {
      if (attempts > 0) gaps.push_back(t - last);
      last = t;
      ++attempts;
      node.onTxRefused(t);
    }
  }
  REQUIRE(gaps.size() >= 7);
  CHECK(gaps[0] == 1 * kNsPerMs);
  CHECK(gaps[1] == 2 * kNsPerMs);
  CHECK(gaps[2] == 4 * kNsPerMs);
  CHECK(gaps[6] == 64 * kNsPerMs);
  CHECK(gaps.back() == 64 * kNsPerMs);
  CHECK(attempts < 20);
  CHECK(node.counters().txRetries == static_cast<uint32_t>(attempts));
  CHECK((node.faults() & kFaultCanTxOverflow) != 0);
  // Status and heartbeat frames are replaced, not piled up; the queue stays small.
  CHECK(node.txPending() <= 6);
  CHECK(node.counters().txDroppedStatus > 0);
  CHECK_FALSE(node.canTransmit(last + 63 * kNsPerMs));
  // The bus accepts again at the next paced attempt: everything goes out.
  const auto sent = drain(node, last + 64 * kNsPerMs);
  REQUIRE_FALSE(sent.empty());
  CHECK(sent.front().id == 0x710);  // boot-up first (queued before the EMCY)
  CHECK(u16(withId(sent, 0x090).at(0), 0) == 0x8110);
}

TEST_CASE("CAN node: the result queue keeps every frame up to its bound", "[protocol][node]") {
  NodeConfig cfg;
  cfg.resultQueueFrames = 50;
  CanNode node(cfg);
  node.start(0);
  for (int i = 0; i < 10; ++i) node.publishResult(ResultHeader{}, {ResultObject{}});
  CHECK(node.counters().txDroppedResult == 0);
  node.publishResult(ResultHeader{}, {ResultObject{}});
  CHECK(node.counters().txDroppedResult == 5);
  node.poll(0, [] { return StatusReport{}; });
  CHECK((node.faults() & kFaultCanTxOverflow) != 0);
}

TEST_CASE("CAN node: with heartbeatByPort only the boot-up is queued; heartbeatFrame has the NMT state", "[protocol][node]") {
  NodeConfig cfg;
  cfg.heartbeatByPort = true;
  cfg.autoStart = false;
  CanNode node(cfg);
  node.start(0);
  int heartbeats = 0;
  for (TimeNs t = 0; t <= 3000 * kNsPerMs; t += 10 * kNsPerMs) {
    node.poll(t, [] { return StatusReport{}; });
    for (const auto& f : drain(node, t))
      if (f.id == 0x710) ++heartbeats;
  }
  CHECK(heartbeats == 1);  // the boot-up
  CHECK(node.heartbeatFrame().id == 0x710);
  CHECK(node.heartbeatFrame().dlc == 1);
  CHECK(node.heartbeatFrame().data[0] == 127);
  CHECK(node.nextDeadline() > 3000 * kNsPerMs);  // no heartbeat deadline, only status
}

TEST_CASE("CAN node: after a poll the next deadline is in the future in every NMT state", "[protocol][node]") {
  for (uint8_t cs : {uint8_t{1}, uint8_t{2}, uint8_t{128}}) {
    CanNode node(NodeConfig{});
    node.start(0);
    ports::CanFrame nmt;
    nmt.dlc = 2;
    nmt.data = {cs, 0x10, 0, 0, 0, 0, 0, 0};
    node.push(nmt, 0);
    for (TimeNs t = 0; t < 2000 * kNsPerMs; t += 37 * kNsPerMs) {
      node.poll(t, [] { return StatusReport{}; });
      drain(node, t);
      INFO("NMT command " << int{cs} << " t " << t);
      REQUIRE(node.nextDeadline() > t);
    }
  }
}
