// Metering the laser frames' exposure from laser-off frames (localize/exposure.h).
#include <catch2/catch.hpp>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

#include "localize/exposure.h"

using namespace alacs;

namespace {

// A BGR frame whose red is `red` inside `roi` and `outside` elsewhere.
struct Frame {
  Frame(int w, int h, const image::Roi& roi, uint8_t red, uint8_t outside = 0,
        image::PixelFormat format = image::PixelFormat::kBgr888)
      : pixels(static_cast<size_t>(w) * static_cast<size_t>(h) * 3U, 7) {
    view = {pixels.data(), w, h, static_cast<size_t>(w) * 3U, format};
    const int r = image::redOffset(format);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const bool in = x >= roi.x && x < roi.x + roi.width && y >= roi.y && y < roi.y + roi.height;
        pixels[(static_cast<size_t>(y) * static_cast<size_t>(w) + static_cast<size_t>(x)) * 3U +
               static_cast<size_t>(r)] = in ? red : outside;
      }
  }
  std::vector<uint8_t> pixels;
  image::ImageView view;
};

const image::Roi kRoi{10, 5, 40, 20};

}  // namespace

TEST_CASE("The metered level is a percentile of the ROI's red only", "[exposure]") {
  Frame f(64, 32, kRoi, 100, 255);
  // 1 % of the ROI's pixels (8 of 800) brighter: the 99th percentile still reads 100.
  for (int i = 0; i < 8; ++i)
    f.pixels[(static_cast<size_t>(kRoi.y + 3) * 64U + static_cast<size_t>(kRoi.x + i)) * 3U + 2U] = 240;
  CHECK(*localize::redPercentileDn(f.view, kRoi, 99.0) == 100);
  CHECK(*localize::redPercentileDn(f.view, kRoi, 100.0) == 240);
  CHECK(*localize::redPercentileDn(f.view, kRoi, 50.0) == 100);
  // The red byte is the format's: in RGB888 it is the first.
  Frame rgb(64, 32, kRoi, 90, 0, image::PixelFormat::kRgb888);
  CHECK(*localize::redPercentileDn(rgb.view, kRoi, 99.0) == 90);
  CHECK_FALSE(localize::redPercentileDn(f.view, image::Roi{60, 0, 10, 10}, 99.0));
  CHECK_FALSE(localize::redPercentileDn(f.view, image::Roi{0, 0, 0, 10}, 99.0));
}

TEST_CASE("Bright skin shortens the exposure to the target level", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 128;
  p.subtractAboveDn = 100;
  localize::ExposureMeter meter(p, 3000);
  REQUIRE(meter.nextMeteringUs() == 3000);
  Frame f(64, 32, kRoi, 200);
  REQUIRE(meter.add(f.view, kRoi, 3000));
  CHECK(meter.nextMeteringUs() == 0);
  const localize::MeteringDecision& d = meter.decision();
  CHECK(d.exposureUs == 1920);  // 3000 · 128 / 200
  CHECK(d.ambientDn == 128);
  CHECK(d.subtract);  // 128 > 100
  CHECK(d.frames == 1);
  CHECK_FALSE(d.saturated);
  CHECK_FALSE(meter.lastFrameAtDecision());    // the laser-off frame needs an exposure of its own
  CHECK_FALSE(meter.add(f.view, kRoi, 3000));  // metering is over
}

TEST_CASE("A dim scene keeps the configured exposure and its metering frame serves as the laser-off frame",
          "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 128;
  p.subtractAboveDn = 40;
  localize::ExposureMeter meter(p, 3000);
  Frame f(64, 32, kRoi, 60);
  REQUIRE(meter.add(f.view, kRoi, 3000));
  CHECK(meter.decision().exposureUs == 3000);  // never longer than configured
  CHECK(meter.decision().ambientDn == 60);
  CHECK(meter.decision().subtract);
  CHECK(meter.lastFrameAtDecision());
  // Just above the target: within 10 % of the metered exposure, which is kept.
  localize::ExposureMeter near(p, 3000);
  Frame g(64, 32, kRoi, 135);
  REQUIRE(near.add(g.view, kRoi, 3000));
  CHECK(near.decision().exposureUs == 3000);
  CHECK(near.lastFrameAtDecision());
}

TEST_CASE("A saturated metering frame steps down and meters again, a bounded number of times", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 128;
  p.stepDown = 4.0;
  p.maxFrames = 3;
  localize::ExposureMeter meter(p, 3000);
  Frame clipped(64, 32, kRoi, 255);
  REQUIRE(meter.add(clipped.view, kRoi, 3000));
  REQUIRE(meter.nextMeteringUs() == 750);
  CHECK(meter.decision().saturated);
  Frame seen(64, 32, kRoi, 100);
  REQUIRE(meter.add(seen.view, kRoi, 750));
  CHECK(meter.nextMeteringUs() == 0);
  CHECK(meter.decision().exposureUs == 960);  // 750 · 128 / 100
  CHECK(meter.decision().frames == 2);
  CHECK_FALSE(meter.decision().saturated);
  CHECK_FALSE(meter.decision().bright);  // 100 DN in 750 us: 133 DN/ms
  // Bright is the last frame's: clipped at 3000 us says only "85 DN/ms or more", the
  // frame after it 200 DN in 750 us, 267 DN/ms.
  localize::ExposureMeter sunny(p, 3000);
  REQUIRE(sunny.add(clipped.view, kRoi, 3000));
  CHECK_FALSE(sunny.decision().bright);
  Frame bright(64, 32, kRoi, 200);
  REQUIRE(sunny.add(bright.view, kRoi, 750));
  CHECK(sunny.decision().bright);

  // Clipped every time: three frames, then a guess one step below the last, flagged.
  localize::ExposureMeter always(p, 3000);
  int frames = 0;
  while (const int64_t us = always.nextMeteringUs()) {
    REQUIRE(always.add(clipped.view, kRoi, us));
    ++frames;
  }
  CHECK(frames == 3);
  CHECK(always.decision().saturated);
  CHECK(always.decision().bright);            // at least 255 DN in 188 us: over 1300 DN/ms
  CHECK(always.decision().meteredUs == 188);  // 3000 / 4 / 4, rounded
  CHECK(always.decision().exposureUs == 24);  // 188 · 128 / (255 · 4)
  // ... and never below the shortest exposure.
  p.minExposureUs = 200;
  localize::ExposureMeter floor(p, 3000);
  while (const int64_t us = floor.nextMeteringUs()) REQUIRE(floor.add(clipped.view, kRoi, us));
  CHECK(floor.decision().exposureUs == 200);
  CHECK(floor.decision().frames == 3);  // 3000, 750, 200 (then no shorter exposure is left)
}

TEST_CASE("The level is scaled by the exposure the frame reports, not the one asked for", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 128;
  localize::ExposureMeter meter(p, 3000);
  Frame f(64, 32, kRoi, 200);
  REQUIRE(meter.add(f.view, kRoi, 1000));     // a replayed frame recorded at 1000 us
  CHECK(meter.decision().exposureUs == 640);  // 1000 · 128 / 200
  CHECK(meter.decision().meteredUs == 1000);
  CHECK_FALSE(meter.add(f.view, kRoi, 1000));
}

TEST_CASE("Bright ambient lengthens the exposure up to the target, dim ambient never", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 220;
  p.brightDnPerMs = 250.0;
  // Sun: 100 DN in 100 us (1000 DN/ms): the laser is weak next to the skin; the exposure
  // grows until the skin is at the target, at most to the longest allowed.
  localize::ExposureMeter sun(p, 100, 3000);
  Frame f(64, 32, kRoi, 100);
  REQUIRE(sun.add(f.view, kRoi, 100));
  CHECK(sun.decision().exposureUs == 220);
  CHECK(sun.decision().ambientDn == 220);
  CHECK(sun.decision().bright);  // what a scan that finds no line then names (BRIGHT_AMBIENT)
  localize::ExposureMeter capped(p, 100, 150);
  REQUIRE(capped.add(f.view, kRoi, 100));
  CHECK(capped.decision().exposureUs == 150);
  // Lab: 100 DN in 1000 us (100 DN/ms): the laser may be as bright as the skin, and a
  // longer exposure would clip it: the first frame's exposure stays.
  localize::ExposureMeter lab(p, 1000, 3000);
  REQUIRE(lab.add(f.view, kRoi, 1000));
  CHECK(lab.decision().exposureUs == 1000);
  CHECK(lab.lastFrameAtDecision());
  CHECK_FALSE(lab.decision().bright);
}

TEST_CASE("In sun with subtraction a stop's second exposure is the factor's, within the longest", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 220;
  p.brightDnPerMs = 250.0;
  p.secondExposureFactor = 2.0;
  Frame f(64, 32, kRoi, 100);
  // Sun: 100 DN in 100 us: 220 us for the first frame, twice that for the second.
  localize::ExposureMeter sun(p, 100, 3000);
  REQUIRE(sun.add(f.view, kRoi, 100));
  REQUIRE(sun.decision().subtract);
  CHECK(sun.decision().exposureUs == 220);
  CHECK(sun.decision().secondExposureUs == 440);
  // The longest allowed caps it; below 1.25 times the first there is none.
  localize::ExposureMeter capped(p, 100, 300);
  REQUIRE(capped.add(f.view, kRoi, 100));
  CHECK(capped.decision().exposureUs == 220);
  CHECK(capped.decision().secondExposureUs == 300);
  localize::ExposureMeter tight(p, 100, 250);
  REQUIRE(tight.add(f.view, kRoi, 100));
  CHECK(tight.decision().exposureUs == 220);
  CHECK(tight.decision().secondExposureUs == 0);
  // Not bright (lab), or factor 0: one exposure per stop.
  localize::ExposureMeter lab(p, 1000, 3000);
  REQUIRE(lab.add(f.view, kRoi, 1000));
  REQUIRE(lab.decision().subtract);
  CHECK(lab.decision().secondExposureUs == 0);
  p.secondExposureFactor = 0.0;
  localize::ExposureMeter off(p, 100, 3000);
  REQUIRE(off.add(f.view, kRoi, 100));
  CHECK(off.decision().exposureUs == 220);
  CHECK(off.decision().secondExposureUs == 0);
  // No subtraction (a dark ROI that still counts as bright at a short exposure): none.
  p.secondExposureFactor = 2.0;
  p.subtractAboveDn = 250;
  localize::ExposureMeter plain(p, 100, 3000);
  REQUIRE(plain.add(f.view, kRoi, 100));
  CHECK(plain.decision().bright);
  CHECK(plain.decision().secondExposureUs == 0);
}

TEST_CASE("Metering off asks for no frame and keeps the configured exposure", "[exposure]") {
  localize::MeteringParams p;
  p.enabled = false;
  localize::ExposureMeter meter(p, 2500);
  CHECK(meter.nextMeteringUs() == 0);
  CHECK(meter.decision().exposureUs == 2500);
  CHECK_FALSE(meter.decision().subtract);
  CHECK_FALSE(meter.lastFrameAtDecision());
}

TEST_CASE("Metering parameters are range-checked", "[exposure]") {
  localize::MeteringParams p;
  CHECK(p.validate());
  p.targetDn = 250;  // not below saturatedDn
  CHECK_FALSE(p.validate());
  p = {};
  p.stepDown = 1.0;
  CHECK_FALSE(p.validate());
  p = {};
  p.maxFrames = 0;
  CHECK_FALSE(p.validate());
  p = {};
  p.percentile = 20.0;
  CHECK_FALSE(p.validate());
  p = {};
  p.brightAnalogueGain = 0.0;  // never changed
  CHECK(p.validate());
  p.brightAnalogueGain = 0.5;  // below the sensor's least
  CHECK_FALSE(p.validate());
  p.brightAnalogueGain = 65.0;
  CHECK_FALSE(p.validate());
  p = {};
  for (const double ok : {0.0, 1.25, 2.0, 8.0}) {
    p.secondExposureFactor = ok;
    CHECK(p.validate());
  }
  for (const double bad : {-1.0, 0.5, 1.0, 1.2, 8.5}) {
    p.secondExposureFactor = bad;
    CHECK_FALSE(p.validate());
  }
}

TEST_CASE("In sun the laser frames take the least gain, the exposure longer by the ratio", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 220;
  p.brightDnPerMs = 250.0;
  p.brightAnalogueGain = 1.0;
  Frame f(64, 32, kRoi, 100);  // 100 DN in 100 us: sun
  // Metered at gain 2: the target's 220 DN would take 220 us there; at gain 1, 440 us.
  localize::ExposureMeter sun(p, 100, 3000);
  REQUIRE(sun.add(f.view, kRoi, 100, 2.0));
  CHECK(sun.decision().bright);
  CHECK(sun.decision().meteredGain == 2.0);
  CHECK(sun.decision().analogueGain == 1.0);
  CHECK(sun.decision().exposureUs == 440);
  CHECK(sun.decision().ambientDn == 220);  // the same level, at half the gain
  CHECK_FALSE(sun.lastFrameAtDecision());  // the frame to subtract is another one
  // The longest exposure (300 us) caps it: the gain falls only as far as that allows.
  localize::ExposureMeter capped(p, 100, 300);
  REQUIRE(capped.add(f.view, kRoi, 100, 2.0));
  CHECK(capped.decision().exposureUs == 300);
  CHECK(capped.decision().analogueGain == Approx(2.0 * 220.0 / 300.0));
  CHECK(capped.decision().ambientDn == 220);
  // Already at the least gain, a gain the camera does not report, the lever off, or an
  // ambient that is not bright: the gain stays, as before.
  for (const double gain : {1.0, 0.0}) {
    localize::ExposureMeter kept(p, 100, 3000);
    REQUIRE(kept.add(f.view, kRoi, 100, gain));
    CHECK(kept.decision().analogueGain == 0.0);
    CHECK(kept.decision().exposureUs == 220);
  }
  localize::MeteringParams off = p;
  off.brightAnalogueGain = 0.0;
  localize::ExposureMeter never(off, 100, 3000);
  REQUIRE(never.add(f.view, kRoi, 100, 2.0));
  CHECK(never.decision().analogueGain == 0.0);
  CHECK(never.decision().exposureUs == 220);
  localize::ExposureMeter lab(p, 1000, 3000);  // 100 DN/ms
  REQUIRE(lab.add(f.view, kRoi, 1000, 2.0));
  CHECK_FALSE(lab.decision().bright);
  CHECK(lab.decision().analogueGain == 0.0);
  CHECK(lab.lastFrameAtDecision());
  // A gain that is not a gain is refused.
  localize::ExposureMeter bad(p, 100, 3000);
  CHECK_FALSE(bad.add(f.view, kRoi, 100, -1.0));
}

namespace {

// A recording fake of the caller's camera: the exposures, gains and uses asked for, and a
// frame whose red (in the ROI) follows the exposure at `dnPerMs` at the camera's own gain
// `ownGain` (and in proportion at a gain asked for), clipped at 255; it reports the gain
// it took the frame at (0 when `ownGain` is 0: a camera that does not tell); it fails from
// the `failFrom`-th frame on (0: never).
struct RecordingCamera {
  explicit RecordingCamera(double dnPerMsIn, int failFromIn = 0, double ownGainIn = 0.0)
      : dnPerMs(dnPerMsIn), failFrom(failFromIn), ownGain(ownGainIn) {}
  double dnPerMs;
  int failFrom;
  double ownGain;
  std::vector<int64_t> asked;
  std::vector<double> gains;
  std::vector<localize::LaserOffUse> uses;
  std::vector<std::unique_ptr<Frame>> frames;
  localize::TakeLaserOffFrame take() {
    return [this](int64_t us, double gain, localize::LaserOffUse use) -> Result<localize::LaserOffFrame> {
      asked.push_back(us);
      gains.push_back(gain);
      uses.push_back(use);
      if (failFrom > 0 && static_cast<int>(asked.size()) >= failFrom) return Status(Error::kTimeout, "frame timed out");
      const double applied = gain > 0.0 ? gain : ownGain;
      const double scale = gain > 0.0 && ownGain > 0.0 ? gain / ownGain : 1.0;
      const double dn = std::min(255.0, dnPerMs * static_cast<double>(us) / 1000.0 * scale);
      frames.push_back(std::make_unique<Frame>(64, 32, kRoi, static_cast<uint8_t>(std::lround(dn))));
      return localize::LaserOffFrame{frames.back()->view, us, applied};
    };
  }
};

}  // namespace

TEST_CASE("A metering run takes the frames the meter asks for, then the one to subtract", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 128;
  p.subtractAboveDn = 100;
  p.stepDown = 4.0;
  // 200 DN/ms: clipped at 3000 us, 150 DN at 750 us -> 640 us; then one more at 640 us.
  RecordingCamera cam(200.0);
  const localize::MeteringRun run = localize::runMetering(p, 3000, 0, kRoi, cam.take());
  REQUIRE(run.status);
  CHECK(cam.asked == std::vector<int64_t>{3000, 750, 640});
  CHECK(cam.uses == std::vector<localize::LaserOffUse>{localize::LaserOffUse::kMetering,
                                                       localize::LaserOffUse::kMetering,
                                                       localize::LaserOffUse::kSubtraction});
  CHECK(run.frames == 3);
  CHECK(run.decision.exposureUs == 640);
  REQUIRE(run.hasLaserOff);
  CHECK(run.laserOff.view.data == cam.frames.back()->view.data);  // the last frame taken
  CHECK(run.laserOff.exposureUs == 640);

  // Dim: the metering frame, at the exposure kept, is the one subtracted.
  p.subtractAboveDn = 20;
  RecordingCamera dim(20.0);
  const localize::MeteringRun kept = localize::runMetering(p, 3000, 0, kRoi, dim.take());
  CHECK(dim.asked == std::vector<int64_t>{3000});
  CHECK(kept.decision.exposureUs == 3000);
  CHECK(kept.hasLaserOff);
  CHECK(kept.frames == 1);

  // Off: no frame, the configured exposure.
  p.enabled = false;
  RecordingCamera off(200.0);
  const localize::MeteringRun none = localize::runMetering(p, 3000, 0, kRoi, off.take());
  CHECK(off.asked.empty());
  CHECK(none.status);
  CHECK(none.decision.exposureUs == 3000);
  CHECK_FALSE(none.hasLaserOff);
}

TEST_CASE("A failed metering frame leaves the configured exposure; a failed one to subtract, no subtraction",
          "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 128;
  p.subtractAboveDn = 100;
  RecordingCamera first(200.0, 2);  // the second metering frame fails
  const localize::MeteringRun failed = localize::runMetering(p, 3000, 0, kRoi, first.take());
  CHECK_FALSE(failed.status);
  CHECK(failed.status.reason() == "frame timed out");
  CHECK(failed.decision.exposureUs == 3000);
  CHECK_FALSE(failed.decision.subtract);
  CHECK_FALSE(failed.hasLaserOff);

  RecordingCamera last(200.0, 3);  // the one to subtract fails
  const localize::MeteringRun metered = localize::runMetering(p, 3000, 0, kRoi, last.take());
  CHECK_FALSE(metered.status);
  CHECK(metered.decision.exposureUs == 640);  // metered: that stands
  CHECK_FALSE(metered.decision.subtract);
  CHECK_FALSE(metered.hasLaserOff);
  CHECK(metered.frames == 2);
}

TEST_CASE("A metering run in sun takes the frame to subtract at the gain chosen", "[exposure]") {
  localize::MeteringParams p;
  p.targetDn = 220;
  p.stepDown = 4.0;
  // 1000 DN/ms at the camera's gain 2: clipped at 3000 and 750 us, 188 DN at 188 us, so
  // 220 us at gain 2, 440 us at gain 1; then the laser-off frame at 440 us and gain 1.
  RecordingCamera cam(1000.0, 0, 2.0);
  const localize::MeteringRun run = localize::runMetering(p, 3000, 0, kRoi, cam.take());
  REQUIRE(run.status);
  CHECK(cam.asked == std::vector<int64_t>{3000, 750, 188, 440});
  CHECK(cam.gains == std::vector<double>{0.0, 0.0, 0.0, 1.0});  // metered at the camera's own
  CHECK(cam.uses.back() == localize::LaserOffUse::kSubtraction);
  CHECK(run.decision.analogueGain == 1.0);
  CHECK(run.decision.exposureUs == 440);
  REQUIRE(run.hasLaserOff);
  CHECK(run.laserOff.analogueGain == 1.0);
  CHECK(*localize::redPercentileDn(run.laserOff.view, kRoi, 99.0) == 220);
}
