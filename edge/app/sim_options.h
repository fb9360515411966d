// The daemon's options for the simulated and the replay platforms (alacsd --sim-*,
// --debug-dir). Plain data in alacs_app, so that alacsd parses the same command line in
// the board's build (ALACS_WITH_SIM=OFF), which has no sim_platform.h and refuses --sim
// and --replay at start.
#pragma once

#include <string>

namespace alacs::app {

struct SimOptions {
  std::string scenePath;        // empty: sim::defaultScene()
  std::string truthOut;         // write the scene's truth here (tests)
  std::string calibrationPath;  // empty: the scene's true calibration (sim), the directory's (replay)
  std::string fault;            // camera-timeout | camera-corrupt | home-stuck | empty
  std::string debugDir;         // the laser timeline of each scan goes here (laser_timeline.json)
  double startMm = 37.0;        // where the simulated slide starts
};

}  // namespace alacs::app
