// The replay platform (alacsd --replay DIR): a scan directory whose frames are of another
// size than the calibration's camera is refused when the platform opens, before any frame
// buffer is allocated and before the CAN bus is opened (issue 15, finding 4: sizes are
// checked against the calibration before any allocation).
#include <catch2/catch.hpp>

#include <opencv2/core.hpp>
#include <string>

#include "app/config.h"
#include "app/sim_platform.h"
#include "geometry/calibration.h"
#include "replay/scan_dir.h"
#include "sim/scene.h"
#include "temp_dir.h"

using namespace alacs;

namespace {

geometry::Calibration calibrationFor(int widthPx, int heightPx) {
  geometry::Calibration cal = sim::defaultScene().truth;
  cal.camera.widthPx = widthPx;
  cal.camera.heightPx = heightPx;
  cal.camera.cxPx = 0.5 * (widthPx - 1);
  cal.camera.cyPx = 0.5 * (heightPx - 1);
  return cal;
}

// A one-frame scan of 64 x 48 frames, with a calibration of the same size.
void writeScan(const std::string& dir) {
  replay::ScanInfo info;
  info.widthPx = 64;
  info.heightPx = 48;
  Result<replay::ScanWriter> w = replay::ScanWriter::create(dir, info, calibrationFor(64, 48));
  REQUIRE(w.isOk());
  cv::Mat img(48, 64, CV_8UC3, cv::Scalar::all(40.0));
  replay::FrameRecord rec;
  rec.slideMm = 10.0;
  rec.exposureUs = 1000;
  rec.laserOn = true;
  REQUIRE(w->addFrame({img.data, img.cols, img.rows, img.step[0], image::PixelFormat::kBgr888}, rec).isOk());
  REQUIRE(w->finish().isOk());
}

}  // namespace

TEST_CASE("Replay: frames of another size than the calibration's are refused before the CAN bus opens",
          "[app][replay]") {
  const test::TempDir tmp("alacs_replay_size");
  const std::string dir = tmp.path() + "/scan";
  writeScan(dir);
  app::DaemonConfig cfg;
  // A name no interface can have (longer than IFNAMSIZ): opening the bus fails at once,
  // on any machine, so whatever is refused before it is refused by the platform's checks.
  cfg.canInterface = "no-such-can-interface";
  app::SimOptions opts;
  VirtualClock clock;
  MonotonicSleeper sleeper;

  SECTION("the scan's own calibration fits its frames: the platform goes on to the CAN bus") {
    Result<std::unique_ptr<app::Platform>> p = app::openReplayPlatform(cfg, dir, opts, clock, sleeper);
    REQUIRE_FALSE(p.isOk());
    CHECK(p.status().reason() == "bad CAN interface name 'no-such-can-interface'");
  }
  SECTION("another camera's calibration (--calibration): refused, naming both sizes") {
    const geometry::Calibration other = calibrationFor(1000, 750);
    opts.calibrationPath = tmp.file("other_camera.json");
    REQUIRE(geometry::saveCalibration(other, opts.calibrationPath).isOk());
    Result<std::unique_ptr<app::Platform>> p = app::openReplayPlatform(cfg, dir, opts, clock, sleeper);
    REQUIRE_FALSE(p.isOk());
    CHECK(p.status().code() == Error::kBadInput);
    CHECK(p.status().reason() == "scan '" + dir + "': frames are 64x48 but the calibration is for 1000x750");
  }
}
