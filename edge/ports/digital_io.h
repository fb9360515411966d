// Role-specific digital I/O ports (Pigweed's pw_digital_io shape): public non-virtual
// methods state the contract, private Do*() virtuals do the work. Levels are LOGICAL:
// `true` means asserted (laser on, switch pressed); active-low wiring is the driver's
// business, configured per line.
#pragma once

#include <string>

#include "common/result.h"

namespace alacs::ports {

class DigitalOut {
 public:
  virtual ~DigitalOut() = default;
  // Drives the line. Thread-safe for one writer. Errors: kIo from the driver.
  Status set(bool asserted) { return doSet(asserted); }

 private:
  virtual Status doSet(bool asserted) = 0;
};

class DigitalIn {
 public:
  virtual ~DigitalIn() = default;
  // Reads the line now. Errors: kIo from the driver.
  Result<bool> get() { return doGet(); }

 private:
  virtual Result<bool> doGet() = 0;
};

// The lines of one ALACS box.
struct SensorLines {
  DigitalOut* step = nullptr;
  DigitalOut* dir = nullptr;      // asserted: away from home (increasing slide mm)
  DigitalOut* enable = nullptr;   // asserted: motor driver energised
  DigitalOut* laser = nullptr;    // asserted: laser emitting
  DigitalIn* home = nullptr;      // asserted: slide at home (0 mm)
  DigitalIn* end = nullptr;       // optional, asserted: slide at the far end
};

// The names of those lines on the board's GPIO chip (gpio-line-names in the device tree),
// and which switches are wired active-low: the configuration's `gpio` table, read by the
// app and used by the GPIO driver.
struct SensorLineNames {
  std::string step = "STEP";
  std::string dir = "DIR";
  std::string enable = "ENABLE";
  std::string laser = "LASER";
  std::string home = "HOME";
  std::string end = "END";  // empty: no end switch
  bool homeActiveLow = false;
  bool endActiveLow = false;
};

}  // namespace alacs::ports
