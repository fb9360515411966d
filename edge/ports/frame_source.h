// The camera port. One implementation per source: libcamera (drivers/libcamera), a
// replay of a scan directory, and the simulator (sim/). Frames are owned by the source
// and lent to the caller until the next capture.
#pragma once

#include <cstdint>
#include <functional>
#include <utility>

#include "common/clock.h"
#include "common/result.h"
#include "image/image_view.h"

namespace alacs::ports {

struct CaptureRequest {
  int64_t exposureUs = 2000;
  // The sensor's analogue gain, linear (libcamera's AnalogueGain: 1 is the sensor's
  // least); 0: the source's own, left as it is.
  double analogueGain = 0.0;
  int64_t timeoutMs = 1000;
  // The part of the frame the caller will read (full-frame pixels); empty: all of it.
  // Sources may deliver only this window valid (the view keeps full-frame geometry), as
  // a sensor's windowed readout or a partial copy does; outside it the pixels are
  // undefined.
  image::Roi window;
};

struct FrameInfo {
  uint64_t sequence = 0;
  TimeNs exposureStartNs = 0;  // the sensor's time base (CLOCK_MONOTONIC on Linux)
  int64_t exposureUs = 0;      // as applied, when the source can tell; else as requested
  double analogueGain = 0.0;   // likewise (linear); 0: not known, or the source cannot set it
};

struct CapturedFrame {
  image::ImageView view;  // valid until the next capture()
  FrameInfo info;
};

// What a capture does with the laser, called on the capturing thread. `begin` switches it
// on just before the exposure: a source that knows its sensor's frame clock calls it just
// before the frame it will deliver starts (drivers/libcamera), one that exposes on request
// calls it at once (beginNow()); an error from it ends the capture with that error. `end`
// switches it off as soon as the exposure is over. A source may call the pair more than
// once in one capture (a frame missed: the laser off, on again for the next), and always
// leaves it ended. Either may be empty (a frame without the laser).
struct ExposureHooks {
  ExposureHooks() = default;
  // Only the end (a capture that does not switch the laser on: metering, tools).
  ExposureHooks(std::function<void()> onEnd) : end(std::move(onEnd)) {}  // NOLINT(google-explicit-constructor)
  ExposureHooks(std::function<Status()> onBegin, std::function<void()> onEnd)
      : begin(std::move(onBegin)), end(std::move(onEnd)) {}

  // A `begin` refused: the laser is ended all the same.
  Status beginNow() const {
    const Status s = begin ? begin() : Status::ok();
    if (!s) endNow();
    return s;
  }
  void endNow() const {
    if (end) end();
  }

  std::function<Status()> begin;
  std::function<void()> end;
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Exposes and returns one frame. Blocking; call from a worker thread, never from the
  // event loop. `hooks` switch the laser around the exposure (ExposureHooks).
  // Errors: kTimeout, kBadInput (corrupted frame), kIo, or the error `hooks.begin` gave.
  Result<CapturedFrame> capture(const CaptureRequest& request, const ExposureHooks& hooks) {
    return doCapture(request, hooks);
  }
  virtual const char* name() const = 0;

  // Thread-safe, for STOP: a capture() in progress on another thread ends as soon as the
  // source can (its request cancelled), and every capture fails at once (kFault) until
  // resume(). Sources whose captures never block long need not override these.
  void interrupt() { doInterrupt(); }
  void resume() { doResume(); }

 private:
  virtual Result<CapturedFrame> doCapture(const CaptureRequest& request, const ExposureHooks& hooks) = 0;
  virtual void doInterrupt() {}
  virtual void doResume() {}
};

}  // namespace alacs::ports
