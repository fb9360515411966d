// Trapezoidal motion profiles for the slide stepper, in steps and nanoseconds.
// Pure logic: no clock, no GPIO. The step runner (app/) turns a plan into pulses.
#pragma once

#include <cstdint>

#include "common/clock.h"
#include "common/result.h"

namespace alacs::motion {

struct SlideLimits {
  double stepsPerMm = 40.0;          // GT2 belt, 20-tooth pulley, 1/16 microstep
  double maxSpeedMmPerS = 300.0;         // NEMA 17 on a GT2 belt: well below pull-out at 12 kHz
  double accelMmPerS2 = 3000.0;          // 0.3 g on a ~150 g carriage
  double strokeMm = 200.0;           // soft limits are [0, strokeMm]
  double homingSpeedMmPerS = 50.0;
  int64_t homingTimeoutMs = 6000;
  int64_t stepPulseNs = 5000;        // STEP high time (driver minimum is ~2 µs)
  int64_t dirSetupNs = 5000;         // DIR stable before the first STEP edge

  Status validate() const;
  int64_t stepsFor(double mm) const;
  double mmFor(int64_t steps) const { return static_cast<double>(steps) / stepsPerMm; }
};

// One move of |steps| steps in one direction, starting at rest and ending at rest.
class TrapezoidMove {
 public:
  TrapezoidMove() = default;
  // speed in steps/s, accel in steps/s².
  TrapezoidMove(int64_t steps, double speedStepsPerS, double accelStepsPerS2);

  int64_t steps() const { return steps_; }
  // Time of the k-th step (1..steps) after the move starts.
  TimeNs stepTimeNs(int64_t k) const;
  TimeNs durationNs() const;
  // Steps travelled (continuous) at time t after the start; clamps outside [0, duration].
  double positionAt(TimeNs t) const;
  double peakSpeedStepsPerS() const { return peak_; }

 private:
  int64_t steps_ = 0;
  double accel_ = 1.0;
  double peak_ = 0.0;
  double accelSteps_ = 0.0;   // steps spent accelerating (== decelerating)
  double accelTimeS_ = 0.0;
  double totalTimeS_ = 0.0;
};

// Plans a move between two slide positions, refusing targets outside the soft limits.
Result<TrapezoidMove> planMove(const SlideLimits& limits, int64_t fromSteps, int64_t toSteps);

}  // namespace alacs::motion
