#include "replay/scan_recorder.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <system_error>

#include "common/log.h"

namespace alacs::replay {

namespace fs = std::filesystem;

namespace {

// The bytes of the regular files under `dir` (symlinks not followed).
uint64_t bytesUnder(const std::string& dir) {
  uint64_t n = 0;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code sizeEc;
    if (it->is_regular_file(sizeEc)) {
      const auto size = it->file_size(sizeEc);
      if (!sizeEc) n += size;
    }
  }
  return n;
}

// The number of a "scan_NNNN" name, or 0.
int scanNumber(const std::string& name) {
  if (name.size() < 6 || name.compare(0, 5, "scan_") != 0) return 0;
  if (!std::all_of(name.begin() + 5, name.end(), [](char c) { return c >= '0' && c <= '9'; }) || name.size() > 14)
    return 0;
  return std::atoi(name.c_str() + 5);
}

}  // namespace

ScanRecorder::ScanRecorder(std::string rootDir, geometry::Calibration calibration, std::string source,
                           RecordQuota quota)
    : root_(std::move(rootDir)), calibration_(std::move(calibration)), source_(std::move(source)), quota_(quota) {
  scanExisting();
}

void ScanRecorder::scanExisting() {
  std::error_code ec;
  for (const fs::directory_entry& e : fs::directory_iterator(root_, ec)) {
    std::error_code typeEc;
    if (!e.is_directory(typeEc) || e.is_symlink(typeEc)) continue;
    const int n = scanNumber(e.path().filename().string());
    if (n <= 0) continue;
    kept_.push_back({n, e.path().string(), bytesUnder(e.path().string())});
    bytes_ += kept_.back().bytes;
    count_ = std::max(count_, n);
  }
  std::sort(kept_.begin(), kept_.end(), [](const Kept& a, const Kept& b) { return a.number < b.number; });
}

void ScanRecorder::makeRoom(uint64_t more, bool newScan) {
  const size_t open = writer_ ? 1 : 0;
  while (kept_.size() > open &&
         ((newScan && kept_.size() >= static_cast<size_t>(std::max(1, quota_.maxScans))) ||
          bytes_ + more > quota_.maxBytes)) {
    const Kept oldest = kept_.front();
    kept_.erase(kept_.begin());
    bytes_ -= std::min(bytes_, oldest.bytes);
    std::error_code ec;
    fs::remove_all(oldest.dir, ec);
    ALACS_LOG_INFO("record", "quota: removed %s (%llu bytes)%s", oldest.dir.c_str(),
                   static_cast<unsigned long long>(oldest.bytes), ec ? " (not all of it)" : "");
  }
}

void ScanRecorder::recountNewest() {
  const uint64_t before = kept_.back().bytes;
  kept_.back().bytes = bytesUnder(kept_.back().dir);
  bytes_ = bytes_ - std::min(bytes_, before) + kept_.back().bytes;
}

std::vector<std::string> ScanRecorder::scansKept() const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<std::string> out;
  for (const Kept& k : kept_) out.push_back(k.dir);
  return out;
}

uint64_t ScanRecorder::bytesKept() const {
  std::lock_guard<std::mutex> lock(mu_);
  return bytes_;
}

Status ScanRecorder::begin(int targetId, const Eigen::Vector3d& roughMm, const std::vector<double>& stopsMm,
                           const image::Roi& roi) {
  std::lock_guard<std::mutex> lock(mu_);
  if (writer_) {
    (void)writer_->finish();
    writer_.reset();
  }
  makeRoom(0, true);
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
  ++started_;
  Result<ScanWriter> w = ScanWriter::create(root_ + name, info, calibration_);
  if (!w) return w.status();
  writer_.emplace(std::move(*w));
  kept_.push_back({count_, root_ + name, bytesUnder(root_ + name)});
  bytes_ += kept_.back().bytes;
  openScanOverQuota_ = false;
  return Status::ok();
}

Status ScanRecorder::frame(const image::ImageView& view, double slideMm, TimeNs exposureStartNs, int64_t exposureUs,
                           bool laserOn, const image::Roi& window, double analogueGain) {
  std::lock_guard<std::mutex> lock(mu_);
  if (!writer_) return {Error::kInvalidArgument, "no scan is being recorded"};
  // At most a full frame's PNG: room for it first, dropping old scans.
  const uint64_t frameBytes = static_cast<uint64_t>(view.width) * static_cast<uint64_t>(view.height) * 3U;
  makeRoom(frameBytes, false);
  if (openScanOverQuota_ || bytes_ + frameBytes > quota_.maxBytes) {
    openScanOverQuota_ = true;
    return {Error::kIo, "record quota: this scan alone would pass " + std::to_string(quota_.maxBytes) + " bytes"};
  }
  FrameRecord r;
  r.slideMm = slideMm;
  r.timestampS = static_cast<double>(exposureStartNs) / static_cast<double>(kNsPerS);
  r.exposureUs = exposureUs;
  r.analogueGain = analogueGain;
  r.laserOn = laserOn;
  const Status s = window.empty() ? writer_->addFrame(view, r) : writer_->addFrame(view, r, window);
  recountNewest();
  return s;
}

Result<std::string> ScanRecorder::end() {
  std::lock_guard<std::mutex> lock(mu_);
  if (!writer_) return Status(Error::kInvalidArgument, "no scan is being recorded");
  const Status s = writer_->finish();
  const std::string dir = writer_->dir();
  writer_.reset();
  recountNewest();
  if (!s) return s;
  return dir;
}

bool ScanRecorder::recording() const {
  std::lock_guard<std::mutex> lock(mu_);
  return writer_.has_value();
}

int ScanRecorder::scansStarted() const {
  std::lock_guard<std::mutex> lock(mu_);
  return started_;
}

RecordingSource::RecordingSource(ports::FrameSource& inner, ScanRecorder& recorder,
                                 std::function<double()> slideMm, std::function<bool()> laserOn)
    : inner_(inner), recorder_(recorder), slideMm_(std::move(slideMm)), laserOn_(std::move(laserOn)) {}

Result<ports::CapturedFrame> RecordingSource::doCapture(const ports::CaptureRequest& request,
                                                        const ports::ExposureHooks& hooks) {
  bool laser = laserOn_();
  double position = slideMm_();
  // The laser's state and the slide's position as the exposure begins: the inner source
  // calls `begin` then (at once, or just before its next frame starts).
  const ports::ExposureHooks recorded = hooks.begin ? ports::ExposureHooks(
                                                          [&]() -> Status {
                                                            const Status s = hooks.begin();
                                                            laser = laserOn_();
                                                            position = slideMm_();
                                                            return s;
                                                          },
                                                          hooks.end)
                                                    : hooks;
  Result<ports::CapturedFrame> f = inner_.capture(request, recorded);
  if (f && recorder_.recording()) {
    // A windowed readout is valid only inside its window: record that part.
    if (Status s = recorder_.frame(f->view, position, f->info.exposureStartNs, f->info.exposureUs, laser,
                                   request.window, f->info.analogueGain);
        !s)
      ALACS_LOG_WARN("record", "frame not recorded: %s", s.toString().c_str());
  }
  return f;
}

}  // namespace alacs::replay
