// The simulated and the replay platforms (library alacs_app_sim, the only part of the
// daemon that links the simulator; the board's build leaves it out with
// -DALACS_WITH_SIM=OFF). The slide and the laser are simulated from the same STEP, DIR,
// ENABLE and LASER pulses the hardware gets; on the bench a real GPIO chip is driven too
// (tee) and its END line can close the end switch. The camera renders the scene
// (sim) or serves a recorded scan directory (replay, docs/scan-format.md).
#pragma once

#include <memory>
#include <string>

#include "app/platform.h"
#include "app/sim_options.h"

namespace alacs::app {

// Errors: a bad scene file, a bad fault name, the GPIO chip (when gpio.chip is set), CAN.
Result<std::unique_ptr<Platform>> openSimPlatform(const DaemonConfig& cfg, const SimOptions& opts, const Clock& clock,
                                                  Sleeper& sleeper);
// The camera replays `dir`; its calibration.json unless opts.calibrationPath is given.
// Errors: the scan directory, frames of another size than the calibration's (refused
// before any frame buffer and before the CAN bus is opened), the GPIO chip, CAN.
Result<std::unique_ptr<Platform>> openReplayPlatform(const DaemonConfig& cfg, const std::string& dir,
                                                     const SimOptions& opts, const Clock& clock, Sleeper& sleeper);

}  // namespace alacs::app
