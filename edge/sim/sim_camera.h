// The simulated camera: a FrameSource that renders the scene at the slide's position
// with the laser as it really was during the exposure (read from the laser line), with
// the requested exposure time; a slide that moves during the exposure smears the line.
#pragma once

#include <functional>
#include <opencv2/core.hpp>

#include "ports/frame_source.h"
#include "sim/renderer.h"

namespace alacs::sim {

class SimCamera final : public ports::FrameSource {
 public:
  // `laserLevel` and `slideMm` are sampled at the start and the end of each exposure;
  // the exposure lasts its time on `clock`, waited through `sleeper` (virtual in tests).
  SimCamera(const SimScene& scene, const Clock& clock, Sleeper& sleeper, std::function<bool()> laserLevel,
            std::function<double()> slideMm);
  const char* name() const override { return "sim"; }
  // A rolling shutter (0, the default: a global one): row v of the sensor starts and ends
  // its exposure v × lineTimeNs after row 0, and the frame is delivered once the sensor's
  // last row is over; the slide's travel meanwhile is taken as even
  // (FrameRequest::slideMmPerRow).
  void setLineTimeNs(TimeNs lineTimeNs) { lineTimeNs_ = lineTimeNs; }
  // Stamp each frame at the end of its first row's exposure, as Raspberry Pi's pipelines
  // do (false, the default: at its start, as libcamera defines SensorTimestamp).
  void setTimestampAtExposureEnd(bool atEnd) { timestampAtExposureEnd_ = atEnd; }
  // The last rendered frame's slide position (mean over the exposure), for tests.
  double lastSlideMm() const { return lastSlideMm_; }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& request,
                                         const ports::ExposureHooks& hooks) override;
  Renderer renderer_;
  const Clock& clock_;
  Sleeper& sleeper_;
  std::function<bool()> laserLevel_;
  std::function<double()> slideMm_;
  cv::Mat frame_;
  cv::Mat crop_;  // windowed renders
  uint64_t sequence_ = 0;
  double lastSlideMm_ = 0.0;
  TimeNs lineTimeNs_ = 0;
  bool timestampAtExposureEnd_ = false;
};

}  // namespace alacs::sim
