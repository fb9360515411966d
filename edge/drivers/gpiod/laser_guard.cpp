#include "drivers/gpiod/laser_guard.h"

#include <poll.h>
#include <sched.h>
#include <spawn.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>

#include "drivers/gpiod/gpiod_lines.h"

extern char** environ;

namespace alacs::drivers {

namespace {

constexpr char kOn = '1';
constexpr char kOff = '0';
constexpr char kCut = 'C';
constexpr char kReady = 'R';
constexpr int kGuardFd = 3;
// The guard is ready once it is loaded and holds the line. alacsd executed again as its
// guard (with OpenCV and libcamera) took 1.7-2.3 s to load inside UML, alacs-laser-guard
// 0.2 s. The daemon waits this long before it gives up.
constexpr int kGuardReadyTimeoutMs = 15000;

int64_t monotonicMs() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1000 + ts.tv_nsec / 1000000;
}

bool sendByte(int fd, char c) {
  for (;;) {
    const ssize_t n = ::send(fd, &c, 1, MSG_NOSIGNAL);
    if (n == 1) return true;
    if (n < 0 && errno == EINTR) continue;
    return false;
  }
}

Status guardError(const std::string& what) { return {Error::kIo, "laser guard: " + what + ": " + std::strerror(errno)}; }

}  // namespace

void serveLaserGuard(int fd, ports::DigitalOut& line, int maxOnMs) {
  (void)line.set(false);
  bool on = false;
  int64_t deadlineMs = 0;
  for (;;) {
    int timeoutMs = -1;
    if (on) timeoutMs = static_cast<int>(std::max<int64_t>(0, deadlineMs - monotonicMs()));
    pollfd p{fd, POLLIN, 0};
    const int r = ::poll(&p, 1, timeoutMs);
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) break;
    if (r == 0) {  // the pulse's time is up and the daemon has not ended it
      (void)line.set(false);
      on = false;
      std::fprintf(stderr, "alacsd laser-guard: laser cut after %d ms (the daemon did not turn it off)\n", maxOnMs);
      if (!sendByte(fd, kCut)) break;
      continue;
    }
    char c = 0;
    const ssize_t n = ::recv(fd, &c, 1, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;  // the daemon is gone (EOF) or the socket failed
    if (c == kOn) {
      // A pulse starts at the first '1'; another '1' while on does not extend it.
      if (!on) deadlineMs = monotonicMs() + maxOnMs;
      on = line.set(true).isOk();
      if (!on) (void)line.set(false);
    } else {
      (void)line.set(false);
      on = false;
    }
    if (!sendByte(fd, on ? kOn : kOff)) break;
  }
  (void)line.set(false);
}

int runLaserGuard(int fd, const std::string& chip, const std::string& line, int maxOnMs) {
  // The daemon ends the guard by closing its end of the socket; a terminal's Ctrl-C or
  // systemd's SIGTERM to the group must not take the laser's line away first.
  std::signal(SIGINT, SIG_IGN);
  std::signal(SIGTERM, SIG_IGN);
  std::signal(SIGHUP, SIG_IGN);
  std::signal(SIGPIPE, SIG_IGN);
  sched_param sp{};
  sp.sched_priority = 90;
  (void)sched_setscheduler(0, SCHED_FIFO, &sp);  // when allowed (the unit's drop-in; root)
  (void)mlockall(MCL_CURRENT | MCL_FUTURE);
  Result<std::unique_ptr<ports::DigitalOut>> out = GpiodLines::openOutput(chip, line, "alacsd-laser-guard");
  if (!out) {
    std::fprintf(stderr, "alacsd laser-guard: %s\n", out.status().toString().c_str());
    return 1;
  }
  (void)(*out)->set(false);
  if (!sendByte(fd, kReady)) return 1;
  serveLaserGuard(fd, **out, maxOnMs);
  return 0;
}

int runLaserGuardFromArgs(int argc, char** argv) {
  if (argc != 6 || std::strcmp(argv[1], "--laser-guard") != 0) return -1;
  return runLaserGuard(std::atoi(argv[2]), argv[3], argv[4], std::atoi(argv[5]));
}

Result<std::unique_ptr<LaserGuardProcess>> LaserGuardProcess::spawn(const std::string& exe, const std::string& chip,
                                                      const std::string& line, int maxOnMs) {
  int sv[2];
  if (::socketpair(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0, sv) != 0) return guardError("socketpair");
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_adddup2(&fa, sv[1], kGuardFd);  // dup2 clears FD_CLOEXEC on the copy
  const std::string fdArg = std::to_string(kGuardFd);
  const std::string maxArg = std::to_string(maxOnMs);
  const char* argv[] = {exe.c_str(), "--laser-guard", fdArg.c_str(), chip.c_str(), line.c_str(), maxArg.c_str(),
                        nullptr};
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, exe.c_str(), &fa, nullptr, const_cast<char* const*>(argv), environ);
  posix_spawn_file_actions_destroy(&fa);
  ::close(sv[1]);
  if (rc != 0) {
    ::close(sv[0]);
    errno = rc;
    return guardError("cannot start " + exe);
  }
  std::unique_ptr<LaserGuardProcess> g(new LaserGuardProcess(sv[0], pid));
  Result<char> ready = g->reply(kGuardReadyTimeoutMs);
  if (!ready)
    return Status(ready.status().code(), "laser guard: did not take the " + line + " line on " + chip + ": " +
                                             ready.status().reason() + " (its own reason, if any, is logged above)");
  if (*ready != kReady)
    return Status(Error::kIo, "laser guard: did not take the " + line + " line on " + chip + ": it answered '" +
                                  std::string(1, *ready) + "' before it was ready");
  return g;
}

Result<char> LaserGuardProcess::reply(int timeoutMs) {
  const int64_t end = monotonicMs() + timeoutMs;
  for (;;) {
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, static_cast<int>(std::max<int64_t>(0, end - monotonicMs())));
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) return Status(guardError("poll"));
    if (r == 0) return Status(Error::kTimeout, "laser guard: no answer within " + std::to_string(timeoutMs) + " ms");
    char c = 0;
    const ssize_t n = ::recv(fd_, &c, 1, 0);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return Status(Error::kIo, "laser guard: the process is gone");
    if (c == kCut) {
      ++cuts_;
      continue;
    }
    return c;
  }
}

Status LaserGuardProcess::doSet(bool asserted) {
  if (!sendByte(fd_, asserted ? kOn : kOff)) return guardError("cannot reach the process");
  Result<char> r = reply(500);
  if (!r) return r.status();
  if (*r != (asserted ? kOn : kOff)) return {Error::kIo, "laser guard: the line could not be set"};
  return Status::ok();
}

LaserGuardProcess::~LaserGuardProcess() {
  (void)sendByte(fd_, kOff);
  ::close(fd_);  // EOF: the guard turns the line off and exits
  int status = 0;
  while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
  }
}

}  // namespace alacs::drivers
