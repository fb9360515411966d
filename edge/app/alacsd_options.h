// alacsd's command line (CLI11): the options, their checks and --help (docs/daemon.md,
// "Options"). Part of the alacsd executable, not of alacs_app.
#pragma once

#include <string>

#include "app/sim_options.h"
#include "replay/scan_recorder.h"

namespace alacs::app {

struct Options {
  std::string configPath, canInterface, gpioChip, calibrationPath, replayDir, recordDir;
  int nodeId = 0;
  replay::RecordQuota recordQuota;
  bool sim = false;
  SimOptions simOpts;
  std::string level = "info";
};

// Parses argv into `o` (`laserOff`: --laser-off). Returns -1 when alacsd goes on;
// otherwise the status to exit with: 0 after --help or --version, 2 after a refused
// command line (one line on stderr).
int parseCommandLine(int argc, char** argv, Options& o, bool& laserOff);

}  // namespace alacs::app
