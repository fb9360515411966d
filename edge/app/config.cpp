#include "app/config.h"

#include <string>

#include "common/json_file.h"

namespace alacs::app {
namespace {

Status bad(const std::string& key, const std::string& what) {
  return {Error::kBadInput, "config key '" + key + "' " + what};
}

}  // namespace

Status validateConfig(const DaemonConfig& c) {
  // The components' own checks (cross-field ones among them, e.g. scan.search_mm against
  // scan.gate_mm) name their keys; from a file they are bad input like any other.
  for (const Status& s : {c.motion.validate(), c.scan.validate(), c.lle.validate(), c.metering.validate()})
    if (!s) return {Error::kBadInput, "config: " + s.reason()};
  if (c.exposureUs * 2 > c.laserMaxOnMs * 1000)
    return bad("camera.exposure_us", "must be at most half of laser.max_on_ms");
  // The frame timeout must fire while the laser guard still has time left: otherwise a
  // camera that never delivers shows up as a laser fault, not as the camera's.
  if (int64_t{c.frameTimeoutMs} * 1000 + c.exposureUs >= int64_t{c.laserMaxOnMs} * 1000)
    return bad("camera.frame_timeout_ms", "(" + std::to_string(c.frameTimeoutMs) + ") + camera.exposure_us (" +
                                              std::to_string(c.exposureUs) + " us) must stay below laser.max_on_ms (" +
                                              std::to_string(c.laserMaxOnMs) + ")");
  if (c.frameDurationUs != 0 && c.frameDurationUs < 1000)
    return bad("camera.frame_duration_us", "must be 0 (the camera's own) or at least 1000 (1000 fps)");
  if (c.frameDurationUs != 0 && c.exposureUs >= c.frameDurationUs)
    return bad("camera.exposure_us", "(" + std::to_string(c.exposureUs) +
                                         ") must be shorter than camera.frame_duration_us (" +
                                         std::to_string(c.frameDurationUs) + ")");
  // A capture may wait out the frame in progress and the next one, then the exposure.
  if (c.frameDurationUs != 0 && 2 * int64_t{c.frameDurationUs} + c.exposureUs >= int64_t{c.frameTimeoutMs} * 1000)
    return bad("camera.frame_timeout_ms", "(" + std::to_string(c.frameTimeoutMs) +
                                              ") must exceed two frames of camera.frame_duration_us (" +
                                              std::to_string(c.frameDurationUs) + " us) plus camera.exposure_us");
  if (c.analogueGain != 0.0 && c.analogueGain < 1.0)
    return bad("camera.analogue_gain", "must be 0 (the camera's own) or in 1..64 (1: the sensor's least)");
  if (c.globalShutter && c.lineTimeUs > 0)
    return bad("camera.global_shutter", "a global shutter has no line time: camera.line_time_us must be 0");
  if (c.scan.stops > 1 && (c.scan.stops - 1) * c.scan.stopSpacingMm > c.motion.strokeMm)
    return bad("scan.stops", "× scan.stop_spacing_mm exceeds the stroke");
  return Status::ok();
}

Status configFromJson(const Json& json, DaemonConfig& c) {
  JsonErrors errors("config");
  JsonObjectReader root(errors, &json, "");
  if (auto can = root.object("can")) {
    can->integer("node_id", c.nodeId, Need::kOptional, 1, 127);
    can->text("interface", c.canInterface);
    can->integer("heartbeat_ms", c.heartbeatMs, Need::kOptional, 0, 65535);
    can->integer("status_period_ms", c.statusPeriodMs, Need::kOptional, 10, 10000);
    can->boolean("auto_start", c.nmtAutoStart);
    can->finish();
  }
  if (auto gpio = root.object("gpio")) {
    gpio->text("chip", c.gpioChip);
    gpio->text("step", c.lines.step);
    gpio->text("dir", c.lines.dir);
    gpio->text("enable", c.lines.enable);
    gpio->text("laser", c.lines.laser);
    gpio->text("home", c.lines.home);
    gpio->text("end", c.lines.end);
    gpio->boolean("home_active_low", c.lines.homeActiveLow);
    gpio->boolean("end_active_low", c.lines.endActiveLow);
    gpio->finish();
  }
  if (auto m = root.object("motion")) {
    m->number("steps_per_mm", c.motion.stepsPerMm, Need::kOptional, 0.1, 10000);
    m->number("max_speed_mm_s", c.motion.maxSpeedMmPerS, Need::kOptional, 1, 2000);
    m->number("accel_mm_s2", c.motion.accelMmPerS2, Need::kOptional, 1, 50000);
    m->number("stroke_mm", c.motion.strokeMm, Need::kOptional, 1, 2000);
    m->number("homing_speed_mm_s", c.motion.homingSpeedMmPerS, Need::kOptional, 1, 2000);
    m->integer("homing_timeout_ms", c.motion.homingTimeoutMs, Need::kOptional, 100, 600000);
    m->integer("step_pulse_ns", c.motion.stepPulseNs, Need::kOptional, 1000, 1000000);
    m->integer("realtime_priority", c.realtimePriority, Need::kOptional, 0, 99);
    m->finish();
  }
  if (auto s = root.object("scan")) {
    s->integer("stops", c.scan.stops, Need::kOptional, 1, 15);
    s->number("stop_spacing_mm", c.scan.stopSpacingMm, Need::kOptional, 0.5, 50);
    s->number("roi_margin_mm", c.scan.roiMarginMm, Need::kOptional, 0, 300);
    s->number("gate_mm", c.scan.gateMm, Need::kOptional, 10, 500);
    s->number("search_mm", c.scan.searchMm, Need::kOptional, 0, 1000);
    s->number("outside_gate_confidence_pct", c.scan.outsideGateConfidencePct, Need::kOptional, 0, 100);
    s->number("rough_sigma_mm", c.scan.roughSigmaMm, Need::kOptional, 0, 500);
    s->number("other_object_prior", c.scan.otherObjectPrior, Need::kOptional, 0, 0.99);
    s->boolean("rough_when_far_from_rough", c.scan.roughWhenFarFromRough);
    s->number("line_bias_px", c.scan.lineBiasPx, Need::kOptional, 0, 5);
    s->number("shape_irregularity_pct", c.scan.shapeIrregularityPct, Need::kOptional, 0, 20);
    s->number("min_radius_mm", c.scan.minRadiusMm, Need::kOptional, 10, 60);
    s->number("max_radius_mm", c.scan.maxRadiusMm, Need::kOptional, 10, 60);
    s->number("prior_radius_mm", c.scan.priorRadiusMm, Need::kOptional, 20, 80);
    s->number("prior_radius_sigma_mm", c.scan.priorRadiusSigmaMm, Need::kOptional, 0.5, 100);
    s->number("prior_aspect", c.scan.priorAspect, Need::kOptional, 0.7, 1.2);
    s->number("prior_aspect_sigma", c.scan.priorAspectSigma, Need::kOptional, 0.01, 0.2);
    s->number("stem_tilt_sigma_deg", c.scan.stemTiltSigmaDeg, Need::kOptional, 1, 90);
    s->integer("follow_up_min_lines", c.scan.followUpMinLines, Need::kOptional, 1, 15);
    s->number("follow_up_hidden_pct", c.scan.followUpHiddenPct, Need::kOptional, 0, 100);
    s->number("follow_up_diameter_sigma_mm", c.scan.followUpDiameterSigmaMm, Need::kOptional, 0, 100);
    s->integer("follow_up_max_stops", c.scan.followUpMaxStops, Need::kOptional, 0, 16);
    s->integer("follow_up_unseen_max_stops", c.scan.followUpUnseenMaxStops, Need::kOptional, 0, 32);
    s->number("follow_up_far_sigmas", c.scan.followUpFarSigmas, Need::kOptional, 0, 10);
    s->number("weak_arc_min_z", c.scan.weakArcMinZ, Need::kOptional, 0, 100);
    s->number("leaf_green_ratio", c.scan.leafGreenRatio, Need::kOptional, 0, 10);
    s->finish();
  }
  if (auto l = root.object("lle")) {
    l->integer("brce_step", c.lle.brceStep, Need::kOptional, 1, 64);
    l->integer("brce_threshold", c.lle.brceThreshold, Need::kOptional, 0, 254);
    l->integer("noise_theta", c.lle.noiseTheta, Need::kOptional, 0, 100000);
    l->integer("noise_gamma", c.lle.noiseGamma, Need::kOptional, 1, 1000);
    l->finish();
  }
  if (auto m = root.object("metering")) {
    m->flag("enabled", c.metering.enabled);
    m->number("percentile", c.metering.percentile, Need::kOptional, 50, 100);
    m->integer("target_dn", c.metering.targetDn, Need::kOptional, 1, 254);
    m->number("bright_dn_per_ms", c.metering.brightDnPerMs, Need::kOptional, 1, 1e6);
    m->integer("saturated_dn", c.metering.saturatedDn, Need::kOptional, 2, 255);
    m->number("step_down", c.metering.stepDown, Need::kOptional, 1.5, 64);
    m->integer("max_frames", c.metering.maxFrames, Need::kOptional, 1, 8);
    m->integer("subtract_above_dn", c.metering.subtractAboveDn, Need::kOptional, 0, 255);
    m->integer("min_exposure_us", c.metering.minExposureUs, Need::kOptional, 1, 1000000);
    m->number("bright_analogue_gain", c.metering.brightAnalogueGain, Need::kOptional, 0, 64);
    m->number("second_exposure_factor", c.metering.secondExposureFactor, Need::kOptional, 0, 8);
    m->finish();
  }
  if (auto cam = root.object("camera")) {
    cam->integer("exposure_us", c.exposureUs, Need::kOptional, 10, 500000);
    cam->number("analogue_gain", c.analogueGain, Need::kOptional, 0, 64);
    cam->integer("frame_timeout_ms", c.frameTimeoutMs, Need::kOptional, 10, 60000);
    cam->integer("retries", c.frameRetries, Need::kOptional, 0, 10);
    cam->number("line_time_us", c.lineTimeUs, Need::kOptional, 0, 1000);
    cam->boolean("timestamp_at_exposure_end", c.timestampAtExposureEnd);
    cam->boolean("global_shutter", c.globalShutter);
    cam->boolean("laser_on_frame_clock", c.laserOnFrameClock);
    cam->number("laser_lead_us", c.laserLeadUs, Need::kOptional, 100, 10000);
    cam->number("frame_clock_jitter_us", c.frameClockJitterUs, Need::kOptional, 1, 100000);
    cam->integer("frame_duration_us", c.frameDurationUs, Need::kOptional, 0, 1000000);
    cam->text("id", c.cameraId);
    cam->finish();
  }
  if (auto laser = root.object("laser")) {
    laser->integer("max_on_ms", c.laserMaxOnMs, Need::kOptional, 1, 5000);
    laser->finish();
  }
  root.text("calibration", c.calibrationPath);
  root.finish();
  return errors.status();
}

OrderedJson configToJson(const DaemonConfig& c) {
  OrderedJson j;
  j["can"] = {{"node_id", c.nodeId},
              {"interface", c.canInterface},
              {"heartbeat_ms", c.heartbeatMs},
              {"status_period_ms", c.statusPeriodMs},
              {"auto_start", c.nmtAutoStart}};
  j["gpio"] = {{"chip", c.gpioChip},
               {"step", c.lines.step},
               {"dir", c.lines.dir},
               {"enable", c.lines.enable},
               {"laser", c.lines.laser},
               {"home", c.lines.home},
               {"end", c.lines.end},
               {"home_active_low", c.lines.homeActiveLow},
               {"end_active_low", c.lines.endActiveLow}};
  j["motion"] = {{"steps_per_mm", c.motion.stepsPerMm},
                 {"max_speed_mm_s", c.motion.maxSpeedMmPerS},
                 {"accel_mm_s2", c.motion.accelMmPerS2},
                 {"stroke_mm", c.motion.strokeMm},
                 {"homing_speed_mm_s", c.motion.homingSpeedMmPerS},
                 {"homing_timeout_ms", c.motion.homingTimeoutMs},
                 {"step_pulse_ns", c.motion.stepPulseNs},
                 {"realtime_priority", c.realtimePriority}};
  j["scan"] = {{"stops", c.scan.stops},
               {"stop_spacing_mm", c.scan.stopSpacingMm},
               {"roi_margin_mm", c.scan.roiMarginMm},
               {"gate_mm", c.scan.gateMm},
               {"search_mm", c.scan.searchMm},
               {"outside_gate_confidence_pct", c.scan.outsideGateConfidencePct},
               {"rough_sigma_mm", c.scan.roughSigmaMm},
               {"other_object_prior", c.scan.otherObjectPrior},
               {"rough_when_far_from_rough", c.scan.roughWhenFarFromRough},
               {"line_bias_px", c.scan.lineBiasPx},
               {"shape_irregularity_pct", c.scan.shapeIrregularityPct},
               {"min_radius_mm", c.scan.minRadiusMm},
               {"max_radius_mm", c.scan.maxRadiusMm},
               {"prior_radius_mm", c.scan.priorRadiusMm},
               {"prior_radius_sigma_mm", c.scan.priorRadiusSigmaMm},
               {"prior_aspect", c.scan.priorAspect},
               {"prior_aspect_sigma", c.scan.priorAspectSigma},
               {"stem_tilt_sigma_deg", c.scan.stemTiltSigmaDeg},
               {"follow_up_min_lines", c.scan.followUpMinLines},
               {"follow_up_hidden_pct", c.scan.followUpHiddenPct},
               {"follow_up_diameter_sigma_mm", c.scan.followUpDiameterSigmaMm},
               {"follow_up_max_stops", c.scan.followUpMaxStops},
               {"follow_up_unseen_max_stops", c.scan.followUpUnseenMaxStops},
               {"follow_up_far_sigmas", c.scan.followUpFarSigmas},
               {"weak_arc_min_z", c.scan.weakArcMinZ},
               {"leaf_green_ratio", c.scan.leafGreenRatio}};
  j["lle"] = {{"brce_step", c.lle.brceStep},
              {"brce_threshold", c.lle.brceThreshold},
              {"noise_theta", c.lle.noiseTheta},
              {"noise_gamma", c.lle.noiseGamma}};
  j["metering"] = {{"enabled", c.metering.enabled},
                   {"percentile", c.metering.percentile},
                   {"target_dn", c.metering.targetDn},
                   {"bright_dn_per_ms", c.metering.brightDnPerMs},
                   {"saturated_dn", c.metering.saturatedDn},
                   {"step_down", c.metering.stepDown},
                   {"max_frames", c.metering.maxFrames},
                   {"subtract_above_dn", c.metering.subtractAboveDn},
                   {"min_exposure_us", c.metering.minExposureUs},
                   {"bright_analogue_gain", c.metering.brightAnalogueGain},
                   {"second_exposure_factor", c.metering.secondExposureFactor}};
  j["camera"] = {{"exposure_us", c.exposureUs},
                 {"analogue_gain", c.analogueGain},
                 {"frame_timeout_ms", c.frameTimeoutMs},
                 {"retries", c.frameRetries},
                 {"line_time_us", c.lineTimeUs},
                 {"timestamp_at_exposure_end", c.timestampAtExposureEnd},
                 {"global_shutter", c.globalShutter},
                 {"laser_on_frame_clock", c.laserOnFrameClock},
                 {"laser_lead_us", c.laserLeadUs},
                 {"frame_clock_jitter_us", c.frameClockJitterUs},
                 {"frame_duration_us", c.frameDurationUs},
                 {"id", c.cameraId}};
  j["laser"] = {{"max_on_ms", c.laserMaxOnMs}};
  j["calibration"] = c.calibrationPath;
  return j;
}

Result<DaemonConfig> loadConfig(const std::string& path) {
  Result<Json> file = readJsonFile(path, "config file", kConfigMaxBytes);
  if (!file) return file.status();
  DaemonConfig c;
  if (Status s = configFromJson(*file, c); !s) return Status(s.code(), "config file '" + path + "': " + s.reason());
  if (Status s = validateConfig(c); !s) return s;
  return c;
}

}  // namespace alacs::app
