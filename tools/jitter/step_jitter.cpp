// Measures how late the step runner's STEP edges are against their planned times on this
// machine: the same StepRunner that drives the motor, with the real monotonic sleeper
// (clock_nanosleep, TIMER_ABSTIME) and a recording output in place of the GPIO line, so
// only scheduling is measured. Runs a 20 mm move at the default profile (8 kHz peak)
// repeatedly, with the normal scheduler and with SCHED_FIFO (when permitted), optionally
// while other threads load every core. Prints median, p99, p99.9 and maximum lateness of
// each edge, measured from the edge before it (the runner shifts the rest of its plan
// by a late edge rather than catching up, so lateness does not add up along a move), and
// the shortest step interval against its planned one (1.00: no edge ever came early,
// no burst of catch-up steps).
//
// usage: alacs_step_jitter [--moves N] [--load]
#include <pthread.h>
#include <sys/prctl.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "motion/step_runner.h"
#include "ports/digital_io_fake.h"
#include "tool_common/cli.h"

using namespace alacs;

namespace {

struct Stats {
  double medianUs, p99Us, p999Us, maxUs;
  double shortestIntervalRatio;  // min over edges of actual / planned interval
};

Stats measure(int moves) {
  MonotonicClock clock;
  MonotonicSleeper sleeper;
  motion::SlideLimits lim;
  ports::FakeDigitalOut step(clock), dir(clock);
  ports::FakeDigitalIn home(false), end(false);
  motion::StepRunner runner(lim, {&step, &dir, &home, &end}, clock, sleeper);
  std::atomic<bool> cancel{false};
  std::vector<double> lateUs;
  double shortest = 1e9;
  for (int m = 0; m < moves; ++m) {
    auto move = motion::planMove(lim, 0, lim.stepsFor(20.0));
    step.clearEdges();
    const TimeNs start = clock.now() + lim.dirSetupNs;
    (void)runner.run(*move, true, cancel);
    const auto edges = step.edges();
    // Planned time of step k from the same profile; the runner's own start is within
    // a microsecond of `start` (it reads the clock right after setting DIR). Edge k is
    // due one planned interval after edge k-1 actually came.
    for (size_t i = 0; i + 1 < edges.size(); i += 2) {
      const auto k = static_cast<int64_t>(i / 2 + 1);
      const TimeNs plannedNs = move->stepTimeNs(k) - (k > 1 ? move->stepTimeNs(k - 1) : 0);
      const TimeNs previousNs = k > 1 ? edges[i - 2].timeNs : start;
      const TimeNs actualNs = edges[i].timeNs - previousNs;
      lateUs.push_back(static_cast<double>(actualNs - plannedNs) / 1e3);
      if (k > 1)
        shortest = std::min(shortest, static_cast<double>(actualNs) / static_cast<double>(plannedNs));
    }
  }
  std::sort(lateUs.begin(), lateUs.end());
  auto at = [&](double q) { return lateUs[static_cast<size_t>(q * static_cast<double>(lateUs.size() - 1))]; };
  return {at(0.5), at(0.99), at(0.999), lateUs.back(), shortest};
}

}  // namespace

int main(int argc, char** argv) {
  int moves = 20;
  bool load = false;
  CLI::App app("Timing of the step runner's STEP edges against the plan, on this machine's clock.",
               "alacs_step_jitter");
  app.add_option("--moves", moves, "moves of 20 mm measured per scheduling policy (at least 1)")->capture_default_str();
  app.add_flag("--load", load, "load every core while measuring");
  if (const int rc = alacs::tools::parseCommandLine(app, argc, argv); rc >= 0) return rc;
  moves = std::max(1, moves);
  std::atomic<bool> stopLoad{false};
  std::vector<std::thread> loaders;
  if (load) {
    for (unsigned i = 0; i < std::thread::hardware_concurrency(); ++i)
      loaders.emplace_back([&] {
        volatile double x = 1.0;
        while (!stopLoad.load()) x = x * 1.0000001 + 1e-9;
      });
  }
  std::printf("step jitter: %d moves of 20 mm (800 steps, 8 kHz peak)%s\n", moves,
              load ? ", every core loaded" : "");
  const Stats normal = measure(moves);
  std::printf("  SCHED_OTHER  median %7.1f us  p99 %7.1f us  p99.9 %7.1f us  max %8.1f us  shortest interval %.2f of plan\n",
              normal.medianUs, normal.p99Us, normal.p999Us, normal.maxUs, normal.shortestIntervalRatio);
  // What the daemon's worker does when it may not use SCHED_FIFO: no timer slack
  // (the kernel's default 50 us slack is the whole median above).
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  const Stats slack = measure(moves);
  std::printf("  OTHER+slack1 median %7.1f us  p99 %7.1f us  p99.9 %7.1f us  max %8.1f us  shortest interval %.2f of plan\n",
              slack.medianUs, slack.p99Us, slack.p999Us, slack.maxUs, slack.shortestIntervalRatio);
  sched_param sp{};
  sp.sched_priority = 80;
  if (pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0) {
    const Stats rt = measure(moves);
    std::printf("  SCHED_FIFO   median %7.1f us  p99 %7.1f us  p99.9 %7.1f us  max %8.1f us  shortest interval %.2f of plan\n",
                rt.medianUs, rt.p99Us, rt.p999Us, rt.maxUs, rt.shortestIntervalRatio);
  } else {
    std::printf("  SCHED_FIFO   not permitted here (%s)\n", std::strerror(errno));
  }
  stopLoad.store(true);
  for (auto& t : loaders) t.join();
  return 0;
}
