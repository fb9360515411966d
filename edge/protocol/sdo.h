// CANopen-lite SDO server: expedited transfers (CiA 301 §7.2.4.3.3) over the object
// dictionary of can_protocol/generated/alacs_od.h (generated from spec.py, the same
// objects as can_protocol/alacs.eds). Pure: a request frame in, the answer out.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "alacs_od.h"
#include "ports/can_port.h"

namespace alacs::protocol {

enum class SdoAbort : uint32_t {
  kNone = 0,
  kUnknownCommand = ALACS_SDO_ABORT_UNKNOWN_COMMAND,  // also segmented/block transfers
  kUnsupportedAccess = ALACS_SDO_ABORT_UNSUPPORTED_ACCESS,
  kReadOnly = ALACS_SDO_ABORT_READ_ONLY,
  kNoObject = ALACS_SDO_ABORT_NO_OBJECT,
  kLengthMismatch = ALACS_SDO_ABORT_LENGTH_MISMATCH,
  kNoSubIndex = ALACS_SDO_ABORT_NO_SUBINDEX,
  kValueRange = ALACS_SDO_ABORT_VALUE_RANGE,
  kValueTooHigh = ALACS_SDO_ABORT_VALUE_TOO_HIGH,
  kValueTooLow = ALACS_SDO_ABORT_VALUE_TOO_LOW,
  kGeneral = ALACS_SDO_ABORT_GENERAL,
  kDeviceState = ALACS_SDO_ABORT_DEVICE_STATE,
};

enum class OdAccess : uint8_t { kReadOnly = ALACS_OD_RO, kConst = ALACS_OD_CONST, kReadWrite = ALACS_OD_RW };

struct OdEntry {
  uint16_t index = 0;
  uint8_t subIndex = 0;
  uint8_t sizeBytes = 0;  // 1, 2 or 4
  OdAccess access = OdAccess::kReadOnly;
  uint32_t low = 0;
  uint32_t high = 0;
  uint32_t defaultValue = 0;
  std::function<uint32_t()> read;  // empty: reads as defaultValue
  // Called for a write that passed the access, size and limit checks; returns
  // SdoAbort::kNone when the value was applied. Empty: writes are refused.
  std::function<SdoAbort(uint32_t)> write;
};

class ObjectDictionary {
 public:
  // Every entry of alacs_od.h, reading as its default value, not yet writable.
  static ObjectDictionary fromSpec();

  // False if (index, subIndex) is not in the dictionary (a programming error).
  bool bindRead(uint16_t index, uint8_t subIndex, std::function<uint32_t()> read);
  bool bindWrite(uint16_t index, uint8_t subIndex, std::function<SdoAbort(uint32_t)> write);

  const OdEntry* find(uint16_t index, uint8_t subIndex) const;
  bool hasIndex(uint16_t index) const;
  const std::vector<OdEntry>& entries() const { return entries_; }

 private:
  OdEntry* findMutable(uint16_t index, uint8_t subIndex);
  std::vector<OdEntry> entries_;
};

// Answers one SDO_Rx frame of node `nodeId`: an upload/download response or an abort
// on SDO_Tx. Nothing for a client's abort, and nothing for a frame whose DLC is not 8
// (CiA 301: SDO frames are always 8 bytes; a short frame has no trustworthy index).
std::optional<ports::CanFrame> serveSdo(uint8_t nodeId, const ports::CanFrame& request, const ObjectDictionary& od);

}  // namespace alacs::protocol
