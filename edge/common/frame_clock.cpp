#include "common/frame_clock.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace alacs {

void FrameClock::observe(uint64_t sequence, TimeNs startNs) {
  uint64_t index = 0;  // the frame's count on the sensor's clock
  if (count_ > 0) {
    const Sample& last = at(count_ - 1);
    const bool onward = sequence > lastSequence_ && startNs > last.startNs;
    bool fits = onward;
    if (fits && count_ >= 2) {
      // How many periods on: by the time, not the sequence number (some drivers, vimc
      // among them, count only the frames that had a buffer). Then, against the model:
      // the same clock?
      const double periods = std::max(1.0, std::round(static_cast<double>(startNs - last.startNs) / periodNs_));
      index = last.index + static_cast<uint64_t>(periods);
      const double predicted = interceptNs_ + periods * periodNs_;
      fits = std::abs(static_cast<double>(startNs) - predicted) <= static_cast<double>(params_.maxJitterNs);
    } else if (fits) {
      // After a finer grid, one slot: its sequence numbers may count the slots it skipped.
      index = last.index + (afterFinerGrid_ ? 1 : sequence - lastSequence_);
    }
    if (!fits && onward && count_ >= params_.minFrames && !outlier_) {
      // One frame off a learnt clock is held aside: a late interrupt's timestamp leaves
      // the clock as it was; a second frame off it (a mode change, a stall) restarts.
      outlier_ = Sample{sequence, startNs};
      lastSequence_ = sequence;
      return;
    }
    if (!fits) {
      count_ = 0;
      if (onward && outlier_ && outlier_->index < sequence && outlier_->startNs < startNs) {
        // Learn again from the frame held aside, counted on by the sequence numbers.
        samples_[static_cast<size_t>(head_)] = {0, outlier_->startNs};
        count_ = 1;
        index = sequence - outlier_->index;
      } else {
        index = 0;
      }
    }
  }
  outlier_.reset();
  afterFinerGrid_ = false;
  lastSequence_ = sequence;
  if (count_ == kFrames) {
    head_ = (head_ + 1) % kFrames;
    --count_;
  }
  samples_[static_cast<size_t>((head_ + count_) % kFrames)] = {index, startNs};
  ++count_;
  if (params_.seesRunsOfFrames && count_ >= params_.minFrames && onFinerGrid()) {
    // Learn again from this frame, the next interval one slot (the frames' own period;
    // sequence numbers that count every slot, as some drivers' do, would give the grid
    // again).
    head_ = (head_ + count_ - 1) % kFrames;
    samples_[static_cast<size_t>(head_)].index = 0;
    count_ = 1;
    afterFinerGrid_ = true;
    ++finerGridRestarts_;
  }
  fit();
}

// Between the frames held: more steps of two slots than of one.
bool FrameClock::onFinerGrid() const {
  int ones = 0;
  int twos = 0;
  for (int i = 1; i < count_; ++i) {
    const uint64_t step = at(i).index - at(i - 1).index;
    ones += step == 1 ? 1 : 0;
    twos += step == 2 ? 1 : 0;
  }
  return twos > ones;
}

// Least squares of start against index, both relative to the last sample (small
// numbers: a double holds them exactly).
void FrameClock::fit() {
  const Sample& last = at(count_ - 1);
  if (count_ < 2) {
    periodNs_ = 0.0;
    interceptNs_ = static_cast<double>(last.startNs);
    jitterNs_ = 0;
    return;
  }
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (int i = 0; i < count_; ++i) {
    const double x = -static_cast<double>(last.index - at(i).index);
    const double y = static_cast<double>(at(i).startNs - last.startNs);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  const double n = count_;
  const double den = n * sxx - sx * sx;
  periodNs_ = den > 0 ? (n * sxy - sx * sy) / den : 0.0;
  const double b = (sy - periodNs_ * sx) / n;
  interceptNs_ = static_cast<double>(last.startNs) + b;
  double worst = 0.0;
  for (int i = 0; i < count_; ++i) {
    const double x = -static_cast<double>(last.index - at(i).index);
    worst = std::max(worst, std::abs(static_cast<double>(at(i).startNs - last.startNs) - (b + periodNs_ * x)));
  }
  jitterNs_ = static_cast<TimeNs>(std::ceil(worst));
}

ExposureSpan exposureSpan(TimeNs timestampNs, TimeNs exposureNs, int y0Px, int y1Px, TimeNs lineTimeNs, TimeNs periodNs,
                          int heightPx) {
  const double startLineNs = static_cast<double>(lineTimeNs);
  const double endLineNs = lineTimeNs > 0                 ? startLineNs
                           : periodNs > 0 && heightPx > 0 ? static_cast<double>(periodNs) / heightPx
                                                          : 0.0;
  return {timestampNs - exposureNs + std::llround(y0Px * startLineNs),
          timestampNs + std::llround(y1Px * endLineNs) + exposureNs};
}

FrameRateNote frameRateNote(int64_t askedUs, bool cameraHasControl, TimeNs periodNs) {
  const int64_t periodUs = (periodNs + kNsPerUs / 2) / kNsPerUs;
  char fps[32];
  std::snprintf(fps, sizeof fps, "%.1f fps", periodNs > 0 ? 1e9 / static_cast<double>(periodNs) : 0.0);
  const std::string rate = "frames every " + std::to_string(periodUs) + " us (" + fps + ")";
  if (askedUs <= 0) return {false, rate + ", the camera's own rate (camera.frame_duration_us 0)"};
  const std::string asked = "camera.frame_duration_us " + std::to_string(askedUs);
  if (!cameraHasControl)
    return {true, rate + ": " + asked + " not applied, the camera has no FrameDurationLimits control"};
  // 2 %: a sensor's frame length is a whole number of lines, and the clock's fit is good to
  // a few microseconds.
  if (std::abs(periodUs - askedUs) * 50 > askedUs)
    return {true, rate + ", not the " + asked + " asked: beyond the sensor mode's limits?"};
  return {false, rate + ", as asked (" + asked + ")"};
}

bool FrameClockMissWatch::afterCapture(uint64_t missesTotal) {
  // The first count seen is the baseline (the adapter's count runs from its open).
  const bool missed = lastTotal_ && missesTotal > *lastTotal_;
  lastTotal_ = missesTotal;
  // The slot's old entry leaves the window (false until the window first fills).
  const size_t slot = static_cast<size_t>(head_);
  missed_ += (missed ? 1 : 0) - (window_[slot] ? 1 : 0);
  window_[slot] = missed;
  head_ = (head_ + 1) % kCaptures;
  if (told_ || missed_ < kMisses) return false;
  told_ = true;
  return true;
}

std::optional<TimeNs> FrameClock::periodNs() const {
  if (count_ < params_.minFrames || periodNs_ <= 0.0 || jitterNs_ > params_.maxJitterNs) return std::nullopt;
  return static_cast<TimeNs>(std::llround(periodNs_));
}

std::optional<TimeNs> FrameClock::nextStart(TimeNs notBeforeNs) const {
  if (!periodNs()) return std::nullopt;
  const double ahead = std::max(0.0, std::ceil((static_cast<double>(notBeforeNs) - interceptNs_) / periodNs_));
  if (ahead > params_.maxPeriodsAhead) return std::nullopt;
  return static_cast<TimeNs>(std::llround(interceptNs_ + ahead * periodNs_));
}

}  // namespace alacs
