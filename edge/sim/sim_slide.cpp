#include "sim/sim_slide.h"

#include <cmath>

namespace alacs::sim {

SimSlide::SimSlide(const Clock& clock, double stepsPerMm, double strokeMm, double startMm)
    : stepsPerMm_(stepsPerMm),
      strokeSteps_(std::llround(strokeMm * stepsPerMm)),
      steps_(std::llround(startMm * stepsPerMm)),
      step_(clock),
      dir_(clock),
      enable_(clock) {
  // The carriage stops mechanically 2 mm beyond each switch.
  const int64_t hardStop = std::llround(2.0 * stepsPerMm);
  step_.onChange([this, hardStop](bool level) {
    if (!level) return;
    if (!enable_.level()) {
      ignored_.fetch_add(1);
      return;
    }
    const int64_t next = steps_.load() + (dir_.level() ? 1 : -1);
    if (next >= -hardStop && next <= strokeSteps_ + hardStop) steps_.store(next);
  });
  home_.setSource([this] { return steps_.load() <= 0; });
  end_.setSource([this] { return steps_.load() >= strokeSteps_; });
}

}  // namespace alacs::sim
