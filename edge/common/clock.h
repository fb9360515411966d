// Time as a parameter. Logic takes `TimeNs now` or a `Clock&`; only the daemon's event
// loop reads the wall clock (MonotonicClock). Tests and the simulator use VirtualClock.
#pragma once

#include <cstdint>

namespace alacs {

using TimeNs = int64_t;  // CLOCK_MONOTONIC nanoseconds (or virtual nanoseconds)
constexpr TimeNs kNsPerUs = 1000;
constexpr TimeNs kNsPerMs = 1000 * 1000;
constexpr TimeNs kNsPerS = 1000 * 1000 * 1000;

class Clock {
 public:
  virtual ~Clock() = default;
  virtual TimeNs now() const = 0;
};

class MonotonicClock final : public Clock {
 public:
  TimeNs now() const override;
};

// A clock that only moves when told to. Not thread-safe.
class VirtualClock final : public Clock {
 public:
  explicit VirtualClock(TimeNs start = 0) : now_(start) {}
  TimeNs now() const override { return now_; }
  void advance(TimeNs dt) { now_ += dt; }
  void set(TimeNs t) { now_ = t; }

 private:
  TimeNs now_;
};

}  // namespace alacs

namespace alacs {

// Waits until an absolute time of its clock. The real one uses clock_nanosleep
// (TIMER_ABSTIME); the virtual one moves a VirtualClock, so pulse trains run instantly
// and exactly in tests.
class Sleeper {
 public:
  virtual ~Sleeper() = default;
  virtual void sleepUntil(TimeNs t) = 0;
  // For a sleeper shared by threads that take turns in virtual time (VirtualTimeline): a
  // thread about to do timed work attaches, and detaches when it is done or before it
  // waits for another attached thread (join). A count, not an identity: a thread may
  // attach for one it is about to start, which then detaches itself at its end. The real
  // and the single-threaded virtual sleeper ignore both.
  virtual void attach() {}
  virtual void detach() {}
};

class MonotonicSleeper final : public Sleeper {
 public:
  void sleepUntil(TimeNs t) override;
};

class VirtualSleeper final : public Sleeper {
 public:
  explicit VirtualSleeper(VirtualClock& clock) : clock_(clock) {}
  void sleepUntil(TimeNs t) override {
    if (t > clock_.now()) clock_.set(t);
  }

 private:
  VirtualClock& clock_;
};

}  // namespace alacs
