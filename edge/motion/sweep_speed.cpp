#include "motion/sweep_speed.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace alacs::motion {

void CaptureTimes::record(TimeNs requestToDeliveryNs) {
  if (requestToDeliveryNs <= 0) return;
  ns_[static_cast<size_t>(next_)] = requestToDeliveryNs;
  next_ = (next_ + 1) % kFrames;
  count_ = std::min(count_ + 1, kFrames);
}

TimeNs CaptureTimes::longestNs() const {
  if (count_ == 0) return 0;
  // The slots not yet filled sort last.
  std::array<TimeNs, kFrames> sorted = ns_;
  std::fill(sorted.begin() + count_, sorted.end(), std::numeric_limits<TimeNs>::max());
  std::sort(sorted.begin(), sorted.end());
  // The lower median: with two captures, the shorter one bounds the longer.
  const TimeNs median = sorted[static_cast<size_t>((count_ - 1) / 2)];
  TimeNs longest = 0;
  for (int i = 0; i < count_; ++i)
    if (sorted[static_cast<size_t>(i)] <= 2 * median) longest = sorted[static_cast<size_t>(i)];
  return longest;
}

TimeNs CaptureTimes::shortestNs() const { return *std::min_element(ns_.begin(), ns_.begin() + count_); }

bool CaptureTimes::waitsOnClock(std::optional<TimeNs> sensorPeriodNs) const {
  return count_ > 0 && sensorPeriodNs && *sensorPeriodNs > 0 && *sensorPeriodNs <= shortestNs();
}

TimeNs CaptureTimes::paceNs(std::optional<TimeNs> sensorPeriodNs) const {
  const TimeNs longest = longestNs();
  if (count_ == 0) return longest;
  const TimeNs shortest = shortestNs();
  if (waitsOnClock(sensorPeriodNs)) {
    const TimeNs p = *sensorPeriodNs;
    return (shortest + p - 1) / p * p;
  }
  if (count_ >= kFrames) return longest;
  return std::max(longest, 2 * shortest);
}

double sweepLatenessMm(const std::vector<double>& stopsMm, double speedMmPerS, TimeNs frameNs) {
  // Stop j+1's frame can be asked for at the later of its passing time and the delivery of
  // stop j's: lateness(j+1) = max(0, lateness(j) + frame - gap(j) / speed).
  const double frameS = static_cast<double>(frameNs) * 1e-9;
  double lateS = 0.0;
  double worstS = 0.0;
  for (size_t i = 1; i < stopsMm.size(); ++i) {
    lateS = std::max(0.0, lateS + frameS - std::abs(stopsMm[i] - stopsMm[i - 1]) / speedMmPerS);
    worstS = std::max(worstS, lateS);
  }
  return worstS * speedMmPerS;
}

double sweepSpeedMmPerS(const SlideLimits& limits, const std::vector<double>& stopsMm, TimeNs frameNs) {
  if (frameNs <= 0 || stopsMm.size() < 2) return limits.maxSpeedMmPerS;
  double closestMm = std::abs(stopsMm[1] - stopsMm[0]);
  for (size_t i = 2; i < stopsMm.size(); ++i) closestMm = std::min(closestMm, std::abs(stopsMm[i] - stopsMm[i - 1]));
  const double toleranceMm = std::max(kSweepLatenessFloorMm, 0.5 * closestMm);
  const auto keepsUp = [&](double v) { return sweepLatenessMm(stopsMm, v, frameNs) <= toleranceMm; };
  if (keepsUp(limits.maxSpeedMmPerS)) return limits.maxSpeedMmPerS;
  if (!keepsUp(kMinSweepSpeedMmPerS)) return kMinSweepSpeedMmPerS;
  // The lateness grows with the speed: the fastest that keeps it within the tolerance.
  double lo = kMinSweepSpeedMmPerS;
  double hi = limits.maxSpeedMmPerS;
  for (int i = 0; i < 40; ++i) {
    const double mid = 0.5 * (lo + hi);
    (keepsUp(mid) ? lo : hi) = mid;
  }
  return lo;
}

std::optional<TimeNs> nearestFrameStartNs(const FrameClock& clock, TimeNs wantedStartNs) {
  const std::optional<TimeNs> periodNs = clock.periodNs();
  const std::optional<TimeNs> after = clock.nextStart(wantedStartNs);
  if (!periodNs || !after) return std::nullopt;
  const TimeNs before = *after - *periodNs;
  return wantedStartNs - before < *after - wantedStartNs ? before : *after;
}

std::optional<double> fastRunUpMm(const SlideLimits& limits, double paceMmPerS, double hereMm, double firstMm) {
  if (!(paceMmPerS < limits.maxSpeedMmPerS) || firstMm == hereMm) return std::nullopt;
  SlideLimits pace = limits;
  pace.maxSpeedMmPerS = paceMmPerS;
  const bool forward = firstMm > hereMm;
  const double runUpMm = paceMmPerS * paceMmPerS / (2.0 * limits.accelMmPerS2) + 0.5;
  const double preMm = firstMm + (forward ? -runUpMm : runUpMm);
  if (forward ? preMm <= hereMm : preMm >= hereMm) return std::nullopt;
  const int64_t here = limits.stepsFor(hereMm);
  const int64_t first = limits.stepsFor(firstMm);
  const int64_t pre = limits.stepsFor(preMm);
  const int64_t past = forward ? 1 : -1;  // a sweep runs on past its first stop
  const Result<TrapezoidMove> crawl = planMove(pace, here, first + past);
  const Result<TrapezoidMove> fast = planMove(limits, here, pre);
  const Result<TrapezoidMove> runIn = planMove(pace, pre, first + past);
  if (!crawl || !fast || !runIn) return std::nullopt;
  const TimeNs viaFast = fast->durationNs() + runIn->stepTimeNs(std::llabs(first - pre));
  if (viaFast >= crawl->stepTimeNs(std::llabs(first - here))) return std::nullopt;
  return preMm;
}

}  // namespace alacs::motion
