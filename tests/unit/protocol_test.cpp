#include <catch2/catch.hpp>

#include <map>
#include <opencv2/core.hpp>

#include "protocol/codec.h"
#include "protocol/node.h"

extern "C" {
#include "alacs_protocol.h"
}

using namespace alacs;
using namespace alacs::protocol;

namespace {
ports::CanFrame frameFromHex(uint32_t id, int dlc, const std::string& hex) {
  ports::CanFrame f;
  f.id = id;
  f.dlc = static_cast<uint8_t>(dlc);
  for (size_t i = 0; i + 1 < hex.size() && i / 2 < 8; i += 2)
    f.data[i / 2] = static_cast<uint8_t>(std::stoi(hex.substr(i, 2), nullptr, 16));
  return f;
}
std::string hexOf(const ports::CanFrame& f) {
  char buf[17] = {};
  for (int i = 0; i < f.dlc; ++i) std::snprintf(buf + 2 * i, 3, "%02X", f.data[static_cast<size_t>(i)]);
  return buf;
}
cv::FileStorage golden() {
  return cv::FileStorage(std::string(ALACS_SOURCE_DIR) + "/can_protocol/vectors/golden.json",
                         cv::FileStorage::READ | cv::FileStorage::FORMAT_JSON);
}
ports::CanFrame command(Opcode op, uint8_t counter, std::array<uint8_t, 6> payload = {}) {
  ports::CanFrame f;
  f.id = 0x210;
  f.dlc = 8;
  f.data[0] = static_cast<uint8_t>(op);
  f.data[1] = counter;
  for (size_t i = 0; i < 5; ++i) f.data[i + 2] = payload[i];
  f.data[7] = alacs_command_checksum(f.data.data());
  return f;
}
}  // namespace

TEST_CASE("Golden command checks: the C++ parser NACKs exactly as the protocol says", "[protocol][golden]") {
  cv::FileStorage fs = golden();
  REQUIRE(fs.isOpened());
  const cv::FileNode checks = fs["command_checks"];
  REQUIRE(checks.size() >= 5);
  static const std::map<std::string, NackReason> kReasons = {
      {"NONE", NackReason::kNone}, {"BAD_DLC", NackReason::kBadDlc}, {"BAD_CHECKSUM", NackReason::kBadChecksum},
      {"UNKNOWN_OPCODE", NackReason::kUnknownOpcode}, {"BAD_VALUE", NackReason::kBadValue}};
  for (const auto& c : checks) {
    const std::string name = c["name"];
    INFO(name);
    const auto f = frameFromHex(0x210, static_cast<int>(c["dlc"]), c["data"]);
    const CommandDecode d = decodeCommand(f);
    const std::string expected = c["expected_nack"];
    REQUIRE(kReasons.count(expected) == 1);
    CHECK(d.reason == kReasons.at(expected));
    CHECK(d.ok == (expected == "NONE"));
  }
}

TEST_CASE("Golden vectors: the C++ encoders produce the DBC's bytes", "[protocol][golden]") {
  cv::FileStorage fs = golden();
  int checked = 0;
  int progress = 0;
  for (const auto& v : fs["vectors"]) {
    const std::string msg = v["message"];
    const std::string data = v["data"];
    const cv::FileNode s = v["signals"];
    INFO(static_cast<std::string>(v["name"]));
    auto phys = [&](const char* k) { return s[k]["physical"].real(); };
    auto raw = [&](const char* k) { return static_cast<int>(s[k]["raw"]); };
    if (msg == "ALACS_ResultHeader") {
      ResultHeader h;
      h.measCounter = static_cast<uint16_t>(raw("MeasCounter"));
      h.objectCount = static_cast<uint8_t>(raw("ObjectCount"));
      h.targetId = static_cast<uint8_t>(raw("ResultTargetId"));
      h.scanAgeMs = static_cast<uint32_t>(raw("ScanAgeMs"));
      h.status = static_cast<ResultStatus>(raw("ResultStatus"));
      h.reason = static_cast<ResultReason>(raw("ResultReason"));
      h.mode = static_cast<uint8_t>(raw("ResultMode"));
      h.cycleTimeMs = static_cast<uint32_t>(phys("CycleTime"));
      CHECK(hexOf(encodeResultHeader(0x10, h)) == data);
      ++checked;
    } else if (msg == "ALACS_Ack" && raw("AckOpcode") != 6 && raw("AckOpcode") != 0) {
      Ack a{static_cast<Opcode>(raw("AckOpcode")), static_cast<uint8_t>(raw("AckCounter")),
            static_cast<AckResult>(raw("AckResult")), static_cast<NackReason>(raw("NackReason"))};
      a.detail = static_cast<NackDetail>(raw("NackDetail"));
      a.nackValue = phys("NackValue");
      a.nackLimit = phys("NackLimit");
      CHECK(hexOf(encodeAck(0x10, a)) == data);
      ++checked;
    } else if (msg == "ALACS_Progress") {
      ProgressReport p;
      p.measCounter = static_cast<uint16_t>(raw("ProgressMeasCounter"));
      p.counter = static_cast<uint8_t>(raw("ProgressCounter"));
      p.mode = static_cast<uint8_t>(raw("ProgressMode"));
      p.phase = static_cast<ProgressPhase>(raw("ProgressPhase"));
      p.stopsDone = static_cast<uint32_t>(raw("StopsDone"));
      p.stopsTotal = static_cast<uint32_t>(raw("StopsTotal"));
      p.objectsFound = static_cast<uint32_t>(raw("ObjectsFound"));
      p.elapsedMs = static_cast<uint32_t>(phys("ElapsedS") * 1000.0);
      CHECK(hexOf(encodeProgress(0x10, p)) == data);
      ++progress;
      ++checked;
    } else if (msg == "ALACS_Command") {
      const auto f = frameFromHex(0x210, static_cast<int>(v["dlc"]), data);
      const CommandDecode d = decodeCommand(f);
      CHECK(d.ok);
      CHECK(static_cast<int>(d.command.opcode) == raw("CmdOpcode"));
      if (raw("CmdOpcode") == 1) {
        CHECK(d.command.localize.roughMm.x() == Approx(phys("RoughX")));
        CHECK(d.command.localize.roughMm.y() == Approx(phys("RoughY")));
        CHECK(d.command.localize.roughMm.z() == Approx(phys("RoughZ")));
      }
      ++checked;
    }
  }
  CHECK(checked >= 8);
  CHECK(progress >= 1);
}

TEST_CASE("A result's status and reason are named as the DBC names them", "[protocol][golden]") {
  // The golden vectors carry cantools' names of each value, read from the DBC itself.
  cv::FileStorage fs = golden();
  int checked = 0;
  for (const auto& v : fs["vectors"]) {
    if (static_cast<std::string>(v["message"]) != "ALACS_ResultHeader") continue;
    const cv::FileNode status = v["signals"]["ResultStatus"];
    const cv::FileNode reason = v["signals"]["ResultReason"];
    const cv::FileNode mode = v["signals"]["ResultMode"];
    INFO(static_cast<std::string>(v["name"]));
    CHECK(std::string(resultStatusName(static_cast<ResultStatus>(static_cast<int>(status["raw"])))) ==
          static_cast<std::string>(status["choice"]));
    CHECK(std::string(resultReasonName(static_cast<ResultReason>(static_cast<int>(reason["raw"])))) ==
          static_cast<std::string>(reason["choice"]));
    CHECK(std::string(resultModeName(static_cast<uint8_t>(static_cast<int>(mode["raw"])))) ==
          static_cast<std::string>(mode["choice"]));
    ++checked;
  }
  CHECK(checked >= 3);
  CHECK(std::string(resultStatusName(ResultStatus::kAmbiguous)) == "AMBIGUOUS");
  CHECK(std::string(resultReasonName(ResultReason::kFarFromRough)) == "FAR_FROM_ROUGH");
  CHECK(std::string(resultModeName(0)) == "LOCALIZE");
  CHECK(std::string(resultModeName(1)) == "SCAN_ALL");
  // A value the DBC does not name (the nibble's 15, the byte's 200) is not given another's name.
  CHECK(std::string(resultStatusName(static_cast<ResultStatus>(15))) == "?");
  CHECK(std::string(resultReasonName(static_cast<ResultReason>(200))) == "?");
}

TEST_CASE("Result objects round to the DBC's resolution and saturate", "[protocol]") {
  ResultObject o;
  o.centerMm = {12.34, -5.66, 1234.56};
  o.normal = {0, 0, -1};
  o.diameterMm = 500.0;  // beyond the 8-bit field: saturates
  ports::CanFrame pages[4];
  encodeResultObject(0x10, 0x1234, o, pages);
  CHECK(pages[0].id == 0x390);
  CHECK(pages[0].data[0] == 0x00);
  CHECK(pages[0].data[1] == 0x34);  // low byte of the measurement counter
  CHECK(static_cast<int16_t>(pages[0].data[2] | pages[0].data[3] << 8) == 123);
  CHECK(pages[2].data[4] == 255);
}

TEST_CASE("CAN node: NMT, counters, duplicate window and queues", "[protocol][node]") {
  CanNode node(NodeConfig{});
  node.start(0);
  REQUIRE(node.peekTx() != nullptr);
  CHECK(node.peekTx()->id == 0x710);  // boot-up
  CHECK(node.peekTx()->data[0] == 0);
  node.popTx();

  SECTION("a command is handed over once; a duplicate within 1 s is NACKed") {
    auto c = node.push(command(Opcode::kHome, 1), 0);
    REQUIRE(c.has_value());
    CHECK_FALSE(node.push(command(Opcode::kHome, 1), 500 * kNsPerMs).has_value());
    REQUIRE(node.peekTx() != nullptr);
    CHECK(node.peekTx()->data[2] == static_cast<uint8_t>(NackReason::kBadCounter));
    node.popTx();
    CHECK(node.push(command(Opcode::kHome, 1), 1600 * kNsPerMs).has_value());
    CHECK(node.push(command(Opcode::kHome, 2), 1700 * kNsPerMs).has_value());
  }
  SECTION("unknown ids are counted, bad frames NACKed with their reason") {
    ports::CanFrame other;
    other.id = 0x123;
    other.dlc = 8;
    CHECK_FALSE(node.push(other, 0).has_value());
    CHECK(node.counters().rxUnknownId == 1);
    CHECK(node.txPending() == 0);
    auto bad = command(Opcode::kHome, 3);
    bad.data[7] ^= 1;
    CHECK_FALSE(node.push(bad, 0).has_value());
    CHECK(node.peekTx()->data[2] == static_cast<uint8_t>(NackReason::kBadChecksum));
    node.popTx();
    auto unknown = command(static_cast<Opcode>(42), 4);
    CHECK_FALSE(node.push(unknown, 0).has_value());
    CHECK(node.peekTx()->data[0] == 0);   // AckOpcode INVALID
    CHECK(node.peekTx()->data[3] == 42);  // RejectedOpcode
  }
  SECTION("NMT stop: commands NACKed except STOP and GET_VERSION") {
    ports::CanFrame nmt;
    nmt.id = 0;
    nmt.dlc = 2;
    nmt.data[0] = 2;
    nmt.data[1] = 0x10;
    node.push(nmt, 0);
    CHECK(node.nmtState() == NmtState::kStopped);
    CHECK_FALSE(node.push(command(Opcode::kHome, 5), 0).has_value());
    CHECK(node.peekTx()->data[2] == static_cast<uint8_t>(NackReason::kNmtNotOperational));
    CHECK(node.push(command(Opcode::kStop, 6), 0).has_value());
    nmt.data[0] = 1;
    node.push(nmt, 0);
    CHECK(node.nmtState() == NmtState::kOperational);
  }
  SECTION("heartbeat keeps its cadence and results are never dropped") {
    StatusReport s;
    int heartbeats = 0;
    for (TimeNs t = 0; t <= 10500 * kNsPerMs; t += 7 * kNsPerMs) {
      node.poll(t, [&] { return s; });
      while (const ports::CanFrame* f = node.peekTx()) {
        if (f->id == 0x710) ++heartbeats;
        node.popTx();
      }
    }
    CHECK(heartbeats == 10);
    for (int i = 0; i < 200; ++i) node.publishResult(ResultHeader{}, {ResultObject{}});
    CHECK(node.counters().txDroppedResult == 0);
    CHECK(node.txPending() == 1000);
  }
}
