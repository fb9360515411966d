#include "common/file_beneath.h"

#include <fcntl.h>
#include <linux/openat2.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <sstream>
#include <vector>

namespace alacs {

void UniqueFd::reset() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

namespace {

constexpr int kReadFlags = O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY;

Status openError(int err, const std::string& name) {
  if (err == ENOENT) return {Error::kNotFound, name + " does not exist"};
  // ELOOP: a symlink (RESOLVE_NO_SYMLINKS, O_NOFOLLOW); EXDEV: the path left the directory.
  if (err == ELOOP || err == EXDEV || err == ENOTDIR)
    return {Error::kBadInput, name + " is not a plain path inside the directory (symlink or escape): " + std::strerror(err)};
  return {Error::kIo, name + " cannot be opened: " + std::strerror(err)};
}

// Linux < 5.6: one component at a time, none of them followed if it is a symlink.
int openByComponents(int dirFd, const std::string& relPath, int& err) {
  std::stringstream ss(relPath);
  std::string part;
  std::vector<std::string> parts;
  while (std::getline(ss, part, '/'))
    if (!part.empty() && part != ".") parts.push_back(part);
  if (parts.empty()) {
    err = ENOENT;
    return -1;
  }
  UniqueFd cur(::fcntl(dirFd, F_DUPFD_CLOEXEC, 0));
  for (size_t i = 0; i + 1 < parts.size(); ++i) {
    UniqueFd next(::openat(cur.get(), parts[i].c_str(), O_PATH | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
    if (next.get() < 0) {
      err = errno;
      return -1;
    }
    cur = std::move(next);
  }
  const int fd = ::openat(cur.get(), parts.back().c_str(), kReadFlags | O_NOFOLLOW);
  err = fd < 0 ? errno : 0;
  return fd;
}

}  // namespace

Result<UniqueFd> openBeneath(const std::string& dir, const std::string& relPath, const std::string& what) {
  const std::string name = what + " '" + relPath + "' in '" + dir + "'";
  if (relPath.empty() || relPath[0] == '/') return Status(Error::kBadInput, name + ": not a relative path");
  std::stringstream ss(relPath);
  for (std::string part; std::getline(ss, part, '/');)
    if (part == "..") return Status(Error::kBadInput, name + ": \"..\" leaves the directory");
  UniqueFd dirFd(::open(dir.c_str(), O_PATH | O_DIRECTORY | O_CLOEXEC));
  if (dirFd.get() < 0) return openError(errno, "directory '" + dir + "'");
  open_how how{};
  how.flags = static_cast<uint64_t>(kReadFlags);
  how.resolve = RESOLVE_BENEATH | RESOLVE_NO_SYMLINKS | RESOLVE_NO_MAGICLINKS;
  int fd = static_cast<int>(::syscall(SYS_openat2, dirFd.get(), relPath.c_str(), &how, sizeof how));
  int err = fd < 0 ? errno : 0;
  if (fd < 0 && err == ENOSYS) fd = openByComponents(dirFd.get(), relPath, err);
  if (fd < 0) return openError(err, name);
  UniqueFd file(fd);
  struct stat st {};
  if (::fstat(file.get(), &st) != 0) return Status(Error::kIo, name + " cannot be read: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) return Status(Error::kBadInput, name + " is not a regular file");
  // Opened non-blocking so that a FIFO could not hang the open; a regular file reads the same.
  if (::fcntl(file.get(), F_SETFL, O_RDONLY) != 0) return Status(Error::kIo, name + ": " + std::strerror(errno));
  return file;
}

Result<std::string> readAllBounded(int fd, const std::string& name, size_t maxBytes) {
  struct stat st {};
  if (::fstat(fd, &st) != 0) return Status(Error::kIo, name + " cannot be read: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) return Status(Error::kBadInput, name + " is not a regular file");
  if (st.st_size < 0 || static_cast<uint64_t>(st.st_size) > maxBytes)
    return Status(Error::kBadInput, name + " is larger than " + std::to_string(maxBytes) + " bytes");
  // Read at most one byte past the cap: the file may grow after the fstat.
  std::string text(static_cast<size_t>(st.st_size) + 1, '\0');
  size_t got = 0;
  while (got < text.size()) {
    const ssize_t n = ::read(fd, text.data() + got, text.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return Status(Error::kIo, name + " cannot be read: " + std::strerror(errno));
    if (n == 0) break;
    got += static_cast<size_t>(n);
    if (got > maxBytes) return Status(Error::kBadInput, name + " is larger than " + std::to_string(maxBytes) + " bytes");
    if (got == text.size()) text.resize(std::min(text.size() * 2, maxBytes + 1));
  }
  text.resize(got);
  return text;
}

}  // namespace alacs
