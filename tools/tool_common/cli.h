// The host tools' command lines, through CLI11: one convention for every tool.
#pragma once

#include <CLI/CLI.hpp>
#include <algorithm>
#include <iostream>
#include <string>
#include <vector>

namespace alacs::tools {

// The exit status of a command line that was refused (unknown option, bad value, missing
// argument): every tool returns it, and its scripts rely on it.
inline constexpr int kUsageExit = 2;

// Prints a refused command line as one line on stderr, "<tool>: <what>", and returns
// kUsageExit.
inline int usageError(const CLI::App& app, std::string what) {
  std::replace(what.begin(), what.end(), '\n', ' ');
  std::cerr << app.get_name() << ": " << what << " (--help for usage)\n";
  return kUsageExit;
}

// Parses argv with `app`. Returns -1 when the tool goes on; otherwise the status to exit
// with: 0 after --help (the help on stdout), kUsageExit after a refused command line
// (one line on stderr). CLI11's own exit codes (105, 106, ...) never reach the shell.
inline int parseCommandLine(CLI::App& app, int argc, const char* const* argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);
    // An argument no option took (a typo) is the cause to name, before what it left
    // missing ("--scans is required"), which CLI11 checks first.
    const std::vector<std::string> extra = app.remaining(true);
    if (!extra.empty() && e.get_name() != "ExtrasError") return usageError(app, "unexpected argument " + extra.front());
    return usageError(app, e.what());
  }
  return -1;
}

}  // namespace alacs::tools
