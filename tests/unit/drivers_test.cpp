// Driver error paths that hold on any machine. The drivers' success paths run against
// real devices in the UML bench (tests/system).
#include <catch2/catch.hpp>

#include "drivers/socketcan/socketcan.h"
#ifdef ALACS_HAVE_GPIOD
#include "drivers/gpiod/gpiod_lines.h"
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
