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
#include "common/frame_clock.h"
#include "ports/frame_source.h"

namespace alacs::ports {

// How the laser is switched around a frame of a free-running sensor.
enum class LaserTiming {
  kAtRequest,   // on at the request, off at the delivery (the frame clock unknown)
  kFrameClock,  // on `leadNs` before the window's exposure span, off `leadNs` after it
};

class FrameSlotSource final : public FrameSource {
 public:
  // `readout` false: no readout here (the inner source models its rows: a rolling shutter,
  // sim::SimCamera::setLineTimeNs). `clock` and `sleeper` are the inner source's (virtual
  // in tests). kFrameClock switches the laser as the libcamera source does with its clock
  // learnt: around common/frame_clock.h's exposureSpan of the request's window, for a
  // sensor `heightPx` rows high whose line time it is told (`lineTimeNs`, 0: not known,
  // unless `globalShutter`).
  FrameSlotSource(FrameSource& inner, const Clock& clock, Sleeper& sleeper, TimeNs periodNs, bool readout = true,
                  LaserTiming timing = LaserTiming::kAtRequest, TimeNs leadNs = 0, int heightPx = 0,
                  TimeNs lineTimeNs = 0, bool globalShutter = false)
      : inner_(inner),
        clock_(clock),
        sleeper_(sleeper),
        periodNs_(std::max<TimeNs>(1, periodNs)),
        readout_(readout),
        timing_(timing),
        leadNs_(std::max<TimeNs>(0, leadNs)),
        heightPx_(heightPx),
        lineTimeNs_(lineTimeNs),
        globalShutter_(globalShutter) {}
  const char* name() const override { return inner_.name(); }

 private:
  Result<CapturedFrame> doCapture(const CaptureRequest& request, const ExposureHooks& hooks) override {
    const TimeNs exposureNs = request.exposureUs * kNsPerUs;
    if (timing_ == LaserTiming::kAtRequest) {
      if (Status s = hooks.beginNow(); !s) return s;
      const TimeNs slot = nextSlot(clock_.now());
      sleeper_.sleepUntil(slot);
      Result<CapturedFrame> f = inner_.capture(request, ExposureHooks());  // the laser is on already
      numberBySlot(f, slot);
      if (readout_) sleeper_.sleepUntil(slot + exposureNs + periodNs_);
      hooks.endNow();  // libcamera tells the exposure's end only at the delivery
      return f;
    }
    // The first frame whose window's span starts two leads from now (the timestamp: the
    // frame's start).
    const int y0 = request.window.empty() ? 0 : request.window.y;
    const int y1 = request.window.empty() ? heightPx_ : request.window.y + request.window.height;
    const TimeNs notBefore = clock_.now() + 2 * leadNs_;
    TimeNs slot = nextSlot(notBefore);
    while (spanAt(slot, exposureNs, y0, y1).startNs < notBefore) slot += periodNs_;
    const ExposureSpan span = spanAt(slot, exposureNs, y0, y1);
    sleeper_.sleepUntil(span.startNs - leadNs_);
    if (Status s = hooks.beginNow(); !s) return s;
    sleeper_.sleepUntil(slot);
    Result<CapturedFrame> f = inner_.capture(request, ExposureHooks());
    numberBySlot(f, slot);
    // Off a lead after the span, or at the delivery if that comes first.
    const TimeNs deliveryNs = readout_ ? slot + exposureNs + periodNs_ : clock_.now();
    sleeper_.sleepUntil(std::min(span.endNs + leadNs_, deliveryNs));
    hooks.endNow();
    sleeper_.sleepUntil(deliveryNs);
    return f;
  }
  // A sensor numbers its frames, delivered or not: the frame's slot, as libcamera's
  // sequence counts the sensor's frames (the inner source counts its captures).
  void numberBySlot(Result<CapturedFrame>& f, TimeNs slotNs) const {
    if (f) f->info.sequence = static_cast<uint64_t>(slotNs / periodNs_);
  }
  TimeNs nextSlot(TimeNs notBeforeNs) const { return (notBeforeNs + periodNs_ - 1) / periodNs_ * periodNs_; }
  ExposureSpan spanAt(TimeNs slotNs, TimeNs exposureNs, int y0, int y1) const {
    return exposureSpan(slotNs, exposureNs, y0, y1, lineTimeNs_, globalShutter_ ? 0 : periodNs_, heightPx_);
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
  int heightPx_;
  TimeNs lineTimeNs_;
  bool globalShutter_;
};

}  // namespace alacs::ports
