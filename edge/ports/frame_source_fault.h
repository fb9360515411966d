// A FrameSource decorator that injects camera faults (a frame that never arrives, a
// corrupted frame) in front of a real source. Used by `alacsd --sim --sim-fault ...`
// and by tests, so the retry-then-fault path runs exactly as it would on a real camera.
#pragma once

#include <atomic>
#include <string>

#include "common/clock.h"
#include "ports/frame_source.h"

namespace alacs::ports {

enum class CameraFault : uint8_t { kNone, kTimeout, kCorrupt };

class FaultInjectingFrameSource final : public FrameSource {
 public:
  // `clock` and `sleeper` time the frame that never comes (virtual in tests).
  FaultInjectingFrameSource(FrameSource& inner, const Clock& clock, Sleeper& sleeper)
      : inner_(inner), clock_(clock), sleeper_(sleeper) {}
  // Every capture fails this way until set back to kNone. Thread-safe.
  void setFault(CameraFault f) { fault_.store(f); }
  const char* name() const override { return inner_.name(); }

 private:
  Result<CapturedFrame> doCapture(const CaptureRequest& request, const ExposureHooks& hooks) override {
    switch (fault_.load()) {
      case CameraFault::kTimeout:
        // A frame that never comes: the caller waits its whole timeout.
        if (Status s = hooks.beginNow(); !s) return s;
        sleeper_.sleepUntil(clock_.now() + request.timeoutMs * kNsPerMs);
        hooks.endNow();
        return Status(Error::kTimeout, "camera frame timed out after " + std::to_string(request.timeoutMs) + " ms");
      case CameraFault::kCorrupt: {
        Result<CapturedFrame> f = inner_.capture(request, hooks);
        if (!f) return f;
        return Status(Error::kBadInput, "camera delivered a corrupted frame (short buffer)");
      }
      case CameraFault::kNone:
        break;
    }
    return inner_.capture(request, hooks);
  }
  void doInterrupt() override { inner_.interrupt(); }
  void doResume() override { inner_.resume(); }

  FrameSource& inner_;
  const Clock& clock_;
  Sleeper& sleeper_;
  std::atomic<CameraFault> fault_{CameraFault::kNone};
};

}  // namespace alacs::ports
