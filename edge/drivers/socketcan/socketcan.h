// SocketCAN adapter: one non-blocking CAN_RAW socket with kernel filters for the ids
// the sensor consumes and error frames enabled (bus-off, restarted, controller and bus
// errors reach the protocol node as error frames). The event loop polls fd(). Writes
// never block: a full device queue (ENOBUFS) or a downed interface is kBusy/kIo and the
// caller paces its retries (protocol::CanNode::onTxRefused).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "ports/can_bus.h"
#include "ports/can_port.h"

namespace alacs::drivers {

struct CanFilter {
  uint32_t id = 0;
  uint32_t mask = 0x7FF;
};

// Kernel-timed cyclic transmission over CAN_BCM, for the CANopen heartbeat: the kernel
// sends the frame every period with hrtimer precision, whatever the event loop is doing
// (a flood, a busy CPU). Liveness is kept honest: the kernel sends at most the frames of
// `guardNs` unless keep() is called again, so a frozen daemon goes silent on the bus
// (a dead one at once: closing the socket deletes the job).
class CyclicSender {
 public:
  // Errors: kNotFound (no such interface), kUnsupported (no CAN_BCM), kIo.
  static Result<std::unique_ptr<CyclicSender>> open(const std::string& iface);
  ~CyclicSender();
  CyclicSender(const CyclicSender&) = delete;
  CyclicSender& operator=(const CyclicSender&) = delete;

  // Sends `frame` every `periodNs` (0: stop). A new period (or a first call) starts the
  // cycle now with one frame; new data alone is sent from the next cycle on, keeping the
  // phase. Call at least every guardNs / 2; cheap when nothing changed.
  Status keep(const ports::CanFrame& frame, TimeNs periodNs, TimeNs now);
  static constexpr TimeNs kGuardNs = 1000 * kNsPerMs;  // and at least 3 periods

 private:
  explicit CyclicSender(int fd) : fd_(fd) {}
  Status setup(const ports::CanFrame& frame, TimeNs periodNs, uint32_t flags, uint32_t count);
  int fd_;
  bool running_ = false;
  TimeNs periodNs_ = 0;
  TimeNs refreshedNs_ = 0;
  ports::CanFrame frame_;
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

// The CAN bus port on SocketCAN: frames through CAN_RAW (SocketCan), the heartbeat
// through CAN_BCM (CyclicSender) when the kernel has it. The event loop polls fd().
class SocketCanBus final : public ports::CanBus {
 public:
  // Errors: as SocketCan::open. A kernel without CAN_BCM is not an error: hasCyclic()
  // is then false and the caller sends the heartbeat itself.
  static Result<std::unique_ptr<SocketCanBus>> open(const std::string& iface, const std::vector<CanFilter>& filters);
  int fd() const { return raw_->fd(); }

 private:
  SocketCanBus(std::unique_ptr<SocketCan> raw, std::unique_ptr<CyclicSender> bcm)
      : raw_(std::move(raw)), bcm_(std::move(bcm)) {}
  Status doSend(const ports::CanFrame& frame) override { return raw_->write(frame); }
  Result<bool> doReceive(ports::CanFrame* frame) override { return raw_->read(frame); }
  Status doKeepCyclic(const ports::CanFrame& frame, TimeNs periodNs, TimeNs now) override;
  bool doHasCyclic() const override { return bcm_ != nullptr; }
  std::unique_ptr<SocketCan> raw_;
  std::unique_ptr<CyclicSender> bcm_;
};

}  // namespace alacs::drivers
