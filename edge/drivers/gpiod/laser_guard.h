// The LASER line owned by a process of its own, so that the laser's on-time is bounded
// outside the daemon's scheduling (issue 15; docs/appliance.md "Laser on-time").
//
// alacsd starts `alacs-laser-guard --laser-guard FD CHIP LINE MAX_ON_MS` (a small program
// beside it, app/laser_guard_main.cpp; alacsd itself when that is missing: either way a
// clean, single-threaded process, exec'd) with one end of a socket pair. The guard requests the LASER line, and drives
// it on and off as the daemon asks; it ends any pulse itself after `maxOnMs`, whatever the daemon does (frozen by
// SIGSTOP, starved, stuck in a driver), and turns the line off and exits when the daemon's end of the socket closes
// (the daemon died: kill -9, a crash). It runs SCHED_FIFO when allowed, memory locked, ignores SIGTERM/SIGINT/SIGHUP
// (the daemon ends it by closing the socket) and logs each cut to stderr (the journal).
//
// What it cannot cover: the guard frozen together with the daemon (SIGSTOP to the whole
// process group or cgroup), or the kernel itself stuck. The board's hardware one-shot
// (docs/appliance.md) bounds those; this is the software layer above it.
#pragma once

#include <sys/types.h>

#include <memory>
#include <string>

#include "ports/digital_io.h"

namespace alacs::drivers {

// The daemon's side: a DigitalOut whose set() returns once the guard has driven the line.
class LaserGuardProcess final : public ports::DigitalOut {
 public:
  // Starts `exe --laser-guard FD CHIP LINE MAX_ON_MS` and waits (up to 2 s) for it to
  // hold the line, off. Errors: kIo (no process, or it could not request the line: the
  // reason is in its log).
  static Result<std::unique_ptr<LaserGuardProcess>> spawn(const std::string& exe, const std::string& chip,
                                                   const std::string& line, int maxOnMs);
  ~LaserGuardProcess() override;
  pid_t pid() const { return pid_; }
  // Pulses the guard has ended on its own (the daemon did not turn the laser off in time).
  int cuts() const { return cuts_; }

 private:
  LaserGuardProcess(int fd, pid_t pid) : fd_(fd), pid_(pid) {}
  Status doSet(bool asserted) override;
  // Waits for one reply byte other than a cut notice (counted). Errors: kIo, kTimeout.
  Result<char> reply(int timeoutMs);
  int fd_;
  pid_t pid_;
  int cuts_ = 0;
};

// The guard process's main (alacsd --laser-guard): serves `fd` until it closes. Returns
// the process's exit code.
int runLaserGuard(int fd, const std::string& chip, const std::string& line, int maxOnMs);
// `PROGRAM --laser-guard FD CHIP LINE MAX_ON_MS`, as LaserGuardProcess::spawn starts it:
// runs the guard and returns its exit code; -1 when argv is not that call.
int runLaserGuardFromArgs(int argc, char** argv);

// The guard's loop on any line (the unit tests drive it with a recording fake): '1' turns
// the line on (a pulse of at most maxOnMs), '0' off; each is answered with the same byte
// once the line is set; a pulse ended by the guard is announced with 'C'. Returns when the
// peer closes or on a socket error, with the line off.
void serveLaserGuard(int fd, ports::DigitalOut& line, int maxOnMs);

}  // namespace alacs::drivers
