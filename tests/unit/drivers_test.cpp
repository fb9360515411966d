// Driver error paths that hold on any machine. The drivers' success paths run against
// real devices in the UML bench (tests/system).
#include <catch2/catch.hpp>

#include "drivers/socketcan/socketcan.h"
#ifdef ALACS_HAVE_GPIOD
#include <sys/socket.h>
#include <unistd.h>

#include <thread>

#include "drivers/gpiod/gpiod_lines.h"
#include "drivers/gpiod/laser_guard.h"
#include "ports/digital_io_fake.h"
#endif
#ifdef ALACS_HAVE_LIBCAMERA
#include "drivers/libcamera/libcamera_source.h"
#endif

using namespace alacs;

TEST_CASE("SocketCAN: a missing interface is a clear error", "[drivers][can]") {
  auto can = drivers::SocketCan::open("nosuchcan0", {});
  REQUIRE_FALSE(can.isOk());
  // Without kernel CAN support: kUnsupported; with it: the interface is not found.
  CHECK((can.status().code() == Error::kUnsupported || can.status().code() == Error::kNotFound));
  CHECK_FALSE(drivers::SocketCan::open("", {}).isOk());
  CHECK(drivers::SocketCan::open("an-interface-name-too-long", {}).status().code() == Error::kInvalidArgument);
}

#ifdef ALACS_HAVE_GPIOD
TEST_CASE("libgpiod: missing chips are named in the error", "[drivers][gpio]") {
  auto byPath = drivers::GpiodLines::open("/dev/gpiochip-none", {}, "test");
  REQUIRE_FALSE(byPath.isOk());
  CHECK(byPath.status().reason().find("/dev/gpiochip-none") != std::string::npos);
  auto byLabel = drivers::GpiodLines::open("no-such-label", {}, "test");
  REQUIRE_FALSE(byLabel.isOk());
  CHECK(byLabel.status().code() == Error::kNotFound);
}
#endif

#ifdef ALACS_HAVE_LIBCAMERA
TEST_CASE("libcamera: with no camera the adapter says so", "[drivers][camera]") {
  auto n = drivers::LibcameraSource::countCameras();
  REQUIRE(n.isOk());
  if (*n == 0) {
    auto cam = drivers::LibcameraSource::open({});
    REQUIRE_FALSE(cam.isOk());
    CHECK(cam.status().code() == Error::kNotFound);
  }
}
#endif

#ifdef ALACS_HAVE_GPIOD
// The laser guard's loop (drivers/gpiod/laser_guard.h) on a recording line, over a real
// socket pair: it follows the daemon, ends a pulse the daemon left on, and leaves the line
// off when the daemon's end closes. Checked by order and count, not by duration.
TEST_CASE("Laser guard: follows on/off, cuts a pulse left on, off when the daemon goes", "[drivers][gpio][guard]") {
  int sv[2];
  REQUIRE(::socketpair(AF_UNIX, SOCK_SEQPACKET, 0, sv) == 0);
  MonotonicClock clock;
  ports::FakeDigitalOut line(clock, true);  // whatever it was: the guard starts by turning it off
  std::thread guard([&] { drivers::serveLaserGuard(sv[1], line, 30); });
  auto exchange = [&](char c) {
    REQUIRE(::send(sv[0], &c, 1, 0) == 1);
    char r = 0;
    REQUIRE(::recv(sv[0], &r, 1, 0) == 1);
    return r;
  };
  CHECK(exchange('1') == '1');
  CHECK(line.level());
  CHECK(exchange('0') == '0');
  CHECK_FALSE(line.level());
  // On, and never turned off by the daemon: the guard ends the pulse and says so.
  CHECK(exchange('1') == '1');
  char note = 0;
  REQUIRE(::recv(sv[0], &note, 1, 0) == 1);
  CHECK(note == 'C');
  CHECK_FALSE(line.level());
  // On again, and the daemon's end closes (it died): off, and the guard returns.
  CHECK(exchange('1') == '1');
  ::close(sv[0]);
  guard.join();
  ::close(sv[1]);
  CHECK_FALSE(line.level());
  const auto edges = line.edges();
  REQUIRE(edges.size() == 7);  // off at start, then on/off three times
  for (size_t i = 0; i < edges.size(); ++i) CHECK(edges[i].level == (i % 2 == 1));
}
#endif

#ifdef ALACS_HAVE_GPIOD
// A guard that exits before it holds the line (here a program that is not alacsd): the
// daemon's error names the line and why, not only "see its log".
TEST_CASE("Laser guard: one that never gets ready is an error naming the line and the reason",
          "[drivers][gpio][guard]") {
  Result<std::unique_ptr<drivers::LaserGuardProcess>> g =
      drivers::LaserGuardProcess::spawn("/bin/false", "/dev/gpiochip-none", "LASER", 250);
  REQUIRE_FALSE(g);
  CHECK(g.status().code() == Error::kIo);
  CHECK_THAT(g.status().reason(),
             Catch::Contains("LASER line on /dev/gpiochip-none") && Catch::Contains("the process is gone"));
}
#endif
