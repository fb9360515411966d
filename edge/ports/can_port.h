// The CAN port: classic frames in and out. The protocol library (edge/protocol) never
// sees a socket; the daemon moves frames between this port and the protocol.
#pragma once

#include <array>
#include <cstdint>

#include "common/clock.h"
#include "common/result.h"

namespace alacs::ports {

struct CanFrame {
  uint32_t id = 0;        // 11-bit standard id (29-bit with `extended`)
  uint8_t dlc = 0;        // 0..8
  bool extended = false;
  bool rtr = false;
  bool error = false;     // an error frame reported by the controller
  uint32_t errorClass = 0;  // CAN_ERR_* bits when `error`
  std::array<uint8_t, 8> data{};
  TimeNs timestampNs = 0;
};

}  // namespace alacs::ports
