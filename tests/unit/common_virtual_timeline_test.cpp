// VirtualTimeline: threads that take turns in virtual time, in the order their times say,
// whatever the machine's scheduler does (each case runs many times to give it chances).
#include <catch2/catch.hpp>
#include <future>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/virtual_timeline.h"

using namespace alacs;

namespace {
struct Log {
  std::mutex mu;
  std::vector<std::string> lines;
  void add(const std::string& who, TimeNs t) {
    std::lock_guard<std::mutex> lock(mu);
    lines.push_back(who + std::to_string(t));
  }
};
}  // namespace

TEST_CASE("Attached threads wake one at a time, in the order of their times", "[common][clock]") {
  for (int run = 0; run < 200; ++run) {
    VirtualTimeline time;
    Log log;
    const auto sleeper = [&](const std::string& who, std::vector<TimeNs> wakeNs) {
      for (TimeNs t : wakeNs) {
        time.sleepUntil(t);
        log.add(who, time.now());
      }
      time.detach();
    };
    time.attach();  // for a
    time.attach();  // for b: both count before either runs
    std::thread a(sleeper, "a", std::vector<TimeNs>{10, 30, 50, 50});
    std::thread b(sleeper, "b", std::vector<TimeNs>{20, 40, 50});
    a.join();
    b.join();
    // Equal times (50): in the order the threads went to sleep; a slept for its 50 at 30,
    // b at 40.
    REQUIRE(log.lines == std::vector<std::string>{"a10", "b20", "a30", "b40", "a50", "a50", "b50"});
    REQUIRE(time.now() == 50);
  }
}

TEST_CASE("Time stands still while an attached thread works or waits, and does not go back", "[common][clock]") {
  for (int run = 0; run < 200; ++run) {
    VirtualTimeline time(1000);
    Log log;
    std::promise<void> go;
    time.attach();  // a
    time.attach();  // b
    std::thread a([&] {
      time.sleepUntil(1100);
      log.add("a", time.now());
      time.sleepUntil(500);  // the past: returns at once, the clock stays
      log.add("a", time.now());
      time.detach();
    });
    std::thread b([&, ready = go.get_future()]() mutable {
      ready.wait();  // not sleeping on the timeline: a must not wake meanwhile
      log.add("b", time.now());
      time.sleepUntil(1050);
      log.add("b", time.now());
      time.detach();
    });
    REQUIRE(time.now() == 1000);
    go.set_value();
    a.join();
    b.join();
    REQUIRE(log.lines == std::vector<std::string>{"b1000", "b1050", "a1100", "a1100"});
  }
}
