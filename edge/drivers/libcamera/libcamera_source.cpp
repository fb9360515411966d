#include "drivers/libcamera/libcamera_source.h"

#include <libcamera/libcamera.h>
#include <sys/mman.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstring>
#include <memory>
#include <mutex>
#include <vector>

namespace alacs::drivers {
namespace {

class Impl final : public LibcameraSource {
 public:
  ~Impl() override {
    if (camera_) {
      camera_->stop();
      camera_->requestCompleted.disconnect(this);
      camera_->release();
    }
    for (auto& m : maps_) munmap(m.first, m.second);
    requests_.clear();
    allocator_.reset();
    camera_.reset();
    if (manager_) manager_->stop();
  }

  Status init(const LibcameraConfig& cfg) {
    cfg_ = cfg;
    manager_ = std::make_unique<libcamera::CameraManager>();
    if (manager_->start() != 0) return {Error::kIo, "libcamera CameraManager failed to start"};
    auto cams = manager_->cameras();
    if (cams.empty()) return {Error::kNotFound, "libcamera sees no camera"};
    camera_ = cfg.cameraId.empty() ? cams.front() : manager_->get(cfg.cameraId);
    if (!camera_) return {Error::kNotFound, "no camera with id '" + cfg.cameraId + "'"};
    if (camera_->acquire() != 0) return {Error::kBusy, "camera is in use by another process"};
    config_ = camera_->generateConfiguration({libcamera::StreamRole::StillCapture});
    if (!config_) return {Error::kIo, "camera cannot produce a still stream"};
    libcamera::StreamConfiguration& sc = config_->at(0);
    sc.pixelFormat = libcamera::formats::RGB888;  // memory order B, G, R (DRM naming)
    sc.size = {static_cast<unsigned>(cfg.widthPx), static_cast<unsigned>(cfg.heightPx)};
    sc.bufferCount = 2;
    if (config_->validate() == libcamera::CameraConfiguration::Invalid) return {Error::kIo, "camera configuration invalid"};
    if (sc.pixelFormat != libcamera::formats::RGB888) return {Error::kUnsupported, "camera cannot deliver RGB888"};
    if (camera_->configure(config_.get()) != 0) return {Error::kIo, "camera configure failed"};
    stream_ = sc.stream();
    allocator_ = std::make_unique<libcamera::FrameBufferAllocator>(camera_);
    if (allocator_->allocate(stream_) < 0) return {Error::kIo, "frame buffer allocation failed"};
    for (const auto& buffer : allocator_->buffers(stream_)) {
      const auto& plane = buffer->planes()[0];
      void* p = mmap(nullptr, plane.length, PROT_READ, MAP_SHARED, plane.fd.get(), static_cast<off_t>(plane.offset));
      if (p == MAP_FAILED) return {Error::kIo, "mmap of a frame buffer failed"};
      maps_.emplace_back(p, plane.length);
      std::unique_ptr<libcamera::Request> req = camera_->createRequest();
      if (!req || req->addBuffer(stream_, buffer.get()) != 0) return {Error::kIo, "cannot create a capture request"};
      requests_.push_back(std::move(req));
    }
    camera_->requestCompleted.connect(this, &Impl::onComplete);
    if (camera_->start() != 0) return {Error::kIo, "camera start failed"};
    stride_ = sc.stride;
    width_ = static_cast<int>(sc.size.width);
    height_ = static_cast<int>(sc.size.height);
    // Left uninitialised (new[] without a value): only the rows of each request's window
    // are written, so only their pages become resident (docs/daemon.md, "Memory").
    copySize_ = static_cast<size_t>(stride_) * static_cast<size_t>(height_);
    copy_.reset(new uint8_t[copySize_]);
    return Status::ok();
  }

  const char* name() const override { return "libcamera"; }

 private:
  void onComplete(libcamera::Request* request) {
    std::lock_guard<std::mutex> lock(mu_);
    completed_ = request;
    cv_.notify_all();
  }

  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r,
                                         const std::function<void()>& onExposureEnd) override {
    Status last(Error::kTimeout, "no attempt");
    for (int attempt = 0; attempt <= cfg_.retries; ++attempt) {
      libcamera::Request* req = requests_[next_ % requests_.size()].get();
      ++next_;
      req->reuse(libcamera::Request::ReuseBuffers);
      req->controls().set(libcamera::controls::AeEnable, false);
      req->controls().set(libcamera::controls::ExposureTime, static_cast<int32_t>(r.exposureUs));
      {
        std::lock_guard<std::mutex> lock(mu_);
        completed_ = nullptr;
      }
      if (camera_->queueRequest(req) != 0) {
        last = Status(Error::kIo, "queueRequest failed");
        continue;
      }
      std::unique_lock<std::mutex> lock(mu_);
      const bool done = cv_.wait_for(lock, std::chrono::milliseconds(r.timeoutMs), [&] { return completed_ == req; });
      if (onExposureEnd) onExposureEnd();
      if (!done) {
        last = Status(Error::kTimeout, "camera frame timed out after " + std::to_string(r.timeoutMs) + " ms");
        continue;
      }
      if (req->status() != libcamera::Request::RequestComplete) {
        last = Status(Error::kBadInput, "camera request was cancelled (dropped frame)");
        continue;
      }
      const libcamera::FrameBuffer* fb = req->buffers().begin()->second;
      const auto& meta = fb->metadata();
      if (meta.status != libcamera::FrameMetadata::FrameSuccess || meta.planes().empty() ||
          meta.planes()[0].bytesused < copySize_) {
        last = Status(Error::kBadInput, "camera delivered a corrupted or short frame");
        continue;
      }
      const size_t index = (next_ - 1) % requests_.size();
      // Copy only the rows of the requested window (a 5 MP frame is 15 MB; a target's
      // window a few hundred kB).
      const auto* src = static_cast<const uint8_t*>(maps_[index].first);
      const int y0 = r.window.empty() ? 0 : std::clamp(r.window.y, 0, height_);
      const int y1 = r.window.empty() ? height_ : std::clamp(r.window.y + r.window.height, y0, height_);
      std::memcpy(copy_.get() + static_cast<size_t>(y0) * stride_, src + static_cast<size_t>(y0) * stride_,
                  static_cast<size_t>(y1 - y0) * stride_);
      ports::CapturedFrame out;
      out.view = {copy_.get(), width_, height_, stride_, image::PixelFormat::kBgr888};
      out.info.sequence = meta.sequence;
      out.info.exposureStartNs = static_cast<TimeNs>(meta.timestamp);
      out.info.exposureUs = r.exposureUs;
      return out;
    }
    return last;
  }

  LibcameraConfig cfg_;
  std::unique_ptr<libcamera::CameraManager> manager_;
  std::shared_ptr<libcamera::Camera> camera_;
  std::unique_ptr<libcamera::CameraConfiguration> config_;
  libcamera::Stream* stream_ = nullptr;
  std::unique_ptr<libcamera::FrameBufferAllocator> allocator_;
  std::vector<std::unique_ptr<libcamera::Request>> requests_;
  std::vector<std::pair<void*, size_t>> maps_;
  std::unique_ptr<uint8_t[]> copy_;
  size_t copySize_ = 0;
  size_t stride_ = 0;
  int width_ = 0;
  int height_ = 0;
  size_t next_ = 0;
  std::mutex mu_;
  std::condition_variable cv_;
  libcamera::Request* completed_ = nullptr;
};

}  // namespace

Result<std::unique_ptr<LibcameraSource>> LibcameraSource::open(const LibcameraConfig& config) {
  auto impl = std::make_unique<Impl>();
  if (Status s = impl->init(config); !s) return s;
  return std::unique_ptr<LibcameraSource>(std::move(impl));
}

Result<int> LibcameraSource::countCameras() {
  libcamera::CameraManager manager;
  if (manager.start() != 0) return Status(Error::kIo, "libcamera CameraManager failed to start");
  const int n = static_cast<int>(manager.cameras().size());
  manager.stop();
  return n;
}

}  // namespace alacs::drivers
