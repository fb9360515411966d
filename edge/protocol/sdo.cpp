#include "protocol/sdo.h"

extern "C" {
#include "alacs_protocol.h"
}

namespace alacs::protocol {
namespace {

constexpr uint8_t kCcsDownload = 1;
constexpr uint8_t kCcsUpload = 2;
constexpr uint8_t kCcsAbort = 4;

ports::CanFrame answer(uint8_t nodeId, uint8_t command, uint16_t index, uint8_t sub, uint32_t data) {
  ports::CanFrame f;
  f.id = alacs_frame_id(ALACS_BASE_ID_SDO_TX, nodeId);
  f.dlc = 8;
  f.data[0] = command;
  f.data[1] = static_cast<uint8_t>(index & 0xFFU);
  f.data[2] = static_cast<uint8_t>(index >> 8);
  f.data[3] = sub;
  for (size_t i = 0; i < 4; ++i) f.data[4 + i] = static_cast<uint8_t>(data >> (8 * i));
  return f;
}

uint32_t maskTo(uint32_t value, uint8_t sizeBytes) {
  return sizeBytes >= 4 ? value : value & ((1U << (8U * sizeBytes)) - 1U);
}

}  // namespace

ObjectDictionary ObjectDictionary::fromSpec() {
  ObjectDictionary od;
#define ALACS_OD_ROW(sym, index, sub, size, access, low, high, def)                                         \
  od.entries_.push_back(OdEntry{static_cast<uint16_t>(index), static_cast<uint8_t>(sub),                    \
                                static_cast<uint8_t>(size), static_cast<OdAccess>(access), (low), (high), \
                                (def), {}, {}});
  ALACS_OD_ENTRIES(ALACS_OD_ROW)
#undef ALACS_OD_ROW
  return od;
}

OdEntry* ObjectDictionary::findMutable(uint16_t index, uint8_t subIndex) {
  for (auto& e : entries_)
    if (e.index == index && e.subIndex == subIndex) return &e;
  return nullptr;
}

const OdEntry* ObjectDictionary::find(uint16_t index, uint8_t subIndex) const {
  for (const auto& e : entries_)
    if (e.index == index && e.subIndex == subIndex) return &e;
  return nullptr;
}

bool ObjectDictionary::hasIndex(uint16_t index) const {
  for (const auto& e : entries_)
    if (e.index == index) return true;
  return false;
}

bool ObjectDictionary::bindRead(uint16_t index, uint8_t subIndex, std::function<uint32_t()> read) {
  OdEntry* e = findMutable(index, subIndex);
  if (e == nullptr) return false;
  e->read = std::move(read);
  return true;
}

bool ObjectDictionary::bindWrite(uint16_t index, uint8_t subIndex, std::function<SdoAbort(uint32_t)> write) {
  OdEntry* e = findMutable(index, subIndex);
  if (e == nullptr || e->access != OdAccess::kReadWrite) return false;
  e->write = std::move(write);
  return true;
}

std::optional<ports::CanFrame> serveSdo(uint8_t nodeId, const ports::CanFrame& request, const ObjectDictionary& od) {
  if (request.dlc != 8) return std::nullopt;
  const uint8_t cmd = request.data[0];
  const auto index = static_cast<uint16_t>(request.data[1] | (request.data[2] << 8));
  const uint8_t sub = request.data[3];
  uint32_t data = 0;
  for (size_t i = 0; i < 4; ++i) data |= static_cast<uint32_t>(request.data[4 + i]) << (8 * i);
  auto abort = [&](SdoAbort code) { return answer(nodeId, 0x80, index, sub, static_cast<uint32_t>(code)); };

  const auto ccs = static_cast<uint8_t>(cmd >> 5);
  if (ccs == kCcsAbort) return std::nullopt;
  if (ccs != kCcsDownload && ccs != kCcsUpload) return abort(SdoAbort::kUnknownCommand);
  const OdEntry* e = od.find(index, sub);
  if (e == nullptr) return abort(od.hasIndex(index) ? SdoAbort::kNoSubIndex : SdoAbort::kNoObject);

  if (ccs == kCcsUpload) {
    const uint32_t value = maskTo(e->read ? e->read() : e->defaultValue, e->sizeBytes);
    // Expedited, size indicated: n = 4 - size unused bytes in bits 3..2.
    const auto command = static_cast<uint8_t>(0x43U | ((4U - e->sizeBytes) << 2U));
    return answer(nodeId, command, index, sub, value);
  }
  const bool expedited = (cmd & 0x02U) != 0;
  const bool sized = (cmd & 0x01U) != 0;
  if (!expedited) return abort(SdoAbort::kUnknownCommand);  // segmented download: not served
  if (e->access != OdAccess::kReadWrite) return abort(SdoAbort::kReadOnly);
  if (sized && 4U - ((cmd >> 2U) & 3U) != e->sizeBytes) return abort(SdoAbort::kLengthMismatch);
  const uint32_t value = maskTo(data, e->sizeBytes);
  if (value > e->high) return abort(SdoAbort::kValueTooHigh);
  if (value < e->low) return abort(SdoAbort::kValueTooLow);
  if (!e->write) return abort(SdoAbort::kUnsupportedAccess);
  if (const SdoAbort r = e->write(value); r != SdoAbort::kNone) return abort(r);
  return answer(nodeId, 0x60, index, sub, 0);
}

}  // namespace alacs::protocol
