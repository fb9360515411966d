#include "app/config.h"

#include <opencv2/core.hpp>

#include "common/json_file.h"
#include <cmath>
#include <fstream>
#include <sstream>

namespace alacs::app {
namespace {

Status bad(const std::string& key, const std::string& what) {
  return {Error::kBadInput, "config key '" + key + "' " + what};
}

struct Reader {
  cv::FileNode root;
  Status status;

  cv::FileNode node(const std::string& dotted) const {
    cv::FileNode n = root;
    size_t start = 0;
    while (true) {
      const size_t dot = dotted.find('.', start);
      n = n[dotted.substr(start, dot - start)];
      if (dot == std::string::npos || n.empty()) return n;
      start = dot + 1;
    }
  }
  void number(const std::string& key, double* out, double lo, double hi) {
    if (!status) return;
    const cv::FileNode n = node(key);
    if (n.empty() || n.isNone()) return;
    if (!n.isReal() && !n.isInt()) { status = bad(key, "must be a number"); return; }
    const double v = n.real();
    if (!(v >= lo && v <= hi)) {
      std::ostringstream s;
      s << "must be in " << lo << ".." << hi << " (got " << v << ")";
      status = bad(key, s.str());
      return;
    }
    *out = v;
  }
  void integer(const std::string& key, int* out, int lo, int hi) {
    double v = *out;
    number(key, &v, lo, hi);
    if (!status) return;
    if (v != std::floor(v)) { status = bad(key, "must be an integer"); return; }
    *out = static_cast<int>(v);
  }
  void integer64(const std::string& key, int64_t* out, int64_t lo, int64_t hi) {
    double v = static_cast<double>(*out);
    number(key, &v, static_cast<double>(lo), static_cast<double>(hi));
    if (status) *out = static_cast<int64_t>(v);
  }
  void text(const std::string& key, std::string* out) {
    if (!status) return;
    const cv::FileNode n = node(key);
    if (n.empty() || n.isNone()) return;
    if (!n.isString()) { status = bad(key, "must be a string"); return; }
    *out = static_cast<std::string>(n);
  }
  void boolean(const std::string& key, bool* out) {
    if (!status) return;
    const cv::FileNode n = node(key);
    if (n.empty() || n.isNone()) return;
    if (!n.isInt() || (static_cast<int>(n) != 0 && static_cast<int>(n) != 1)) {
      status = bad(key, "must be true or false");
      return;
    }
    *out = static_cast<int>(n) != 0;
  }
};

}  // namespace

Status validateConfig(const DaemonConfig& c) {
  if (Status s = c.motion.validate(); !s) return s;
  if (Status s = c.scan.validate(); !s) return s;
  if (Status s = c.lle.validate(); !s) return s;
  if (c.exposureUs * 2 > c.laserMaxOnMs * 1000)
    return bad("camera.exposure_us", "must be at most half of laser.max_on_ms");
  if (c.scan.stops > 1 && (c.scan.stops - 1) * c.scan.stopSpacingMm > c.motion.strokeMm)
    return bad("scan.stops", "× scan.stop_spacing_mm exceeds the stroke");
  return Status::ok();
}

Result<DaemonConfig> loadConfig(const std::string& path) {
  Result<cv::FileStorage> file = openJsonFile(path, "config file");
  if (!file) return file.status();
  cv::FileStorage& fs = *file;
  DaemonConfig c;
  Reader r{fs.root(), Status::ok()};
  r.integer("can.node_id", &c.nodeId, 1, 127);
  r.text("can.interface", &c.canInterface);
  r.integer("can.heartbeat_ms", &c.heartbeatMs, 0, 65535);
  r.integer("can.status_period_ms", &c.statusPeriodMs, 10, 10000);
  r.text("gpio.chip", &c.gpioChip);
  r.text("gpio.step", &c.lines.step);
  r.text("gpio.dir", &c.lines.dir);
  r.text("gpio.enable", &c.lines.enable);
  r.text("gpio.laser", &c.lines.laser);
  r.text("gpio.home", &c.lines.home);
  r.text("gpio.end", &c.lines.end);
  r.boolean("gpio.home_active_low", &c.lines.homeActiveLow);
  r.boolean("gpio.end_active_low", &c.lines.endActiveLow);
  r.number("motion.steps_per_mm", &c.motion.stepsPerMm, 0.1, 10000);
  r.number("motion.max_speed_mm_s", &c.motion.maxSpeedMmPerS, 1, 2000);
  r.number("motion.accel_mm_s2", &c.motion.accelMmPerS2, 1, 50000);
  r.number("motion.stroke_mm", &c.motion.strokeMm, 1, 2000);
  r.number("motion.homing_speed_mm_s", &c.motion.homingSpeedMmPerS, 1, 2000);
  r.integer64("motion.homing_timeout_ms", &c.motion.homingTimeoutMs, 100, 600000);
  r.integer64("motion.step_pulse_ns", &c.motion.stepPulseNs, 1000, 1000000);
  r.integer("motion.realtime_priority", &c.realtimePriority, 0, 99);
  r.integer("scan.stops", &c.scan.stops, 1, 15);
  r.number("scan.stop_spacing_mm", &c.scan.stopSpacingMm, 0.5, 50);
  r.number("scan.roi_margin_mm", &c.scan.roiMarginMm, 0, 300);
  r.number("scan.gate_mm", &c.scan.gateMm, 10, 500);
  r.integer("scan.follow_up_min_lines", &c.scan.followUpMinLines, 1, 15);
  r.number("scan.follow_up_diameter_sigma_mm", &c.scan.followUpDiameterSigmaMm, 0, 100);
  r.integer("scan.follow_up_max_stops", &c.scan.followUpMaxStops, 0, 16);
  r.integer("lle.brce_step", &c.lle.brceStep, 1, 64);
  r.integer("lle.brce_threshold", &c.lle.brceThreshold, 0, 254);
  r.integer("lle.noise_theta", &c.lle.noiseTheta, 0, 100000);
  r.integer("lle.noise_gamma", &c.lle.noiseGamma, 1, 1000);
  r.integer("camera.exposure_us", &c.exposureUs, 10, 500000);
  r.integer("camera.frame_timeout_ms", &c.frameTimeoutMs, 10, 60000);
  r.integer("camera.retries", &c.frameRetries, 0, 10);
  r.text("camera.id", &c.cameraId);
  r.integer("laser.max_on_ms", &c.laserMaxOnMs, 1, 5000);
  r.text("calibration", &c.calibrationPath);
  if (!r.status) return r.status;
  if (Status s = validateConfig(c); !s) return s;
  return c;
}

}  // namespace alacs::app
