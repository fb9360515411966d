#include "protocol/codec.h"

#include <algorithm>
#include <cmath>
#include <limits>

extern "C" {
#include "alacs.h"
#include "alacs_names.h"
#include "alacs_protocol.h"
}

namespace alacs::protocol {

// The C++ enums are the generated codec's value tables (spec.py is the source of both).
#define ALACS_SAME(cxx, choice) static_assert(static_cast<unsigned>(cxx) == (choice), #cxx " != " #choice)
ALACS_SAME(Opcode::kInvalid, ALACS_ALACS_ACK_ACK_OPCODE_INVALID_CHOICE);
ALACS_SAME(Opcode::kLocalize, ALACS_ALACS_COMMAND_CMD_OPCODE_LOCALIZE_CHOICE);
ALACS_SAME(Opcode::kScanAll, ALACS_ALACS_COMMAND_CMD_OPCODE_SCAN_ALL_CHOICE);
ALACS_SAME(Opcode::kHome, ALACS_ALACS_COMMAND_CMD_OPCODE_HOME_CHOICE);
ALACS_SAME(Opcode::kStop, ALACS_ALACS_COMMAND_CMD_OPCODE_STOP_CHOICE);
ALACS_SAME(Opcode::kSetConfig, ALACS_ALACS_COMMAND_CMD_OPCODE_SET_CONFIG_CHOICE);
ALACS_SAME(Opcode::kGetVersion, ALACS_ALACS_COMMAND_CMD_OPCODE_GET_VERSION_CHOICE);
ALACS_SAME(Opcode::kClearFault, ALACS_ALACS_COMMAND_CMD_OPCODE_CLEAR_FAULT_CHOICE);
ALACS_SAME(Opcode::kLocalize, ALACS_ALACS_ACK_ACK_OPCODE_LOCALIZE_CHOICE);
ALACS_SAME(Opcode::kClearFault, ALACS_ALACS_ACK_ACK_OPCODE_CLEAR_FAULT_CHOICE);
ALACS_SAME(NackReason::kNone, ALACS_ALACS_ACK_NACK_REASON_NONE_CHOICE);
ALACS_SAME(NackReason::kBadDlc, ALACS_ALACS_ACK_NACK_REASON_BAD_DLC_CHOICE);
ALACS_SAME(NackReason::kBadChecksum, ALACS_ALACS_ACK_NACK_REASON_BAD_CHECKSUM_CHOICE);
ALACS_SAME(NackReason::kBadCounter, ALACS_ALACS_ACK_NACK_REASON_BAD_COUNTER_CHOICE);
ALACS_SAME(NackReason::kUnknownOpcode, ALACS_ALACS_ACK_NACK_REASON_UNKNOWN_OPCODE_CHOICE);
ALACS_SAME(NackReason::kBusy, ALACS_ALACS_ACK_NACK_REASON_BUSY_CHOICE);
ALACS_SAME(NackReason::kNotHomed, ALACS_ALACS_ACK_NACK_REASON_NOT_HOMED_CHOICE);
ALACS_SAME(NackReason::kNotCalibrated, ALACS_ALACS_ACK_NACK_REASON_NOT_CALIBRATED_CHOICE);
ALACS_SAME(NackReason::kOutOfRange, ALACS_ALACS_ACK_NACK_REASON_OUT_OF_RANGE_CHOICE);
ALACS_SAME(NackReason::kFaultActive, ALACS_ALACS_ACK_NACK_REASON_FAULT_ACTIVE_CHOICE);
ALACS_SAME(NackReason::kNmtNotOperational, ALACS_ALACS_ACK_NACK_REASON_NMT_NOT_OPERATIONAL_CHOICE);
ALACS_SAME(NackReason::kBadValue, ALACS_ALACS_ACK_NACK_REASON_BAD_VALUE_CHOICE);
ALACS_SAME(NackReason::kInternal, ALACS_ALACS_ACK_NACK_REASON_INTERNAL_CHOICE);
ALACS_SAME(AckResult::kAck, ALACS_ALACS_ACK_ACK_RESULT_ACK_CHOICE);
ALACS_SAME(AckResult::kNack, ALACS_ALACS_ACK_ACK_RESULT_NACK_CHOICE);
ALACS_SAME(AckResult::kDone, ALACS_ALACS_ACK_ACK_RESULT_DONE_CHOICE);
ALACS_SAME(NackDetail::kNone, ALACS_ALACS_ACK_NACK_DETAIL_NONE_CHOICE);
ALACS_SAME(NackDetail::kStroke, ALACS_ALACS_ACK_NACK_DETAIL_STROKE_CHOICE);
ALACS_SAME(NackDetail::kDepth, ALACS_ALACS_ACK_NACK_DETAIL_DEPTH_CHOICE);
ALACS_SAME(NackDetail::kLateral, ALACS_ALACS_ACK_NACK_DETAIL_LATERAL_CHOICE);
ALACS_SAME(NackDetail::kFrame, ALACS_ALACS_ACK_NACK_DETAIL_FRAME_CHOICE);
ALACS_SAME(NackDetail::kCrossField, ALACS_ALACS_ACK_NACK_DETAIL_CROSS_FIELD_CHOICE);
ALACS_SAME(NackDetail::kSpacingXStops, ALACS_ALACS_ACK_NACK_DETAIL_SPACING_X_STOPS_CHOICE);
ALACS_SAME(NackDetail::kMode, ALACS_ALACS_ACK_NACK_DETAIL_MODE_CHOICE);
ALACS_SAME(NackDetail::kExposure, ALACS_ALACS_ACK_NACK_DETAIL_EXPOSURE_CHOICE);
ALACS_SAME(NackDetail::kBrceStep, ALACS_ALACS_ACK_NACK_DETAIL_BRCE_STEP_CHOICE);
ALACS_SAME(NackDetail::kScanStops, ALACS_ALACS_ACK_NACK_DETAIL_SCAN_STOPS_CHOICE);
ALACS_SAME(NackDetail::kStopSpacing, ALACS_ALACS_ACK_NACK_DETAIL_STOP_SPACING_CHOICE);
ALACS_SAME(NackDetail::kHeartbeat, ALACS_ALACS_ACK_NACK_DETAIL_HEARTBEAT_CHOICE);
ALACS_SAME(ScanMode::kStopAndGo, ALACS_ALACS_COMMAND_LOCALIZE_MODE_STOP_AND_GO_CHOICE);
ALACS_SAME(ScanMode::kContinuous, ALACS_ALACS_COMMAND_LOCALIZE_MODE_CONTINUOUS_CHOICE);
ALACS_SAME(ScanMode::kStopAndGo, ALACS_ALACS_COMMAND_SCAN_ALL_MODE_STOP_AND_GO_CHOICE);
ALACS_SAME(ScanMode::kContinuous, ALACS_ALACS_COMMAND_SCAN_ALL_MODE_CONTINUOUS_CHOICE);
ALACS_SAME(State::kBoot, ALACS_ALACS_STATUS_STATE_BOOT_CHOICE);
ALACS_SAME(State::kHoming, ALACS_ALACS_STATUS_STATE_HOMING_CHOICE);
ALACS_SAME(State::kIdle, ALACS_ALACS_STATUS_STATE_IDLE_CHOICE);
ALACS_SAME(State::kScanning, ALACS_ALACS_STATUS_STATE_SCANNING_CHOICE);
ALACS_SAME(State::kFault, ALACS_ALACS_STATUS_STATE_FAULT_CHOICE);
ALACS_SAME(State::kStopped, ALACS_ALACS_STATUS_STATE_STOPPED_CHOICE);
ALACS_SAME(ResultStatus::kMeasured, ALACS_ALACS_RESULT_HEADER_RESULT_STATUS_MEASURED_CHOICE);
ALACS_SAME(ResultStatus::kNotFound, ALACS_ALACS_RESULT_HEADER_RESULT_STATUS_NOT_FOUND_CHOICE);
ALACS_SAME(ResultStatus::kRoughOnly, ALACS_ALACS_RESULT_HEADER_RESULT_STATUS_ROUGH_ONLY_CHOICE);
ALACS_SAME(ResultStatus::kFailed, ALACS_ALACS_RESULT_HEADER_RESULT_STATUS_FAILED_CHOICE);
ALACS_SAME(ResultStatus::kAborted, ALACS_ALACS_RESULT_HEADER_RESULT_STATUS_ABORTED_CHOICE);
ALACS_SAME(ResultStatus::kAmbiguous, ALACS_ALACS_RESULT_HEADER_RESULT_STATUS_AMBIGUOUS_CHOICE);
ALACS_SAME(ResultReason::kNone, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_NONE_CHOICE);
ALACS_SAME(ResultReason::kNoLinesInGate, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_NO_LINES_IN_GATE_CHOICE);
ALACS_SAME(ResultReason::kTooFewLines, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_TOO_FEW_LINES_CHOICE);
ALACS_SAME(ResultReason::kFitFailed, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_FIT_FAILED_CHOICE);
ALACS_SAME(ResultReason::kTwoSurfaces, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_TWO_SURFACES_CHOICE);
ALACS_SAME(ResultReason::kFarFromRough, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_FAR_FROM_ROUGH_CHOICE);
ALACS_SAME(ResultReason::kCameraFault, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_CAMERA_FAULT_CHOICE);
ALACS_SAME(ResultReason::kMotionFault, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_MOTION_FAULT_CHOICE);
ALACS_SAME(ResultReason::kLaserFault, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_LASER_FAULT_CHOICE);
ALACS_SAME(ResultReason::kStopped, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_STOPPED_CHOICE);
ALACS_SAME(ResultReason::kShutdown, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_SHUTDOWN_CHOICE);
ALACS_SAME(ResultReason::kInternal, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_INTERNAL_CHOICE);
ALACS_SAME(ResultReason::kOutsideGate, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_OUTSIDE_GATE_CHOICE);
ALACS_SAME(ResultReason::kBrightAmbient, ALACS_ALACS_RESULT_HEADER_RESULT_REASON_BRIGHT_AMBIENT_CHOICE);
ALACS_SAME(ProgressPhase::kMoving, ALACS_ALACS_PROGRESS_PROGRESS_PHASE_MOVING_CHOICE);
ALACS_SAME(ProgressPhase::kExposing, ALACS_ALACS_PROGRESS_PROGRESS_PHASE_EXPOSING_CHOICE);
ALACS_SAME(ProgressPhase::kFitting, ALACS_ALACS_PROGRESS_PROGRESS_PHASE_FITTING_CHOICE);
ALACS_SAME(ProgressPhase::kSecondPass, ALACS_ALACS_PROGRESS_PROGRESS_PHASE_SECOND_PASS_CHOICE);
#undef ALACS_SAME

namespace {

ports::CanFrame frameFor(uint32_t baseId, uint8_t nodeId, uint8_t dlc) {
  ports::CanFrame f;
  f.id = alacs_frame_id(baseId, nodeId);
  f.dlc = dlc;
  return f;
}

template <typename T>
T saturate(double v) {
  const double lo = static_cast<double>(std::numeric_limits<T>::min());
  const double hi = static_cast<double>(std::numeric_limits<T>::max());
  if (!std::isfinite(v)) return T{0};
  return static_cast<T>(std::lround(std::clamp(v, lo, hi)));
}

}  // namespace

CommandDecode decodeCommand(const ports::CanFrame& frame) {
  CommandDecode out;
  out.command.opcode = frame.dlc > 0 ? static_cast<Opcode>(frame.data[0] <= 7 ? frame.data[0] : 0) : Opcode::kInvalid;
  out.command.counter = frame.dlc > 1 ? static_cast<uint8_t>(frame.data[1] & 0x0F) : 0;
  if (frame.dlc != ALACS_COMMAND_DLC) {
    out.reason = NackReason::kBadDlc;
    return out;
  }
  if (!alacs_command_checksum_ok(frame.data.data(), frame.dlc)) {
    out.reason = NackReason::kBadChecksum;
    return out;
  }
  alacs_alacs_command_t m{};
  if (alacs_alacs_command_unpack(&m, frame.data.data(), frame.dlc) != 0) {
    out.reason = NackReason::kBadDlc;
    return out;
  }
  if (m.cmd_opcode < 1 || m.cmd_opcode > 7) {
    out.command.opcode = Opcode::kInvalid;
    out.reason = NackReason::kUnknownOpcode;
    return out;
  }
  Command& c = out.command;
  c.opcode = static_cast<Opcode>(m.cmd_opcode);
  c.counter = m.cmd_counter;
  switch (c.opcode) {
    case Opcode::kLocalize:
      if (m.localize_mode > 1) {
        out.reason = NackReason::kBadValue;
        return out;
      }
      c.localize.mode = static_cast<ScanMode>(m.localize_mode);
      c.localize.targetId = m.target_id;
      c.localize.roughMm = Eigen::Vector3d(alacs_alacs_command_rough_x_decode(m.rough_x),
                                           alacs_alacs_command_rough_y_decode(m.rough_y),
                                           alacs_alacs_command_rough_z_decode(m.rough_z));
      break;
    case Opcode::kScanAll:
      if (m.scan_all_mode > 1) {
        out.reason = NackReason::kBadValue;
        return out;
      }
      c.scanAllMode = static_cast<ScanMode>(m.scan_all_mode);
      break;
    case Opcode::kSetConfig: {
      SetConfigCommand& s = c.config;
      s.page = m.cfg_page;
      if (m.cfg_page == 0) {
        if (m.cfg_exposure_valid) s.exposureUs = m.cfg_exposure_us;
        if (m.cfg_brce_step_valid) s.brceStep = m.cfg_brce_step;
        if (m.cfg_brce_threshold_valid) s.brceThreshold = m.cfg_brce_threshold;
      } else if (m.cfg_page == 1) {
        if (m.cfg_scan_stops_valid) s.scanStops = m.cfg_scan_stops;
        if (m.cfg_stop_spacing_valid) s.stopSpacingMm = alacs_alacs_command_cfg_stop_spacing_mm_decode(m.cfg_stop_spacing_mm);
        if (m.cfg_heartbeat_valid) s.heartbeatMs = m.cfg_heartbeat_ms;
      } else {
        out.reason = NackReason::kBadValue;
        return out;
      }
      break;
    }
    case Opcode::kHome:
    case Opcode::kStop:
    case Opcode::kGetVersion:
    case Opcode::kClearFault:
    case Opcode::kInvalid:
      break;
  }
  out.ok = true;
  return out;
}

ports::CanFrame encodeAck(uint8_t nodeId, const Ack& ack) {
  alacs_alacs_ack_t m{};
  m.ack_opcode = static_cast<uint8_t>(ack.opcode);
  m.ack_counter = static_cast<uint8_t>(ack.counter & 0x0F);
  m.ack_result = static_cast<uint8_t>(ack.result);
  m.nack_reason = static_cast<uint8_t>(ack.reason);
  m.rejected_opcode = ack.rejectedOpcode;
  // The generated pack writes the members of AckOpcode's page only, so the detail never
  // lands on an INVALID or GET_VERSION ack.
  m.nack_detail = static_cast<uint8_t>(ack.detail);
  m.nack_value = saturate<int16_t>(ack.nackValue * 10.0);
  m.nack_limit = saturate<int16_t>(ack.nackLimit * 10.0);
  ports::CanFrame f = frameFor(ALACS_BASE_ID_ACK, nodeId, 8);
  (void)alacs_alacs_ack_pack(f.data.data(), &m, f.data.size());
  return f;
}

ports::CanFrame encodeVersionAck(uint8_t nodeId, uint8_t counter, int major, int minor, int patch) {
  alacs_alacs_ack_t m{};
  m.ack_opcode = static_cast<uint8_t>(Opcode::kGetVersion);
  m.ack_counter = static_cast<uint8_t>(counter & 0x0F);
  m.ack_result = static_cast<uint8_t>(AckResult::kAck);
  m.sw_major = static_cast<uint8_t>(major);
  m.sw_minor = static_cast<uint8_t>(minor);
  m.sw_patch = static_cast<uint8_t>(patch);
  m.protocol_version = static_cast<uint8_t>(ALACS_PROTOCOL_VERSION);
  ports::CanFrame f = frameFor(ALACS_BASE_ID_ACK, nodeId, 8);
  (void)alacs_alacs_ack_pack(f.data.data(), &m, f.data.size());
  return f;
}

ports::CanFrame encodeStatus(uint8_t nodeId, const StatusReport& s) {
  alacs_alacs_status_t m{};
  m.state = static_cast<uint8_t>(s.state);
  m.homed = s.homed;
  m.laser_on = s.laserOn;
  m.calibrated = s.calibrated;
  m.home_switch = s.homeSwitch;
  auto bit = [&](uint16_t b) { return static_cast<uint8_t>((s.faults & b) != 0 ? 1 : 0); };
  m.fault_homing_timeout = bit(kFaultHomingTimeout);
  m.fault_limit_hit = bit(kFaultLimitHit);
  m.fault_camera_timeout = bit(kFaultCameraTimeout);
  m.fault_camera_corrupt = bit(kFaultCameraCorrupt);
  m.fault_can_bus_off = bit(kFaultCanBusOff);
  m.fault_can_tx_overflow = bit(kFaultCanTxOverflow);
  m.fault_config_invalid = bit(kFaultConfigInvalid);
  m.fault_not_calibrated = bit(kFaultNotCalibrated);
  m.fault_laser_overtime = bit(kFaultLaserOvertime);
  m.fault_internal = bit(kFaultInternal);
  m.fault_stop_requested = bit(kFaultStopRequested);
  m.last_latency_ms = static_cast<uint16_t>(std::min<uint32_t>(s.lastLatencyMs, 4095));
  m.max_latency_ms = static_cast<uint16_t>(std::min<uint32_t>(s.maxLatencyMs, 4095));
  m.dropped_frames = static_cast<uint8_t>(std::min<uint32_t>(s.droppedFrames, 255));
  m.rx_error_count = static_cast<uint8_t>(std::min<uint32_t>(s.rxErrors, 255));
  ports::CanFrame f = frameFor(ALACS_BASE_ID_STATUS, nodeId, 8);
  (void)alacs_alacs_status_pack(f.data.data(), &m, f.data.size());
  return f;
}

ports::CanFrame encodeResultHeader(uint8_t nodeId, const ResultHeader& h) {
  alacs_alacs_result_header_t m{};
  m.meas_counter = h.measCounter;
  m.object_count = std::min<uint8_t>(h.objectCount, 16);  // ObjIndex is 4 bits; the field 5
  m.result_target_id = h.targetId;
  m.scan_age_ms = static_cast<uint16_t>(std::min<uint32_t>(h.scanAgeMs, 65535));
  m.result_status = static_cast<uint8_t>(h.status);
  m.result_mode = h.mode;
  m.result_reason = static_cast<uint8_t>(h.reason);
  m.cycle_time = alacs_alacs_result_header_cycle_time_encode(std::min(5100.0, static_cast<double>(h.cycleTimeMs)));
  ports::CanFrame f = frameFor(ALACS_BASE_ID_RESULT_HEADER, nodeId, 8);
  (void)alacs_alacs_result_header_pack(f.data.data(), &m, f.data.size());
  return f;
}

ports::CanFrame encodeProgress(uint8_t nodeId, const ProgressReport& p) {
  alacs_alacs_progress_t m{};
  m.progress_meas_counter = p.measCounter;
  m.progress_counter = static_cast<uint8_t>(p.counter & 0x0F);
  m.progress_mode = p.mode;
  m.progress_phase = static_cast<uint8_t>(p.phase);
  m.stops_done = static_cast<uint8_t>(std::min<uint32_t>(p.stopsDone, 255));
  m.stops_total = static_cast<uint8_t>(std::min<uint32_t>(p.stopsTotal, 255));
  m.objects_found = static_cast<uint8_t>(std::min<uint32_t>(p.objectsFound, 255));
  m.elapsed_s = static_cast<uint8_t>(std::min<uint32_t>(p.elapsedMs / 500U, 255));
  ports::CanFrame f = frameFor(ALACS_BASE_ID_PROGRESS, nodeId, 8);
  (void)alacs_alacs_progress_pack(f.data.data(), &m, f.data.size());
  return f;
}

void encodeResultObject(uint8_t nodeId, uint16_t measCounter, const ResultObject& o, ports::CanFrame out[4]) {
  for (uint8_t page = 0; page < 4; ++page) {
    alacs_alacs_result_object_t m{};
    m.obj_page = page;
    m.obj_index = static_cast<uint8_t>(o.index & 0x0F);
    m.obj_meas_counter = static_cast<uint8_t>(measCounter & 0xFF);
    switch (page) {
      case 0:
        m.center_x = saturate<int16_t>(o.centerMm.x() * 10.0);
        m.center_y = saturate<int16_t>(o.centerMm.y() * 10.0);
        m.center_z = saturate<uint16_t>(o.centerMm.z() * 10.0);
        break;
      case 1:
        m.approach_x = saturate<int16_t>(o.approachMm.x() * 10.0);
        m.approach_y = saturate<int16_t>(o.approachMm.y() * 10.0);
        m.approach_z = saturate<uint16_t>(o.approachMm.z() * 10.0);
        break;
      case 2:
        m.sigma_mm = saturate<uint8_t>(o.sigmaMm * 10.0);
        m.confidence = saturate<uint8_t>(std::min(100.0, o.confidencePct));
        m.diameter_mm = saturate<uint8_t>(o.diameterMm * 2.0);
        m.occlusion_pct = saturate<uint8_t>(std::min(100.0, o.occlusionPct));
        m.lines_used = static_cast<uint8_t>(std::clamp(o.linesUsed, 0, 15));
        m.points_used = static_cast<uint16_t>(std::clamp(o.pointsUsed, 0, 4095));
        break;
      default:
        m.normal_x = saturate<int16_t>(o.normal.x() * 32767.0);
        m.normal_y = saturate<int16_t>(o.normal.y() * 32767.0);
        m.normal_z = saturate<int16_t>(o.normal.z() * 32767.0);
        break;
    }
    out[page] = frameFor(ALACS_BASE_ID_RESULT_OBJECT, nodeId, 8);
    (void)alacs_alacs_result_object_pack(out[page].data.data(), &m, out[page].data.size());
  }
}

ports::CanFrame encodeHeartbeat(uint8_t nodeId, uint8_t nmtState) {
  ports::CanFrame f = frameFor(ALACS_BASE_ID_HEARTBEAT, nodeId, 1);
  f.data[0] = nmtState;
  return f;
}

ports::CanFrame encodeEmcy(uint8_t nodeId, uint16_t errorCode, uint16_t faults, uint8_t reason) {
  alacs_emcy_t m{};
  m.emcy_error_code = errorCode;
  m.emcy_error_register = errorRegister(faults);
  m.emcy_fault_bits = faults;
  m.emcy_reason = reason;
  ports::CanFrame f = frameFor(ALACS_BASE_ID_EMCY, nodeId, 8);
  (void)alacs_emcy_pack(f.data.data(), &m, f.data.size());
  return f;
}

uint16_t emcyErrorCode(uint16_t bit) {
  switch (bit) {
    case kFaultHomingTimeout:
    case kFaultLimitHit: return 0xFF00;  // device specific
    case kFaultCameraTimeout:
    case kFaultCameraCorrupt: return 0x5000;  // device hardware
    case kFaultCanBusOff: return 0x8140;      // recovered from bus-off (sent once it has)
    case kFaultCanTxOverflow: return 0x8110;  // CAN overrun (objects lost)
    case kFaultConfigInvalid:
    case kFaultNotCalibrated: return 0x6300;  // data set
    case kFaultLaserOvertime: return 0x8000;  // monitoring
    case kFaultInternal: return 0x6100;       // internal software
    case kFaultStopRequested: return 0x1000;  // generic
    default: return 0x1000;
  }
}

uint8_t errorRegister(uint16_t faults) {
  const uint16_t canFaults = kFaultCanBusOff | kFaultCanTxOverflow;
  return static_cast<uint8_t>((faults != 0 ? 0x01U : 0U) | ((faults & canFaults) != 0 ? 0x10U : 0U));
}

#define ALACS_NAME_CASE(value, name) \
  case value: return name;

const char* resultStatusName(ResultStatus status) {
  switch (static_cast<unsigned>(status)) {
    ALACS_RESULT_STATUS_NAMES(ALACS_NAME_CASE)
    default: return "?";
  }
}

const char* resultReasonName(ResultReason reason) {
  switch (static_cast<unsigned>(reason)) {
    ALACS_RESULT_REASON_NAMES(ALACS_NAME_CASE)
    default: return "?";
  }
}

const char* resultModeName(uint8_t mode) {
  switch (static_cast<unsigned>(mode)) {
    ALACS_RESULT_MODE_NAMES(ALACS_NAME_CASE)
    default: return "?";
  }
}

#undef ALACS_NAME_CASE

}  // namespace alacs::protocol
