#include "alacsd_options.h"

#include <CLI/CLI.hpp>
#include <cstdint>
#include <cstdio>

namespace alacs::app {

int parseCommandLine(int argc, char** argv, Options& o, bool& laserOff) {
  CLI::App cli{"alacsd: the ALACS sensor daemon (docs/daemon.md)", "alacsd"};
  cli.set_version_flag("--version", "alacsd " + std::to_string(ALACS_VERSION_MAJOR) + "." +
                                        std::to_string(ALACS_VERSION_MINOR) + "." +
                                        std::to_string(ALACS_VERSION_PATCH));
  cli.add_option("--config", o.configPath, "configuration JSON (default: built-in defaults)")->check(CLI::ExistingFile);
  cli.add_option("--can", o.canInterface, "CAN interface (overrides can.interface)");
  cli.add_option("--node-id", o.nodeId, "CAN node id (overrides can.node_id)")->check(CLI::Range(1, 127));
  cli.add_option("--gpio-chip", o.gpioChip, "GPIO chip path or label (overrides gpio.chip)");
  cli.add_option("--calibration", o.calibrationPath, "calibration JSON (overrides calibration)");
  auto* sim = cli.add_flag("--sim", o.sim, "simulated camera and slide (the built-in scene)");
  cli.add_option("--sim-scene", o.simOpts.scenePath, "scene JSON for --sim")->needs(sim);
  cli.add_option("--sim-truth-out", o.simOpts.truthOut, "write the simulated scene's truth as JSON")->needs(sim);
  cli.add_option("--sim-start-mm", o.simOpts.startMm, "where the simulated slide starts (mm)")->capture_default_str();
  cli.add_option("--sim-fault", o.simOpts.fault,
                 "inject a simulated hardware fault (home-stuck: the home switch never closes)")
      ->check(CLI::IsMember({"camera-timeout", "camera-corrupt", "home-stuck"}));
  cli.add_option("--replay", o.replayDir,
                 "replay a scan directory as the camera (docs/scan-format.md); slide and "
                 "laser simulated; its calibration unless --calibration")
      ->excludes(sim);
  cli.add_option("--record", o.recordDir, "write every scan as a scan directory DIR/scan_NNNN");
  cli.add_option("--record-max-scans", o.recordQuota.maxScans, "keep at most N scans in DIR, the oldest dropped")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  uint64_t recordMaxMb = o.recordQuota.maxBytes >> 20;
  cli.add_option("--record-max-mb", recordMaxMb, "keep at most MB megabytes in DIR, the oldest scans dropped")
      ->check(CLI::Range(uint64_t{1}, uint64_t{1} << 30))
      ->capture_default_str();
  cli.add_option("--debug-dir", o.simOpts.debugDir,
                 "write an overlay PNG of the lines found per scan (overlay_NNNN.png)");
  cli.add_flag("--laser-off", laserOff, "drive the configured LASER line off and exit (the unit's ExecStopPost)");
  cli.add_option("--log-level", o.level, "log level")
      ->check(CLI::IsMember({"error", "warning", "info", "debug"}))
      ->capture_default_str();
  try {
    cli.parse(argc, argv);
    if (!o.simOpts.fault.empty() && !o.sim && o.replayDir.empty())
      throw CLI::ValidationError("--sim-fault needs --sim or --replay");
  } catch (const CLI::Success& e) {  // --help, --version
    return cli.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "alacsd: %s (see --help)\n", e.what());
    return 2;
  }
  o.recordQuota.maxBytes = recordMaxMb << 20;
  return -1;
}

}  // namespace alacs::app
