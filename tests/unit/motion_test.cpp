#include <catch2/catch.hpp>

#include "app/laser_guard.h"
#include "motion/step_runner.h"
#include "motion/sweep_speed.h"
#include "sim/sim_slide.h"

using namespace alacs;
using namespace alacs::motion;

TEST_CASE("Trapezoid step times rise monotonically within the speed limit", "[motion]") {
  SlideLimits lim;
  lim.maxSpeedMmPerS = 200.0;
  lim.accelMmPerS2 = 2000.0;
  auto move = planMove(lim, 0, lim.stepsFor(20.0));
  REQUIRE(move.isOk());
  REQUIRE(move->steps() == 800);
  TimeNs prev = 0;
  double fastest = 0;
  for (int64_t k = 1; k <= move->steps(); ++k) {
    const TimeNs t = move->stepTimeNs(k);
    REQUIRE(t > prev);
    fastest = std::max(fastest, 1e9 / static_cast<double>(t - prev));
    prev = t;
  }
  CHECK(fastest <= lim.maxSpeedMmPerS * lim.stepsPerMm * 1.05);
  // 20 mm at 200 mm/s, 2000 mm/s²: 0.1 s ramp up, 0.1 s down, no cruise.
  CHECK(static_cast<double>(move->durationNs()) * 1e-9 == Approx(0.2).margin(0.002));
  CHECK(move->positionAt(move->durationNs()) == Approx(800.0));
}

TEST_CASE("Soft limits refuse targets outside the stroke", "[motion]") {
  SlideLimits lim;
  CHECK(planMove(lim, 0, lim.stepsFor(200.5)).status().code() == Error::kOutOfRange);
  CHECK(planMove(lim, 0, -1).status().code() == Error::kOutOfRange);
  CHECK(planMove(lim, 0, lim.stepsFor(200.0)).isOk());
}

namespace {
// The step runner on the simulated slide (at 50 mm, enabled), its STEP line recorded.
struct RecordedRunner {
  RecordedRunner(VirtualClock& clock, Sleeper& sleeper)
      : slide(clock, lim.stepsPerMm, lim.strokeMm, 50.0),
        step(clock),
        tee(step, slide.stepInput()),
        runner(lim, {&tee, &slide.dirInput(), &slide.homeSwitch(), &slide.endSwitch()}, clock, sleeper) {
    enabled = slide.enableInput().set(true).isOk();
  }
  SlideLimits lim;
  sim::SimSlide slide;
  ports::FakeDigitalOut step;
  ports::TeeDigitalOut tee;
  StepRunner runner;
  bool enabled = false;
};
}  // namespace

TEST_CASE("The step runner emits the planned pulses in virtual time", "[motion]") {
  VirtualClock clock(1000);
  VirtualSleeper sleeper(clock);
  RecordedRunner rig(clock, sleeper);
  auto& [lim, slide, step, tee, runner, enabled] = rig;
  REQUIRE(enabled);
  std::atomic<bool> cancel{false};
  auto move = planMove(lim, lim.stepsFor(50.0), lim.stepsFor(70.0));
  REQUIRE(move.isOk());
  const TimeNs start = clock.now();
  const MoveReport r = runner.run(*move, true, cancel);
  CHECK(r.outcome == MoveOutcome::kCompleted);
  CHECK(r.stepsDone == 800);
  CHECK(slide.positionMm() == Approx(70.0));
  const auto edges = step.edges();
  REQUIRE(edges.size() == 1600);
  // Each rising edge sits exactly at its planned time; each pulse is stepPulseNs wide.
  for (int64_t k = 1; k <= 800; ++k) {
    const auto& rise = edges[static_cast<size_t>(2 * (k - 1))];
    const auto& fall = edges[static_cast<size_t>(2 * (k - 1) + 1)];
    REQUIRE(rise.level);
    REQUIRE(rise.timeNs == start + lim.dirSetupNs + move->stepTimeNs(k));
    REQUIRE(fall.timeNs - rise.timeNs == lim.stepPulseNs);
  }
  CHECK(r.maxLatenessNs == 0);
}

TEST_CASE("The step log says how many steps were done at a past instant", "[motion]") {
  VirtualClock clock(1000);
  VirtualSleeper sleeper(clock);
  RecordedRunner rig(clock, sleeper);
  REQUIRE(rig.enabled);
  std::atomic<bool> cancel{false};
  auto move = planMove(rig.lim, rig.lim.stepsFor(50.0), rig.lim.stepsFor(60.0));
  REQUIRE(move.isOk());
  StepLog log(move->steps());
  CHECK(log.stepsAt(0) == 0);
  rig.runner.logSteps(&log);
  REQUIRE(rig.runner.run(*move, true, cancel).outcome == MoveOutcome::kCompleted);
  REQUIRE(log.recorded() == 400);
  // Each step counts from its rising edge on (the STEP line's record).
  const auto edges = rig.step.edges();
  for (int64_t k = 1; k <= 400; ++k) {
    const TimeNs rise = edges[static_cast<size_t>(2 * (k - 1))].timeNs;
    REQUIRE(log.stepsAt(rise - 1) == k - 1);
    REQUIRE(log.stepsAt(rise) == k);
  }
  CHECK(log.stepsAt(clock.now() + 1'000'000'000) == 400);
  // A log sized for fewer steps keeps the first ones and ignores the rest.
  StepLog small(2);
  small.record(10);
  small.record(20);
  small.record(30);
  CHECK(small.recorded() == 2);
  CHECK(small.stepsAt(25) == 2);
  CHECK(small.stepsAt(15) == 1);
}

TEST_CASE("Homing finds the switch, or times out with a reason", "[motion][homing]") {
  VirtualClock clock;
  VirtualSleeper sleeper(clock);
  SlideLimits lim;
  std::atomic<bool> cancel{false};
  SECTION("switch found") {
    sim::SimSlide slide(clock, lim.stepsPerMm, lim.strokeMm, 37.0);
    REQUIRE(slide.enableInput().set(true).isOk());
    StepRunner runner(lim, {&slide.stepInput(), &slide.dirInput(), &slide.homeSwitch(), nullptr}, clock, sleeper);
    const MoveReport r = runner.home(cancel);
    CHECK(r.outcome == MoveOutcome::kSwitchReached);
    CHECK(slide.positionSteps() == 0);
  }
  SECTION("switch never closes") {
    sim::SimSlide slide(clock, lim.stepsPerMm, lim.strokeMm, 37.0);
    ports::FakeDigitalIn deadSwitch(false);
    REQUIRE(slide.enableInput().set(true).isOk());
    StepRunner runner(lim, {&slide.stepInput(), &slide.dirInput(), &deadSwitch, nullptr}, clock, sleeper);
    const MoveReport r = runner.home(cancel);
    CHECK(r.outcome == MoveOutcome::kLimitHit);
    CHECK(r.status.code() == Error::kTimeout);
    CHECK(static_cast<double>(clock.now()) <= static_cast<double>(lim.homingTimeoutMs * kNsPerMs) * 1.01);
  }
}

TEST_CASE("A limit switch closing mid-move stops the move as a fault", "[motion]") {
  VirtualClock clock;
  VirtualSleeper sleeper(clock);
  SlideLimits lim;
  ports::FakeDigitalOut step(clock), dir(clock);
  ports::FakeDigitalIn end(false);
  int pulses = 0;
  step.onChange([&](bool level) {
    if (level && ++pulses == 100) end.setLevel(true);
  });
  ports::FakeDigitalIn home(false);
  StepRunner runner(lim, {&step, &dir, &home, &end}, clock, sleeper);
  std::atomic<bool> cancel{false};
  const MoveReport r = runner.run(TrapezoidMove(800, 8000, 80000), true, cancel);
  CHECK(r.outcome == MoveOutcome::kLimitHit);
  CHECK(r.status.code() == Error::kLimitHit);
  CHECK(r.stepsDone == 100);
  CHECK_FALSE(step.level());
}

TEST_CASE("The laser guard forces the laser off beyond its maximum on-time", "[laser]") {
  VirtualClock clock;
  ports::FakeDigitalOut line(clock);
  app::LaserGuard laser(line, clock, 50 * kNsPerMs);
  REQUIRE(laser.on().isOk());
  clock.advance(40 * kNsPerMs);
  CHECK_FALSE(laser.enforce(clock.now()));
  REQUIRE(laser.off().isOk());
  REQUIRE(laser.on().isOk());
  clock.advance(51 * kNsPerMs);
  CHECK(laser.enforce(clock.now()));
  CHECK_FALSE(line.level());
  CHECK(laser.on().code() == Error::kFault);
  CHECK_FALSE(line.level());
  const auto edges = line.edges();
  REQUIRE(edges.size() == 4);
  // The laser timeline: on 0..40 ms, on again 40..91 ms, forced off.
  CHECK(edges[0].timeNs == 0);
  CHECK(edges[1].timeNs == 40 * kNsPerMs);
  CHECK(edges[3].timeNs - edges[2].timeNs == 51 * kNsPerMs);
  laser.reset();
  CHECK(laser.on().isOk());
}

namespace {
// A sleeper that wakes `lateNs` late once, at its `lateAt`-th call: a thread the
// scheduler ran late.
class LateOnceSleeper final : public Sleeper {
 public:
  LateOnceSleeper(VirtualClock& clock, int lateAt, TimeNs lateNs) : clock_(clock), lateAt_(lateAt), lateNs_(lateNs) {}
  void sleepUntil(TimeNs t) override {
    const TimeNs wake = t + (++calls_ == lateAt_ ? lateNs_ : 0);
    if (wake > clock_.now()) clock_.set(wake);
  }

 private:
  VirtualClock& clock_;
  int calls_ = 0;
  int lateAt_;
  TimeNs lateNs_;
};
}  // namespace

TEST_CASE("A late edge shifts the rest of the move instead of a burst of catch-up steps", "[motion]") {
  VirtualClock clock(1000);
  // The sleep before step 401 (two sleeps per step: the edge and the pulse's end) wakes
  // 2.4 ms late: mid-move, at its top speed, where 2.4 ms is ~24 planned steps.
  LateOnceSleeper sleeper(clock, 2 * 400 + 1, 2'400'000);
  RecordedRunner rig(clock, sleeper);
  auto& [lim, slide, step, tee, runner, enabled] = rig;
  REQUIRE(enabled);
  std::atomic<bool> cancel{false};
  auto move = planMove(lim, lim.stepsFor(50.0), lim.stepsFor(70.0));
  REQUIRE(move.isOk());
  const MoveReport r = runner.run(*move, true, cancel);
  CHECK(r.outcome == MoveOutcome::kCompleted);
  CHECK(r.stepsDone == 800);
  CHECK(slide.positionMm() == Approx(70.0));
  CHECK(r.maxLatenessNs == 2'400'000);
  const auto edges = step.edges();
  REQUIRE(edges.size() == 1600);
  // Every interval between rising edges is at least its planned one (the late one is
  // longer by the delay), and every pulse keeps its width.
  double shortest = 1e9;
  for (int64_t k = 2; k <= 800; ++k) {
    const TimeNs actual = edges[static_cast<size_t>(2 * (k - 1))].timeNs - edges[static_cast<size_t>(2 * (k - 2))].timeNs;
    const TimeNs planned = move->stepTimeNs(k) - move->stepTimeNs(k - 1);
    shortest = std::min(shortest, static_cast<double>(actual) / static_cast<double>(planned));
    if (k == 401) CHECK(actual == planned + 2'400'000);
    const auto& rise = edges[static_cast<size_t>(2 * (k - 1))];
    const auto& fall = edges[static_cast<size_t>(2 * (k - 1) + 1)];
    CHECK(fall.timeNs - rise.timeNs == lim.stepPulseNs);
  }
  CHECK(shortest >= 1.0);
  // The move ends the delay later than planned.
  CHECK(edges.back().timeNs - edges.front().timeNs ==
        move->stepTimeNs(800) - move->stepTimeNs(1) + 2'400'000 + lim.stepPulseNs);
}

TEST_CASE("A sweep passes its stops no faster than the camera gives frames", "[motion][sweep]") {
  const SlideLimits lim;  // 300 mm/s
  const std::vector<double> seven{28.5, 41.8, 55.1, 68.4, 81.7, 95.0, 108.3};
  constexpr TimeNs kFrameNs = 68 * kNsPerMs;  // a 30 fps sensor's longest capture: two periods and the exposure
  // Not known yet, or a camera that keeps up: the motor's own speed.
  CHECK(sweepSpeedMmPerS(lim, seven, 0) == lim.maxSpeedMmPerS);
  CHECK(sweepSpeedMmPerS(lim, seven, 20 * kNsPerMs) == lim.maxSpeedMmPerS);
  // At the motor's speed the frames fall behind, more at every stop: the last one 40 mm
  // late, past the span.
  CHECK(sweepLatenessMm(seven, 300.0, kFrameNs) == Approx(6 * (300.0 * 0.068 - 13.3)));
  // Even stops 13.3 mm apart: the fastest speed that keeps the worst frame within half a
  // gap, a little above one gap per capture (196 mm/s), since the lateness only builds up
  // over the six gaps.
  const double v = sweepSpeedMmPerS(lim, seven, kFrameNs);
  CHECK(v == Approx((13.3 + 6.65 / 6) / 0.068).epsilon(1e-6));
  CHECK(sweepLatenessMm(seven, v, kFrameNs) <= 6.65 + 1e-9);
  CHECK(sweepLatenessMm(seven, 1.01 * v, kFrameNs) > 6.65);
  // The second pass's thirds, in either direction of travel, a first-pass stop between
  // them: 4.4 and 8.9 mm gaps. The short gap's own pace (65 mm/s) would crawl through the
  // long ones; a frame may run late in a short gap and catch up in the next.
  for (const std::vector<double>& second :
       {std::vector<double>{32.93, 37.37, 46.23, 50.67}, std::vector<double>{50.67, 46.23, 37.37, 32.93}}) {
    const double w = sweepSpeedMmPerS(lim, second, kFrameNs);
    CHECK(w > 1.3 * 4.43 / 0.068);
    CHECK(w < 8.87 / 0.068);
    CHECK(sweepLatenessMm(second, w, kFrameNs) <= 0.5 * (37.37 - 32.93) + 1e-9);
  }
  // One stop: nothing to keep up with.
  CHECK(sweepSpeedMmPerS(lim, {50.0}, kFrameNs) == lim.maxSpeedMmPerS);
  // Two stops on one place (a clamped end stop): the frame after it is one capture late
  // whatever the speed, so no later than kSweepLatenessFloorMm; not a division by zero.
  const double same = sweepSpeedMmPerS(lim, {0.0, 0.0, 13.3}, kFrameNs);
  CHECK(same == Approx(kSweepLatenessFloorMm / 0.068).epsilon(1e-6));
}

TEST_CASE("The sensor's frame nearest a wanted time, before or after it", "[motion][sweep]") {
  constexpr TimeNs kPeriodNs = 33'333'333;
  constexpr TimeNs kPhaseNs = 5'000'000;
  FrameClock clock;
  CHECK_FALSE(nearestFrameStartNs(clock, kPhaseNs).has_value());  // not learnt
  for (uint64_t n = 0; n < 8; ++n) clock.observe(n, kPhaseNs + static_cast<TimeNs>(n) * kPeriodNs);
  REQUIRE(clock.periodNs().has_value());
  const TimeNs tenth = kPhaseNs + 10 * kPeriodNs;
  CHECK(nearestFrameStartNs(clock, tenth + kPeriodNs / 5) == tenth);                  // the one before
  CHECK(nearestFrameStartNs(clock, tenth + 3 * kPeriodNs / 5) == tenth + kPeriodNs);  // the one after
  CHECK(nearestFrameStartNs(clock, tenth) == tenth);
  CHECK(nearestFrameStartNs(clock, tenth - kPeriodNs / 5) == tenth);
}

TEST_CASE("The camera's capture time is its longest recent one, a stall left out", "[motion][sweep]") {
  CaptureTimes t;
  CHECK(t.longestNs() == 0);
  // A 30 fps sensor asked at any phase: 34-68 ms from request to delivery.
  for (TimeNs ms : {40, 67, 35, 52, 60}) t.record(ms * kNsPerMs);
  CHECK(t.longestNs() == 67 * kNsPerMs);
  // A stall (a camera restart) does not slow the sweeps after it...
  t.record(900 * kNsPerMs);
  CHECK(t.longestNs() == 67 * kNsPerMs);
  // ... and a slower camera mode, once most frames say so, does.
  for (int i = 0; i < CaptureTimes::kFrames; ++i) t.record(130 * kNsPerMs);
  CHECK(t.longestNs() == 130 * kNsPerMs);
  CHECK(t.count() == CaptureTimes::kFrames);
  // Two captures: the lower median bounds the longer one.
  CaptureTimes two;
  two.record(34 * kNsPerMs);
  two.record(68 * kNsPerMs);
  CHECK(two.longestNs() == 68 * kNsPerMs);
  two.record(0);  // not a capture
  CHECK(two.count() == 2);
  // Few captures known: at least twice the shortest (the sensor's worst phase not seen yet).
  CaptureTimes one;
  CHECK(one.paceNs() == 0);
  one.record(36 * kNsPerMs);
  CHECK(one.longestNs() == 36 * kNsPerMs);
  CHECK(one.paceNs() == 72 * kNsPerMs);
  // A full window: its longest.
  CHECK(t.paceNs() == t.longestNs());
}

TEST_CASE("A sensor's known period bounds its worst capture, even when eight did not show it", "[motion][sweep]") {
  // A 30 fps sensor (33.3 ms), whose frame is delivered 36 ms after its slot starts at the
  // earliest, asked at a steady phase of its clock: eight captures of 36-55 ms, none at
  // the worst phase. Back to back, from one slot to the first usable one after the
  // delivery, every capture takes two periods, 66.7 ms.
  constexpr TimeNs kPeriodNs = 33'333'333;
  constexpr TimeNs kBackToBackNs = 2 * kPeriodNs;
  CaptureTimes t;
  for (TimeNs ms : {36, 55, 41, 55, 48, 39, 52, 44}) t.record(ms * kNsPerMs);
  REQUIRE(t.count() == CaptureTimes::kFrames);
  CHECK(t.paceNs() == 55 * kNsPerMs);  // the window alone
  CHECK(t.paceNs(std::nullopt) == 55 * kNsPerMs);
  CHECK(t.paceNs(kPeriodNs) == kBackToBackNs);
  // A sweep at the window's pace falls behind its stops by more than a gap; at the
  // period's it keeps within half a gap.
  const SlideLimits lim = SlideLimits{};
  const std::vector<double> stops = {0.0, 13.3, 26.6, 39.9, 53.2, 66.5, 79.8};
  CHECK(sweepLatenessMm(stops, sweepSpeedMmPerS(lim, stops, t.paceNs()), kBackToBackNs) > 13.3);
  CHECK(sweepLatenessMm(stops, sweepSpeedMmPerS(lim, stops, t.paceNs(kPeriodNs)), kBackToBackNs) <= 0.5 * 13.3 + 1e-9);
  // A "period" longer than the shortest capture is not a clock the captures wait on (a
  // camera that exposes on request, asked every 44 ms): the window decides.
  CHECK(t.paceNs(44 * kNsPerMs) == 55 * kNsPerMs);
  // Few captures and a known period: the period's bound, not twice the shortest.
  CaptureTimes one;
  one.record(36 * kNsPerMs);
  CHECK(one.paceNs(kPeriodNs) == kBackToBackNs);
  CHECK(one.paceNs() == 72 * kNsPerMs);
  // A pipeline that delivers later (an ISP stage more): three periods.
  CaptureTimes late;
  for (TimeNs ms : {70, 88, 95}) late.record(ms * kNsPerMs);
  CHECK(late.paceNs(kPeriodNs) == 3 * kPeriodNs);
}

TEST_CASE("A slow sweep far from its first stop goes there at full speed first", "[motion][sweep]") {
  const SlideLimits lim;  // 300 mm/s, 3000 mm/s²
  // The second pass at 30 fps (about 100 mm/s), the slide braked 47 mm past its first stop:
  // at full speed to where 100 mm/s is reached from rest (1.7 mm, and half a millimetre).
  const std::optional<double> back = fastRunUpMm(lim, 100.0, 185.0, 137.6);
  REQUIRE(back);
  CHECK(*back == Approx(137.6 + 100.0 * 100.0 / 6000.0 + 0.5));
  // Forward alike.
  const std::optional<double> ahead = fastRunUpMm(lim, 100.0, 10.0, 60.0);
  REQUIRE(ahead);
  CHECK(*ahead == Approx(60.0 - 100.0 * 100.0 / 6000.0 - 0.5));
  // Sooner that way: the crawl at 100 mm/s takes about 0.49 s, full speed then the run-in 0.28 s.
  SlideLimits pace = lim;
  pace.maxSpeedMmPerS = 100.0;
  const TimeNs crawlNs = planMove(pace, lim.stepsFor(10.0), lim.stepsFor(60.0) + 1)->stepTimeNs(lim.stepsFor(50.0));
  const TimeNs fastNs = planMove(lim, lim.stepsFor(10.0), lim.stepsFor(*ahead))->durationNs();
  CHECK(fastNs < crawlNs / 2);
  // At the motor's own speed, or a little below it, or too near: sweep from where it is.
  CHECK_FALSE(fastRunUpMm(lim, 300.0, 10.0, 60.0));
  CHECK_FALSE(fastRunUpMm(lim, 280.0, 10.0, 60.0));
  CHECK_FALSE(fastRunUpMm(lim, 100.0, 59.0, 60.0));
  CHECK_FALSE(fastRunUpMm(lim, 100.0, 60.0, 60.0));
}
