#include "motion/trapezoid.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>

namespace alacs::motion {

Status SlideLimits::validate() const {
  if (!(stepsPerMm > 0.1 && stepsPerMm < 10000.0)) return {Error::kInvalidArgument, "motion.steps_per_mm must be in 0.1..10000"};
  if (!(maxSpeedMmPerS > 0.0 && maxSpeedMmPerS <= 2000.0)) return {Error::kInvalidArgument, "motion.max_speed_mm_s must be in (0, 2000]"};
  if (!(accelMmPerS2 > 0.0 && accelMmPerS2 <= 50000.0)) return {Error::kInvalidArgument, "motion.accel_mm_s2 must be in (0, 50000]"};
  if (!(strokeMm > 0.0 && strokeMm <= 2000.0)) return {Error::kInvalidArgument, "motion.stroke_mm must be in (0, 2000]"};
  if (!(homingSpeedMmPerS > 0.0 && homingSpeedMmPerS <= maxSpeedMmPerS)) return {Error::kInvalidArgument, "motion.homing_speed_mm_s must be in (0, max_speed_mm_s]"};
  if (homingTimeoutMs < 100 || homingTimeoutMs > 600000) return {Error::kInvalidArgument, "motion.homing_timeout_ms must be in 100..600000"};
  if (stepPulseNs < 1000 || stepPulseNs > 1000000) return {Error::kInvalidArgument, "motion.step_pulse_ns must be in 1000..1000000"};
  const double maxRate = maxSpeedMmPerS * stepsPerMm;
  if (maxRate * 2.0 * static_cast<double>(stepPulseNs) * 1e-9 > 1.0)
    return {Error::kInvalidArgument, "motion.max_speed_mm_s needs a step period shorter than twice the pulse"};
  return Status::ok();
}

int64_t SlideLimits::stepsFor(double mm) const { return std::llround(mm * stepsPerMm); }

TrapezoidMove::TrapezoidMove(int64_t steps, double speed, double accel)
    : steps_(steps), accel_(accel) {
  const double n = static_cast<double>(steps);
  // Triangle when the move is too short to reach the cruise speed.
  peak_ = std::min(speed, std::sqrt(accel * n));
  accelSteps_ = peak_ * peak_ / (2.0 * accel);
  accelTimeS_ = peak_ / accel;
  const double cruiseSteps = std::max(0.0, n - 2.0 * accelSteps_);
  totalTimeS_ = steps > 0 ? 2.0 * accelTimeS_ + cruiseSteps / peak_ : 0.0;
}

TimeNs TrapezoidMove::stepTimeNs(int64_t k) const {
  const double x = static_cast<double>(k);
  const double n = static_cast<double>(steps_);
  double t = 0.0;
  if (x <= accelSteps_) {
    t = std::sqrt(2.0 * x / accel_);
  } else if (x <= n - accelSteps_) {
    t = accelTimeS_ + (x - accelSteps_) / peak_;
  } else {
    t = totalTimeS_ - std::sqrt(std::max(0.0, 2.0 * (n - x) / accel_));
  }
  return static_cast<TimeNs>(std::llround(t * 1e9));
}

TimeNs TrapezoidMove::durationNs() const { return static_cast<TimeNs>(std::llround(totalTimeS_ * 1e9)); }

double TrapezoidMove::positionAt(TimeNs tNs) const {
  const double t = std::clamp(static_cast<double>(tNs) * 1e-9, 0.0, totalTimeS_);
  const double n = static_cast<double>(steps_);
  if (t <= accelTimeS_) return 0.5 * accel_ * t * t;
  if (t <= totalTimeS_ - accelTimeS_) return accelSteps_ + (t - accelTimeS_) * peak_;
  const double r = totalTimeS_ - t;
  return n - 0.5 * accel_ * r * r;
}

Result<TrapezoidMove> planMove(const SlideLimits& limits, int64_t fromSteps, int64_t toSteps) {
  const int64_t maxSteps = limits.stepsFor(limits.strokeMm);
  if (toSteps < 0 || toSteps > maxSteps)
    return Status(Error::kOutOfRange, "target " + std::to_string(limits.mmFor(toSteps)) +
                                          " mm is outside the stroke [0, " + std::to_string(limits.strokeMm) + "] mm");
  return TrapezoidMove(std::llabs(toSteps - fromSteps), limits.maxSpeedMmPerS * limits.stepsPerMm,
                       limits.accelMmPerS2 * limits.stepsPerMm);
}

}  // namespace alacs::motion
