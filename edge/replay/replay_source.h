// Replays a scan directory as a camera: a FrameSource that, at each capture, serves the
// recorded frame nearest the slide's current position (with the laser state the laser
// line has at that moment) and reports the position it was recorded at, so that the
// scan worker processes it exactly as it processed the live frame (alacsd --replay).
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <opencv2/core.hpp>
#include <string>

#include "ports/frame_source.h"
#include "replay/scan_dir.h"

namespace alacs::replay {

class ReplaySource final : public ports::FrameSource {
 public:
  // `laserLevel` and `slideMm` are read at the start of each capture. Errors: those of
  // readManifest; kBadInput when the scan holds no frame.
  static Result<std::unique_ptr<ReplaySource>> open(const std::string& dir, const Clock& clock,
                                                    std::function<bool()> laserLevel,
                                                    std::function<double()> slideMm);
  const char* name() const override { return "replay"; }

  // The recorded slide position (mm) of the last frame served; NaN before the first.
  // Read it on the thread that captures.
  double lastSlideMm() const { return lastSlideMm_.load(); }
  // |recorded - requested| position of the last frame served, mm.
  double lastPositionErrorMm() const { return lastErrorMm_.load(); }
  // Index into manifest().frames of the last frame served; -1 before the first.
  int lastFrame() const { return lastFrame_.load(); }
  const ScanManifest& manifest() const { return manifest_; }
  const std::string& dir() const { return dir_; }
  // True when laser frames were recorded at a gain 5 % or more below the scan's first
  // laser-off frame's, where metering starts (a scan taken with the lower gain in sun).
  // Otherwise (recorded without it, with it off, or without gains) the scan holds no laser
  // frame at a lowered gain: it is a camera without a gain control, and reports no gain
  // (FrameInfo::analogueGain 0), so that the metering replays it at the gain it was taken
  // at, as the scan worker leaves a live camera without the control at its own.
  bool gainLowered() const { return gainLowered_; }

  // The frame a capture at `slideMm` with the laser `laserOn` would serve; -1: none
  // (replay::nearestFrame).
  int nearestFrame(double slideMm, bool laserOn, int64_t exposureUs = 0, double analogueGain = 0.0) const;

 private:
  ReplaySource(std::string dir, ScanManifest m, const Clock& clock, std::function<bool()> laserLevel,
               std::function<double()> slideMm);
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& request,
                                         const ports::ExposureHooks& hooks) override;

  std::string dir_;
  ScanManifest manifest_;
  const Clock& clock_;
  std::function<bool()> laserLevel_;
  std::function<double()> slideMm_;
  bool gainLowered_ = false;
  cv::Mat frame_;
  uint64_t sequence_ = 0;
  std::atomic<double> lastSlideMm_;
  std::atomic<double> lastErrorMm_{0.0};
  std::atomic<int> lastFrame_{-1};
};

}  // namespace alacs::replay
