// The simulated slide: a stepper that listens to the STEP/DIR/ENABLE lines exactly as a
// real driver would, and closes the home and end switches at the ends of its travel.
// The step runner cannot tell it from hardware. Thread-safe.
#pragma once

#include <atomic>
#include <cstdint>

#include "ports/digital_io_fake.h"

namespace alacs::sim {

class SimSlide {
 public:
  SimSlide(const Clock& clock, double stepsPerMm, double strokeMm, double startMm);

  ports::DigitalOut& stepInput() { return step_; }
  ports::DigitalOut& dirInput() { return dir_; }
  ports::DigitalOut& enableInput() { return enable_; }
  ports::DigitalIn& homeSwitch() { return home_; }
  ports::DigitalIn& endSwitch() { return end_; }

  double positionMm() const { return static_cast<double>(steps_.load()) / stepsPerMm_; }
  int64_t positionSteps() const { return steps_.load(); }
  // Steps received while the driver was disabled (a bug if ever non-zero).
  int64_t ignoredSteps() const { return ignored_.load(); }

 private:
  const double stepsPerMm_;
  const int64_t strokeSteps_;
  std::atomic<int64_t> steps_;
  std::atomic<int64_t> ignored_{0};
  ports::FakeDigitalOut step_;
  ports::FakeDigitalOut dir_;
  ports::FakeDigitalOut enable_;
  ports::FakeDigitalIn home_;
  ports::FakeDigitalIn end_;
};

}  // namespace alacs::sim
