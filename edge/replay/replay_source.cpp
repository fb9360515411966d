#include "replay/replay_source.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace alacs::replay {

Result<std::unique_ptr<ReplaySource>> ReplaySource::open(const std::string& dir, const Clock& clock,
                                                         std::function<bool()> laserLevel,
                                                         std::function<double()> slideMm) {
  Result<ScanManifest> m = readManifest(dir);
  if (!m) return m.status();
  if (m->frames.empty()) return Status(Error::kBadInput, "scan '" + dir + "' holds no frame");
  return std::unique_ptr<ReplaySource>(
      new ReplaySource(dir, std::move(*m), clock, std::move(laserLevel), std::move(slideMm)));
}

ReplaySource::ReplaySource(std::string dir, ScanManifest m, const Clock& clock, std::function<bool()> laserLevel,
                           std::function<double()> slideMm)
    : dir_(std::move(dir)),
      manifest_(std::move(m)),
      clock_(clock),
      laserLevel_(std::move(laserLevel)),
      slideMm_(std::move(slideMm)),
      lastSlideMm_(std::numeric_limits<double>::quiet_NaN()) {
  // The laser frames against the first laser-off frame's gain (the least step the metering
  // lowers it by is 5 %).
  const auto& frames = manifest_.frames;
  const auto firstOff = std::find_if(frames.begin(), frames.end(), [](const FrameRecord& f) { return !f.laserOn; });
  if (firstOff == frames.end() || firstOff->analogueGain <= 0.0) return;
  const double metered = firstOff->analogueGain;
  gainLowered_ = std::any_of(frames.begin(), frames.end(), [&](const FrameRecord& f) {
    return f.laserOn && f.analogueGain > 0.0 && f.analogueGain < 0.95 * metered;
  });
}

int ReplaySource::nearestFrame(double slideMm, bool laserOn, int64_t exposureUs, double analogueGain) const {
  return replay::nearestFrame(manifest_, slideMm, laserOn, exposureUs, analogueGain);
}

Result<ports::CapturedFrame> ReplaySource::doCapture(const ports::CaptureRequest& request,
                                                     const ports::ExposureHooks& hooks) {
  if (request.exposureUs <= 0 || request.exposureUs > 1000000)
    return Status(Error::kInvalidArgument, "exposure must be in 1..1000000 us");
  if (Status s = hooks.beginNow(); !s) return s;
  const TimeNs start = clock_.now();
  const bool laserOn = laserLevel_();
  const double position = slideMm_();
  // The recorded exposure is over at once: the laser goes off before the PNG is decoded.
  hooks.endNow();
  const int index = nearestFrame(position, laserOn, request.exposureUs, request.analogueGain);
  if (index < 0)
    return Status(Error::kNotFound, std::string("scan '") + dir_ + "' has no frame with the laser " + (laserOn ? "on" : "off"));
  const FrameRecord& rec = manifest_.frames[static_cast<size_t>(index)];
  // Decoded into the one frame buffer (the previous frame's view is no longer valid).
  if (Status s = loadFrameInto(dir_, manifest_, rec, frame_); !s) return s;
  lastSlideMm_.store(rec.slideMm);
  lastErrorMm_.store(std::abs(rec.slideMm - position));
  lastFrame_.store(index);
  ports::CapturedFrame out;
  out.view = {frame_.data, frame_.cols, frame_.rows, frame_.step[0], image::PixelFormat::kBgr888};
  out.info.sequence = sequence_++;
  out.info.exposureStartNs = start;
  out.info.exposureUs = rec.exposureUs;
  out.info.analogueGain = gainLowered_ ? rec.analogueGain : 0.0;
  return out;
}

}  // namespace alacs::replay
