#include "app/frame_pipeline.h"

#include <sys/mman.h>

#include <cmath>
#include <cstring>
#include <new>

#include "common/log.h"

namespace alacs::app {

void FramePipeline::Mapping::reset(size_t bytes) {
  if (data_ != nullptr) ::munmap(data_, bytes_);
  data_ = nullptr;
  bytes_ = 0;
  if (bytes == 0) return;
  void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
  if (p == MAP_FAILED) throw std::bad_alloc();
  data_ = static_cast<uint8_t*>(p);
  bytes_ = bytes;
}

void FramePipeline::Mapping::dropPages() {
  if (data_ != nullptr) (void)::madvise(data_, bytes_, MADV_DONTNEED);
}

FramePipeline::FramePipeline() { thread_ = std::thread([this] { run(); }); }

FramePipeline::~FramePipeline() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    quit_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void FramePipeline::begin(const localize::Localizer& localizer, const localize::ScanPlan& plan) {
  (void)finish();
  std::lock_guard<std::mutex> lock(mu_);
  for (Mapping& b : buffers_) b.dropPages();
  localizer_.emplace(localizer);
  plan_ = plan;
  results_.clear();
}

namespace {
// Copies the rows and columns of `roi` (3 bytes a pixel) from `frame` into `to`, a buffer
// of the frame's geometry.
void copyRoi(const image::ImageView& frame, const image::Roi& roi, uint8_t* to) {
  for (int y = roi.y; y < roi.y + roi.height; ++y) {
    const size_t off = static_cast<size_t>(y) * frame.strideBytes + static_cast<size_t>(roi.x) * 3U;
    std::memcpy(to + off, frame.data + off, static_cast<size_t>(roi.width) * 3U);
  }
}
}  // namespace

namespace {
// `frame`'s `roi` into `buffer` (mapped to the frame's size), and a view of it.
image::ImageView keepRoi(const image::ImageView& frame, const image::Roi& roi, auto& buffer) {
  const size_t bytes = frame.strideBytes * static_cast<size_t>(frame.height);
  if (buffer.bytes() != bytes) buffer.reset(bytes);
  buffer.dropPages();
  copyRoi(frame, roi, buffer.data());
  image::ImageView v = frame;
  v.data = buffer.data();
  return v;
}
}  // namespace

void FramePipeline::setLaserOff(const image::ImageView& frame, const image::Roi& roi, bool brightAmbient) {
  (void)finish();
  std::lock_guard<std::mutex> lock(mu_);
  laserOff_ = keepRoi(frame, roi, laserOffBuffer_);
  brightAmbient_ = brightAmbient;
}

void FramePipeline::setSecondLaserOff(const image::ImageView& frame, const image::Roi& roi) {
  (void)finish();
  std::lock_guard<std::mutex> lock(mu_);
  secondLaserOff_ = keepRoi(frame, roi, secondLaserOffBuffer_);
}

void FramePipeline::clearLaserOff() {
  (void)finish();
  std::lock_guard<std::mutex> lock(mu_);
  laserOff_.reset();
  secondLaserOff_.reset();
  brightAmbient_ = false;
  laserOffBuffer_.dropPages();
  secondLaserOffBuffer_.dropPages();
}

bool FramePipeline::hasLaserOff() const {
  std::lock_guard<std::mutex> lock(mu_);
  return laserOff_.has_value();
}

void FramePipeline::push(const image::ImageView& frame, double slideMm, double slideMmPerRow, Exposure exposure) {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [&] { return !bufferBusy_[0] || !bufferBusy_[1]; });
  const size_t b = bufferBusy_[0] ? 1 : 0;
  const size_t bytes = frame.strideBytes * static_cast<size_t>(frame.height);
  if (buffers_[b].bytes() != bytes) buffers_[b].reset(bytes);  // once per frame size
  shape_ = frame;
  // Only the ROI rows and columns are read by the LLE: copy those.
  copyRoi(frame, plan_.roi, buffers_[b].data());
  bufferBusy_[b] = true;
  lastBuffer_ = b;
  queue_.push_back({b, slideMm, slideMmPerRow, exposure});
  ++inFlight_;
  cv_.notify_all();
}

std::vector<localize::LineObservation> FramePipeline::finish() {
  std::unique_lock<std::mutex> lock(mu_);
  cv_.wait(lock, [&] { return inFlight_ == 0; });
  return results_;
}

image::ImageView FramePipeline::lastFrame() const {
  std::lock_guard<std::mutex> lock(mu_);
  image::ImageView v = shape_;
  v.data = buffers_[lastBuffer_].data();
  return v;
}

void FramePipeline::run() {
  while (true) {
    Task task;
    image::ImageView view;
    std::optional<image::ImageView> laserOff;
    bool bright = false;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [&] { return quit_ || !queue_.empty(); });
      if (quit_ && queue_.empty()) return;
      task = queue_.front();
      queue_.pop_front();
      view = shape_;
      view.data = buffers_[task.buffer].data();
      laserOff = task.exposure == Exposure::kFirst ? laserOff_ : secondLaserOff_;
      bright = brightAmbient_;
    }
    // The localizer, plan and laser-off frames only change in begin() and setLaserOff()
    // (and setSecondLaserOff), which first wait for this work.
    Result<localize::LineObservation> obs = localizer_->observe(
        view, plan_, task.slideMm, ws_, laserOff ? &*laserOff : nullptr, task.slideMmPerRow, bright);
    std::lock_guard<std::mutex> lock(mu_);
    // A stop's second exposure joins its first frame's observation, the last one (frames
    // are processed in push order), when that was taken at the same place.
    const bool merge = obs && task.exposure == Exposure::kSecondMerged && !results_.empty() &&
                       std::abs(results_.back().slideMm - task.slideMm) <= 0.05;
    if (merge) {
      const size_t joined = localize::Localizer::mergeSecondExposure(results_.back(), *obs);
      ALACS_LOG_DEBUG("scan", "frame at %.2f mm, second exposure: %zu points joined", task.slideMm, joined);
    } else if (obs) {
      ALACS_LOG_DEBUG("scan", "frame at %.2f mm: %zu rows, %zu points", task.slideMm, obs->line.rows.size(),
                      obs->pointsMm.size());
      results_.push_back(std::move(*obs));
    } else {
      ALACS_LOG_WARN("scan", "frame at %.2f mm: %s", task.slideMm, obs.status().toString().c_str());
    }
    bufferBusy_[task.buffer] = false;
    --inFlight_;
    cv_.notify_all();
  }
}

}  // namespace alacs::app
