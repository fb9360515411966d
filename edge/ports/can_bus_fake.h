// A recording fake of the CAN bus: every frame sent is stored with the time of an
// injected clock, received frames come from a queue the test fills, and the transmit
// queue can be made to refuse (kBusy) to exercise the node's pacing. The cyclic
// (kernel-timed) transmission is recorded as requested, optionally unsupported.
#pragma once

#include <deque>
#include <vector>

#include "common/clock.h"
#include "ports/can_bus.h"

namespace alacs::ports {

struct SentFrame {
  TimeNs timeNs = 0;
  CanFrame frame;
};

struct CyclicRequest {
  TimeNs timeNs = 0;
  CanFrame frame;
  TimeNs periodNs = 0;
};

class FakeCanBus final : public CanBus {
 public:
  explicit FakeCanBus(const Clock& clock, bool cyclic = true) : clock_(clock), cyclic_(cyclic) {}

  // Frames the next receive() calls return, in order.
  void inject(const CanFrame& frame) { rx_.push_back(frame); }
  // The next `count` sends are refused with kBusy (a full transmit queue).
  void refuseSends(int count) { refuse_ = count; }
  // Every send is refused with kIo while down (an interface taken down).
  void setDown(bool down) { down_ = down; }

  const std::vector<SentFrame>& sent() const { return sent_; }
  void clearSent() { sent_.clear(); }
  const std::vector<CyclicRequest>& cyclic() const { return cyclicLog_; }
  // The cyclic frame and period in force (period 0: none).
  TimeNs cyclicPeriodNs() const { return cyclicPeriodNs_; }
  const CanFrame& cyclicFrame() const { return cyclicFrame_; }
  size_t refusedSends() const { return refused_; }

 private:
  Status doSend(const CanFrame& frame) override {
    if (down_) {
      ++refused_;
      return {Error::kIo, "CAN interface down (fake)"};
    }
    if (refuse_ > 0) {
      --refuse_;
      ++refused_;
      return {Error::kBusy, "CAN transmit queue full (fake)"};
    }
    sent_.push_back({clock_.now(), frame});
    return Status::ok();
  }
  Result<bool> doReceive(CanFrame* frame) override {
    if (rx_.empty()) return false;
    *frame = rx_.front();
    rx_.pop_front();
    return true;
  }
  Status doKeepCyclic(const CanFrame& frame, TimeNs periodNs, TimeNs now) override {
    if (!cyclic_) return CanBus::doKeepCyclic(frame, periodNs, now);
    const bool changed = periodNs != cyclicPeriodNs_ || frame.id != cyclicFrame_.id || frame.data != cyclicFrame_.data ||
                         frame.dlc != cyclicFrame_.dlc;
    if (changed) cyclicLog_.push_back({now, frame, periodNs});
    cyclicPeriodNs_ = periodNs;
    cyclicFrame_ = frame;
    return Status::ok();
  }
  bool doHasCyclic() const override { return cyclic_; }

  const Clock& clock_;
  const bool cyclic_;
  std::deque<CanFrame> rx_;
  std::vector<SentFrame> sent_;
  std::vector<CyclicRequest> cyclicLog_;
  CanFrame cyclicFrame_;
  TimeNs cyclicPeriodNs_ = 0;
  int refuse_ = 0;
  size_t refused_ = 0;
  bool down_ = false;
};

}  // namespace alacs::ports
