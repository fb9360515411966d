// SocketCAN adapter: one non-blocking CAN_RAW socket with kernel filters for the ids
// the sensor consumes and error frames enabled. The event loop polls fd().
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "ports/can_port.h"

namespace alacs::drivers {

struct CanFilter {
  uint32_t id = 0;
  uint32_t mask = 0x7FF;
};

class SocketCan {
 public:
  // Errors: kNotFound (no such interface), kUnsupported (kernel without CAN), kIo.
  static Result<std::unique_ptr<SocketCan>> open(const std::string& iface, const std::vector<CanFilter>& filters);
  ~SocketCan();
  SocketCan(const SocketCan&) = delete;
  SocketCan& operator=(const SocketCan&) = delete;

  int fd() const { return fd_; }
  // Reads one frame if one is waiting. Ok(false) when none is.
  Result<bool> read(ports::CanFrame* frame);
  // Sends one frame without blocking. kBusy when the queue is full (ENOBUFS/EAGAIN):
  // the caller keeps the frame and retries; kIo otherwise (e.g. the interface is down).
  Status write(const ports::CanFrame& frame);

 private:
  explicit SocketCan(int fd) : fd_(fd) {}
  int fd_;
};

}  // namespace alacs::drivers
