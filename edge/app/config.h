// alacsd's configuration file (JSON, /etc/alacs/alacsd.json on the box; see
// firmware/config/alacsd.json and docs/configuration.md). Every key is optional and
// falls back to the default below; a present key with a bad type or range is an error
// that names it.
#pragma once

#include <string>

#include "common/result.h"
#include "drivers/gpiod/gpiod_lines.h"
#include "image/lle.h"
#include "localize/localizer.h"
#include "motion/trapezoid.h"

namespace alacs::app {

struct DaemonConfig {
  int nodeId = 0x10;
  std::string canInterface = "can0";
  int heartbeatMs = 1000;
  int statusPeriodMs = 100;
  std::string gpioChip;                 // empty: no GPIO (only valid with --sim)
  drivers::GpioLineNames lines;
  motion::SlideLimits motion;
  localize::ScanParams scan;
  image::LleParams lle;
  int realtimePriority = 0;             // SCHED_FIFO priority of the step-timing thread; 0: none
  int exposureUs = 3000;
  int laserMaxOnMs = 250;               // the laser is forced off (and a fault raised) beyond this
  int frameTimeoutMs = 1000;
  int frameRetries = 2;
  std::string calibrationPath = "/var/lib/alacs/calibration.json";
  std::string cameraId;
};

Result<DaemonConfig> loadConfig(const std::string& path);
Status validateConfig(const DaemonConfig& c);

}  // namespace alacs::app
