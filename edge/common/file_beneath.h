// Opening a file named by an untrusted manifest (a scan directory's frames and its
// calibration) without leaving the directory: no absolute path, no "..", no symlink
// anywhere on the way, nothing but a regular file (a FIFO is refused, never waited on).
#pragma once

#include <string>
#include <utility>

#include "common/result.h"

namespace alacs {

// A file descriptor, closed when it goes out of scope.
class UniqueFd {
 public:
  UniqueFd() = default;
  explicit UniqueFd(int fd) : fd_(fd) {}
  UniqueFd(UniqueFd&& o) noexcept : fd_(std::exchange(o.fd_, -1)) {}
  UniqueFd& operator=(UniqueFd&& o) noexcept {
    if (this != &o) {
      reset();
      fd_ = std::exchange(o.fd_, -1);
    }
    return *this;
  }
  UniqueFd(const UniqueFd&) = delete;
  UniqueFd& operator=(const UniqueFd&) = delete;
  ~UniqueFd() { reset(); }
  int get() const { return fd_; }
  void reset();

 private:
  int fd_ = -1;
};

// Opens `relPath` for reading inside the directory `dir`. Linux ≥ 5.6: openat2() with
// RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS | RESOLVE_NO_MAGICLINKS, which the kernel enforces
// on every component; older kernels: each component opened with O_NOFOLLOW from the last.
// `what` names the file in errors ("frame", "scan calibration").
// Errors: kNotFound (missing), kBadInput (absolute, "..", a symlink on the way, not a
// regular file), kIo.
Result<UniqueFd> openBeneath(const std::string& dir, const std::string& relPath, const std::string& what);

// Reads at most `maxBytes` of a regular file from `fd`; more is kBadInput ("larger than").
Result<std::string> readAllBounded(int fd, const std::string& name, size_t maxBytes);

}  // namespace alacs
