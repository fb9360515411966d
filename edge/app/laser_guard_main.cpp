// alacs-laser-guard: the process that alone holds the LASER line while alacsd runs
// (drivers/gpiod/laser_guard.h, docs/appliance.md "Laser on-time"). alacsd starts it as
// `alacs-laser-guard --laser-guard FD CHIP LINE MAX_ON_MS`; it is not for people.
//
// A program of its own, not alacsd executed again: it loads in milliseconds and its
// mlockall pins libgpiod and the C++ runtime, not the daemon's OpenCV and libcamera
// (alacsd itself took 2 s to load inside UML, and pinned 65 MB as its own guard).
#include <cstdio>

#include "drivers/gpiod/laser_guard.h"

int main(int argc, char** argv) {
  const int exit = alacs::drivers::runLaserGuardFromArgs(argc, argv);
  if (exit >= 0) return exit;
  std::fprintf(stderr, "usage: alacs-laser-guard --laser-guard FD CHIP LINE MAX_ON_MS (started by alacsd)\n");
  return 2;
}
