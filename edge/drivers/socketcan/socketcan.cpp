#include "drivers/socketcan/socketcan.h"

#include <linux/can.h>
#include <linux/can/bcm.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace alacs::drivers {

Result<std::unique_ptr<SocketCan>> SocketCan::open(const std::string& iface, const std::vector<CanFilter>& filters) {
  if (iface.empty() || iface.size() >= IFNAMSIZ) return Status(Error::kInvalidArgument, "bad CAN interface name '" + iface + "'");
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_RAW);
  if (fd < 0) {
    if (errno == EAFNOSUPPORT) return Status(Error::kUnsupported, "this kernel has no SocketCAN (AF_CAN unsupported)");
    return Status(Error::kIo, std::string("socket(PF_CAN): ") + std::strerror(errno));
  }
  auto self = std::unique_ptr<SocketCan>(new SocketCan(fd));
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, iface.c_str(), IFNAMSIZ - 1);
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) < 0) return Status(Error::kNotFound, "no CAN interface '" + iface + "'");
  std::vector<can_filter> kf;
  for (const auto& f : filters) kf.push_back({f.id, f.mask | CAN_EFF_FLAG | CAN_RTR_FLAG});
  if (!kf.empty() && ::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, kf.data(),
                                  static_cast<socklen_t>(kf.size() * sizeof(can_filter))) < 0)
    return Status(Error::kIo, std::string("CAN_RAW_FILTER: ") + std::strerror(errno));
  const can_err_mask_t errMask = CAN_ERR_TX_TIMEOUT | CAN_ERR_CRTL | CAN_ERR_BUSOFF | CAN_ERR_BUSERROR | CAN_ERR_RESTARTED;
  if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &errMask, sizeof errMask) < 0)
    return Status(Error::kIo, std::string("CAN_RAW_ERR_FILTER: ") + std::strerror(errno));
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0)
    return Status(Error::kIo, "bind to '" + iface + "': " + std::strerror(errno));
  return self;
}

SocketCan::~SocketCan() { ::close(fd_); }

Result<bool> SocketCan::read(ports::CanFrame* out) {
  can_frame f{};
  const ssize_t n = ::read(fd_, &f, sizeof f);
  if (n < 0) {
    if (errno == EAGAIN || errno == EWOULDBLOCK) return false;
    return Status(Error::kIo, std::string("CAN read: ") + std::strerror(errno));
  }
  if (static_cast<size_t>(n) != sizeof f) return Status(Error::kBadInput, "short CAN frame");
  *out = {};
  out->error = (f.can_id & CAN_ERR_FLAG) != 0;
  out->extended = (f.can_id & CAN_EFF_FLAG) != 0;
  out->rtr = (f.can_id & CAN_RTR_FLAG) != 0;
  out->id = f.can_id & (out->extended ? CAN_EFF_MASK : CAN_SFF_MASK);
  if (out->error) out->errorClass = f.can_id & CAN_ERR_MASK;
  out->dlc = f.len > 8 ? 8 : f.len;
  std::memcpy(out->data.data(), f.data, 8);
  return true;
}

Status SocketCan::write(const ports::CanFrame& frame) {
  can_frame f{};
  f.can_id = frame.id & (frame.extended ? CAN_EFF_MASK : CAN_SFF_MASK);
  if (frame.extended) f.can_id |= CAN_EFF_FLAG;
  f.len = frame.dlc > 8 ? 8 : frame.dlc;
  std::memcpy(f.data, frame.data.data(), 8);
  const ssize_t n = ::write(fd_, &f, sizeof f);
  if (n == static_cast<ssize_t>(sizeof f)) return Status::ok();
  if (n < 0 && (errno == ENOBUFS || errno == EAGAIN || errno == EWOULDBLOCK))
    return {Error::kBusy, "CAN transmit queue full"};
  return {Error::kIo, std::string("CAN write: ") + (n < 0 ? std::strerror(errno) : "short write")};
}

Result<std::unique_ptr<CyclicSender>> CyclicSender::open(const std::string& iface) {
  if (iface.empty() || iface.size() >= IFNAMSIZ) return Status(Error::kInvalidArgument, "bad CAN interface name '" + iface + "'");
  const int fd = ::socket(PF_CAN, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, CAN_BCM);
  if (fd < 0) return Status(Error::kUnsupported, std::string("socket(CAN_BCM): ") + std::strerror(errno));
  auto self = std::unique_ptr<CyclicSender>(new CyclicSender(fd));
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, iface.c_str(), IFNAMSIZ - 1);
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) < 0) return Status(Error::kNotFound, "no CAN interface '" + iface + "'");
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0)
    return Status(Error::kIo, "CAN_BCM connect to '" + iface + "': " + std::strerror(errno));
  return self;
}

CyclicSender::~CyclicSender() { ::close(fd_); }

Status CyclicSender::setup(const ports::CanFrame& frame, TimeNs periodNs, uint32_t flags, uint32_t count) {
  // bcm_msg_head ends in a flexible array: build head + one frame in a byte buffer.
  bcm_msg_head head{};
  head.opcode = TX_SETUP;
  head.flags = flags;
  head.can_id = frame.id & CAN_SFF_MASK;
  head.nframes = 1;
  head.count = count;
  // ival1 for `count` frames, then nothing (ival2 = 0): the guard.
  head.ival1.tv_sec = static_cast<decltype(head.ival1.tv_sec)>(periodNs / kNsPerS);
  head.ival1.tv_usec = static_cast<decltype(head.ival1.tv_usec)>((periodNs % kNsPerS) / kNsPerUs);
  can_frame f{};
  f.can_id = frame.id & CAN_SFF_MASK;
  f.len = frame.dlc > 8 ? 8 : frame.dlc;
  std::memcpy(f.data, frame.data.data(), 8);
  alignas(8) unsigned char msg[sizeof(bcm_msg_head) + sizeof(can_frame)];
  std::memcpy(msg, &head, sizeof head);
  std::memcpy(msg + sizeof head, &f, sizeof f);
  if (::write(fd_, msg, sizeof msg) != static_cast<ssize_t>(sizeof msg))
    return {Error::kIo, std::string("CAN_BCM TX_SETUP: ") + std::strerror(errno)};
  return Status::ok();
}

Status CyclicSender::keep(const ports::CanFrame& frame, TimeNs periodNs, TimeNs now) {
  if (periodNs <= 0) {
    if (!running_) return Status::ok();
    running_ = false;
    bcm_msg_head head{};
    head.opcode = TX_DELETE;
    head.can_id = frame_.id & CAN_SFF_MASK;
    if (::write(fd_, &head, sizeof head) != static_cast<ssize_t>(sizeof head))
      return {Error::kIo, std::string("CAN_BCM TX_DELETE: ") + std::strerror(errno)};
    return Status::ok();
  }
  const auto guard = static_cast<uint32_t>(std::max<TimeNs>(3, kGuardNs / periodNs + 1));
  const bool sameFrame = running_ && frame.id == frame_.id && frame.dlc == frame_.dlc && frame.data == frame_.data;
  // A job whose guard has certainly run out (we were not run for that long: the kernel
  // has stopped sending) is restarted, as is one with a new period. Not earlier: a
  // restart sends at once and so shifts the phase.
  const bool expired = running_ && now - refreshedNs_ > static_cast<TimeNs>(guard) * periodNs;
  Status s = Status::ok();
  if (!running_ || periodNs != periodNs_ || frame.id != frame_.id || expired) {
    s = setup(frame, periodNs, SETTIMER | STARTTIMER, guard);
  } else if (!sameFrame) {
    // New data (an NMT state change) from the next cycle on; the timer keeps its phase.
    s = setup(frame, periodNs, SETTIMER, guard);
  } else if (now - refreshedNs_ >= periodNs / 2) {
    s = setup(frame, periodNs, SETTIMER, guard);  // refresh the guard, same phase
  } else {
    return Status::ok();
  }
  if (!s) return s;
  running_ = true;
  periodNs_ = periodNs;
  refreshedNs_ = now;
  frame_ = frame;
  return Status::ok();
}

Result<std::unique_ptr<SocketCanBus>> SocketCanBus::open(const std::string& iface,
                                                        const std::vector<CanFilter>& filters) {
  Result<std::unique_ptr<SocketCan>> raw = SocketCan::open(iface, filters);
  if (!raw) return raw.status();
  std::unique_ptr<CyclicSender> bcm;
  if (Result<std::unique_ptr<CyclicSender>> b = CyclicSender::open(iface)) bcm = std::move(*b);
  return std::unique_ptr<SocketCanBus>(new SocketCanBus(std::move(*raw), std::move(bcm)));
}

Status SocketCanBus::doKeepCyclic(const ports::CanFrame& frame, TimeNs periodNs, TimeNs now) {
  if (!bcm_) return CanBus::doKeepCyclic(frame, periodNs, now);
  return bcm_->keep(frame, periodNs, now);
}

}  // namespace alacs::drivers
