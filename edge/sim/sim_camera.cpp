#include "sim/sim_camera.h"

#include <algorithm>

namespace alacs::sim {

SimCamera::SimCamera(const SimScene& scene, const Clock& clock, Sleeper& sleeper, std::function<bool()> laserLevel,
                     std::function<double()> slideMm)
    : renderer_(scene), clock_(clock), sleeper_(sleeper), laserLevel_(std::move(laserLevel)), slideMm_(std::move(slideMm)) {}

Result<ports::CapturedFrame> SimCamera::doCapture(const ports::CaptureRequest& request,
                                                  const ports::ExposureHooks& hooks) {
  if (request.exposureUs <= 0 || request.exposureUs > 1000000)
    return Status(Error::kInvalidArgument, "exposure must be in 1..1000000 us");
  if (!(request.analogueGain == 0.0 || (request.analogueGain >= 1.0 && request.analogueGain <= 251.0)))
    return Status(Error::kInvalidArgument, "analogue gain must be 0 (the scene's) or in 1..251 (0..48 dB)");
  // Exposes on request: the laser goes on now.
  if (Status s = hooks.beginNow(); !s) return s;
  const TimeNs start = clock_.now();
  const bool laserAtStart = laserLevel_();
  const double slideAtStart = slideMm_();
  sleeper_.sleepUntil(start + request.exposureUs * kNsPerUs);
  const double slideAtEnd = slideMm_();
  // A rolling shutter: the sensor's last row ends its exposure that many line times later,
  // and the frame (the sensor reads out its whole height) is delivered then.
  const int lastRow = renderer_.scene().truth.camera.heightPx - 1;
  double slideMmPerRow = 0.0;
  if (lineTimeNs_ > 0 && lastRow > 0) {
    sleeper_.sleepUntil(start + request.exposureUs * kNsPerUs + lastRow * lineTimeNs_);
    slideMmPerRow = (slideMm_() - slideAtEnd) / lastRow;
  }
  const bool laserAtEnd = laserLevel_();
  hooks.endNow();
  // The laser counts for the part of the exposure it was seen on (start and end samples).
  const double laserFraction = 0.5 * ((laserAtStart ? 1.0 : 0.0) + (laserAtEnd ? 1.0 : 0.0));
  lastSlideMm_ = 0.5 * (slideAtStart + slideAtEnd);
  // A frame exposed while the slide moves smears the line between the two positions.
  FrameRequest r;
  r.slideStartMm = slideAtStart;
  r.slideEndMm = slideAtEnd;
  r.slideMmPerRow = slideMmPerRow;
  r.laserFraction = laserFraction;
  r.exposureUs = request.exposureUs;
  r.analogueGain = request.analogueGain;
  r.frameIndex = sequence_;
  if (request.window.empty()) {
    renderer_.render(r, frame_);
  } else {
    // A windowed readout: only the requested region is rendered (the same pixels as the
    // full frame's crop); the rest of the buffer is left as it was.
    const auto& cam = renderer_.scene().truth.camera;
    frame_.create(cam.heightPx, cam.widthPx, CV_8UC3);
    const cv::Rect window = cv::Rect(request.window.x, request.window.y, request.window.width, request.window.height) &
                            cv::Rect(0, 0, cam.widthPx, cam.heightPx);
    if (!window.empty()) {
      renderer_.renderRegion(r, window, crop_);
      crop_.copyTo(frame_(window));
    }
  }
  ports::CapturedFrame out;
  out.view = {frame_.data, frame_.cols, frame_.rows, frame_.step[0], image::PixelFormat::kBgr888};
  out.info.sequence = sequence_++;
  out.info.exposureStartNs = start + (timestampAtExposureEnd_ ? request.exposureUs * kNsPerUs : 0);
  out.info.exposureUs = request.exposureUs;
  out.info.analogueGain = request.analogueGain > 0.0 ? request.analogueGain : renderer_.scene().sensor.analogueGain();
  return out;
}

}  // namespace alacs::sim
