// Recording fakes for the digital ports: each edge is stored with the time of an
// injected clock, so tests assert pulse timing and the laser's timeline exactly.
#pragma once

#include <functional>
#include <mutex>
#include <vector>

#include "common/clock.h"
#include "ports/digital_io.h"

namespace alacs::ports {

struct Edge {
  TimeNs timeNs = 0;
  bool level = false;
};

class FakeDigitalOut final : public DigitalOut {
 public:
  explicit FakeDigitalOut(const Clock& clock, bool initial = false) : clock_(clock), level_(initial) {}
  bool level() const {
    std::lock_guard<std::mutex> lock(mu_);
    return level_;
  }
  std::vector<Edge> edges() const {
    std::lock_guard<std::mutex> lock(mu_);
    return edges_;
  }
  void clearEdges() {
    std::lock_guard<std::mutex> lock(mu_);
    edges_.clear();
  }
  // Called after each change (with the new level), e.g. by a simulated motor.
  void onChange(std::function<void(bool)> f) { listener_ = std::move(f); }
  void failNext(Status s) { failNext_ = std::move(s); }

 private:
  Status doSet(bool asserted) override {
    if (!failNext_.isOk()) {
      Status s = failNext_;
      failNext_ = Status::ok();
      return s;
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (asserted != level_) edges_.push_back({clock_.now(), asserted});
      level_ = asserted;
    }
    if (listener_) listener_(asserted);
    return Status::ok();
  }

  const Clock& clock_;
  mutable std::mutex mu_;
  bool level_;
  std::vector<Edge> edges_;
  std::function<void(bool)> listener_;
  Status failNext_;
};

class FakeDigitalIn final : public DigitalIn {
 public:
  explicit FakeDigitalIn(bool initial = false) : level_(initial) {}
  void setLevel(bool level) { level_ = level; }
  // When set, the level is computed at each read (e.g. from a simulated slide).
  void setSource(std::function<bool()> f) { source_ = std::move(f); }

 private:
  Result<bool> doGet() override { return source_ ? source_() : level_; }
  bool level_;
  std::function<bool()> source_;
};

// Forwards writes to two outputs (a real line and a simulated motor's input), so that
// `alacsd --sim --gpio-chip` drives real GPIO and the simulation at once.
class TeeDigitalOut final : public DigitalOut {
 public:
  TeeDigitalOut(DigitalOut& a, DigitalOut& b) : a_(a), b_(b) {}

 private:
  Status doSet(bool asserted) override {
    Status sa = a_.set(asserted);
    Status sb = b_.set(asserted);
    return sa.isOk() ? sb : sa;
  }
  DigitalOut& a_;
  DigitalOut& b_;
};

}  // namespace alacs::ports

namespace alacs::ports {

// Asserted when either input is: a real limit switch line beside the simulated slide's
// own switch, so a bench test can close the switch mid-move. A failed read is an error.
class AnyOfDigitalIn final : public DigitalIn {
 public:
  AnyOfDigitalIn(DigitalIn& a, DigitalIn& b) : a_(a), b_(b) {}

 private:
  Result<bool> doGet() override {
    Result<bool> ra = a_.get();
    if (!ra) return ra;
    if (*ra) return true;
    return b_.get();
  }
  DigitalIn& a_;
  DigitalIn& b_;
};

}  // namespace alacs::ports
