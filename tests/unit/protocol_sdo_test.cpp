// The SDO server against the golden exchanges (recorded from the Python reference, which
// is itself checked against canopen's LocalNode), and wired to an application's settings.
#include <catch2/catch.hpp>

#include <opencv2/core.hpp>
#include <string>

#include "protocol/node.h"
#include "protocol/sdo.h"

using namespace alacs;
using namespace alacs::protocol;

namespace {
ports::CanFrame sdoFrame(uint32_t id, const std::string& hex) {
  ports::CanFrame f;
  f.id = id;
  f.dlc = static_cast<uint8_t>(hex.size() / 2);
  for (size_t i = 0; i + 1 < hex.size() && i / 2 < 8; i += 2)
    f.data[i / 2] = static_cast<uint8_t>(std::stoi(hex.substr(i, 2), nullptr, 16));
  return f;
}
std::string hexOf(const ports::CanFrame& f) {
  char buf[17] = {};
  for (size_t i = 0; i < f.dlc; ++i) std::snprintf(buf + 2 * i, 3, "%02X", f.data[i]);
  return buf;
}
ports::CanFrame upload(uint16_t index, uint8_t sub) {
  ports::CanFrame f;
  f.id = 0x610;
  f.dlc = 8;
  f.data = {0x40, static_cast<uint8_t>(index & 0xFF), static_cast<uint8_t>(index >> 8), sub, 0, 0, 0, 0};
  return f;
}
ports::CanFrame download(uint16_t index, uint8_t sub, uint32_t value, uint8_t size) {
  ports::CanFrame f;
  f.id = 0x610;
  f.dlc = 8;
  f.data = {static_cast<uint8_t>(0x23 | ((4 - size) << 2)), static_cast<uint8_t>(index & 0xFF),
            static_cast<uint8_t>(index >> 8), sub, static_cast<uint8_t>(value), static_cast<uint8_t>(value >> 8),
            static_cast<uint8_t>(value >> 16), static_cast<uint8_t>(value >> 24)};
  return f;
}
uint32_t dataOf(const ports::CanFrame& f) {
  return static_cast<uint32_t>(f.data[4] | f.data[5] << 8 | f.data[6] << 16) | static_cast<uint32_t>(f.data[7]) << 24;
}
// Pops frames until one with `id` (SDO answers share the ordered queue with acks).
std::optional<ports::CanFrame> take(CanNode& node, uint32_t id) {
  while (const ports::CanFrame* f = node.peekTx()) {
    const ports::CanFrame copy = *f;
    node.popTx();
    if (copy.id == id) return copy;
  }
  return std::nullopt;
}
}  // namespace

TEST_CASE("SDO server answers the golden exchanges byte for byte", "[protocol][sdo][golden]") {
  cv::FileStorage fs(std::string(ALACS_SOURCE_DIR) + "/can_protocol/vectors/golden.json",
                     cv::FileStorage::READ | cv::FileStorage::FORMAT_JSON);
  REQUIRE(fs.isOpened());
  ObjectDictionary od = ObjectDictionary::fromSpec();
  // A freshly booted sensor: every object at its default, every valid write accepted.
  for (const OdEntry& e : od.entries())
    if (e.access == OdAccess::kReadWrite) REQUIRE(od.bindWrite(e.index, e.subIndex, [](uint32_t) { return SdoAbort::kNone; }));
  int checked = 0;
  for (const auto& ex : fs["sdo_exchanges"]) {
    INFO(static_cast<std::string>(ex["name"]));
    const std::optional<ports::CanFrame> answer = serveSdo(0x10, sdoFrame(0x610, ex["request"]), od);
    const std::string expected = ex["response"];
    if (expected.empty()) {
      CHECK_FALSE(answer.has_value());
    } else {
      REQUIRE(answer.has_value());
      CHECK(answer->id == 0x590);
      CHECK(hexOf(*answer) == expected);
    }
    ++checked;
  }
  CHECK(checked > 30);
}

TEST_CASE("SDO server: short frames get no answer; every OD entry is readable", "[protocol][sdo]") {
  const ObjectDictionary od = ObjectDictionary::fromSpec();
  ports::CanFrame shortFrame = upload(0x1000, 0);
  shortFrame.dlc = 4;
  CHECK_FALSE(serveSdo(0x10, shortFrame, od).has_value());
  CHECK(od.entries().size() == ALACS_OD_ENTRY_COUNT);
  for (const OdEntry& e : od.entries()) {
    const auto a = serveSdo(0x10, upload(e.index, e.subIndex), od);
    REQUIRE(a.has_value());
    CHECK(a->data[0] == static_cast<uint8_t>(0x43 | ((4 - e.sizeBytes) << 2)));
  }
}

TEST_CASE("CAN node SDO: config objects go through the application's SET_CONFIG path", "[protocol][sdo][node]") {
  CanNode node(NodeConfig{});
  node.start(0);
  SetConfigCommand current;
  current.exposureUs = 3000;
  current.brceStep = 4;
  current.brceThreshold = 40;
  current.scanStops = 5;
  current.stopSpacingMm = 20.0;
  current.heartbeatMs = 1000;
  std::vector<SetConfigCommand> applied;
  bool busy = false;
  node.setConfigAccess({[&] { return current; },
                        [&](const SetConfigCommand& c) {
                          if (busy) return NackReason::kBusy;
                          if (c.exposureUs && *c.exposureUs > 125000 / 1) return NackReason::kBadValue;
                          if (c.stopSpacingMm && *c.stopSpacingMm < 0.5) return NackReason::kBadValue;
                          applied.push_back(c);
                          if (c.exposureUs) current.exposureUs = c.exposureUs;
                          if (c.stopSpacingMm) current.stopSpacingMm = c.stopSpacingMm;
                          if (c.heartbeatMs) current.heartbeatMs = c.heartbeatMs;
                          return NackReason::kNone;
                        }});

  node.push(upload(0x2001, 2), 0);
  auto a = take(node, 0x590);
  REQUIRE(a);
  CHECK(a->data[0] == 0x4B);
  CHECK(dataOf(*a) == 200);  // 20 mm in 0.1 mm

  node.push(download(0x2000, 1, 1500, 2), 0);
  a = take(node, 0x590);
  REQUIRE(a);
  CHECK(a->data[0] == 0x60);
  REQUIRE(applied.size() == 1);
  CHECK(applied[0].page == 0);
  CHECK(applied[0].exposureUs == std::optional<uint16_t>(1500));
  CHECK_FALSE(applied[0].brceStep.has_value());

  node.push(download(0x2001, 2, 3, 2), 0);  // 0.3 mm: the application refuses
  a = take(node, 0x590);
  REQUIRE(a);
  CHECK(a->data[0] == 0x80);
  CHECK(dataOf(*a) == static_cast<uint32_t>(SdoAbort::kValueRange));

  busy = true;
  node.push(download(0x1017, 0, 250, 2), 0);
  a = take(node, 0x590);
  REQUIRE(a);
  CHECK(dataOf(*a) == static_cast<uint32_t>(SdoAbort::kDeviceState));
  busy = false;
  node.push(download(0x1017, 0, 250, 2), 0);
  a = take(node, 0x590);
  REQUIRE(a);
  CHECK(a->data[0] == 0x60);
  CHECK(applied.back().heartbeatMs == std::optional<uint16_t>(250));
  node.push(upload(0x1017, 0), 0);
  a = take(node, 0x590);
  REQUIRE(a);
  CHECK(dataOf(*a) == 250);

  SECTION("no SDO in NMT STOPPED") {
    ports::CanFrame nmt;
    nmt.dlc = 2;
    nmt.data[0] = 2;
    nmt.data[1] = 0x10;
    node.push(nmt, 0);
    node.push(upload(0x1000, 0), 0);
    CHECK_FALSE(take(node, 0x590).has_value());
  }
  SECTION("diagnostic counters are readable") {
    ports::CanFrame other;
    other.id = 0x310;  // our id block, not a message we consume
    other.dlc = 3;
    node.push(other, 0);
    node.push(other, 0);
    node.push(upload(0x2100, 2), 0);
    a = take(node, 0x590);
    REQUIRE(a);
    CHECK(dataOf(*a) == 2);
  }
}
