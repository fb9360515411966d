// A FrameSource decorator with a free-running sensor's timing, in front of a source that
// exposes at once on request (the simulated camera, a replay): the sensor starts a frame
// every `periodNs` (at multiples of it from time 0), so an exposure begins at the next
// frame start after the request, and the frame is delivered once the sensor has read out
// its whole height, which takes one period (libcamera streams full frames; the window is
// cut from the frame afterwards). ISP time after the readout is not modelled. Used by
// `alacs_cycle --virtual-time` and by the worker's tests: the position a sweep gives a
// frame must be the slide's at the frame's own mid-exposure, not at the request or at
// the delivery, which are a frame slot and a readout apart. The laser is switched as the
// libcamera source switches it (LaserTiming): from the request to the delivery, or, with
// the frame clock learnt, just around the exposure.
#pragma once

#include <algorithm>

#include "common/clock.h"
#include "ports/frame_source.h"

namespace alacs::ports {

// How the laser is switched around a frame of a free-running sensor.
enum class LaserTiming {
  kAtRequest,   // on at the request, off at the delivery (the frame clock unknown)
  kFrameClock,  // on `leadNs` before the frame starts, off `leadNs` after its exposure
};

class FrameSlotSource final : public FrameSource {
 public:
  // `readout` false: no readout here (the inner source models its rows: a rolling shutter,
  // sim::SimCamera::setLineTimeNs). `clock` and `sleeper` are the inner source's (virtual
  // in tests).
  FrameSlotSource(FrameSource& inner, const Clock& clock, Sleeper& sleeper, TimeNs periodNs, bool readout = true,
                  LaserTiming timing = LaserTiming::kAtRequest, TimeNs leadNs = 0)
      : inner_(inner),
        clock_(clock),
        sleeper_(sleeper),
        periodNs_(std::max<TimeNs>(1, periodNs)),
        readout_(readout),
        timing_(timing),
        leadNs_(std::max<TimeNs>(0, leadNs)) {}
  const char* name() const override { return inner_.name(); }

 private:
  Result<CapturedFrame> doCapture(const CaptureRequest& request, const ExposureHooks& hooks) override {
    const bool clocked = timing_ == LaserTiming::kFrameClock;
    if (!clocked)
      if (Status s = hooks.beginNow(); !s) return s;
    const TimeNs notBefore = clock_.now() + (clocked ? leadNs_ : 0);
    const TimeNs slot = (notBefore + periodNs_ - 1) / periodNs_ * periodNs_;
    sleeper_.sleepUntil(slot - (clocked ? leadNs_ : 0));
    if (clocked)
      if (Status s = hooks.beginNow(); !s) return s;
    sleeper_.sleepUntil(slot);
    Result<CapturedFrame> f = inner_.capture(request, ExposureHooks());  // the laser is on already
    if (clocked) {
      sleeper_.sleepUntil(clock_.now() + leadNs_);
      hooks.endNow();
    }
    if (readout_) sleeper_.sleepUntil(slot + request.exposureUs * kNsPerUs + periodNs_);
    if (!clocked) hooks.endNow();
    return f;
  }
  void doInterrupt() override { inner_.interrupt(); }
  void doResume() override { inner_.resume(); }

  FrameSource& inner_;
  const Clock& clock_;
  Sleeper& sleeper_;
  TimeNs periodNs_;
  bool readout_;
  LaserTiming timing_;
  TimeNs leadNs_;
};

}  // namespace alacs::ports
