#include "motion/step_runner.h"

#include <algorithm>

namespace alacs::motion {

int64_t StepLog::stepsAt(TimeNs t) const {
  const auto n = static_cast<std::ptrdiff_t>(recorded());
  return std::upper_bound(edgesNs_.begin(), edgesNs_.begin() + n, t) - edgesNs_.begin();
}

MoveReport StepRunner::run(const TrapezoidMove& move, bool forward, const std::atomic<bool>& cancel) {
  return runSteps(move, forward, cancel, false, 0);
}

MoveReport StepRunner::home(const std::atomic<bool>& cancel) {
  // Already home: nothing to do.
  if (lines_.home != nullptr) {
    Result<bool> atHome = lines_.home->get();
    if (!atHome) return {MoveOutcome::kIoError, 0, 0, atHome.status()};
    if (*atHome) return {MoveOutcome::kSwitchReached, 0, 0, Status::ok()};
  }
  // Travel budget: the whole stroke plus 10 %, at the homing speed.
  const int64_t budget = limits_.stepsFor(limits_.strokeMm * 1.1 + 5.0);
  const TrapezoidMove move(budget, limits_.homingSpeedMmPerS * limits_.stepsPerMm,
                           limits_.accelMmPerS2 * limits_.stepsPerMm);
  const TimeNs deadline = clock_.now() + limits_.homingTimeoutMs * kNsPerMs;
  MoveReport r = runSteps(move, false, cancel, true, deadline);
  if (r.outcome == MoveOutcome::kCompleted) {
    r.outcome = MoveOutcome::kLimitHit;
    r.status = Status(Error::kTimeout, "homing: the home switch did not close within the travel budget");
  }
  return r;
}

MoveReport StepRunner::runSteps(const TrapezoidMove& move, bool forward, const std::atomic<bool>& cancel,
                                bool homing, TimeNs deadline) {
  MoveReport report;
  if (Status s = lines_.dir->set(forward); !s) return {MoveOutcome::kIoError, 0, 0, s};
  ports::DigitalIn* aheadSwitch = forward ? lines_.end : lines_.home;
  const TimeNs start = clock_.now() + limits_.dirSetupNs;
  // A late edge (the thread woke late) shifts the rest of the plan by its lateness instead
  // of being caught up: catching up would fire the next edges back to back, a step-rate
  // jump that stalls a real motor at speed. The move then ends that much later; the
  // position is counted from the pulses, so nothing else depends on the plan's times.
  TimeNs slipNs = 0;
  for (int64_t k = 1; k <= move.steps(); ++k) {
    const TimeNs due = start + move.stepTimeNs(k) + slipNs;
    sleeper_.sleepUntil(due);
    if (cancel.load(std::memory_order_relaxed)) {
      report.outcome = MoveOutcome::kCancelled;
      report.status = Status(Error::kFault, "move cancelled");
      return report;
    }
    if (homing && deadline > 0 && clock_.now() > deadline) {
      report.outcome = MoveOutcome::kLimitHit;
      report.status = Status(Error::kTimeout, "homing timed out");
      return report;
    }
    if (aheadSwitch != nullptr) {
      Result<bool> closed = aheadSwitch->get();
      if (!closed) return {MoveOutcome::kIoError, report.stepsDone, report.maxLatenessNs, closed.status()};
      if (*closed) {
        report.outcome = homing ? MoveOutcome::kSwitchReached : MoveOutcome::kLimitHit;
        if (!homing) report.status = Status(Error::kLimitHit, forward ? "end switch closed during a move"
                                                                        : "home switch closed during a move");
        return report;
      }
    }
    const TimeNs edgeNs = clock_.now();
    const TimeNs latenessNs = edgeNs - due;
    report.maxLatenessNs = std::max(report.maxLatenessNs, latenessNs);
    if (latenessNs > 0) slipNs += latenessNs;
    if (Status s = lines_.step->set(true); !s) return {MoveOutcome::kIoError, report.stepsDone, report.maxLatenessNs, s};
    if (log_ != nullptr) log_->record(edgeNs);
    sleeper_.sleepUntil(edgeNs + limits_.stepPulseNs);
    if (Status s = lines_.step->set(false); !s) return {MoveOutcome::kIoError, report.stepsDone, report.maxLatenessNs, s};
    ++report.stepsDone;
    if (position_ != nullptr) position_->fetch_add(forward ? 1 : -1, std::memory_order_relaxed);
  }
  return report;
}

}  // namespace alacs::motion
