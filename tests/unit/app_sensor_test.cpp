// app::Sensor in virtual time: every command in every state, every NACK reason, STOP in
// each scan phase, faults, CLEAR_FAULT, SET_CONFIG and SDO while busy, NMT, the heartbeat
// and the boot-up order, bus-off, shutdown, and the laser on each path. The CAN bus and
// the worker are recording fakes (ports/can_bus_fake.h, app/scan_jobs_fake.h); the whole
// file runs in milliseconds.
#include <catch2/catch.hpp>

#include <memory>
#include <vector>

#include "app/scan_jobs_fake.h"
#include "app/sensor.h"
#include "ports/can_bus_fake.h"
#include "ports/digital_io_fake.h"
#include "sim/scene.h"

extern "C" {
#include "alacs.h"
#include "alacs_protocol.h"
}

using namespace alacs;
using protocol::NackReason;
using protocol::Opcode;
using protocol::State;

namespace {

constexpr uint8_t kNode = 0x10;

struct AckSeen {
  Opcode opcode = Opcode::kInvalid;
  int counter = 0;
  protocol::AckResult result = protocol::AckResult::kAck;
  NackReason reason = NackReason::kNone;
  protocol::NackDetail detail = protocol::NackDetail::kNone;
  double value = 0.0;
  double limit = 0.0;
};

struct Rig {
  explicit Rig(bool calibrated = true, bool cyclic = true, bool autoStart = true, int statusPeriodMs = 100)
      : can(clock, cyclic), laser(laserLine, clock, 250 * kNsPerMs) {
    cfg.nodeId = kNode;
    cfg.nmtAutoStart = autoStart;
    cfg.statusPeriodMs = statusPeriodMs;
    Result<geometry::Calibration> cal =
        calibrated ? Result<geometry::Calibration>(sim::defaultScene().truth)
                   : Result<geometry::Calibration>(Status(Error::kBadInput, "calibration.json: laser.plane_normal: missing"));
    sensor = std::make_unique<app::Sensor>(cfg, app::SensorPorts{&can, &worker, &laser, &home, nullptr}, cal,
                                           app::SensorVersion{1, 2, 3});
  }
  TimeNs now() const { return clock.now(); }
  // One wake-up of the daemon's event loop: the CAN socket drained, then the tick.
  void tick() {
    sensor->serviceCan(now());
    sensor->tick(now());
  }
  void advanceMs(int ms) {
    for (int i = 0; i < ms; ++i) {
      clock.advance(kNsPerMs);
      tick();
    }
  }
  void boot() {
    sensor->start(now());
    tick();
  }
  // Boot, home, idle; the frames so far forgotten.
  void bootIdle() {
    boot();
    finish();
    can.clearSent();
  }
  void finish(app::WorkerEvent ev = {}) {
    sensor->onWorkerEvent(worker.finish(std::move(ev)), now());
    tick();
  }
  void finishCancelled() {
    sensor->onWorkerEvent(worker.finishCancelled(), now());
    tick();
  }
  void receive(const ports::CanFrame& f) {
    sensor->onCanFrame(f, now());
    tick();
  }
  ports::CanFrame command(alacs_alacs_command_t m) {
    m.cmd_counter = static_cast<uint8_t>(++counter & 0x0F);
    ports::CanFrame f;
    f.id = ALACS_BASE_ID_COMMAND + kNode;
    f.dlc = 8;
    REQUIRE(alacs_alacs_command_pack(f.data.data(), &m, 8) == 8);
    f.data[7] = alacs_command_checksum(f.data.data());
    return f;
  }
  ports::CanFrame simple(Opcode op) {
    alacs_alacs_command_t m{};
    m.cmd_opcode = static_cast<uint8_t>(op);
    return command(m);
  }
  ports::CanFrame localize(double xMm, double yMm, double zMm) {
    alacs_alacs_command_t m{};
    m.cmd_opcode = static_cast<uint8_t>(Opcode::kLocalize);
    m.target_id = 7;
    m.rough_x = alacs_alacs_command_rough_x_encode(xMm);
    m.rough_y = alacs_alacs_command_rough_y_encode(yMm);
    m.rough_z = alacs_alacs_command_rough_z_encode(zMm);
    return command(m);
  }
  ports::CanFrame setConfigScan(int stops, double spacingMm, int heartbeatMs) {
    alacs_alacs_command_t m{};
    m.cmd_opcode = static_cast<uint8_t>(Opcode::kSetConfig);
    m.cfg_page = 1;
    m.cfg_scan_stops_valid = 1;
    m.cfg_scan_stops = alacs_alacs_command_cfg_scan_stops_encode(stops);
    m.cfg_stop_spacing_valid = 1;
    m.cfg_stop_spacing_mm = alacs_alacs_command_cfg_stop_spacing_mm_encode(spacingMm);
    m.cfg_heartbeat_valid = 1;
    m.cfg_heartbeat_ms = static_cast<uint16_t>(heartbeatMs);
    return command(m);
  }
  ports::CanFrame setExposure(int exposureUs) {
    alacs_alacs_command_t m{};
    m.cmd_opcode = static_cast<uint8_t>(Opcode::kSetConfig);
    m.cfg_page = 0;
    m.cfg_exposure_valid = 1;
    m.cfg_exposure_us = static_cast<uint16_t>(exposureUs);
    return command(m);
  }
  // The answers (ALACS_Ack) sent since the last call.
  std::vector<AckSeen> acks() {
    std::vector<AckSeen> out;
    for (; seen < can.sent().size(); ++seen) {
      const ports::CanFrame& f = can.sent()[seen].frame;
      if (f.id != ALACS_BASE_ID_ACK + kNode) continue;
      alacs_alacs_ack_t a{};
      REQUIRE(alacs_alacs_ack_unpack(&a, f.data.data(), f.dlc) == 0);
      out.push_back({static_cast<Opcode>(a.ack_opcode), a.ack_counter, static_cast<protocol::AckResult>(a.ack_result),
                     static_cast<NackReason>(a.nack_reason), static_cast<protocol::NackDetail>(a.nack_detail),
                     alacs_alacs_ack_nack_value_decode(a.nack_value), alacs_alacs_ack_nack_limit_decode(a.nack_limit)});
    }
    return out;
  }
  // The one answer to the frame just received.
  AckSeen answer(const ports::CanFrame& f) {
    acks();
    receive(f);
    std::vector<AckSeen> a = acks();
    REQUIRE(a.size() == 1);
    return a[0];
  }
  std::vector<ports::CanFrame> sentWithId(uint32_t id) const {
    std::vector<ports::CanFrame> out;
    for (const ports::SentFrame& s : can.sent())
      if (s.frame.id == id) out.push_back(s.frame);
    return out;
  }
  std::vector<alacs_alacs_result_header_t> results() const {
    std::vector<alacs_alacs_result_header_t> out;
    for (const ports::CanFrame& f : sentWithId(ALACS_BASE_ID_RESULT_HEADER + kNode)) {
      alacs_alacs_result_header_t h{};
      REQUIRE(alacs_alacs_result_header_unpack(&h, f.data.data(), f.dlc) == 0);
      out.push_back(h);
    }
    return out;
  }
  std::vector<uint16_t> emcyCodes() const {
    std::vector<uint16_t> out;
    for (const ports::CanFrame& f : sentWithId(ALACS_BASE_ID_EMCY + kNode))
      out.push_back(static_cast<uint16_t>(f.data[0] | f.data[1] << 8));
    return out;
  }
  alacs_alacs_status_t lastStatus() const {
    const std::vector<ports::CanFrame> s = sentWithId(ALACS_BASE_ID_STATUS + kNode);
    REQUIRE(!s.empty());
    alacs_alacs_status_t st{};
    REQUIRE(alacs_alacs_status_unpack(&st, s.back().data.data(), s.back().dlc) == 0);
    return st;
  }

  VirtualClock clock{5 * kNsPerS};
  ports::FakeCanBus can;
  app::FakeScanJobs worker;
  ports::FakeDigitalOut laserLine{clock};
  ports::FakeDigitalIn home{true};
  app::LaserGuard laser;
  app::DaemonConfig cfg;
  std::unique_ptr<app::Sensor> sensor;
  uint8_t counter = 0;
  size_t seen = 0;
};

bool laserEverOn(const Rig& r) {
  for (const ports::Edge& e : r.laserLine.edges())
    if (e.level) return true;
  return false;
}

}  // namespace

TEST_CASE("Sensor boot: the boot-up is the node's first frame; the cyclic heartbeat starts one period after it",
          "[app][sensor]") {
  Rig r(true, true, true, 0);  // no cyclic status: the heartbeat's start is the only deadline
  r.sensor->start(r.now());
  CHECK(r.can.cyclic().empty());  // nothing cyclic before the boot-up went out
  const TimeNs bootNs = r.now();
  r.tick();
  REQUIRE(!r.can.sent().empty());
  CHECK(r.can.sent().front().frame.id == 0x700U + kNode);
  CHECK(r.can.sent().front().frame.dlc == 1);
  CHECK(r.can.sent().front().frame.data[0] == 0x00);
  CHECK(r.sensor->state() == State::kHoming);
  REQUIRE(r.worker.submitted().size() == 1);
  CHECK(r.worker.submitted()[0].kind == app::WorkerJob::Kind::kHome);
  // Not at once: a master waiting for the boot-up would read the heartbeat's state instead.
  CHECK(r.can.cyclicPeriodNs() == 0);
  CHECK(r.sensor->nextDeadline() == bootNs + 1000 * kNsPerMs);  // the loop wakes for it
  r.advanceMs(999);
  CHECK(r.can.cyclicPeriodNs() == 0);
  r.advanceMs(1);
  std::vector<ports::CyclicRequest> started;
  for (const ports::CyclicRequest& c : r.can.cyclic())
    if (c.periodNs > 0) started.push_back(c);
  REQUIRE(started.size() == 1);
  CHECK(started[0].timeNs == bootNs + 1000 * kNsPerMs);
  CHECK(started[0].periodNs == 1000 * kNsPerMs);
  CHECK(started[0].frame.data[0] == 0x05);  // OPERATIONAL (auto start)
}

TEST_CASE("Sensor boot: a refused first write keeps the boot-up first and the heartbeat waiting", "[app][sensor]") {
  Rig r;
  r.can.refuseSends(3);
  r.sensor->start(r.now());
  r.tick();
  CHECK(r.can.sent().empty());
  CHECK(r.can.cyclicPeriodNs() == 0);
  r.advanceMs(20);  // the node's back-off: 1, 2, 4 .. ms
  REQUIRE(!r.can.sent().empty());
  CHECK(r.can.sent().front().frame.id == 0x700U + kNode);
  CHECK(r.can.sent().front().frame.data[0] == 0x00);
  // One period after the boot-up went out (a few ms late), not after start().
  const TimeNs bootUpNs = r.can.sent().front().timeNs;
  REQUIRE(bootUpNs > 0);
  while (r.now() < bootUpNs + 999 * kNsPerMs) r.advanceMs(1);
  CHECK(r.can.cyclicPeriodNs() == 0);
  r.advanceMs(1);
  CHECK(r.can.cyclicPeriodNs() == 1000 * kNsPerMs);
}

TEST_CASE("Sensor without a cyclic bus: boot-up, then heartbeats at the period, exactly", "[app][sensor]") {
  Rig r(true, false);
  r.boot();
  r.advanceMs(3000);
  std::vector<TimeNs> times;
  for (const ports::SentFrame& s : r.can.sent())
    if (s.frame.id == 0x700U + kNode) times.push_back(s.timeNs);
  REQUIRE(times.size() == 4);
  CHECK(r.sentWithId(0x700U + kNode)[0].data[0] == 0x00);
  for (size_t i = 1; i < times.size(); ++i) CHECK(times[i] - times[i - 1] == 1000 * kNsPerMs);
}

TEST_CASE("Sensor: every command in every state", "[app][sensor]") {
  // Expected first answer per state, in the order LOCALIZE, SCAN_ALL, HOME, SET_CONFIG,
  // GET_VERSION, CLEAR_FAULT, STOP. 'A': ACK; otherwise the NACK reason.
  struct Row {
    const char* name;
    std::function<void(Rig&)> enter;
    State state;
    std::vector<NackReason> expected;  // kNone = ACK
  };
  const NackReason A = NackReason::kNone;
  const std::vector<Row> rows = {
      {"HOMING", [](Rig& r) { r.boot(); }, State::kHoming,
       {NackReason::kBusy, NackReason::kBusy, NackReason::kBusy, A, A, A, A}},
      {"IDLE", [](Rig& r) { r.bootIdle(); }, State::kIdle, {A, A, A, A, A, A, A}},
      {"SCANNING", [](Rig& r) { r.bootIdle(); r.receive(r.localize(0, 0, 1100)); }, State::kScanning,
       {NackReason::kBusy, NackReason::kBusy, NackReason::kBusy, A, A, A, A}},
      {"FAULT", [](Rig& r) {
         r.bootIdle();
         r.receive(r.localize(0, 0, 1100));
         app::WorkerEvent ev;
         ev.faultBit = protocol::kFaultCameraTimeout;
         ev.status = Status(Error::kTimeout, "camera frame timed out");
         ev.resultStatus = protocol::ResultStatus::kFailed;
         r.finish(ev);
       }, State::kFault,
       {NackReason::kFaultActive, NackReason::kFaultActive, NackReason::kFaultActive, A, A, A, A}},
      {"STOPPED", [](Rig& r) { r.bootIdle(); r.receive(r.simple(Opcode::kStop)); }, State::kStopped,
       {NackReason::kFaultActive, NackReason::kFaultActive, NackReason::kFaultActive, A, A, A, A}},
  };
  const std::vector<Opcode> ops = {Opcode::kLocalize, Opcode::kScanAll,    Opcode::kHome, Opcode::kSetConfig,
                                   Opcode::kGetVersion, Opcode::kClearFault, Opcode::kStop};
  for (const Row& row : rows) {
    for (size_t i = 0; i < ops.size(); ++i) {
      Rig r;
      row.enter(r);
      REQUIRE(r.sensor->state() == row.state);
      const ports::CanFrame f = ops[i] == Opcode::kLocalize  ? r.localize(0, 0, 1100)
                                : ops[i] == Opcode::kSetConfig ? r.setExposure(2500)
                                                              : r.simple(ops[i]);
      INFO(row.name << " / opcode " << static_cast<int>(ops[i]));
      const AckSeen a = r.answer(f);
      CHECK(a.opcode == ops[i]);
      CHECK(a.counter == (r.counter & 0x0F));
      if (row.expected[i] == A) {
        CHECK(a.result == protocol::AckResult::kAck);
      } else {
        CHECK(a.result == protocol::AckResult::kNack);
        CHECK(a.reason == row.expected[i]);
      }
    }
  }
}

TEST_CASE("Sensor: each NACK reason, with the frame that earns it", "[app][sensor]") {
  SECTION("BAD_DLC, BAD_CHECKSUM, UNKNOWN_OPCODE, BAD_COUNTER") {
    Rig r;
    r.bootIdle();
    ports::CanFrame shortFrame = r.simple(Opcode::kGetVersion);
    shortFrame.dlc = 5;
    CHECK(r.answer(shortFrame).reason == NackReason::kBadDlc);
    ports::CanFrame badSum = r.simple(Opcode::kGetVersion);
    badSum.data[7] ^= 0x5A;
    CHECK(r.answer(badSum).reason == NackReason::kBadChecksum);
    ports::CanFrame unknown = r.simple(Opcode::kGetVersion);
    unknown.data[0] = 0x0E;
    unknown.data[7] = alacs_command_checksum(unknown.data.data());
    CHECK(r.answer(unknown).reason == NackReason::kUnknownOpcode);
    const ports::CanFrame v = r.simple(Opcode::kGetVersion);
    CHECK(r.answer(v).result == protocol::AckResult::kAck);
    CHECK(r.answer(v).reason == NackReason::kBadCounter);  // the same counter within 1 s
  }
  SECTION("NOT_CALIBRATED: refused with the reason in the status, never a scan") {
    Rig r(false);
    r.bootIdle();
    CHECK(r.answer(r.localize(0, 0, 1100)).reason == NackReason::kNotCalibrated);
    CHECK(r.answer(r.simple(Opcode::kScanAll)).reason == NackReason::kNotCalibrated);
    CHECK(r.worker.submitted().size() == 1);  // only the boot's HOME
    CHECK(!r.worker.localizer().has_value());  // no stand-in calibration, ever
    CHECK(r.sensor->calibrationRefusal().find("laser.plane_normal") != std::string::npos);
    r.advanceMs(100);
    CHECK(r.lastStatus().calibrated == 0);
    CHECK(r.lastStatus().fault_not_calibrated == 1);
  }
  SECTION("a refused configuration file: up on the defaults, CONFIG_INVALID, no motion") {
    Rig r;
    r.sensor->refuseConfig("alacsd.json: laser.max_on_ms: wrong type (a number is needed)");
    r.boot();
    CHECK(r.worker.submitted().empty());  // not even the boot's HOME
    CHECK(r.answer(r.simple(Opcode::kHome)).reason == NackReason::kFaultActive);
    CHECK(r.answer(r.localize(0, 0, 1100)).reason == NackReason::kFaultActive);
    CHECK(r.answer(r.simple(Opcode::kScanAll)).reason == NackReason::kFaultActive);
    CHECK(r.answer(r.simple(Opcode::kGetVersion)).result == protocol::AckResult::kAck);  // it answers
    r.advanceMs(100);
    CHECK(r.lastStatus().fault_config_invalid == 1);
    // CLEAR_FAULT does not clear it: only a good file (and a restart) does.
    CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
    r.advanceMs(100);
    CHECK(r.lastStatus().fault_config_invalid == 1);
    CHECK(r.answer(r.localize(0, 0, 1100)).reason == NackReason::kFaultActive);
    CHECK(r.worker.submitted().empty());
    CHECK(r.sensor->configFileRefusal().find("laser.max_on_ms") != std::string::npos);
  }
  SECTION("NOT_HOMED: homing failed") {
    Rig r;
    r.boot();
    app::WorkerEvent ev;
    ev.status = Status(Error::kIo, "step line write failed");
    r.finish(ev);
    CHECK(r.answer(r.localize(0, 0, 1100)).reason == NackReason::kNotHomed);
  }
  SECTION("OUT_OF_RANGE: a target the slide cannot reach, with the limit on the bus") {
    Rig r;
    r.bootIdle();
    const AckSeen a = r.answer(r.localize(900, 0, 1100));
    CHECK(a.reason == NackReason::kOutOfRange);
    CHECK(a.detail == protocol::NackDetail::kStroke);
    CHECK(a.value > 200.0);  // the slide position the target needs
    CHECK(a.limit == Approx(200.0));
    const AckSeen deep = r.answer(r.localize(0, 0, 2400));
    CHECK(deep.reason == NackReason::kOutOfRange);
    CHECK(deep.detail == protocol::NackDetail::kDepth);
    CHECK(deep.value == Approx(2400.0));
    CHECK(deep.limit == Approx(2000.0));
  }
  SECTION("BAD_VALUE: (stops - 1) x spacing (14 x 20 mm) beyond the 200 mm stroke; nothing applied") {
    Rig r;
    r.bootIdle();
    const app::DaemonConfig before = r.sensor->config();
    const AckSeen a = r.answer(r.setConfigScan(15, 20.0, 500));
    CHECK(a.reason == NackReason::kBadValue);
    CHECK(a.detail == protocol::NackDetail::kSpacingXStops);
    CHECK(a.value == Approx(280.0));
    CHECK(a.limit == Approx(200.0));
    CHECK(r.sensor->config().heartbeatMs == before.heartbeatMs);  // all fields or none
    CHECK(r.sensor->config().scan.stops == before.scan.stops);
  }
  SECTION("NMT_NOT_OPERATIONAL: pre-operational and stopped; STOP still executes") {
    Rig r;
    r.bootIdle();
    ports::CanFrame nmt;
    nmt.id = 0;
    nmt.dlc = 2;
    nmt.data[0] = 0x80;  // enter pre-operational
    nmt.data[1] = kNode;
    r.receive(nmt);
    CHECK(r.answer(r.localize(0, 0, 1100)).reason == NackReason::kNmtNotOperational);
    nmt.data[0] = 0x02;  // stop
    r.receive(nmt);
    CHECK(r.answer(r.simple(Opcode::kHome)).reason == NackReason::kNmtNotOperational);
    CHECK(r.answer(r.simple(Opcode::kStop)).result == protocol::AckResult::kAck);
    CHECK(r.sensor->state() == State::kStopped);
    nmt.data[0] = 0x01;  // start
    r.receive(nmt);
    CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
    CHECK(r.answer(r.localize(0, 0, 1100)).result == protocol::AckResult::kAck);
  }
  SECTION("FAULT_ACTIVE and INTERNAL on HOME's DONE") {
    Rig r;
    r.bootIdle();
    CHECK(r.answer(r.simple(Opcode::kHome)).result == protocol::AckResult::kAck);
    app::WorkerEvent ev;
    ev.status = Status(Error::kInternal, "no pulse");
    r.finish(ev);
    std::vector<AckSeen> done = r.acks();
    REQUIRE(done.size() == 1);
    CHECK(done[0].result == protocol::AckResult::kNack);
    CHECK(done[0].reason == NackReason::kInternal);
    CHECK(r.answer(r.simple(Opcode::kHome)).result == protocol::AckResult::kAck);
    app::WorkerEvent stuck;
    stuck.status = Status(Error::kTimeout, "home switch never closed");
    stuck.faultBit = protocol::kFaultHomingTimeout;
    r.finish(stuck);
    done = r.acks();
    REQUIRE(done.size() == 1);
    CHECK(done[0].reason == NackReason::kFaultActive);
    CHECK(r.sensor->state() == State::kFault);
  }
}

TEST_CASE("Sensor: STOP in each phase ends the job, the laser and latches STOPPED", "[app][sensor]") {
  for (const char* phase : {"homing", "localize", "scan-all"}) {
    INFO(phase);
    Rig r;
    if (std::string(phase) == "homing") {
      r.boot();
    } else {
      r.bootIdle();
      r.receive(std::string(phase) == "localize" ? r.localize(0, 0, 1100) : r.simple(Opcode::kScanAll));
      REQUIRE(r.sensor->state() == State::kScanning);
    }
    REQUIRE(r.laser.on());  // the worker exposing
    const int cancelsBefore = r.worker.cancels();
    CHECK(r.answer(r.simple(Opcode::kStop)).result == protocol::AckResult::kAck);
    CHECK(r.worker.cancels() == cancelsBefore + 1);
    CHECK(!r.laserLine.level());
    CHECK(r.sensor->state() == State::kStopped);
    // Still busy: CLEAR_FAULT cannot leave STOPPED yet, and its NACK says so (BUSY).
    CHECK(r.answer(r.simple(Opcode::kClearFault)).reason == NackReason::kBusy);
    CHECK(r.sensor->state() == State::kStopped);
    r.finishCancelled();
    if (std::string(phase) != "homing") {
      const auto res = r.results();
      REQUIRE(res.size() == 1);
      CHECK(res[0].result_status == static_cast<uint8_t>(protocol::ResultStatus::kAborted));
    }
    CHECK(r.sensor->state() == State::kStopped);
    CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
    CHECK(r.sensor->state() == State::kIdle);
  }
}

TEST_CASE("Sensor: a fault mid-scan fails the result for that fault, not as a STOP", "[app][sensor]") {
  SECTION("laser beyond laser.max_on_ms") {
    Rig r;
    r.bootIdle();
    r.receive(r.localize(0, 0, 1100));
    REQUIRE(r.laser.on());
    r.advanceMs(250);
    CHECK(r.laserLine.level());  // exactly the limit: still allowed
    r.advanceMs(1);
    CHECK(!r.laserLine.level());
    CHECK(r.sensor->state() == State::kFault);
    CHECK(r.worker.cancelPending());
    CHECK(r.emcyCodes() == std::vector<uint16_t>{static_cast<uint16_t>(protocol::emcyErrorCode(protocol::kFaultLaserOvertime))});
    r.finishCancelled();
    const auto res = r.results();
    REQUIRE(res.size() == 1);
    CHECK(res[0].result_status == static_cast<uint8_t>(protocol::ResultStatus::kFailed));
    CHECK(!r.laser.on().isOk());  // latched until CLEAR_FAULT
    CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
    CHECK(r.sensor->state() == State::kIdle);
    CHECK(r.laser.on().isOk());
    CHECK(r.laser.off().isOk());
  }
  SECTION("camera timeout reported by the worker") {
    Rig r;
    r.bootIdle();
    r.receive(r.localize(0, 0, 1100));
    app::WorkerEvent ev;
    ev.faultBit = protocol::kFaultCameraTimeout;
    ev.status = Status(Error::kTimeout, "camera frame timed out after 150 ms");
    ev.resultStatus = protocol::ResultStatus::kFailed;
    r.finish(ev);
    CHECK(r.sensor->state() == State::kFault);
    CHECK(r.emcyCodes() == std::vector<uint16_t>{static_cast<uint16_t>(protocol::emcyErrorCode(protocol::kFaultCameraTimeout))});
    REQUIRE(r.results().size() == 1);
    CHECK(r.results()[0].result_status == static_cast<uint8_t>(protocol::ResultStatus::kFailed));
    r.advanceMs(100);
    CHECK(r.lastStatus().fault_camera_timeout == 1);
    CHECK(r.lastStatus().fault_laser_overtime == 0);
  }
}

TEST_CASE("Sensor: SET_CONFIG and SDO writes while busy are accepted, the scan settings applied when idle", "[app][sensor]") {
  Rig r;
  r.boot();  // homing
  CHECK(r.answer(r.setExposure(2500)).result == protocol::AckResult::kAck);
  CHECK(r.sensor->config().exposureUs == 2500);
  CHECK(r.worker.exposureUs() == 3000);  // the running job keeps its settings
  // A CANopen master writes the heartbeat period (0x1017) right after the boot-up.
  ports::CanFrame sdo;
  sdo.id = 0x600U + kNode;
  sdo.dlc = 8;
  sdo.data = {0x2B, 0x17, 0x10, 0x00, 0xF4, 0x01, 0x00, 0x00};  // 500 ms
  r.receive(sdo);
  const auto answers = r.sentWithId(0x580U + kNode);
  REQUIRE(answers.size() == 1);
  CHECK(answers[0].data[0] == 0x60);  // download confirmed, not aborted
  CHECK(r.can.cyclicPeriodNs() == 0);  // the first heartbeat comes one (new) period after the boot-up
  r.advanceMs(500);
  CHECK(r.can.cyclicPeriodNs() == 500 * kNsPerMs);
  r.finish();
  CHECK(r.worker.exposureUs() == 2500);  // applied once idle
  REQUIRE(r.worker.localizer().has_value());
}

TEST_CASE("Sensor: heartbeat period changes over SET_CONFIG; 0 stops it", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  r.advanceMs(1000);  // the heartbeat has started
  CHECK(r.answer(r.setConfigScan(7, 13.3, 200)).result == protocol::AckResult::kAck);
  CHECK(r.can.cyclicPeriodNs() == 200 * kNsPerMs);  // the new period at once
  CHECK(r.answer(r.setConfigScan(7, 13.3, 0)).result == protocol::AckResult::kAck);
  CHECK(r.can.cyclicPeriodNs() == 0);
}

TEST_CASE("Sensor: NMT reset sends a new boot-up before any heartbeat", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  ports::CanFrame nmt;
  nmt.dlc = 2;
  nmt.data[0] = 0x81;  // reset node
  nmt.data[1] = 0;     // all nodes
  r.sensor->onCanFrame(nmt, r.now());
  r.can.refuseSends(1);  // the boot-up's first try is refused: the heartbeat must wait for it
  r.tick();
  CHECK(r.can.cyclicPeriodNs() == 0);
  r.advanceMs(5);
  const auto hb = r.sentWithId(0x700U + kNode);
  REQUIRE(hb.size() == 1);
  CHECK(hb[0].data[0] == 0x00);
  CHECK(r.can.cyclicPeriodNs() == 0);  // one period after the new boot-up, not after the reset
  TimeNs bootUpNs = 0;
  for (const ports::SentFrame& f : r.can.sent())
    if (f.frame.id == 0x700U + kNode) bootUpNs = f.timeNs;
  REQUIRE(bootUpNs > 0);
  while (r.now() < bootUpNs + 999 * kNsPerMs) r.advanceMs(1);
  CHECK(r.can.cyclicPeriodNs() == 0);
  r.advanceMs(1);
  CHECK(r.can.cyclicPeriodNs() == 1000 * kNsPerMs);
}

TEST_CASE("Sensor: bus-off holds transmission; the restart lets it out with CAN_BUS_OFF", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  ports::CanFrame err;
  err.error = true;
  err.dlc = 8;
  err.errorClass = protocol::kCanErrBusOff;
  r.receive(err);
  CHECK(r.sensor->node().busOff());
  r.can.clearSent();
  r.sensor->onCanFrame(r.simple(Opcode::kGetVersion), r.now());
  r.advanceMs(50);
  CHECK(r.can.sent().empty());  // nothing written while bus-off
  err.errorClass = protocol::kCanErrRestarted;
  r.receive(err);
  r.advanceMs(5);
  CHECK(!r.sensor->node().busOff());
  CHECK(r.acks().size() == 1);  // the held answer went out
  CHECK(r.emcyCodes() == std::vector<uint16_t>{static_cast<uint16_t>(protocol::emcyErrorCode(protocol::kFaultCanBusOff))});
}

TEST_CASE("Sensor: shutdown answers the ACKed command as ABORTED and ends the laser", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  r.receive(r.localize(0, 0, 1100));
  REQUIRE(r.laser.on());
  r.sensor->shutdown(r.now());
  r.tick();
  CHECK(!r.laserLine.level());
  CHECK(r.worker.cancelPending());
  const auto res = r.results();
  REQUIRE(res.size() == 1);
  CHECK(res[0].result_status == static_cast<uint8_t>(protocol::ResultStatus::kAborted));
  CHECK(res[0].result_target_id == 7);
  r.finishCancelled();  // the worker's own event after shutdown is not a second result
  CHECK(r.results().size() == 1);
  CHECK(r.sensor->txPending() == 0);
}

TEST_CASE("Sensor: a result is published once per scan with its own counter", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  for (int i = 0; i < 3; ++i) {
    r.receive(r.localize(0, 0, 1100));
    r.clock.advance(400 * kNsPerMs);
    app::WorkerEvent ev;
    ev.resultStatus = protocol::ResultStatus::kNotFound;
    r.finish(ev);
  }
  const auto res = r.results();
  REQUIRE(res.size() == 3);
  for (size_t i = 0; i < res.size(); ++i) {
    CHECK(res[i].meas_counter == i + 1);
    CHECK(res[i].cycle_time == 20);  // 400 ms at 20 ms/bit
  }
  CHECK(!laserEverOn(r));  // the sensor never switches the laser on by itself
}

TEST_CASE("Sensor: STOP is fail-safe: a bad checksum or a repeated counter still stops, NACKed for the record", "[app][sensor]") {
  for (const char* fault : {"checksum", "counter"}) {
    INFO(fault);
    Rig r;
    r.bootIdle();
    r.receive(r.localize(0, 0, 1100));
    REQUIRE(r.laser.on());
    ports::CanFrame stop = r.simple(Opcode::kStop);
    if (std::string(fault) == "checksum") {
      stop.data[7] ^= 0xFF;
    } else {
      stop.data[1] = static_cast<uint8_t>(r.counter - 1);  // the LOCALIZE's counter, within 1 s
      stop.data[7] = alacs_command_checksum(stop.data.data());
    }
    const AckSeen a = r.answer(stop);
    CHECK(a.opcode == Opcode::kStop);
    CHECK(a.result == protocol::AckResult::kNack);
    CHECK(a.reason == (std::string(fault) == "checksum" ? NackReason::kBadChecksum : NackReason::kBadCounter));
    CHECK(r.sensor->state() == State::kStopped);
    CHECK(!r.laserLine.level());
    CHECK(r.worker.cancelPending());
  }
  // Other opcodes with a bad checksum are only NACKed.
  Rig r;
  r.bootIdle();
  ports::CanFrame home = r.simple(Opcode::kHome);
  home.data[7] ^= 0xFF;
  CHECK(r.answer(home).reason == NackReason::kBadChecksum);
  CHECK(r.sensor->state() == State::kIdle);
  CHECK(r.worker.submitted().size() == 1);
}

TEST_CASE("Sensor: a worker without progress beyond its deadline is a fault, answered and unhealthy", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  // Homing 6000 ms is the longest phase by default; plus 2 s of slack.
  CHECK(r.sensor->workerDeadlineNs() == 8000 * kNsPerMs);
  r.receive(r.localize(0, 0, 1100));
  r.worker.setProgressNs(r.now());
  r.advanceMs(8000);
  CHECK(r.sensor->healthy());
  CHECK(r.sensor->state() == State::kScanning);
  r.advanceMs(1);
  CHECK(!r.sensor->healthy());
  CHECK(r.sensor->state() == State::kFault);
  CHECK(r.worker.cancelPending());
  CHECK(r.emcyCodes() == std::vector<uint16_t>{static_cast<uint16_t>(protocol::emcyErrorCode(protocol::kFaultInternal))});
  auto res = r.results();
  REQUIRE(res.size() == 1);  // answered at once: the worker may never come back
  CHECK(res[0].result_status == static_cast<uint8_t>(protocol::ResultStatus::kFailed));
  // CLEAR_FAULT while the worker is still stuck: NACKed BUSY (nothing is cleared), the
  // fault and the unhealthy watchdog stay.
  CHECK(r.answer(r.simple(Opcode::kClearFault)).reason == NackReason::kBusy);
  CHECK(r.sensor->state() == State::kFault);
  CHECK(!r.sensor->healthy());
  // If it does come back, its event is not a second result, and the sensor is healthy again.
  r.finishCancelled();
  CHECK(r.results().size() == 1);
  CHECK(r.sensor->healthy());
  CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
  CHECK(r.sensor->state() == State::kIdle);
}

TEST_CASE("Sensor: a frame read beyond its deadline is a camera fault naming the frame source, and unhealthy",
          "[app][sensor]") {
  Rig r;
  r.bootIdle();
  // camera.frame_timeout_ms 150 + the exposure 3 ms + 2 s of slack: well inside the
  // worker's own deadline (8 s), which alone would see this read only 6 s later.
  CHECK(r.sensor->frameDeadlineNs() == 2153 * kNsPerMs);
  r.receive(r.localize(0, 0, 1100));
  r.worker.setProgressNs(r.now());
  r.worker.setFrameReadSinceNs(r.now());
  r.advanceMs(2153);
  CHECK(r.sensor->healthy());
  CHECK(r.sensor->state() == State::kScanning);
  CHECK(r.sensor->stallReason().empty());
  r.advanceMs(1);
  CHECK(!r.sensor->healthy());
  CHECK(r.sensor->workerStuck());
  CHECK(r.sensor->state() == State::kFault);
  CHECK(r.sensor->stallReason() ==
        "frame source: a frame read has not returned for 2154 ms (deadline 2153 ms: camera.frame_timeout_ms + "
        "exposure + slack)");
  CHECK(r.worker.cancelPending());
  CHECK(r.emcyCodes() ==
        std::vector<uint16_t>{static_cast<uint16_t>(protocol::emcyErrorCode(protocol::kFaultCameraTimeout))});
  auto res = r.results();
  REQUIRE(res.size() == 1);  // answered at once: the read may never return
  CHECK(res[0].result_status == static_cast<uint8_t>(protocol::ResultStatus::kFailed));
  CHECK(res[0].result_reason == static_cast<uint8_t>(protocol::ResultReason::kCameraFault));
  // The read returns (cancelled): the watchdog may be fed again; the fault stays latched.
  r.worker.setFrameReadSinceNs(0);
  r.tick();
  CHECK(r.sensor->healthy());
  CHECK(r.sensor->state() == State::kFault);
  r.finishCancelled();
  CHECK(r.results().size() == 1);
  CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
  CHECK(r.sensor->state() == State::kIdle);
  // Reads that each return within the deadline keep a long scan healthy.
  r.receive(r.simple(Opcode::kScanAll));
  for (int i = 0; i < 10; ++i) {
    r.worker.setFrameReadSinceNs(r.now());
    r.worker.setProgressNs(r.now());
    r.advanceMs(2000);
  }
  CHECK(r.sensor->healthy());
  CHECK(r.sensor->state() == State::kScanning);
}

TEST_CASE("Sensor: an event loop that stops servicing CAN beyond its deadline is a fault naming the CAN loop",
          "[app][sensor]") {
  Rig r;
  r.bootIdle();
  CHECK(app::Sensor::canLoopDeadlineNs() == 1000 * kNsPerMs);
  SECTION("the loop is away (frozen, or blocked in a call) beyond the deadline") {
    r.clock.advance(1000 * kNsPerMs);  // exactly the deadline: still within it
    r.tick();
    CHECK(r.sensor->healthy());
    CHECK(r.sensor->state() == State::kIdle);
    r.clock.advance(1001 * kNsPerMs);
    r.sensor->serviceCan(r.now());  // the first wake-up after it: the watchdog is withheld
    CHECK(!r.sensor->healthy());
    CHECK(!r.sensor->workerStuck());
    CHECK(r.sensor->state() == State::kFault);
    CHECK(r.sensor->stallReason() == "CAN loop: no CAN receive or transmit processing for 1001 ms (deadline 1000 ms)");
    r.sensor->tick(r.now());
    CHECK(!r.sensor->healthy());
    CHECK(r.emcyCodes() ==
          std::vector<uint16_t>{static_cast<uint16_t>(protocol::emcyErrorCode(protocol::kFaultInternal))});
    // The next wake-up within the deadline: healthy again; the fault stays latched.
    r.advanceMs(10);
    CHECK(r.sensor->healthy());
    CHECK(r.sensor->state() == State::kFault);
    CHECK(r.answer(r.simple(Opcode::kClearFault)).result == protocol::AckResult::kAck);
    CHECK(r.sensor->state() == State::kIdle);
  }
  SECTION("the loop ticks but no longer drains the receive queue") {
    for (int i = 0; i < 100; ++i) {
      r.clock.advance(10 * kNsPerMs);
      r.sensor->tick(r.now());
    }
    CHECK(r.sensor->healthy());  // 1000 ms: within the deadline
    r.clock.advance(1 * kNsPerMs);
    r.sensor->tick(r.now());
    CHECK(!r.sensor->healthy());
    CHECK(r.sensor->state() == State::kFault);
    CHECK(r.sensor->stallReason() == "CAN loop: no CAN receive processing for 1001 ms (deadline 1000 ms)");
  }
  SECTION("a bus that refuses every frame is the bus's state, not a stalled loop") {
    r.can.setDown(true);
    r.receive(r.simple(Opcode::kGetVersion));  // an answer that cannot go out
    r.advanceMs(5000);
    CHECK(r.sensor->healthy());
    CHECK(r.sensor->stallReason().empty());
    CHECK(r.sensor->state() == State::kIdle);
  }
}

TEST_CASE("Sensor: progress within the deadline keeps a long scan healthy", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  r.receive(r.simple(Opcode::kScanAll));
  for (int i = 0; i < 20; ++i) {  // 20 frames, 5 s apart: 100 s of SCAN_ALL
    r.advanceMs(5000);
    r.worker.setProgressNs(r.now());
  }
  CHECK(r.sensor->healthy());
  CHECK(r.sensor->state() == State::kScanning);
  r.finish();
  CHECK(r.results().size() == 1);
}

TEST_CASE("Sensor: progress frames during a scan, on change and every 500 ms, none after the result", "[app][sensor]") {
  Rig r;
  r.bootIdle();
  r.receive(r.simple(Opcode::kScanAll));
  const uint32_t progressId = ALACS_BASE_ID_PROGRESS + kNode;
  auto progress = [&] {
    std::vector<alacs_alacs_progress_t> out;
    for (const ports::CanFrame& f : r.sentWithId(progressId)) {
      alacs_alacs_progress_t p{};
      REQUIRE(alacs_alacs_progress_unpack(&p, f.data.data(), f.dlc) == 0);
      out.push_back(p);
    }
    return out;
  };
  REQUIRE(progress().size() == 1);  // at once
  r.worker.setProgress({0, 26, 0, protocol::ProgressPhase::kMoving});
  r.tick();
  REQUIRE(progress().size() == 2);  // a change
  r.advanceMs(499);
  CHECK(progress().size() == 2);
  r.advanceMs(1);
  REQUIRE(progress().size() == 3);  // 500 ms without change
  r.worker.setProgress({3, 26, 0, protocol::ProgressPhase::kExposing});
  r.tick();
  const auto p = progress();
  REQUIRE(p.size() == 4);
  CHECK(p.back().stops_done == 3);
  CHECK(p.back().stops_total == 26);
  CHECK(p.back().progress_phase == static_cast<uint8_t>(protocol::ProgressPhase::kExposing));
  CHECK(p.back().progress_mode == 1);
  CHECK(p.back().progress_counter == (r.counter & 0x0F));
  CHECK(p.back().progress_meas_counter == 1);  // the result's MeasCounter to come
  app::WorkerEvent ev;
  ev.resultStatus = protocol::ResultStatus::kNotFound;
  r.finish(ev);
  r.advanceMs(2000);
  CHECK(progress().size() == 4);
  REQUIRE(r.results().size() == 1);
  CHECK(r.results()[0].meas_counter == 1);
}

TEST_CASE("Sensor: every result that is not a measurement says why", "[app][sensor]") {
  using protocol::ResultReason;
  using protocol::ResultStatus;
  struct Case {
    const char* name;
    ResultStatus status;
    ResultReason reason;
  };
  SECTION("the worker's reasons pass through") {
    for (const Case& c : {Case{"rough only", ResultStatus::kRoughOnly, ResultReason::kTooFewLines},
                          Case{"nothing in the gate", ResultStatus::kNotFound, ResultReason::kNoLinesInGate},
                          Case{"no line in sun", ResultStatus::kNotFound, ResultReason::kBrightAmbient}}) {
      INFO(c.name);
      Rig r;
      r.bootIdle();
      r.receive(r.localize(0, 0, 1100));
      app::WorkerEvent ev;
      ev.resultStatus = c.status;
      ev.resultReason = c.reason;
      r.finish(ev);
      REQUIRE(r.results().size() == 1);
      CHECK(r.results()[0].result_status == static_cast<uint8_t>(c.status));
      CHECK(r.results()[0].result_reason == static_cast<uint8_t>(c.reason));
    }
  }
  SECTION("STOP, a fault and shutdown name themselves") {
    Rig stop;
    stop.bootIdle();
    stop.receive(stop.localize(0, 0, 1100));
    stop.receive(stop.simple(Opcode::kStop));
    stop.finishCancelled();
    CHECK(stop.results()[0].result_reason == static_cast<uint8_t>(ResultReason::kStopped));
    Rig laser;
    laser.bootIdle();
    laser.receive(laser.localize(0, 0, 1100));
    REQUIRE(laser.laser.on());
    laser.advanceMs(300);
    laser.finishCancelled();
    CHECK(laser.results()[0].result_status == static_cast<uint8_t>(ResultStatus::kFailed));
    CHECK(laser.results()[0].result_reason == static_cast<uint8_t>(ResultReason::kLaserFault));
    Rig cam;
    cam.bootIdle();
    cam.receive(cam.localize(0, 0, 1100));
    app::WorkerEvent ev;
    ev.faultBit = protocol::kFaultCameraTimeout;
    ev.status = Status(Error::kTimeout, "camera frame timed out");
    ev.resultStatus = ResultStatus::kFailed;
    cam.finish(ev);
    CHECK(cam.results()[0].result_reason == static_cast<uint8_t>(ResultReason::kCameraFault));
    Rig term;
    term.bootIdle();
    term.receive(term.localize(0, 0, 1100));
    term.sensor->shutdown(term.now());
    term.tick();
    CHECK(term.results()[0].result_reason == static_cast<uint8_t>(ResultReason::kShutdown));
  }
  SECTION("a measurement has no reason") {
    Rig r;
    r.bootIdle();
    r.receive(r.localize(0, 0, 1100));
    app::WorkerEvent ev;
    ev.estimates.emplace_back();
    r.finish(ev);
    CHECK(r.results()[0].result_status == static_cast<uint8_t>(ResultStatus::kMeasured));
    CHECK(r.results()[0].result_reason == static_cast<uint8_t>(ResultReason::kNone));
    CHECK(r.results()[0].object_count == 1);
  }
  SECTION("a measurement of the widened search says it was found outside the gate") {
    Rig r;
    r.bootIdle();
    r.receive(r.localize(0, 0, 1100));
    app::WorkerEvent ev;
    ev.estimates.emplace_back();
    ev.resultReason = ResultReason::kOutsideGate;
    r.finish(ev);
    CHECK(r.results()[0].result_status == static_cast<uint8_t>(ResultStatus::kMeasured));
    CHECK(r.results()[0].result_reason == static_cast<uint8_t>(ResultReason::kOutsideGate));
  }
}

TEST_CASE("Sensor: can.auto_start false waits in PRE-OPERATIONAL for NMT START; SDO is served meanwhile", "[app][sensor]") {
  Rig r(true, true, false);
  r.bootIdle();
  CHECK(r.sensor->node().nmtState() == protocol::NmtState::kPreOperational);
  CHECK(r.can.cyclicFrame().data[0] == 127);
  CHECK(r.answer(r.localize(0, 0, 1100)).reason == NackReason::kNmtNotOperational);
  ports::CanFrame sdo;
  sdo.id = 0x600U + kNode;
  sdo.dlc = 8;
  sdo.data = {0x40, 0x17, 0x10, 0x00, 0, 0, 0, 0};  // upload 0x1017
  r.receive(sdo);
  REQUIRE(r.sentWithId(0x580U + kNode).size() == 1);
  ports::CanFrame start;
  start.dlc = 2;
  start.data[0] = 0x01;
  start.data[1] = kNode;
  r.receive(start);
  CHECK(r.can.cyclicFrame().data[0] == 5);
  CHECK(r.answer(r.localize(0, 0, 1100)).result == protocol::AckResult::kAck);
}
