// alacs-laser-guard: the process that alone holds the LASER line while alacsd runs
// (drivers/gpiod/laser_guard.h, docs/appliance.md "Laser on-time"). alacsd starts it as
// `alacs-laser-guard --laser-guard FD CHIP LINE MAX_ON_MS`; it is not for people.
//
// A program of its own, not alacsd executed again: it loads in milliseconds and its
// mlockall pins libgpiod and the C++ runtime, not the daemon's OpenCV and libcamera
// (alacsd itself took 2 s to load inside UML, and pinned 65 MB as its own guard).
#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "drivers/gpiod/laser_guard.h"

int main(int argc, char** argv) {
  if (argc != 6 || std::string_view(argv[1]) != "--laser-guard") {
    std::fprintf(stderr, "usage: alacs-laser-guard --laser-guard FD CHIP LINE MAX_ON_MS (started by alacsd)\n");
    return 2;
  }
  return alacs::drivers::runLaserGuard(std::atoi(argv[2]), argv[3], argv[4], std::atoi(argv[5]));
}
