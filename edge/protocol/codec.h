// Typed C++ view of the ALACS CAN messages on top of the codec that cantools generates
// from can_protocol/alacs.dbc. Pure functions: frames in, structs out, and back.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>

#include "ports/can_port.h"

namespace alacs::protocol {

enum class Opcode : uint8_t {
  kInvalid = 0, kLocalize = 1, kScanAll = 2, kHome = 3, kStop = 4, kSetConfig = 5, kGetVersion = 6, kClearFault = 7,
};

enum class NackReason : uint8_t {
  kNone = 0, kBadDlc = 1, kBadChecksum = 2, kBadCounter = 3, kUnknownOpcode = 4, kBusy = 5, kNotHomed = 6,
  kNotCalibrated = 7, kOutOfRange = 8, kFaultActive = 9, kNmtNotOperational = 10, kBadValue = 11, kInternal = 12,
};

enum class AckResult : uint8_t { kAck = 0, kNack = 1, kDone = 2 };

enum class ScanMode : uint8_t { kStopAndGo = 0, kContinuous = 1 };

struct LocalizeCommand {
  ScanMode mode = ScanMode::kStopAndGo;
  uint8_t targetId = 0;
  Eigen::Vector3d roughMm = Eigen::Vector3d::Zero();
};

struct SetConfigCommand {
  uint8_t page = 0;
  std::optional<uint16_t> exposureUs;
  std::optional<uint8_t> brceStep;
  std::optional<uint8_t> brceThreshold;
  std::optional<uint8_t> scanStops;
  std::optional<double> stopSpacingMm;
  std::optional<uint16_t> heartbeatMs;
};

struct Command {
  Opcode opcode = Opcode::kInvalid;
  uint8_t counter = 0;
  LocalizeCommand localize;
  ScanMode scanAllMode = ScanMode::kStopAndGo;
  SetConfigCommand config;
  // Already answered by the node: a STOP that failed its checksum or counter check is
  // NACKed for the record and still executed (fail-safe); the application must not ACK it.
  bool answered = false;
};

// Decoded command or the reason it was refused (with the opcode/counter to echo).
struct CommandDecode {
  bool ok = false;
  Command command;
  NackReason reason = NackReason::kNone;
};

// Checks DLC and checksum, then unpacks. The counter rule is the node's (node.h).
CommandDecode decodeCommand(const ports::CanFrame& frame);

// ALACS_Ack.NackDetail: which limit a NACKed command broke. NackValue/NackLimit carry the
// offending value and the bound it broke in the unit docs/can-protocol.md gives per detail.
enum class NackDetail : uint8_t {
  kNone = 0, kStroke = 1, kDepth = 2, kLateral = 3, kFrame = 4, kCrossField = 5, kSpacingXStops = 6,
  kMode = 7, kExposure = 8, kBrceStep = 9, kScanStops = 10, kStopSpacing = 11, kHeartbeat = 12,
};

struct Ack {
  Opcode opcode = Opcode::kInvalid;
  uint8_t counter = 0;
  AckResult result = AckResult::kAck;
  NackReason reason = NackReason::kNone;
  uint8_t rejectedOpcode = 0;  // byte 0 of a command with an unknown opcode
  // NACK detail, sent for every opcode but GET_VERSION and INVALID (their bytes 3..7 are
  // taken); value and limit at 0.1 resolution, saturating at ±3276.7.
  NackDetail detail = NackDetail::kNone;
  double nackValue = 0.0;
  double nackLimit = 0.0;
};

enum class State : uint8_t { kBoot = 0, kHoming = 1, kIdle = 2, kScanning = 3, kFault = 4, kStopped = 5 };

// Fault bits, as in ALACS_Status.Fault* and EMCY.
enum FaultBit : uint16_t {
  kFaultHomingTimeout = 1U << 0, kFaultLimitHit = 1U << 1, kFaultCameraTimeout = 1U << 2,
  kFaultCameraCorrupt = 1U << 3, kFaultCanBusOff = 1U << 4, kFaultCanTxOverflow = 1U << 5,
  kFaultConfigInvalid = 1U << 6, kFaultNotCalibrated = 1U << 7, kFaultLaserOvertime = 1U << 8,
  kFaultInternal = 1U << 9, kFaultStopRequested = 1U << 10,
};

struct StatusReport {
  State state = State::kBoot;
  bool homed = false;
  bool laserOn = false;
  bool calibrated = false;
  bool homeSwitch = false;
  uint16_t faults = 0;
  uint32_t lastLatencyMs = 0;
  uint32_t maxLatencyMs = 0;
  uint32_t droppedFrames = 0;
  uint32_t rxErrors = 0;
};

// ALACS_ResultHeader.ResultStatus: only kMeasured is a measurement; every other status
// goes with a ResultReason.
enum class ResultStatus : uint8_t {
  kMeasured = 0, kNotFound = 1, kRoughOnly = 2, kFailed = 3, kAborted = 4, kAmbiguous = 5,
};

// ALACS_ResultHeader.ResultReason: why a result is not kMeasured (kNone when it is;
// kOutsideGate with kMeasured: found by the widened search, away from the rough position).
enum class ResultReason : uint8_t {
  kNone = 0,
  kNoLinesInGate = 1,
  kTooFewLines = 2,
  kFitFailed = 3,
  kTwoSurfaces = 4,
  kFarFromRough = 5,
  kCameraFault = 6,
  kMotionFault = 7,
  kLaserFault = 8,
  kStopped = 9,
  kShutdown = 10,
  kInternal = 11,
  kOutsideGate = 12,
  kBrightAmbient = 13,
};

// The DBC's names of a status and a reason ("ROUGH_ONLY", "FAR_FROM_ROUGH"), for logs and
// tools: generated from spec.py (can_protocol/generated/alacs_names.h); "?" for a value the
// DBC does not name.
const char* resultStatusName(ResultStatus status);
const char* resultReasonName(ResultReason reason);
// ALACS_ResultHeader.ResultMode's name ("LOCALIZE", "SCAN_ALL") of ResultHeader::mode.
const char* resultModeName(uint8_t mode);

struct ResultHeader {
  uint16_t measCounter = 0;
  uint8_t objectCount = 0;  // 0..16 (5 bits on the bus)
  uint8_t targetId = 0;
  uint32_t scanAgeMs = 0;
  ResultStatus status = ResultStatus::kMeasured;
  uint8_t mode = 0;  // 0 LOCALIZE, 1 SCAN_ALL
  uint32_t cycleTimeMs = 0;
  ResultReason reason = ResultReason::kNone;
};

// ALACS_Progress.ProgressPhase.
enum class ProgressPhase : uint8_t { kMoving = 0, kExposing = 1, kFitting = 2, kSecondPass = 3 };

// One ALACS_Progress frame of a running LOCALIZE or SCAN_ALL.
struct ProgressReport {
  uint16_t measCounter = 0;  // the MeasCounter the scan's result will carry
  uint8_t counter = 0;       // CmdCounter of the command that started the scan
  uint8_t mode = 0;          // 0 LOCALIZE, 1 SCAN_ALL
  ProgressPhase phase = ProgressPhase::kMoving;
  uint32_t stopsDone = 0;     // saturating at 255
  uint32_t stopsTotal = 0;    // planned so far, second pass included once planned; saturating
  uint32_t objectsFound = 0;  // saturating at 255
  uint32_t elapsedMs = 0;     // since the command; 500 ms/bit on the bus, saturating at 127.5 s
};

struct ResultObject {
  uint8_t index = 0;
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
  Eigen::Vector3d approachMm = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  double sigmaMm = 0.0;
  double confidencePct = 0.0;
  double diameterMm = 0.0;
  double occlusionPct = 0.0;
  int linesUsed = 0;
  int pointsUsed = 0;
};

ports::CanFrame encodeAck(uint8_t nodeId, const Ack& ack);
ports::CanFrame encodeVersionAck(uint8_t nodeId, uint8_t counter, int major, int minor, int patch);
ports::CanFrame encodeStatus(uint8_t nodeId, const StatusReport& s);
ports::CanFrame encodeResultHeader(uint8_t nodeId, const ResultHeader& h);
// ALACS_Progress (base 0x680): send on every phase change, after every stop and at least
// every 500 ms while a LOCALIZE or SCAN_ALL runs.
ports::CanFrame encodeProgress(uint8_t nodeId, const ProgressReport& p);
// The four pages of one object: CENTER, APPROACH_POINT, QUALITY, APPROACH_NORMAL.
void encodeResultObject(uint8_t nodeId, uint16_t measCounter, const ResultObject& o, ports::CanFrame out[4]);
ports::CanFrame encodeHeartbeat(uint8_t nodeId, uint8_t nmtState);
// EMCY: `reason` is the fault bit index + 1 (0: all cleared); the error register is
// errorRegister(faults).
ports::CanFrame encodeEmcy(uint8_t nodeId, uint16_t errorCode, uint16_t faults, uint8_t reason);
// CiA 301 error code sent when fault `bit` (one FaultBit) is raised (docs/can-protocol.md).
uint16_t emcyErrorCode(uint16_t bit);
// CiA 301 error register (object 0x1001): bit 0 any fault, bit 4 a CAN fault.
uint8_t errorRegister(uint16_t faults);

}  // namespace alacs::protocol
