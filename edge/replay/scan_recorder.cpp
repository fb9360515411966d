#include "replay/scan_recorder.h"

#include <cstdio>

#include "common/log.h"

namespace alacs::replay {

ScanRecorder::ScanRecorder(std::string rootDir, geometry::Calibration calibration, std::string source)
    : root_(std::move(rootDir)), calibration_(std::move(calibration)), source_(std::move(source)) {}

Status ScanRecorder::begin(int targetId, const Eigen::Vector3d& roughMm, const std::vector<double>& stopsMm,
                           const image::Roi& roi) {
  std::lock_guard<std::mutex> lock(mu_);
  if (writer_) {
    (void)writer_->finish();
    writer_.reset();
  }
  ScanInfo info;
  info.kind = "localize";
  info.source = source_;
  info.widthPx = calibration_.camera.widthPx;
  info.heightPx = calibration_.camera.heightPx;
  info.targetId = targetId;
  info.roughMm = roughMm;
  info.stopsMm = stopsMm;
  info.roiPx = roi;
  char name[32];
  std::snprintf(name, sizeof name, "/scan_%04d", ++count_);
  Result<ScanWriter> w = ScanWriter::create(root_ + name, info, calibration_);
  if (!w) return w.status();
  writer_.emplace(std::move(*w));
  return Status::ok();
}

Status ScanRecorder::frame(const image::ImageView& view, double slideMm, TimeNs exposureStartNs, int64_t exposureUs,
                           bool laserOn, const image::Roi& window) {
  std::lock_guard<std::mutex> lock(mu_);
  if (!writer_) return {Error::kInvalidArgument, "no scan is being recorded"};
  FrameRecord r;
  r.slideMm = slideMm;
  r.timestampS = static_cast<double>(exposureStartNs) / static_cast<double>(kNsPerS);
  r.exposureUs = exposureUs;
  r.laserOn = laserOn;
  if (!window.empty()) return writer_->addFrame(view, r, window);
  return writer_->addFrame(view, r);
}

Result<std::string> ScanRecorder::end() {
  std::lock_guard<std::mutex> lock(mu_);
  if (!writer_) return Status(Error::kInvalidArgument, "no scan is being recorded");
  const Status s = writer_->finish();
  const std::string dir = writer_->dir();
  writer_.reset();
  if (!s) return s;
  return dir;
}

bool ScanRecorder::recording() const {
  std::lock_guard<std::mutex> lock(mu_);
  return writer_.has_value();
}

int ScanRecorder::scansStarted() const {
  std::lock_guard<std::mutex> lock(mu_);
  return count_;
}

RecordingSource::RecordingSource(ports::FrameSource& inner, ScanRecorder& recorder,
                                 std::function<double()> slideMm, std::function<bool()> laserOn)
    : inner_(inner), recorder_(recorder), slideMm_(std::move(slideMm)), laserOn_(std::move(laserOn)) {}

Result<ports::CapturedFrame> RecordingSource::doCapture(const ports::CaptureRequest& request,
                                                        const std::function<void()>& onExposureEnd) {
  const bool laser = laserOn_();
  const double position = slideMm_();
  Result<ports::CapturedFrame> f = inner_.capture(request, onExposureEnd);
  if (f && recorder_.recording()) {
    // A windowed readout is valid only inside its window: record that part.
    if (Status s = recorder_.frame(f->view, position, f->info.exposureStartNs, f->info.exposureUs, laser,
                                   request.window);
        !s)
      ALACS_LOG_WARN("record", "frame not recorded: %s", s.toString().c_str());
  }
  return f;
}

}  // namespace alacs::replay
