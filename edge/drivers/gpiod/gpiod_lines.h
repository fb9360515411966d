// libgpiod adapter: the box's lines requested by NAME from one GPIO chip, exposed as
// the ports' DigitalOut/DigitalIn. Built against the v1 API (Debian 12, libgpiod 1.6)
// or the v2 API (Yocto scarthgap, libgpiod 2.x), chosen at configure time. No gpiod
// type leaves this folder; its errors become Status here.
#pragma once

#include <memory>
#include <string>

#include "ports/digital_io.h"

namespace alacs::drivers {

using GpioLineNames = ports::SensorLineNames;  // the configuration's `gpio` table

// The LASER line through a guard process of its own (laser_guard.h): `exe` is the binary
// that serves `--laser-guard` (alacsd itself); empty: the line is requested here.
struct LaserGuardOptions {
  std::string exe;
  int maxOnMs = 250;
};

class GpiodLines {
 public:
  // `chip` is a device path (/dev/gpiochip0) or a chip label (alacs-sim). Outputs are
  // requested deasserted (laser off, motor disabled). Errors name the missing line.
  static Result<std::unique_ptr<GpiodLines>> open(const std::string& chip, const GpioLineNames& names,
                                                  const std::string& consumer, const LaserGuardOptions& guard = {});
  // One output line, deasserted, owning its chip (the laser guard's).
  static Result<std::unique_ptr<ports::DigitalOut>> openOutput(const std::string& chip, const std::string& name,
                                                               const std::string& consumer);
  virtual ~GpiodLines() = default;
  virtual ports::SensorLines lines() = 0;
  // Drives every output to its safe level (laser off, motor disabled, STEP low).
  virtual void makeSafe() = 0;
  virtual std::string chipName() const = 0;
};

}  // namespace alacs::drivers
