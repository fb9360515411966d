// Image work of a scan, overlapped with the motion: the scan worker hands each frame over
// and moves on to the next stop while this thread runs LLE and triangulation on it.
// Bounded: two frame buffers (allocated once per frame size); the plan's ROI is the only
// part copied, so a hand-over costs a fraction of one frame copy. push() blocks while
// both buffers are being processed. Thread-safe for one producer.
#pragma once

#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "localize/localizer.h"

namespace alacs::app {

class FramePipeline {
 public:
  FramePipeline();
  ~FramePipeline();
  FramePipeline(const FramePipeline&) = delete;
  FramePipeline& operator=(const FramePipeline&) = delete;

  // Starts a scan with this localizer and plan; forgets the previous scan's results.
  void begin(const localize::Localizer& localizer, const localize::ScanPlan& plan);
  // Queues `frame` (copied: the caller may reuse its buffer at once), taken at `slideMm`.
  void push(const image::ImageView& frame, double slideMm);
  // Waits until every queued frame is processed; the observations in push order (frames
  // whose LLE failed are logged and left out).
  std::vector<localize::LineObservation> finish();
  // The last frame pushed (its ROI is valid), for the debug overlay. Valid until begin().
  image::ImageView lastFrame() const;

 private:
  struct Task {
    size_t buffer;
    double slideMm;
  };
  void run();

  std::thread thread_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool quit_ = false;
  std::deque<Task> queue_;
  size_t inFlight_ = 0;
  // Left uninitialised on purpose: only the window's pages are ever written, so a 5 MP
  // frame buffer costs the window's size in resident memory, not 15 MB.
  std::unique_ptr<uint8_t[]> buffers_[2];
  size_t bufferBytes_[2] = {0, 0};
  bool bufferBusy_[2] = {false, false};
  size_t lastBuffer_ = 0;
  image::ImageView shape_;  // size and format of the frames of this scan
  std::optional<localize::Localizer> localizer_;
  localize::ScanPlan plan_;
  std::vector<localize::LineObservation> results_;
  image::LleWorkspace ws_;
};

}  // namespace alacs::app
