// Image work of a scan, overlapped with the motion: the scan worker hands each frame over
// and moves on to the next stop while this thread runs LLE and triangulation on it.
// Bounded: two frame buffers (mapped once per frame size); the plan's ROI is the only
// part copied, so a hand-over costs a fraction of one frame copy, and only the ROI's pages
// of a buffer are ever resident (begin() returns the previous scan's to the system, so
// windows all over the frame never add up to whole frames). push() blocks while both
// buffers are being processed. Thread-safe for one producer.
#pragma once

#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "localize/localizer.h"

namespace alacs::app {

class FramePipeline {
 public:
  // How a frame joins the scan's observations (MeteringParams::secondExposureFactor).
  enum class Exposure {
    kFirst,  // a stop's frame: setLaserOff()'s frame subtracted
    // The same stop's second exposure, at the same position: setSecondLaserOff()'s frame
    // subtracted, its rows joined to the previous frame's where that has none
    // (Localizer::mergeSecondExposure); a line of its own when the previous frame was
    // taken elsewhere or failed.
    kSecondMerged,
    // A second exposure at a position of its own (a sweep's): setSecondLaserOff()'s frame
    // subtracted, a line of its own.
    kSecondLine,
  };

  FramePipeline();
  ~FramePipeline();
  FramePipeline(const FramePipeline&) = delete;
  FramePipeline& operator=(const FramePipeline&) = delete;

  // Starts a scan with this localizer and plan; forgets the previous scan's results.
  void begin(const localize::Localizer& localizer, const localize::ScanPlan& plan);
  // The laser-off frame every following frame's LLE subtracts (its `roi` copied: the
  // caller may reuse its buffer at once), until clearLaserOff(); kept across begin(), since
  // the camera is fixed and one ambient frame serves every stop of both passes. Waits for
  // the frames already queued (they keep the previous setting). `brightAmbient`: the
  // metering found direct sun (Localizer::observe's matched filter for the rows LLE leaves).
  void setLaserOff(const image::ImageView& frame, const image::Roi& roi, bool brightAmbient = false);
  // The laser-off frame at the stops' second exposure (its `roi` copied), subtracted from
  // the frames pushed as a second exposure; until clearLaserOff().
  void setSecondLaserOff(const image::ImageView& frame, const image::Roi& roi);
  // Forgets both laser-off frames.
  void clearLaserOff();
  bool hasLaserOff() const;
  // Queues `frame` (copied: the caller may reuse its buffer at once), taken at `slideMm`
  // (with a rolling shutter in a sweep: for the ROI's middle row, moving `slideMmPerRow`
  // a row; Localizer::observe).
  void push(const image::ImageView& frame, double slideMm, double slideMmPerRow = 0.0,
            Exposure exposure = Exposure::kFirst);
  // Waits until every queued frame is processed; the observations in push order (frames
  // whose LLE failed are logged and left out).
  std::vector<localize::LineObservation> finish();
  // The last frame pushed (its ROI is valid), for the debug overlay. Valid until begin().
  image::ImageView lastFrame() const;

 private:
  struct Task {
    size_t buffer;
    double slideMm;
    double slideMmPerRow;
    Exposure exposure;
  };
  void run();

  std::thread thread_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  bool quit_ = false;
  std::deque<Task> queue_;
  size_t inFlight_ = 0;
  // Anonymous mappings, not heap blocks: untouched pages are never resident, so a 5 MP
  // frame buffer costs the window's pages in resident memory, not 15 MB (a heap block
  // could reuse pages another frame has already made resident).
  class Mapping {
   public:
    Mapping() = default;
    ~Mapping() { reset(0); }
    Mapping(const Mapping&) = delete;
    Mapping& operator=(const Mapping&) = delete;
    void reset(size_t bytes);  // unmaps, then maps `bytes` (none for 0); throws std::bad_alloc
    void dropPages();          // returns the written pages to the system (they read as zero)
    uint8_t* data() const { return data_; }
    size_t bytes() const { return bytes_; }

   private:
    uint8_t* data_ = nullptr;
    size_t bytes_ = 0;
  };
  Mapping buffers_[2];
  Mapping laserOffBuffer_;
  std::optional<image::ImageView> laserOff_;  // a view of laserOffBuffer_ when set
  Mapping secondLaserOffBuffer_;
  std::optional<image::ImageView> secondLaserOff_;  // a view of secondLaserOffBuffer_ when set
  bool brightAmbient_ = false;                // with laserOff_ (setLaserOff)
  bool bufferBusy_[2] = {false, false};
  size_t lastBuffer_ = 0;
  image::ImageView shape_;  // size and format of the frames of this scan
  std::optional<localize::Localizer> localizer_;
  localize::ScanPlan plan_;
  std::vector<localize::LineObservation> results_;
  image::LleWorkspace ws_;
};

}  // namespace alacs::app
