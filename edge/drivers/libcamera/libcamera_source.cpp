#include "drivers/libcamera/libcamera_source.h"

#include <dirent.h>
#include <libcamera/libcamera.h>
#include <libcamera/version.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <string_view>
#include <utility>
#include <vector>

#include "common/frame_clock.h"

// libcamera 0.5 replaced AeEnable with per-quantity modes (ExposureTimeMode,
// AnalogueGainMode); 0.0.x-0.4 only have AeEnable.
#if LIBCAMERA_VERSION_MAJOR > 0 || LIBCAMERA_VERSION_MINOR >= 5
#define ALACS_LIBCAMERA_HAS_EXPOSURE_MODE 1
#else
#define ALACS_LIBCAMERA_HAS_EXPOSURE_MODE 0
#endif

namespace alacs::drivers {
namespace {

namespace lc = libcamera;

// The sensor timestamps' base: V4L2 (and so libcamera) stamps frames with CLOCK_MONOTONIC.
TimeNs monotonicNowNs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<TimeNs>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// A frame whose applied exposure (metadata) differs from the one asked for by more than
// this or 5 % is one of the frames queued before the change, not this capture's.
constexpr int64_t kExposureToleranceUs = 50;
// Likewise for the analogue gain, as a share of the one asked for (a sensor's gain steps
// are coarse: 1/16 dB to a few %).
constexpr double kGainTolerance = 0.05;
// After a timeout, how long to wait for libcamera to report the camera removed.
constexpr int kRemovalWaitMs = 300;

// True when a V4L2 or media-controller node this process holds open has been deleted
// (its device unplugged or its driver unbound): /proc/self/fd shows it "(deleted)".
// libcamera 0.0.3 does not always report such a removal (cameraRemoved), and stopping a
// camera whose device is gone aborts the process there; this is the check that does
// not depend on it. The product has one camera, so any such node is the camera's.
bool videoNodeVanished() {
  DIR* dir = opendir("/proc/self/fd");
  if (dir == nullptr) return false;
  bool vanished = false;
  char target[256];
  while (const dirent* e = readdir(dir)) {
    const std::string link = std::string("/proc/self/fd/") + e->d_name;
    const ssize_t n = readlink(link.c_str(), target, sizeof(target) - 1);
    if (n <= 0) continue;
    const std::string_view t(target, static_cast<size_t>(n));
    const bool v4l =
        t.rfind("/dev/video", 0) == 0 || t.rfind("/dev/media", 0) == 0 || t.rfind("/dev/v4l-subdev", 0) == 0;
    if (v4l && t.size() > 10 && t.substr(t.size() - 10) == " (deleted)") vanished = true;
  }
  closedir(dir);
  return vanished;
}

bool advertises(const lc::Camera& camera, const lc::ControlId& id) {
  return camera.controls().find(&id) != camera.controls().end();
}

// What a camera offers for a stream role, for the refusal message.
std::string describeOffer(const lc::StreamConfiguration& sc) {
  std::ostringstream out;
  bool first = true;
  for (const lc::PixelFormat& f : sc.formats().pixelformats()) {
    const lc::SizeRange range = sc.formats().range(f);
    out << (first ? "" : ", ") << f.toString() << " " << range.min.toString() << ".." << range.max.toString();
    first = false;
  }
  return first ? std::string("nothing") : out.str();
}

class Impl final : public LibcameraSource {
 public:
  ~Impl() override {
    close();
    if (manager_) {
      manager_->cameraRemoved.disconnect(this);
      manager_->stop();
    }
  }

  Status init(const LibcameraConfig& cfg) {
    cfg_ = cfg;
    FrameClockParams clock;
    clock.maxJitterNs = cfg.frameClockJitterNs;
    // Its buffers go back to the camera as each capture drains them: with three or more
    // the clock sees runs of consecutive frames, and a model with most slots empty is a
    // grid finer than the frames (FrameClockParams::seesRunsOfFrames).
    clock.seesRunsOfFrames = cfg.bufferCount >= 3;
    frameClock_ = FrameClock(clock);
    if (cfg.widthPx <= 0 || cfg.heightPx <= 0 || cfg.bufferCount < 1)
      return {Error::kInvalidArgument, "camera size and buffer count must be positive"};
    manager_ = std::make_unique<lc::CameraManager>();
    if (manager_->start() != 0) return {Error::kIo, "libcamera CameraManager failed to start"};
    manager_->cameraRemoved.connect(this, &Impl::onCameraRemoved);
    return openCamera();
  }

  const char* name() const override { return "libcamera"; }

  LibcameraStats stats() const override {
    std::lock_guard<std::mutex> lock(mu_);
    return stats_;
  }

 private:
  // Acquires, configures and starts the camera; allocates every buffer and request.
  Status openCamera() {
    const std::vector<std::shared_ptr<lc::Camera>> cams = manager_->cameras();
    if (cams.empty()) return {Error::kNotFound, "libcamera sees no camera"};
    const std::string wanted = cfg_.cameraId.empty() ? openedId_ : cfg_.cameraId;
    camera_ = wanted.empty() ? cams.front() : manager_->get(wanted);
    if (!camera_)
      return {Error::kNotFound,
              "no camera with id '" + wanted + "' (libcamera sees " + std::to_string(cams.size()) + ")"};
    if (camera_->acquire() != 0) {
      camera_.reset();
      return {Error::kBusy, "camera is in use by another process"};
    }
    acquired_ = true;
    {
      std::lock_guard<std::mutex> lock(mu_);
      openedId_ = camera_->id();
      removed_ = false;
    }
    config_ = camera_->generateConfiguration({lc::StreamRole::StillCapture});
    if (!config_ || config_->empty()) return {Error::kIo, "camera cannot produce a still stream"};
    lc::StreamConfiguration& sc = config_->at(0);
    const lc::Size want{static_cast<unsigned>(cfg_.widthPx), static_cast<unsigned>(cfg_.heightPx)};
    // RGB888 is memory B, G, R (DRM naming), BGR888 memory R, G, B; the LLE reads both.
    const std::string offer = describeOffer(sc);
    bool configured = false;
    for (const lc::PixelFormat f : {lc::formats::RGB888, lc::formats::BGR888}) {
      sc.pixelFormat = f;
      sc.size = want;
      sc.bufferCount = static_cast<unsigned>(cfg_.bufferCount);
      if (config_->validate() != lc::CameraConfiguration::Invalid && sc.pixelFormat == f && sc.size == want) {
        configured = true;
        break;
      }
    }
    if (!configured)
      return {Error::kUnsupported, "camera " + openedId_ + " cannot give RGB888 or BGR888 at " + want.toString() +
                                       " (it offers " + offer + ")"};
    format_ = sc.pixelFormat == lc::formats::RGB888 ? image::PixelFormat::kBgr888 : image::PixelFormat::kRgb888;
    if (camera_->configure(config_.get()) != 0) return {Error::kIo, "camera configure failed"};
    stream_ = sc.stream();
    allocator_ = std::make_unique<lc::FrameBufferAllocator>(camera_);
    if (allocator_->allocate(stream_) < 0) return {Error::kIo, "frame buffer allocation failed"};
    for (const std::unique_ptr<lc::FrameBuffer>& buffer : allocator_->buffers(stream_)) {
      const lc::FrameBuffer::Plane& plane = buffer->planes()[0];
      void* p = mmap(nullptr, plane.length, PROT_READ, MAP_SHARED, plane.fd.get(), static_cast<off_t>(plane.offset));
      if (p == MAP_FAILED) return {Error::kIo, "mmap of a frame buffer failed"};
      maps_.emplace_back(p, plane.length);
      std::unique_ptr<lc::Request> req = camera_->createRequest(maps_.size() - 1);
      if (!req || req->addBuffer(stream_, buffer.get()) != 0) return {Error::kIo, "cannot create a capture request"};
      requests_.push_back(std::move(req));
    }
    stride_ = sc.stride;
    width_ = static_cast<int>(sc.size.width);
    height_ = static_cast<int>(sc.size.height);
    const size_t size = static_cast<size_t>(stride_) * static_cast<size_t>(height_);
    // Left uninitialised (new[] without a value): only the rows of each request's window
    // are written, so only their pages become resident (docs/daemon.md, "Memory"). Kept
    // across a reopen of the same geometry.
    if (size != copySize_) {
      copySize_ = size;
      copy_.reset(new uint8_t[copySize_]);
    }
    exposureControl_ = advertises(*camera_, lc::controls::ExposureTime);
    gainControl_ = advertises(*camera_, lc::controls::AnalogueGain);
    gainMin_ = gainMax_ = 0.0;
    if (gainControl_) {
      const lc::ControlInfo& range = camera_->controls().find(&lc::controls::AnalogueGain)->second;
      if (range.min().type() == lc::ControlTypeFloat && range.max().type() == lc::ControlTypeFloat) {
        gainMin_ = static_cast<double>(range.min().get<float>());
        gainMax_ = static_cast<double>(range.max().get<float>());
      }
    }
    camera_->requestCompleted.connect(this, &Impl::onComplete);
    if (Status s = startStreaming(); !s) return s;
    std::lock_guard<std::mutex> lock(mu_);
    stats_.cameraId = openedId_;
    stats_.pixelFormat = sc.pixelFormat.toString();
    stats_.widthPx = width_;
    stats_.heightPx = height_;
    stats_.strideBytes = static_cast<int>(stride_);
    stats_.buffers = static_cast<int>(requests_.size());
    stats_.exposureControl = exposureControl_;
    stats_.gainControl = gainControl_;
    stats_.frameDurationControl = advertises(*camera_, lc::controls::FrameDurationLimits);
    stats_.frameDurationAskedUs = stats_.frameDurationControl ? cfg_.frameDurationNs / kNsPerUs : 0;
    return Status::ok();
  }

  // Undoes openCamera(), whatever state it reached. The copy buffer stays.
  void close() {
    if (camera_) {
      if (started_) camera_->stop();
      camera_->requestCompleted.disconnect(this);
    }
    started_ = false;
    for (auto& m : maps_) munmap(m.first, m.second);
    maps_.clear();
    requests_.clear();
    allocator_.reset();
    config_.reset();
    if (camera_ && acquired_) camera_->release();
    acquired_ = false;
    camera_.reset();
    stream_ = nullptr;
    std::lock_guard<std::mutex> lock(mu_);
    doneHead_ = doneCount_ = 0;
  }

  // Starts the camera with every request queued. The stream is kept fed: V4L2 drivers
  // start streaming only with enough buffers queued (vimc: 2), so one request at a time
  // would never see a frame. Frames that began before a capture was asked for are
  // dropped and their requests queued again (capture()).
  Status startStreaming() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      done_.assign(requests_.size(), nullptr);
      doneHead_ = doneCount_ = 0;
    }
    // The frame duration, asked once for the stream (min = max): a Raspberry Pi pipeline
    // holds it from start() on; a camera without the control keeps its own rate.
    const bool askDuration = cfg_.frameDurationNs > 0 && advertises(*camera_, lc::controls::FrameDurationLimits);
    lc::ControlList startControls(lc::controls::controls);
    if (askDuration) {
      const int64_t us = cfg_.frameDurationNs / kNsPerUs;
      startControls.set(lc::controls::FrameDurationLimits, {us, us});
    }
    if (camera_->start(askDuration ? &startControls : nullptr) != 0) return {Error::kIo, "camera start failed"};
    started_ = true;
    for (const std::unique_ptr<lc::Request>& req : requests_)
      if (Status s = requeue(req.get(), nullptr); !s) return s;
    return Status::ok();
  }

  // `r`: the capture whose exposure and gain the request carries; null: none set.
  Status requeue(lc::Request* req, const ports::CaptureRequest* r) {
    req->reuse(lc::Request::ReuseBuffers);
    if (r != nullptr && r->exposureUs > 0) setControls(*req, *r);
    if (camera_->queueRequest(req) != 0) return {Error::kIo, "queueRequest failed (camera gone?)"};
    return Status::ok();
  }

  // libcamera's thread. done_ has room for every request: reserved at open.
  void onComplete(lc::Request* request) {
    std::lock_guard<std::mutex> lock(mu_);
    if (request->status() == lc::Request::RequestCancelled) ++stats_.requestsCancelled;
    if (doneCount_ == done_.size()) return;  // a request completed twice: cannot happen
    done_[(doneHead_ + doneCount_++) % done_.size()] = request;
    cv_.notify_all();
  }

  void doInterrupt() override {
    std::lock_guard<std::mutex> lock(mu_);
    interrupted_ = true;
    cv_.notify_all();
  }
  bool lost() const override {
    std::lock_guard<std::mutex> lock(mu_);
    return stats_.lost;
  }
  void doResume() override {
    std::lock_guard<std::mutex> lock(mu_);
    interrupted_ = false;
  }

  // The analogue gain a request carries to the camera (0: none, the camera's own). One
  // asked for, clamped to the range the camera advertises (a sensor's least may be above
  // 1); none asked for, once a gain was set: the camera's own gain as it reported it before
  // (libcamera keeps a control once set, so a gain lowered for a sunlit scan would stay
  // for the next scan's metering otherwise).
  double gainFor(const ports::CaptureRequest& r) const {
    if (!exposureControl_ || !gainControl_) return 0.0;
    double g = r.analogueGain > 0.0 ? r.analogueGain : (gainSet_ ? ownGain_ : 0.0);
    if (g > 0.0 && gainMin_ > 0.0 && gainMax_ > gainMin_) g = std::clamp(g, gainMin_, gainMax_);
    return g;
  }

  // The capture's exposure, and its analogue gain (gainFor). A camera without the control
  // keeps its own: FrameInfo reports a gain only where the camera has the control.
  void setControls(lc::Request& req, const ports::CaptureRequest& r) {
    if (!exposureControl_) return;
    lc::ControlList& c = req.controls();
    const double gain = gainFor(r);
#if ALACS_LIBCAMERA_HAS_EXPOSURE_MODE
    if (advertises(*camera_, lc::controls::ExposureTimeMode))
      c.set(lc::controls::ExposureTimeMode, lc::controls::ExposureTimeModeManual);
    if (advertises(*camera_, lc::controls::AnalogueGainMode) && (gain > 0.0 || gainSet_))
      c.set(lc::controls::AnalogueGainMode,
            gain > 0.0 ? lc::controls::AnalogueGainModeManual : lc::controls::AnalogueGainModeAuto);
#else
    if (advertises(*camera_, lc::controls::AeEnable)) c.set(lc::controls::AeEnable, false);
#endif
    c.set(lc::controls::ExposureTime, static_cast<int32_t>(r.exposureUs));
    if (gain > 0.0) {
      c.set(lc::controls::AnalogueGain, static_cast<float>(gain));
      gainSet_ = true;
    }
  }

  // The next completed request; or kTimeout at `deadlineNs`, or kFault when interrupted,
  // after `beforeRecovery` (the laser off) and the camera's recovery: stop and start again
  // (interrupted: stop() completes every queued request, cancelled, before it returns),
  // or after a timeout, stop and reopen at the next capture.
  Result<lc::Request*> nextCompleted(TimeNs deadlineNs, int64_t timeoutMs,
                                     const std::function<void()>& beforeRecovery) {
    std::unique_lock<std::mutex> lock(mu_);
    const auto left = std::chrono::nanoseconds(std::max<TimeNs>(deadlineNs - monotonicNowNs(), 0));
    cv_.wait_for(lock, left, [&] { return doneCount_ > 0 || interrupted_; });
    if (interrupted_) {
      ++stats_.interrupted;
      lock.unlock();
      beforeRecovery();
      camera_->stop();
      started_ = false;
      if (!startStreaming()) needReopen_ = true;
      return Status(Error::kFault, "capture interrupted (STOP)");
    }
    if (doneCount_ == 0) {
      ++stats_.timeouts;
      lock.unlock();
      beforeRecovery();
      stopAfterTimeout();
      return Status(Error::kTimeout, "camera frame timed out after " + std::to_string(timeoutMs) + " ms");
    }
    lc::Request* req = done_[doneHead_];
    doneHead_ = (doneHead_ + 1) % done_.size();
    --doneCount_;
    return req;
  }

  // A camera that stopped answering may be slow, or gone (unplugged, its driver unbound).
  // libcamera 0.0.3 aborts the process (an assertion in PipelineHandler::stop) when a
  // vanished camera is stopped before libcamera has seen it removed; once it has,
  // Camera::stop() returns at once. So: wait for udev's word on the removal first.
  void stopAfterTimeout() {
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait_for(lock, std::chrono::milliseconds(kRemovalWaitMs), [&] { return removed_; });
    }
    if (removed_ || videoNodeVanished()) {
      {
        std::lock_guard<std::mutex> lock(mu_);
        stats_.lost = true;
      }
      // Requests the pipeline still holds must outlive it: keep them (and the buffers they
      // point to) until the process ends, rather than free memory libcamera may touch.
      parked_.push_back({std::move(camera_), std::move(allocator_), std::move(requests_)});
      for (auto& m : maps_) munmap(m.first, m.second);
      maps_.clear();
      config_.reset();
      acquired_ = started_ = false;
      stream_ = nullptr;
    } else {
      camera_->stop();
      started_ = false;
    }
    needReopen_ = true;
  }

  void onCameraRemoved(std::shared_ptr<lc::Camera> camera) {
    std::lock_guard<std::mutex> lock(mu_);
    if (camera && camera->id() == openedId_) {
      removed_ = true;
      cv_.notify_all();
    }
  }

  // The laser as one capture switches it: when it went on and off (0 while on), and the
  // promise that it is left off.
  struct LaserWindow {
    const ports::ExposureHooks& hooks;
    bool on = false;
    bool ended = false;
    TimeNs onNs = 0;
    TimeNs offNs = 0;
    Status begin() {
      if (Status s = hooks.beginNow(); !s) return s;
      on = true;
      onNs = monotonicNowNs();
      offNs = 0;
      return Status::ok();
    }
    void end() {
      // The time first: the line goes low somewhere inside the call (through the laser
      // guard), so a frame is counted lit only up to when it was asked off.
      if (on) offNs = monotonicNowNs();
      if (on || !ended) hooks.endNow();
      on = false;
      ended = true;
    }
    ~LaserWindow() { end(); }
  };

  // The request's window's rows [y0, y1), clamped to the frame (all of it when empty).
  std::pair<int, int> windowRows(const ports::CaptureRequest& r) const {
    const int y0 = r.window.empty() ? 0 : std::clamp(r.window.y, 0, height_);
    return {y0, r.window.empty() ? height_ : std::clamp(r.window.y + r.window.height, y0, height_)};
  }

  // When the request's window exposed in a frame with this timestamp (ExposureSpan: for
  // either meaning of the timestamp and any readout within `periodNs`).
  ExposureSpan spanOf(TimeNs timestampNs, int64_t exposureUs, const ports::CaptureRequest& r, TimeNs periodNs) const {
    const auto [y0, y1] = windowRows(r);
    return exposureSpan(timestampNs, exposureUs * kNsPerUs, y0, y1, cfg_.lineTimeNs, cfg_.globalShutter ? 0 : periodNs,
                        height_);
  }

  // Learns the frame clock from a completed request.
  void learn(lc::Request* req) {
    if (req->status() != lc::Request::RequestComplete) return;
    const lc::FrameMetadata& meta = req->buffers().begin()->second->metadata();
    if (meta.status != lc::FrameMetadata::FrameSuccess) return;
    const std::optional<int64_t> sensorNs = req->metadata().get(lc::controls::SensorTimestamp);
    frameClock_.observe(meta.sequence, sensorNs ? static_cast<TimeNs>(*sensorNs) : static_cast<TimeNs>(meta.timestamp));
    // The camera's own gain, until the daemon first sets one (gainFor restores it).
    if (!gainSet_)
      if (const std::optional<float> g = req->metadata().get(lc::controls::AnalogueGain))
        ownGain_ = static_cast<double>(*g);
    std::lock_guard<std::mutex> lock(mu_);
    stats_.framePeriodNs = frameClock_.periodNs().value_or(0);
    stats_.frameJitterNs = frameClock_.jitterNs();
    stats_.frameClockFinerGrids = frameClock_.finerGridRestarts();
  }

  // Frames completed before this capture: back to the camera at once (so that a buffer is
  // queued for the frame the laser will light), their timestamps taught to the clock.
  Status drainCompleted(const ports::CaptureRequest& r) {
    while (true) {
      lc::Request* req = nullptr;
      {
        std::lock_guard<std::mutex> lock(mu_);
        if (doneCount_ == 0 || interrupted_) return Status::ok();
        req = done_[doneHead_];
        doneHead_ = (doneHead_ + 1) % done_.size();
        --doneCount_;
        ++stats_.staleFramesSkipped;
      }
      learn(req);
      if (Status s = requeue(req, &r); !s) {
        needReopen_ = true;
        return s;
      }
    }
  }

  // Waits until `untilNs`, or a completed request, or interrupt(); false when interrupted.
  bool waitUntil(TimeNs untilNs, bool orCompletion) {
    std::unique_lock<std::mutex> lock(mu_);
    while (!interrupted_ && !(orCompletion && doneCount_ > 0)) {
      const TimeNs left = untilNs - monotonicNowNs();
      if (left <= 0) break;
      cv_.wait_for(lock, std::chrono::nanoseconds(left));
    }
    return !interrupted_;
  }

  // Switches the laser on for the next frame: when the clock is learnt, a lead before the
  // window of the first frame it can still catch starts exposing, with `offAtNs` a lead
  // after the window's end and `periodNs` the period that end was reckoned with; else at
  // once, `offAtNs` 0 (off at the delivery). No frame it can catch before the deadline:
  // the laser stays off (the capture times out). A thread that wakes too late for its
  // frame (a loaded machine, a coarse timer) does not pulse the laser for it. Either miss,
  // that or a frame that came after the laser went off (doCapture), counts in
  // `clockMisses`; after kMaxClockMisses in one capture the capture takes the laser from
  // now on, so that a clock the frames do not keep to costs a capture at most one frame
  // period. (On the bench, trying 3 late wakes cost 60 ms a capture; a clock that missed
  // every frame, unbounded, timed a capture out after 2 s of pulses.)
  static constexpr int kMaxClockMisses = 1;
  Status armLaser(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks, LaserWindow& laser,
                  TimeNs deadlineNs, int& clockMisses, TimeNs& offAtNs, TimeNs& periodNs) {
    offAtNs = 0;
    periodNs = frameClock_.periodNs().value_or(0);
    const TimeNs leadNs = cfg_.laserLeadNs;
    while (cfg_.laserOnFrameClock && hooks.begin && clockMisses < kMaxClockMisses) {
      // A frame whose window starts before now + 2 leads is not caught: one lead to wake,
      // one to switch.
      const TimeNs notBefore = monotonicNowNs() + 2 * leadNs;
      std::optional<TimeNs> next = frameClock_.nextStart(notBefore);
      if (!next) break;
      periodNs = *frameClock_.periodNs();
      while (spanOf(*next, r.exposureUs, r, periodNs).startNs < notBefore) *next += periodNs;
      ExposureSpan span = spanOf(*next, r.exposureUs, r, periodNs);
      if (span.endNs > deadlineNs) return Status::ok();  // nothing to catch in time: no laser
      // Frames that complete meanwhile go back to the camera at once (a buffer must be
      // queued for the frame to catch); the clock they refine says when that frame starts.
      while (monotonicNowNs() < span.startNs - leadNs) {
        if (!waitUntil(span.startNs - leadNs, true)) return Status::ok();  // interrupted: the caller sees it
        if (Status s = drainCompleted(r); !s) return s;
        const std::optional<TimeNs> refined = frameClock_.periodNs();
        next = refined ? frameClock_.nextStart(*next - *refined / 2) : std::nullopt;
        if (!next) break;
        periodNs = *refined;
        span = spanOf(*next, r.exposureUs, r, periodNs);
      }
      if (!next) break;  // the clock was lost meanwhile: from the request
      // Woke too late for this frame (half the lead gone): the next one, the laser not
      // pulsed for nothing.
      const bool late = monotonicNowNs() > span.startNs - leadNs / 2;
      if (!late) {
        if (Status s = laser.begin(); !s) return s;
        if (laser.onNs <= span.startNs) {
          offAtNs = span.endNs + leadNs;
          std::lock_guard<std::mutex> lock(mu_);
          ++stats_.laserOnFrameClock;
          stats_.lastPredictedStartNs = *next;
          return Status::ok();
        }
        laser.end();  // the switch itself took the lead
      }
      ++clockMisses;
      std::lock_guard<std::mutex> lock(mu_);
      ++stats_.frameClockMisses;
    }
    periodNs = frameClock_.periodNs().value_or(0);
    if (Status s = laser.begin(); !s) return s;
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.laserFromRequest;
    stats_.lastPredictedStartNs = 0;
    return Status::ok();
  }

  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& r, const ports::ExposureHooks& hooks) override {
    // Whatever happens, the laser ends off (LaserWindow's destructor).
    LaserWindow laser{hooks};
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (interrupted_) return Status(Error::kFault, "capture interrupted (STOP)");
      stats_.lastExposureRequestedUs = r.exposureUs;
    }
    if (lost()) return Status(Error::kTimeout, "camera " + openedId_ + " is gone (its device was removed)");
    if (needReopen_) {
      close();
      frameClock_.reset();
      if (Status s = openCamera(); !s) {
        close();
        return Status(Error::kTimeout, "camera " + (openedId_.empty() ? std::string("?") : openedId_) +
                                           " stopped answering and cannot be opened again: " + s.reason());
      }
      needReopen_ = false;
      std::lock_guard<std::mutex> lock(mu_);
      ++stats_.reopens;
      stats_.framePeriodNs = 0;  // learnt again from the new stream
      stats_.frameJitterNs = 0;
    }
    if (Status s = drainCompleted(r); !s) return s;
    const TimeNs deadlineNs = monotonicNowNs() + r.timeoutMs * kNsPerMs;
    TimeNs offAtNs = 0;   // when the laser goes off; 0: at the delivery
    TimeNs periodNs = 0;  // the period the laser's window was reckoned with
    bool armed = false;
    int clockMisses = 0;  // this capture's, both kinds (armLaser)
    while (true) {
      if (!armed) {
        if (Status s = armLaser(r, hooks, laser, deadlineNs, clockMisses, offAtNs, periodNs); !s) return s;
        armed = true;
      }
      if (laser.on && offAtNs > 0) {
        if (waitUntil(std::min(offAtNs, deadlineNs), true) && monotonicNowNs() >= offAtNs) laser.end();
      }
      Result<lc::Request*> next = nextCompleted(deadlineNs, r.timeoutMs, [&laser] { laser.end(); });
      if (!next) return next.status();
      lc::Request* req = *next;
      learn(req);
      bool cameLate = false;
      if (std::optional<Result<ports::CapturedFrame>> out = take(req, r, laser, periodNs, cameLate))
        return std::move(*out);
      // Not this capture's frame. One that began under the laser but ended after it went
      // off (later than predicted, or the one predicted was dropped): on again for the
      // next, from the request once the clock has missed kMaxClockMisses. An older one: the
      // frame lit may still come.
      if (cameLate) {
        armed = false;
        ++clockMisses;
      }
    }
  }

  // The capture's frame, or an error; nullopt for a frame that is not the capture's
  // (queued again, unseen).
  std::optional<Result<ports::CapturedFrame>> take(lc::Request* req, const ports::CaptureRequest& r, LaserWindow& laser,
                                                   TimeNs periodNs, bool& cameLate) {
    const lc::FrameBuffer* fb = req->buffers().begin()->second;
    const lc::FrameMetadata& meta = fb->metadata();
    const std::optional<int64_t> sensorNs = req->metadata().get(lc::controls::SensorTimestamp);
    const TimeNs stampNs = sensorNs ? static_cast<TimeNs>(*sensorNs) : static_cast<TimeNs>(meta.timestamp);
    const bool failed = req->status() != lc::Request::RequestComplete ||
                        meta.status != lc::FrameMetadata::FrameSuccess || meta.planes().empty() ||
                        meta.planes()[0].bytesused < copySize_;
    // The requests in flight carry the controls they were queued with: after a change
    // of exposure, the first frames may still have the old one.
    const std::optional<int32_t> appliedUs = req->metadata().get(lc::controls::ExposureTime);
    const int64_t exposureUs = appliedUs ? *appliedUs : r.exposureUs;
    const std::optional<float> appliedGain = req->metadata().get(lc::controls::AnalogueGain);
    const double askedGain = gainFor(r);
    const bool otherExposure = (appliedUs && std::abs(*appliedUs - r.exposureUs) >
                                                 std::max<int64_t>(kExposureToleranceUs, r.exposureUs / 20)) ||
                               (appliedGain && askedGain > 0.0 &&
                                std::abs(static_cast<double>(*appliedGain) - askedGain) > kGainTolerance * askedGain);
    // The laser lit the frame's window from its first row's start to its last row's end.
    const ExposureSpan span = spanOf(stampNs, exposureUs, r, periodNs);
    const bool begunUnder = laser.onNs > 0 && span.startNs >= laser.onNs;
    const bool lit = litBy(span, laser.onNs, laser.on ? 0 : laser.offNs);
    cameLate = begunUnder && !laser.on;
    if (failed || !lit || otherExposure) {
      // A frame of the stream that began before the laser was on, or ended after it went
      // off, or a failed one: its request goes back, with this capture's exposure for the
      // frames to come.
      {
        std::lock_guard<std::mutex> lock(mu_);
        ++(failed ? stats_.failedFrames : stats_.staleFramesSkipped);
        if (!failed && begunUnder && !lit) ++stats_.frameClockMisses;
      }
      if (Status s = requeue(req, &r); !s) {
        needReopen_ = true;
        return Result<ports::CapturedFrame>(s);
      }
      if (failed && begunUnder)
        return Result<ports::CapturedFrame>(Status(Error::kBadInput, "camera delivered a failed or short frame"));
      return std::nullopt;
    }
    laser.end();  // this frame is complete: the laser's work is done before the copy
    const size_t index = req->cookie();
    // Copy only the rows of the requested window (a 5 MP frame is 15 MB; a target's
    // window a few hundred kB).
    const auto* src = static_cast<const uint8_t*>(maps_[index].first);
    const auto [y0, y1] = windowRows(r);
    std::memcpy(copy_.get() + static_cast<size_t>(y0) * stride_, src + static_cast<size_t>(y0) * stride_,
                static_cast<size_t>(y1 - y0) * stride_);
    ports::CapturedFrame out;
    out.view = {copy_.get(), width_, height_, stride_, format_};
    out.info.sequence = meta.sequence;
    out.info.exposureStartNs = stampNs;
    out.info.exposureUs = exposureUs;
    out.info.analogueGain = appliedGain && gainControl_ ? static_cast<double>(*appliedGain) : 0.0;
    if (Status s = requeue(req, &r); !s) needReopen_ = true;  // the frame is copied: still good
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.framesDelivered;
    stats_.sensorTimestamp = sensorNs.has_value();
    stats_.lastExposureAppliedUs = appliedUs ? *appliedUs : -1;
    const std::optional<int64_t> durationUs = req->metadata().get(lc::controls::FrameDuration);
    stats_.frameDurationReportedUs = durationUs ? *durationUs : -1;
    stats_.framePeriodNs = frameClock_.periodNs().value_or(0);
    stats_.frameJitterNs = frameClock_.jitterNs();
    return out;
  }

  LibcameraConfig cfg_;
  std::unique_ptr<lc::CameraManager> manager_;
  std::shared_ptr<lc::Camera> camera_;
  std::string openedId_;
  bool acquired_ = false;
  bool started_ = false;
  bool needReopen_ = false;
  bool exposureControl_ = false;
  bool gainControl_ = false;  // the camera advertises AnalogueGain
  double gainMin_ = 0.0;      // ... over this range (0: not advertised as floats)
  double gainMax_ = 0.0;
  double ownGain_ = 0.0;  // the camera's own gain, reported before the daemon set one (0: not known)
  bool gainSet_ = false;  // the daemon has set a gain (kept by libcamera until changed)
  std::unique_ptr<lc::CameraConfiguration> config_;
  lc::Stream* stream_ = nullptr;
  std::unique_ptr<lc::FrameBufferAllocator> allocator_;
  std::vector<std::unique_ptr<lc::Request>> requests_;
  std::vector<std::pair<void*, size_t>> maps_;
  std::unique_ptr<uint8_t[]> copy_;
  size_t copySize_ = 0;
  size_t stride_ = 0;
  int width_ = 0;
  int height_ = 0;
  image::PixelFormat format_ = image::PixelFormat::kBgr888;
  mutable std::mutex mu_;  // guards what libcamera's thread and interrupt() touch, and stats_
  std::condition_variable cv_;
  // Completed requests not yet looked at, in completion order: a ring with room for every
  // request, sized at open, so that completing a frame allocates nothing.
  std::vector<lc::Request*> done_;
  size_t doneHead_ = 0;
  size_t doneCount_ = 0;
  bool interrupted_ = false;
  bool removed_ = false;  // libcamera reported the open camera removed
  LibcameraStats stats_;
  FrameClock frameClock_;  // the capturing thread's
  struct Parked {
    std::shared_ptr<lc::Camera> camera;
    std::unique_ptr<lc::FrameBufferAllocator> allocator;
    std::vector<std::unique_ptr<lc::Request>> requests;
  };
  std::vector<Parked> parked_;  // cameras that vanished with requests queued (stopAfterTimeout)
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
