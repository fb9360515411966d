#include "common/virtual_timeline.h"

namespace alacs {

void VirtualTimeline::attach() {
  std::lock_guard<std::mutex> lock(mu_);
  ++awake_;
}

void VirtualTimeline::detach() {
  std::lock_guard<std::mutex> lock(mu_);
  --awake_;
  wakeNextLocked();
}

void VirtualTimeline::sleepUntil(TimeNs t) {
  std::unique_lock<std::mutex> lock(mu_);
  if (t <= now_.load()) return;
  const uint64_t ticket = nextTicket_++;
  sleepers_.emplace(t, ticket);
  --awake_;
  wakeNextLocked();
  cv_.wait(lock, [&] { return woken_.count(ticket) != 0; });
  woken_.erase(ticket);
}

void VirtualTimeline::wakeNextLocked() {
  if (awake_ > 0 || sleepers_.empty()) return;
  const auto [t, ticket] = *sleepers_.begin();
  sleepers_.erase(sleepers_.begin());
  if (t > now_.load()) now_.store(t);
  ++awake_;
  woken_.insert(ticket);
  cv_.notify_all();
}

}  // namespace alacs
