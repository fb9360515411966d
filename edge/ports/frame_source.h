// The camera port. One implementation per source: libcamera (drivers/libcamera), a
// replay of a scan directory, and the simulator (sim/). Frames are owned by the source
// and lent to the caller until the next capture.
#pragma once

#include <cstdint>
#include <functional>

#include "common/clock.h"
#include "common/result.h"
#include "image/image_view.h"

namespace alacs::ports {

struct CaptureRequest {
  int64_t exposureUs = 2000;
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
};

struct CapturedFrame {
  image::ImageView view;  // valid until the next capture()
  FrameInfo info;
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Exposes and returns one frame. Blocking; call from a worker thread, never from the
  // event loop. `onExposureEnd` is called (on the same thread) as soon as the sensor
  // stops integrating, before readout, so the laser can be switched off at once.
  // Errors: kTimeout, kBadInput (corrupted frame), kIo.
  Result<CapturedFrame> capture(const CaptureRequest& request, const std::function<void()>& onExposureEnd) {
    return doCapture(request, onExposureEnd);
  }
  virtual const char* name() const = 0;

  // Thread-safe, for STOP: a capture() in progress on another thread ends as soon as the
  // source can (its request cancelled), and every capture fails at once (kFault) until
  // resume(). Sources whose captures never block long need not override these.
  void interrupt() { doInterrupt(); }
  void resume() { doResume(); }

 private:
  virtual Result<CapturedFrame> doCapture(const CaptureRequest& request,
                                          const std::function<void()>& onExposureEnd) = 0;
  virtual void doInterrupt() {}
  virtual void doResume() {}
};

}  // namespace alacs::ports
