// A FrameSource decorator with a free-running sensor's timing, in front of a source that
// exposes at once on request (the simulated camera, a replay): the sensor starts a frame
// every `periodNs` (at multiples of it from time 0), so an exposure begins at the next
// frame start after the request, and the frame's window is read out row by row after it,
// at the line time of a sensor that reads its whole height in one period. A real camera
// behaves so (libcamera delivers the frame after its readout, its timestamp the start of
// the exposure). Used by `alacs_cycle --virtual-time` and by the worker's tests: the
// position a sweep gives a frame must be the slide's at the frame's own mid-exposure,
// not at the request or at the delivery, which are a frame slot and a readout apart.
#pragma once

#include <algorithm>

#include "common/clock.h"
#include "ports/frame_source.h"

namespace alacs::ports {

class FrameSlotSource final : public FrameSource {
 public:
  // `heightPx`: the sensor's full height (the readout of a window takes its share of the
  // period); 0: no readout here (the inner source models its rows: a rolling shutter,
  // sim::SimCamera::setLineTimeNs). `clock` and `sleeper` are the inner source's (virtual
  // in tests).
  FrameSlotSource(FrameSource& inner, const Clock& clock, Sleeper& sleeper, TimeNs periodNs, int heightPx)
      : inner_(inner),
        clock_(clock),
        sleeper_(sleeper),
        periodNs_(std::max<TimeNs>(1, periodNs)),
        heightPx_(std::max(0, heightPx)) {}
  const char* name() const override { return inner_.name(); }

 private:
  Result<CapturedFrame> doCapture(const CaptureRequest& request, const std::function<void()>& onExposureEnd) override {
    const TimeNs now = clock_.now();
    sleeper_.sleepUntil((now + periodNs_ - 1) / periodNs_ * periodNs_);
    Result<CapturedFrame> f = inner_.capture(request, onExposureEnd);
    if (heightPx_ > 0) {
      const int rows = request.window.empty() ? heightPx_ : std::clamp(request.window.height, 0, heightPx_);
      sleeper_.sleepUntil(clock_.now() + periodNs_ * rows / heightPx_);
    }
    return f;
  }
  void doInterrupt() override { inner_.interrupt(); }
  void doResume() override { inner_.resume(); }

  FrameSource& inner_;
  const Clock& clock_;
  Sleeper& sleeper_;
  TimeNs periodNs_;
  int heightPx_;
};

}  // namespace alacs::ports
