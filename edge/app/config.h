// alacsd's configuration file (JSON, /etc/alacs/alacsd.json on the box; see
// firmware/config/alacsd.json and docs/daemon.md). Every key is optional and falls back
// to the default below; a present key with a bad type or range, an unknown key and a
// section that is not an object are errors that name the key by its full path.
#pragma once

#include <string>

#include "common/json_file.h"
#include "common/result.h"
#include "image/lle.h"
#include "localize/exposure.h"
#include "localize/localizer.h"
#include "motion/trapezoid.h"
#include "ports/digital_io.h"

namespace alacs::app {

struct DaemonConfig {
  int nodeId = 0x10;
  std::string canInterface = "can0";
  int heartbeatMs = 1000;
  int statusPeriodMs = 100;
  bool nmtAutoStart = true;             // can.auto_start: OPERATIONAL after boot-up; false: wait for NMT START
  std::string gpioChip;                 // empty: no GPIO (only valid with --sim)
  ports::SensorLineNames lines;
  motion::SlideLimits motion;
  localize::ScanParams scan;
  image::LleParams lle;
  localize::MeteringParams metering;    // the laser frames' exposure from laser-off frames
  int realtimePriority = 0;             // SCHED_FIFO priority of the step-timing thread; 0: none
  int exposureUs = 3000;
  // The sensor's analogue gain for every frame (libcamera's AnalogueGain, linear: 1 is the
  // sensor's least), fixed so that no pipeline's AGC moves it between the metering frames
  // and the laser frames; 0: the camera's own. Metering may lower it in sun
  // (metering.bright_analogue_gain).
  double analogueGain = 0.0;
  int laserMaxOnMs = 250;               // the laser is forced off (and a fault raised) beyond this
  int frameTimeoutMs = 150;             // plus the exposure, must stay below laserMaxOnMs
  int frameRetries = 2;
  // A rolling-shutter sensor's line time in its mode (the time from one row's exposure
  // start to the next's): a sweep gives each row its own slide position. 0: a global
  // shutter (docs/daemon.md "Scanning").
  double lineTimeUs = 0.0;
  // The frame timestamp (libcamera's SensorTimestamp) marks the end of the first row's
  // exposure, the start of its readout, as on Raspberry Pi's pipelines, not its start as
  // libcamera defines it: the worker takes the exposure off it.
  bool timestampAtExposureEnd = false;
  // The laser around each frame of the camera's free-running sensor: on `laserLeadUs`
  // before the target's rows start exposing and off that long after they end, once the
  // sensor's frame clock is learnt from its timestamps (a jitter within
  // `frameClockJitterUs`); false, or until then: on from the capture request to the
  // frame's delivery (docs/daemon.md "The laser and the frame clock").
  bool laserOnFrameClock = true;
  // The sensor exposes all its rows at once: the laser covers the exposure alone. False
  // with camera.line_time_us 0: the line time is not known, and the laser covers any
  // readout up to the whole frame period.
  bool globalShutter = false;
  double laserLeadUs = 1000.0;
  double frameClockJitterUs = 300.0;
  // The sensor's frame duration asked of the camera (libcamera's FrameDurationLimits, min
  // = max); 0: the camera's own. A sensor mode cannot go faster than its limit; the
  // daemon logs the period it learns (docs/daemon.md "Frame rate").
  int frameDurationUs = 0;
  std::string calibrationPath = "/var/lib/alacs/calibration.json";
  std::string cameraId;
};

inline constexpr size_t kConfigMaxBytes = 1 << 20;

// Reads the file at `path` (a regular file of at most kConfigMaxBytes), then checks the
// result with validateConfig. Errors: kNotFound, kBadInput naming the key.
Result<DaemonConfig> loadConfig(const std::string& path);
// Overrides the fields of `config` present in `json` (ranges checked, cross-field rules
// not). Errors: kBadInput naming the key by its full path.
Status configFromJson(const Json& json, DaemonConfig& config);
// Every field, in the layout of firmware/config/alacsd.json.
OrderedJson configToJson(const DaemonConfig& config);
// Ranges of the parts and the rules between fields. Errors: kBadInput naming the keys.
Status validateConfig(const DaemonConfig& c);

}  // namespace alacs::app
