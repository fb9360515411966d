// Turns a planned move into STEP/DIR pulses on digital outputs, watching the limit
// switches. Time comes from a Clock and waits go through a Sleeper, so the same code
// drives a real motor from a real-time thread and runs in virtual time in tests.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <vector>

#include "common/clock.h"
#include "motion/trapezoid.h"
#include "ports/digital_io.h"

namespace alacs::motion {

struct StepLines {
  ports::DigitalOut* step = nullptr;
  ports::DigitalOut* dir = nullptr;
  ports::DigitalIn* home = nullptr;
  ports::DigitalIn* end = nullptr;  // optional
};

enum class MoveOutcome : uint8_t {
  kCompleted,
  kSwitchReached,  // homing: the home switch closed (success)
  kLimitHit,       // a switch closed during an ordinary move (fault)
  kCancelled,      // stop requested
  kIoError,
};

struct MoveReport {
  MoveOutcome outcome = MoveOutcome::kCompleted;
  int64_t stepsDone = 0;
  TimeNs maxLatenessNs = 0;  // worst delay of a STEP edge after its planned time
  Status status;
};

// The times of one move's STEP edges, for where the slide was at a past instant: a
// frame's mid-exposure in a continuous sweep, known only once the frame arrives (a sensor
// exposes in its next frame slot and delivers after its readout). One writer (the
// runner's thread) and readers on other threads, without a lock; sized before the move,
// so recording allocates nothing.
class StepLog {
 public:
  explicit StepLog(int64_t steps) : edgesNs_(static_cast<size_t>(std::max<int64_t>(0, steps))) {}
  // The writer: the next step's edge. Steps beyond the size are not recorded.
  void record(TimeNs edgeNs) {
    const int64_t n = count_.load(std::memory_order_relaxed);
    if (n >= static_cast<int64_t>(edgesNs_.size())) return;
    edgesNs_[static_cast<size_t>(n)] = edgeNs;
    count_.store(n + 1, std::memory_order_release);
  }
  // Steps whose edge came at or before `t` (0 before the first; those recorded so far after).
  int64_t stepsAt(TimeNs t) const;
  int64_t recorded() const { return count_.load(std::memory_order_acquire); }

 private:
  std::vector<TimeNs> edgesNs_;
  std::atomic<int64_t> count_{0};
};

class StepRunner {
 public:
  StepRunner(const SlideLimits& limits, StepLines lines, const Clock& clock, Sleeper& sleeper)
      : limits_(limits), lines_(lines), clock_(clock), sleeper_(sleeper) {}

  // Runs `move` towards increasing slide mm when `forward`. A switch closing in the
  // direction of travel ends the move with kLimitHit. Blocking.
  MoveReport run(const TrapezoidMove& move, bool forward, const std::atomic<bool>& cancel);

  // Moves towards home at the homing speed until the home switch closes (kSwitchReached),
  // or fails with kLimitHit status kTimeout after the homing timeout / travel budget.
  MoveReport home(const std::atomic<bool>& cancel);

  // When set, each completed step adds ±1 to `*steps` (the slide position in steps), so
  // another thread can read where the slide is during a move.
  void trackPosition(std::atomic<int64_t>* steps) { position_ = steps; }
  // When set, each step's edge time is recorded in `log` (StepLog).
  void logSteps(StepLog* log) { log_ = log; }

 private:
  MoveReport runSteps(const TrapezoidMove& move, bool forward, const std::atomic<bool>& cancel, bool homing,
                      TimeNs deadline);
  SlideLimits limits_;
  StepLines lines_;
  const Clock& clock_;
  Sleeper& sleeper_;
  std::atomic<int64_t>* position_ = nullptr;
  StepLog* log_ = nullptr;
};

}  // namespace alacs::motion
