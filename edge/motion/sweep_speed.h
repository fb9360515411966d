// How fast a continuous sweep may pass its stops: no faster than the camera gives frames.
// The worker asks for each stop's frame as the slide passes the stop and waits for it. A
// free-running sensor exposes in its next frame slot after the request and delivers after
// its readout, so a frame takes between one and two frame periods (plus the exposure) from
// request to delivery: about 67 ms at 30 fps. Stops closer than the slide travels in that
// time are passed before their frame can be asked for, and the frames fall behind their
// stops, more at each one: at 300 mm/s and 30 fps the first pass's seven stops 13.3 mm
// apart were taken about 20 mm apart, the last two in the braking past the span, and the
// second pass's stops, 4.4-8.9 mm apart, 20 mm apart too (docs/daemon.md, "A sweep at the
// camera's pace"). Pure logic: durations in, a speed out.
#pragma once

#include <array>
#include <optional>
#include <vector>

#include "common/clock.h"
#include "common/frame_clock.h"
#include "motion/trapezoid.h"

namespace alacs::motion {

// The camera's recent captures, request to delivery, laser-on and laser-off alike.
class CaptureTimes {
 public:
  static constexpr int kFrames = 8;

  void record(TimeNs requestToDeliveryNs);
  // The longest of the last kFrames captures, leaving out any longer than twice their
  // median (a stall, a restart: one slow frame must not slow every sweep after it);
  // 0 until a capture is recorded. A free-running sensor's captures all lie between one
  // period plus the exposure and twice that, so twice the median never leaves one of them out.
  TimeNs longestNs() const;
  // What a sweep allows each capture:
  //  - with the free-running sensor's frame period known (`sensorPeriodNs`, learnt from
  //    the frames' timestamps: common/frame_clock.h), the least whole number of periods
  //    that holds the shortest capture seen. Back to back a capture runs from one slot to
  //    the first usable slot after the delivery, a whole number of periods, and no capture
  //    is shorter than a slot's delivery. Eight captures need not include the worst:
  //    requests that came at a steady phase of the clock gave a first pass 55 ms a capture
  //    where back to back it takes 67 ms (at 30 fps), and its frames fell up to 23 mm
  //    behind their stops. A period longer than the shortest capture is no frame clock a
  //    capture waits on (a camera that exposes on request, asked at a steady pace) and is
  //    not used;
  //  - else longestNs(), and while fewer than kFrames captures are known at least twice
  //    the shortest (the best is at least a period, so twice it bounds the worst; a first
  //    scan knows one metering frame).
  TimeNs paceNs(std::optional<TimeNs> sensorPeriodNs = std::nullopt) const;
  // A free-running sensor's clock of `sensorPeriodNs` is what the captures wait on: no
  // capture was shorter than a period (see paceNs).
  bool waitsOnClock(std::optional<TimeNs> sensorPeriodNs) const;
  int count() const { return count_; }

 private:
  TimeNs shortestNs() const;  // of the captures recorded; count_ > 0

  std::array<TimeNs, kFrames> ns_{};
  int count_ = 0;  // recorded, at most kFrames kept
  int next_ = 0;   // where the next one goes
};

// How late (mm of travel) a sweep at `speedMmPerS` through `stopsMm` (in the order the
// slide passes them) takes its worst frame, when each frame is asked for as the slide
// passes its stop or, if the last frame is not delivered yet, at its delivery, and every
// capture takes `frameNs`. (The wait for the sensor's next frame slot comes on top: up to
// a period's travel, the same at every stop, not accumulated.)
double sweepLatenessMm(const std::vector<double>& stopsMm, double speedMmPerS, TimeNs frameNs);

// The cruise speed of a sweep through `stopsMm` that takes no frame later than half the
// closest two stops' gap (at least kSweepLatenessFloorMm), for a camera whose captures take
// `frameNs`: the limits' own speed when the camera keeps up or `frameNs` is 0 (not known).
// Uneven gaps (the second pass's thirds: 4.4 and 8.9 mm) let a frame run a little late in
// a short gap and catch up in the long one, rather than the whole sweep crawl at the
// short gap's pace. Never below kMinSweepSpeedMmPerS, mm/s.
inline constexpr double kMinSweepSpeedMmPerS = 1.0;
inline constexpr double kSweepLatenessFloorMm = 1.0;
double sweepSpeedMmPerS(const SlideLimits& limits, const std::vector<double>& stopsMm, TimeNs frameNs);

// The start of the frame of a free-running sensor (its clock learnt) nearest `wantedStartNs`,
// before or after it; nullopt while the clock is not learnt. A sweep asks for that frame
// (ScanWorker::sweepStops): the frame then lies within half a period's travel of its stop,
// before or after it, where asking as the slide passes the stop takes the first frame after
// it, up to a whole period's travel late (6-7 mm at 200 mm/s and 30 fps).
std::optional<TimeNs> nearestFrameStartNs(const FrameClock& clock, TimeNs wantedStartNs);

// Where a sweep at `paceMmPerS`, slower than the motor, should first go at the motor's full
// speed (then from rest, at its pace, through its first stop), when the slide waits at
// `hereMm` before the first stop `firstMm`: the point from which the pace is reached, half a
// millimetre early, when going there first passes the first stop sooner than sweeping all
// the way at the pace; nullopt otherwise (no slower, or too near to gain).
std::optional<double> fastRunUpMm(const SlideLimits& limits, double paceMmPerS, double hereMm, double firstMm);

}  // namespace alacs::motion
