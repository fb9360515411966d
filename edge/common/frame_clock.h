// A free-running sensor's frame clock, learnt from its frames' timestamps. libcamera has
// no start-of-frame event and the sensor does not wait for requests: it starts a frame
// every period whatever the application does. So the camera source predicts when the
// next frame will start from the frames it has seen, and switches the laser on just
// before it and off just after the exposure (drivers/libcamera, docs/daemon.md "The
// laser and the frame clock"). Pure logic: it sees timestamps, never a clock.
//
// The model is start(n) = anchor + n * period, fitted by least squares over the last
// kFrames frames, n counted on the clock: from the driver's sequence numbers for the first
// interval, then from the time (drivers differ on whether a frame dropped for want of a
// buffer takes a sequence number; vimc's does not). One frame that does not fit a learnt
// model is held aside (a timestamp taken late); a second in a row (a mode change, a stall)
// starts the learning again from the first of them, a sequence that goes back (a restart)
// from that frame. A model whose slots are mostly empty, where every frame should fill one
// (FrameClockParams::seesRunsOfFrames), starts it again from the last frame, the next
// interval counted as one slot.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "common/clock.h"

namespace alacs {

struct FrameClockParams {
  int minFrames = 4;                    // frames seen before a prediction is made
  TimeNs maxJitterNs = 300 * kNsPerUs;  // a frame further than this from the model is off it
  int maxPeriodsAhead = 16;             // no prediction this far past the last frame seen
  // The clock is shown runs of consecutive frames (a consumer that keeps buffers queued, as
  // the libcamera adapter with its 4), not one frame now and then (the scan worker's clock,
  // one frame a capture). A model on which steps of two slots outnumber steps of one is
  // then a grid finer than the frames (a timer's ticks: vimc on a 100 Hz kernel), whose
  // empty slots the laser would be switched for: it is learnt again from the last frame.
  bool seesRunsOfFrames = false;
};

// When rows [y0Px, y1Px) of a frame exposed, as the laser must cover them, from the frame's
// timestamp. It holds for either meaning of the timestamp (the first row's exposure start,
// as libcamera defines SensorTimestamp, or its end, as Raspberry Pi's pipelines stamp it)
// and, with the line time unknown (0), for any readout from none (a global shutter) to the
// whole frame period (`periodNs` over `heightPx` rows; 0: not known).
struct ExposureSpan {
  TimeNs startNs = 0;  // the first of the rows starts exposing, at the earliest
  TimeNs endNs = 0;    // the last of them ends, at the latest
};
ExposureSpan exposureSpan(TimeNs timestampNs, TimeNs exposureNs, int y0Px, int y1Px, TimeNs lineTimeNs, TimeNs periodNs,
                          int heightPx);

// The laser lit the whole span: on at or before its start and, unless still on (offNs 0)
// when the frame was complete, off at or after its end.
inline bool litBy(const ExposureSpan& span, TimeNs onNs, TimeNs offNs) {
  return onNs > 0 && span.startNs >= onNs && (offNs == 0 || span.endNs <= offNs);
}

// What the log says of the sensor's rate once its clock is learnt (`periodNs`), against the
// frame duration asked (config camera.frame_duration_us; 0: none) and whether the camera
// has the control to take it. Level: a warning when the rate is not the one asked.
struct FrameRateNote {
  bool warning = false;
  std::string text;
};
FrameRateNote frameRateNote(int64_t askedUs, bool cameraHasControl, TimeNs periodNs);

// Says when the laser's timing on the frame clock keeps failing: a camera whose frames keep
// coming later than predicted (or a capturing thread that keeps waking late) costs every
// such capture a frame period and a second laser pulse, from the request (the libcamera
// adapter tries the clock once a capture). Fed the adapter's running count of misses after
// each capture, it answers true once, the first time kMisses of the last kCaptures
// captures missed; reset() when the camera is opened again.
class FrameClockMissWatch {
 public:
  static constexpr int kCaptures = 30;
  static constexpr int kMisses = 10;

  bool afterCapture(uint64_t missesTotal);
  void reset() { *this = FrameClockMissWatch{}; }
  int missedInWindow() const { return missed_; }

 private:
  std::array<bool, kCaptures> window_{};  // the last kCaptures captures: did each miss?
  int head_ = 0;
  int missed_ = 0;  // true entries in window_
  std::optional<uint64_t> lastTotal_;
  bool told_ = false;
};

class FrameClock {
 public:
  static constexpr int kFrames = 8;

  explicit FrameClock(FrameClockParams params = {}) : params_(params) {}

  // A frame's start, in sequence order (a sequence or a time that does not increase
  // restarts).
  void observe(uint64_t sequence, TimeNs startNs);
  void reset() {
    count_ = 0;
    outlier_.reset();
    afterFinerGrid_ = false;
  }

  // The fitted period; nullopt until minFrames frames fit one.
  std::optional<TimeNs> periodNs() const;
  // The largest distance of the frames seen from the fitted model.
  TimeNs jitterNs() const { return jitterNs_; }
  // Times a model was dropped as a grid finer than the frames (seesRunsOfFrames).
  uint64_t finerGridRestarts() const { return finerGridRestarts_; }
  // The start of the first frame that starts at or after `notBeforeNs`; nullopt while the
  // clock is not learnt, or when that is more than maxPeriodsAhead past the last frame
  // seen (a stream that stalled may have drifted or restarted).
  std::optional<TimeNs> nextStart(TimeNs notBeforeNs) const;

 private:
  struct Sample {
    uint64_t index;  // the frame's count on the learnt clock (from 0 at each restart)
    TimeNs startNs;
  };
  void fit();
  bool onFinerGrid() const;
  const Sample& at(int i) const { return samples_[static_cast<size_t>((head_ + i) % kFrames)]; }

  FrameClockParams params_;
  std::array<Sample, kFrames> samples_{};
  int head_ = 0;   // oldest
  int count_ = 0;  // samples held
  double periodNs_ = 0.0;
  double interceptNs_ = 0.0;  // model start at the last sample's sequence
  TimeNs jitterNs_ = 0;
  uint64_t lastSequence_ = 0;  // the driver's, of the last frame seen
  // A frame off the learnt clock, held aside until the next shows whether the clock
  // changed (index: its driver sequence number).
  std::optional<Sample> outlier_;
  uint64_t finerGridRestarts_ = 0;
  bool afterFinerGrid_ = false;  // learning again from the last frame after a finer grid
};

}  // namespace alacs
