// Virtual time for several threads at once (the scan worker's tests). See VirtualTimeline.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <set>
#include <utility>

#include "common/clock.h"

namespace alacs {

// Virtual time shared by several threads, deterministic however loaded the machine: the
// clock moves only when every attached thread sleeps, to the earliest wake-up, and wakes
// that one sleeper alone (equal times: in the order they went to sleep). Attached threads
// so take turns exactly as their times say, and their computing takes no virtual time.
// Threads that are not attached only read the clock (a test's thread waiting for events).
// Used by the scan worker's tests: its job thread and its sweep's step thread.
class VirtualTimeline final : public Clock, public Sleeper {
 public:
  explicit VirtualTimeline(TimeNs start = 0) : now_(start) {}
  TimeNs now() const override { return now_.load(); }
  // Called by an attached thread: sleeps its turn. A time not in the future returns at once.
  void sleepUntil(TimeNs t) override;
  void attach() override;
  void detach() override;

 private:
  // With no attached thread awake, wakes the earliest sleeper (time first moved to its).
  void wakeNextLocked();
  std::atomic<TimeNs> now_;
  std::mutex mu_;
  std::condition_variable cv_;
  int awake_ = 0;  // attached threads not sleeping
  uint64_t nextTicket_ = 0;
  std::set<std::pair<TimeNs, uint64_t>> sleepers_;  // (wake-up time, ticket)
  std::set<uint64_t> woken_;                        // tickets whose turn has come
};

}  // namespace alacs
