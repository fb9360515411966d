#include "common/clock.h"

#include <time.h>

namespace alacs {

TimeNs MonotonicClock::now() const {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<TimeNs>(ts.tv_sec) * kNsPerS + ts.tv_nsec;
}

}  // namespace alacs

namespace alacs {

void MonotonicSleeper::sleepUntil(TimeNs t) {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(t / kNsPerS);
  ts.tv_nsec = static_cast<long>(t % kNsPerS);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) != 0) {
  }
}

}  // namespace alacs
