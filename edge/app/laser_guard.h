// The laser's only switch. On only when asked, off on request, and forced off by the
// event loop's enforce() when it has been on longer than the configured maximum; after
// that it refuses to switch on until reset(). Thread-safe (worker switches, loop enforces).
#pragma once

#include <mutex>

#include "common/clock.h"
#include "ports/digital_io.h"

namespace alacs::app {

class LaserGuard {
 public:
  LaserGuard(ports::DigitalOut& out, const Clock& clock, TimeNs maxOnNs) : out_(out), clock_(clock), maxOnNs_(maxOnNs) {}

  Status on() {
    std::lock_guard<std::mutex> lock(mu_);
    if (tripped_) return {Error::kFault, "laser over-time trip is latched"};
    if (Status s = out_.set(true); !s) {
      (void)out_.set(false);
      return s;
    }
    if (!on_) onSinceNs_ = clock_.now();
    on_ = true;
    return Status::ok();
  }
  Status off() {
    std::lock_guard<std::mutex> lock(mu_);
    if (on_) totalOnNs_ += clock_.now() - onSinceNs_;
    on_ = false;
    return out_.set(false);
  }
  // Returns true when it had to force the laser off (a fault to report).
  bool enforce(TimeNs now) {
    std::lock_guard<std::mutex> lock(mu_);
    if (!on_ || now - onSinceNs_ <= maxOnNs_) return false;
    (void)out_.set(false);
    totalOnNs_ += now - onSinceNs_;
    on_ = false;
    tripped_ = true;
    return true;
  }
  bool isOn() const {
    std::lock_guard<std::mutex> lock(mu_);
    return on_;
  }
  bool tripped() const {
    std::lock_guard<std::mutex> lock(mu_);
    return tripped_;
  }
  void reset() {
    std::lock_guard<std::mutex> lock(mu_);
    tripped_ = false;
  }
  TimeNs totalOnNs() const {
    std::lock_guard<std::mutex> lock(mu_);
    return totalOnNs_;
  }

 private:
  ports::DigitalOut& out_;
  const Clock& clock_;
  const TimeNs maxOnNs_;
  mutable std::mutex mu_;
  bool on_ = false;
  bool tripped_ = false;
  TimeNs onSinceNs_ = 0;
  TimeNs totalOnNs_ = 0;
};

}  // namespace alacs::app
