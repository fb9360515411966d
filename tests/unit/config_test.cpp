#include <catch2/catch.hpp>


#include "app/config.h"
#include "temp_dir.h"

using namespace alacs;

namespace {
std::string write(const std::string& text) {
  static const test::TempDir dir("alacs_cfg");  // removed when the test program ends
  static int n = 0;
  return dir.write(std::to_string(n++) + ".json", text);
}
}  // namespace

TEST_CASE("Config: defaults, overrides and errors that name the key", "[config]") {
  auto ok = app::loadConfig(write(R"({"can": {"node_id": 5, "interface": "can1"}, "scan": {"stops": 7}})"));
  REQUIRE(ok.isOk());
  CHECK(ok->nodeId == 5);
  CHECK(ok->canInterface == "can1");
  CHECK(ok->scan.stops == 7);
  CHECK(ok->lle.brceStep == 4);

  CHECK(app::loadConfig("/nonexistent.json").status().code() == Error::kNotFound);
  CHECK(app::loadConfig(write("{ nope")).status().code() == Error::kBadInput);
  auto range = app::loadConfig(write(R"({"can": {"node_id": 200}})"));
  CHECK(range.status().reason().find("can.node_id") != std::string::npos);
  auto type = app::loadConfig(write(R"({"motion": {"stroke_mm": "long"}})"));
  CHECK(type.status().reason().find("motion.stroke_mm") != std::string::npos);
  auto followUp = app::loadConfig(
      write(R"({"scan": {"follow_up_min_lines": 4, "follow_up_max_stops": 0, "follow_up_unseen_max_stops": 20,
                         "follow_up_far_sigmas": 0}})"));
  REQUIRE(followUp.isOk());
  CHECK(followUp->scan.followUpFarSigmas == 0.0);
  CHECK(ok->scan.followUpFarSigmas == 2.5);
  CHECK(app::loadConfig(write(R"({"scan": {"follow_up_far_sigmas": 0.5}})"))
            .status()
            .reason()
            .find("follow_up_far_sigmas") != std::string::npos);
  CHECK(followUp->scan.followUpMinLines == 4);
  CHECK(followUp->scan.followUpMaxStops == 0);
  CHECK(followUp->scan.followUpUnseenMaxStops == 20);
  CHECK(ok->scan.followUpMinLines == 3);
  CHECK(ok->scan.followUpMaxStops == 6);
  CHECK(ok->scan.followUpDiameterSigmaMm == 0.0);
  CHECK(ok->scan.roughWhenFarFromRough);
  auto fitOut = app::loadConfig(write(R"({"scan": {"rough_when_far_from_rough": false}})"));
  REQUIRE(fitOut.isOk());
  CHECK_FALSE(fitOut->scan.roughWhenFarFromRough);
  auto notBool = app::loadConfig(write(R"({"scan": {"rough_when_far_from_rough": 1}})"));
  CHECK(notBool.status().reason().find("scan.rough_when_far_from_rough") != std::string::npos);
  auto shape = app::loadConfig(write(R"({"scan": {"shape_irregularity_pct": 0}})"));
  REQUIRE(shape.isOk());
  CHECK(shape->scan.shapeIrregularityPct == 0.0);
  CHECK(ok->scan.shapeIrregularityPct == 2.0);
  auto lumpy = app::loadConfig(write(R"({"scan": {"shape_irregularity_pct": 25}})"));
  CHECK(lumpy.status().reason().find("scan.shape_irregularity_pct") != std::string::npos);
  auto tooMany = app::loadConfig(write(R"({"scan": {"follow_up_max_stops": 40}})"));
  CHECK(tooMany.status().reason().find("scan.follow_up_max_stops") != std::string::npos);
  // A component's cross-field rule broken in a file is bad input naming the keys (the
  // fuzzer's finding: it was kInvalidArgument, as if the caller had erred).
  auto pulse = app::loadConfig(write(R"({"motion": {"max_speed_mm_s": 2000, "step_pulse_ns": 1000000}})"));
  CHECK(pulse.status().code() == Error::kBadInput);
  CHECK(pulse.status().reason().find("motion.max_speed_mm_s") != std::string::npos);
  auto search = app::loadConfig(write(R"({"scan": {"gate_mm": 120, "search_mm": 100}})"));
  CHECK(search.status().code() == Error::kBadInput);
  CHECK(search.status().reason().find("scan.search_mm") != std::string::npos);
  // A gate that cannot hold the largest fruit's face when the rough position is 2σ off
  // (52.5 + 2 x 25 mm > 90): refused naming both sides; a wider gate holds.
  auto sloppy = app::loadConfig(write(R"({"scan": {"rough_sigma_mm": 25}})"));
  CHECK(sloppy.status().code() == Error::kBadInput);
  CHECK(sloppy.status().reason().find("scan.gate_mm") != std::string::npos);
  CHECK(sloppy.status().reason().find("scan.rough_sigma_mm") != std::string::npos);
  CHECK(app::loadConfig(write(R"({"scan": {"rough_sigma_mm": 25, "gate_mm": 103, "search_mm": 250}})")).isOk());
  auto frac = app::loadConfig(write(R"({"scan": {"stops": 2.5}})"));
  CHECK(frac.status().reason().find("scan.stops") != std::string::npos);
  auto cross = app::loadConfig(write(R"({"camera": {"exposure_us": 200000}, "laser": {"max_on_ms": 100}})"));
  CHECK(cross.status().reason().find("camera.exposure_us") != std::string::npos);
}

TEST_CASE("Config: the fruit model is set for another crop, and one that cannot hold is refused by its keys",
          "[config]") {
  auto defaults = app::loadConfig(write("{}"));
  REQUIRE(defaults.isOk());
  CHECK(defaults->scan.maxRadiusMm == 52.5);
  CHECK(defaults->scan.priorAspect == 0.9);
  CHECK(defaults->scan.sphereMaxRadiusMm() == Approx(57.75));
  auto large = app::loadConfig(write(R"({"scan": {"min_radius_mm": 35, "max_radius_mm": 60, "prior_radius_mm": 48,
      "prior_radius_sigma_mm": 5, "prior_aspect": 1.0, "prior_aspect_sigma": 0.05, "stem_tilt_sigma_deg": 30}})"));
  REQUIRE(large.isOk());
  CHECK(large->scan.minRadiusMm == 35.0);
  CHECK(large->scan.priorRadiusMm == 48.0);
  CHECK(large->scan.priorRadiusSigmaMm == 5.0);
  CHECK(large->scan.stemTiltSigmaDeg == 30.0);
  CHECK(large->scan.sphereMaxRadiusMm() == Approx(60.0 * 1.1));
  // A prior outside the bounds it is a prior within, bounds the wrong way round, and an
  // aspect the spheroid refinement never takes: each refused naming the keys.
  auto outside = app::loadConfig(write(R"({"scan": {"prior_radius_mm": 60}})"));
  CHECK(outside.status().code() == Error::kBadInput);
  CHECK(outside.status().reason().find("scan.prior_radius_mm") != std::string::npos);
  auto reversed = app::loadConfig(write(R"({"scan": {"min_radius_mm": 50, "max_radius_mm": 40}})"));
  CHECK(reversed.status().reason().find("scan.min_radius_mm") != std::string::npos);
  CHECK(reversed.status().code() == Error::kBadInput);
  auto aspect = app::loadConfig(write(R"({"scan": {"prior_aspect": 1.4}})"));
  CHECK(aspect.status().code() == Error::kBadInput);
  CHECK(aspect.status().reason().find("scan.prior_aspect") != std::string::npos);
  auto noSpread = app::loadConfig(write(R"({"scan": {"prior_aspect_sigma": 0}})"));
  CHECK(noSpread.status().reason().find("scan.prior_aspect_sigma") != std::string::npos);
  // Each within its range, but the aspect's 2σ past what the spheroid refinement takes.
  auto tall = app::loadConfig(write(R"({"scan": {"prior_aspect": 1.1, "prior_aspect_sigma": 0.1}})"));
  CHECK(tall.status().code() == Error::kBadInput);
  CHECK(tall.status().reason().find("scan.prior_aspect_sigma") != std::string::npos);
  // A fruit whose diameter the bus's DiameterMm (0..127.5 mm) could not carry.
  auto huge = app::loadConfig(write(R"({"scan": {"max_radius_mm": 70}})"));
  CHECK(huge.status().reason().find("scan.max_radius_mm") != std::string::npos);
  auto edge = app::loadConfig(write(R"({"scan": {"prior_radius_sigma_mm": 0.5}})"));
  CHECK(edge.isOk());
}

TEST_CASE("Config: the laser on the frame clock, and a sensor's shutter stated once", "[config]") {
  auto defaults = app::loadConfig(write("{}"));
  REQUIRE(defaults.isOk());
  CHECK(defaults->laserOnFrameClock);
  CHECK(defaults->laserLeadUs == 1000.0);
  CHECK(defaults->frameClockJitterUs == 300.0);
  CHECK_FALSE(defaults->globalShutter);
  auto set = app::loadConfig(write(
      R"({"camera": {"laser_on_frame_clock": false, "laser_lead_us": 2500, "frame_clock_jitter_us": 50,
          "global_shutter": true}})"));
  REQUIRE(set.isOk());
  CHECK_FALSE(set->laserOnFrameClock);
  CHECK(set->laserLeadUs == 2500.0);
  CHECK(set->frameClockJitterUs == 50.0);
  CHECK(set->globalShutter);
  // A lead too short to wake and switch in would only ever miss its frame.
  auto noLead = app::loadConfig(write(R"({"camera": {"laser_lead_us": 0}})"));
  CHECK(noLead.status().reason().find("camera.laser_lead_us") != std::string::npos);
  // A global shutter has no line time.
  auto both = app::loadConfig(write(R"({"camera": {"global_shutter": true, "line_time_us": 21.7}})"));
  CHECK(both.status().code() == Error::kBadInput);
  CHECK(both.status().reason().find("camera.global_shutter") != std::string::npos);
}

TEST_CASE("Config: the sensor's frame duration, the camera's own unless asked", "[config]") {
  auto defaults = app::loadConfig(write("{}"));
  REQUIRE(defaults.isOk());
  CHECK(defaults->frameDurationUs == 0);
  auto sixty = app::loadConfig(write(R"({"camera": {"frame_duration_us": 16667}})"));
  REQUIRE(sixty.isOk());
  CHECK(sixty->frameDurationUs == 16667);
  CHECK(app::configToJson(*sixty)["camera"]["frame_duration_us"] == 16667);
  // Faster than any sensor (and a likely unit slip: milliseconds, fps).
  auto tiny = app::loadConfig(write(R"({"camera": {"frame_duration_us": 60}})"));
  CHECK(tiny.status().code() == Error::kBadInput);
  CHECK(tiny.status().reason().find("camera.frame_duration_us") != std::string::npos);
  // An exposure cannot last longer than its frame.
  auto longExposure = app::loadConfig(write(R"({"camera": {"frame_duration_us": 2000, "exposure_us": 3000}})"));
  CHECK(longExposure.status().code() == Error::kBadInput);
  CHECK(longExposure.status().reason().find("frame_duration_us") != std::string::npos);
  // A frame so long that a capture would wait past its timeout (150 ms by default): refused
  // with both keys named, not a timeout at every scan.
  auto slow = app::loadConfig(write(R"({"camera": {"frame_duration_us": 100000}})"));
  CHECK(slow.status().code() == Error::kBadInput);
  CHECK(slow.status().reason().find("camera.frame_timeout_ms") != std::string::npos);
  CHECK(slow.status().reason().find("camera.frame_duration_us") != std::string::npos);
  CHECK(app::loadConfig(write(R"({"camera": {"frame_duration_us": 66667}})")).isOk());
}

TEST_CASE("Config: the analogue gain, the camera's own unless asked, and the least gain in sun", "[config]") {
  auto defaults = app::loadConfig(write("{}"));
  REQUIRE(defaults.isOk());
  CHECK(defaults->analogueGain == 0.0);
  CHECK(defaults->metering.brightAnalogueGain == 1.0);
  auto fixed = app::loadConfig(write(R"({"camera": {"analogue_gain": 2.0}, "metering": {"bright_analogue_gain": 0}})"));
  REQUIRE(fixed.isOk());
  CHECK(fixed->analogueGain == 2.0);
  CHECK(fixed->metering.brightAnalogueGain == 0.0);
  CHECK(app::configToJson(*fixed)["camera"]["analogue_gain"] == 2.0);
  CHECK(app::configToJson(*fixed)["metering"]["bright_analogue_gain"] == 0.0);
  // Below the sensor's least (a dB value or a fraction slipped in), or beyond any sensor's.
  for (const char* text : {R"({"camera": {"analogue_gain": 0.5}})", R"({"metering": {"bright_analogue_gain": 0.5}})",
                           R"({"camera": {"analogue_gain": 100}})"}) {
    INFO(text);
    auto bad = app::loadConfig(write(text));
    CHECK(bad.status().code() == Error::kBadInput);
    CHECK(bad.status().reason().find("analogue_gain") != std::string::npos);
  }
}
