#include "drivers/gpiod/gpiod_lines.h"

#include <gpiod.h>

#include <cerrno>
#include <cstring>
#include <dirent.h>
#include <vector>

#include "drivers/gpiod/laser_guard.h"

namespace alacs::drivers {
namespace {

Status ioError(const std::string& what) { return {Error::kIo, what + ": " + std::strerror(errno)}; }
Status lineNotFound(const std::string& name, const std::string& chip) {
  return {Error::kNotFound, "GPIO line '" + name + "' not found on " + chip};
}

std::vector<std::string> chipPaths() {
  std::vector<std::string> out;
  DIR* d = opendir("/dev");
  if (d == nullptr) return out;
  while (dirent* e = readdir(d)) {
    if (std::strncmp(e->d_name, "gpiochip", 8) == 0) out.push_back(std::string("/dev/") + e->d_name);
  }
  closedir(d);
  return out;
}

struct ChipDeleter {
  void operator()(gpiod_chip* c) const { gpiod_chip_close(c); }
};
using ChipPtr = std::unique_ptr<gpiod_chip, ChipDeleter>;

// What differs between the two libgpiod APIs, behind four functions per API:
//   bool chipMatches(gpiod_chip*, const std::string& labelOrName);
//   std::string chipLabelName(gpiod_chip*);
//   Result<std::unique_ptr<ports::DigitalOut>> requestOut(gpiod_chip*, name, chipSpec, consumer);
//   Result<std::unique_ptr<ports::DigitalIn>> requestIn(gpiod_chip*, name, activeLow, chipSpec, consumer);
// Outputs are requested deasserted.

#if ALACS_GPIOD_API == 1
// ---------------------------------------------------------------- libgpiod 1.x
bool chipMatches(gpiod_chip* c, const std::string& spec) { return spec == gpiod_chip_label(c) || spec == gpiod_chip_name(c); }
std::string chipLabelName(gpiod_chip* c) { return gpiod_chip_name(c); }

class LineOut final : public ports::DigitalOut {
 public:
  explicit LineOut(gpiod_line* line) : line_(line) {}
  ~LineOut() override { gpiod_line_release(line_); }

 private:
  Status doSet(bool asserted) override {
    if (gpiod_line_set_value(line_, asserted ? 1 : 0) < 0) return ioError("gpiod_line_set_value");
    return Status::ok();
  }
  gpiod_line* line_;
};

class LineIn final : public ports::DigitalIn {
 public:
  explicit LineIn(gpiod_line* line) : line_(line) {}
  ~LineIn() override { gpiod_line_release(line_); }

 private:
  Result<bool> doGet() override {
    const int v = gpiod_line_get_value(line_);
    if (v < 0) return Status(ioError("gpiod_line_get_value"));
    return v != 0;
  }
  gpiod_line* line_;
};

Result<std::unique_ptr<ports::DigitalOut>> requestOut(gpiod_chip* chip, const std::string& name,
                                                      const std::string& chipSpec, const std::string& consumer) {
  gpiod_line* l = gpiod_chip_find_line(chip, name.c_str());
  if (l == nullptr) return lineNotFound(name, chipSpec);
  if (gpiod_line_request_output(l, consumer.c_str(), 0) < 0)
    return Status(ioError("cannot request GPIO line '" + name + "' as output"));
  return std::unique_ptr<ports::DigitalOut>(std::make_unique<LineOut>(l));
}

Result<std::unique_ptr<ports::DigitalIn>> requestIn(gpiod_chip* chip, const std::string& name, bool activeLow,
                                                    const std::string& chipSpec, const std::string& consumer) {
  gpiod_line* l = gpiod_chip_find_line(chip, name.c_str());
  if (l == nullptr) return lineNotFound(name, chipSpec);
  const int flags = activeLow ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
  if (gpiod_line_request_input_flags(l, consumer.c_str(), flags) < 0)
    return Status(ioError("cannot request GPIO line '" + name + "' as input"));
  return std::unique_ptr<ports::DigitalIn>(std::make_unique<LineIn>(l));
}

#else
// ---------------------------------------------------------------- libgpiod 2.x
struct RequestDeleter {
  void operator()(gpiod_line_request* r) const { gpiod_line_request_release(r); }
};
using RequestPtr = std::unique_ptr<gpiod_line_request, RequestDeleter>;

template <typename F>
auto withChipInfo(gpiod_chip* c, F f) {
  gpiod_chip_info* info = gpiod_chip_get_info(c);
  auto r = f(info);
  if (info != nullptr) gpiod_chip_info_free(info);
  return r;
}
bool chipMatches(gpiod_chip* c, const std::string& spec) {
  return withChipInfo(c, [&](gpiod_chip_info* info) {
    return info != nullptr && (spec == gpiod_chip_info_get_label(info) || spec == gpiod_chip_info_get_name(info));
  });
}
std::string chipLabelName(gpiod_chip* c) {
  return withChipInfo(c, [](gpiod_chip_info* info) {
    return info != nullptr ? std::string(gpiod_chip_info_get_name(info)) : std::string();
  });
}

// One request per line keeps each port independent (and each release safe).
Result<RequestPtr> requestLine(gpiod_chip* chip, unsigned int offset, bool output, bool activeLow,
                               const std::string& consumer) {
  gpiod_line_settings* settings = gpiod_line_settings_new();
  gpiod_line_config* config = gpiod_line_config_new();
  gpiod_request_config* rconfig = gpiod_request_config_new();
  RequestPtr req;
  if (settings != nullptr && config != nullptr && rconfig != nullptr) {
    gpiod_line_settings_set_direction(settings, output ? GPIOD_LINE_DIRECTION_OUTPUT : GPIOD_LINE_DIRECTION_INPUT);
    gpiod_line_settings_set_active_low(settings, activeLow);
    if (output) gpiod_line_settings_set_output_value(settings, GPIOD_LINE_VALUE_INACTIVE);
    if (gpiod_line_config_add_line_settings(config, &offset, 1, settings) == 0) {
      gpiod_request_config_set_consumer(rconfig, consumer.c_str());
      req.reset(gpiod_chip_request_lines(chip, rconfig, config));
    }
  }
  const int err = errno;
  if (rconfig != nullptr) gpiod_request_config_free(rconfig);
  if (config != nullptr) gpiod_line_config_free(config);
  if (settings != nullptr) gpiod_line_settings_free(settings);
  errno = err;
  if (!req) return Status(ioError("cannot request GPIO line offset " + std::to_string(offset)));
  return req;
}

class LineOut final : public ports::DigitalOut {
 public:
  LineOut(RequestPtr req, unsigned int offset) : req_(std::move(req)), offset_(offset) {}

 private:
  Status doSet(bool asserted) override {
    if (gpiod_line_request_set_value(req_.get(), offset_,
                                     asserted ? GPIOD_LINE_VALUE_ACTIVE : GPIOD_LINE_VALUE_INACTIVE) < 0)
      return ioError("gpiod_line_request_set_value");
    return Status::ok();
  }
  RequestPtr req_;
  unsigned int offset_;
};

class LineIn final : public ports::DigitalIn {
 public:
  LineIn(RequestPtr req, unsigned int offset) : req_(std::move(req)), offset_(offset) {}

 private:
  Result<bool> doGet() override {
    const gpiod_line_value v = gpiod_line_request_get_value(req_.get(), offset_);
    if (v == GPIOD_LINE_VALUE_ERROR) return Status(ioError("gpiod_line_request_get_value"));
    return v == GPIOD_LINE_VALUE_ACTIVE;
  }
  RequestPtr req_;
  unsigned int offset_;
};

Result<unsigned int> offsetOf(gpiod_chip* chip, const std::string& name, const std::string& chipSpec) {
  const int off = gpiod_chip_get_line_offset_from_name(chip, name.c_str());
  if (off < 0) return lineNotFound(name, chipSpec);
  return static_cast<unsigned int>(off);
}

Result<std::unique_ptr<ports::DigitalOut>> requestOut(gpiod_chip* chip, const std::string& name,
                                                      const std::string& chipSpec, const std::string& consumer) {
  Result<unsigned int> off = offsetOf(chip, name, chipSpec);
  if (!off) return off.status();
  Result<RequestPtr> req = requestLine(chip, *off, true, false, consumer);
  if (!req) return req.status();
  return std::unique_ptr<ports::DigitalOut>(std::make_unique<LineOut>(std::move(*req), *off));
}

Result<std::unique_ptr<ports::DigitalIn>> requestIn(gpiod_chip* chip, const std::string& name, bool activeLow,
                                                    const std::string& chipSpec, const std::string& consumer) {
  Result<unsigned int> off = offsetOf(chip, name, chipSpec);
  if (!off) return off.status();
  Result<RequestPtr> req = requestLine(chip, *off, false, activeLow, consumer);
  if (!req) return req.status();
  return std::unique_ptr<ports::DigitalIn>(std::make_unique<LineIn>(std::move(*req), *off));
}
#endif

// ---------------------------------------------------------------- both APIs
Result<ChipPtr> openChip(const std::string& chip) {
  if (chip.rfind("/dev/", 0) == 0) {
    gpiod_chip* c = gpiod_chip_open(chip.c_str());
    if (c == nullptr) return Status(ioError("cannot open GPIO chip '" + chip + "'"));
    return ChipPtr(c);
  }
  for (const auto& path : chipPaths()) {
    gpiod_chip* c = gpiod_chip_open(path.c_str());
    if (c == nullptr) continue;
    if (chipMatches(c, chip)) return ChipPtr(c);
    gpiod_chip_close(c);
  }
  return Status(Error::kNotFound, "no GPIO chip labelled '" + chip + "'");
}

class Lines final : public GpiodLines {
 public:
  static Result<std::unique_ptr<GpiodLines>> make(const std::string& chipSpec, const GpioLineNames& names,
                                                  const std::string& consumer, const LaserGuardOptions& guard) {
    Result<ChipPtr> chip = openChip(chipSpec);
    if (!chip) return chip.status();
    auto self = std::unique_ptr<Lines>(new Lines(std::move(*chip)));
    gpiod_chip* c = self->chip_.get();
    auto out = [&](const std::string& name, std::unique_ptr<ports::DigitalOut>* dst) -> Status {
      Result<std::unique_ptr<ports::DigitalOut>> r = requestOut(c, name, chipSpec, consumer);
      if (!r) return r.status();
      *dst = std::move(*r);
      return Status::ok();
    };
    auto in = [&](const std::string& name, bool activeLow, std::unique_ptr<ports::DigitalIn>* dst) -> Status {
      Result<std::unique_ptr<ports::DigitalIn>> r = requestIn(c, name, activeLow, chipSpec, consumer);
      if (!r) return r.status();
      *dst = std::move(*r);
      return Status::ok();
    };
    // First: the laser is off from here on (held by its guard process when there is one).
    if (!guard.exe.empty()) {
      Result<std::unique_ptr<LaserGuardProcess>> g = LaserGuardProcess::spawn(guard.exe, chipSpec, names.laser, guard.maxOnMs);
      if (!g) return g.status();
      self->laser_ = std::move(*g);
    } else if (Status s = out(names.laser, &self->laser_); !s) {
      return s;
    }
    if (Status s = out(names.enable, &self->enable_); !s) return s;
    if (Status s = out(names.step, &self->step_); !s) return s;
    if (Status s = out(names.dir, &self->dir_); !s) return s;
    if (Status s = in(names.home, names.homeActiveLow, &self->home_); !s) return s;
    if (!names.end.empty()) {
      if (Status s = in(names.end, names.endActiveLow, &self->end_); !s) return s;
    }
    self->name_ = chipLabelName(c);
    return std::unique_ptr<GpiodLines>(std::move(self));
  }
  // Members are destroyed in reverse order: the lines are released before the chip closes.
  ~Lines() override { makeSafe(); }
  ports::SensorLines lines() override {
    return {step_.get(), dir_.get(), enable_.get(), laser_.get(), home_.get(), end_.get()};
  }
  void makeSafe() override {
    if (laser_) (void)laser_->set(false);
    if (step_) (void)step_->set(false);
    if (enable_) (void)enable_->set(false);
  }
  std::string chipName() const override { return name_; }

 private:
  explicit Lines(ChipPtr chip) : chip_(std::move(chip)) {}
  ChipPtr chip_;
  std::unique_ptr<ports::DigitalOut> laser_, enable_, step_, dir_;
  std::unique_ptr<ports::DigitalIn> home_, end_;
  std::string name_;
};

}  // namespace

Result<std::unique_ptr<GpiodLines>> GpiodLines::open(const std::string& chip, const GpioLineNames& names,
                                                     const std::string& consumer, const LaserGuardOptions& guard) {
  return Lines::make(chip, names, consumer, guard);
}

namespace {
// One output line with the chip it belongs to (the line is released before the chip closes).
class OwnedOut final : public ports::DigitalOut {
 public:
  OwnedOut(ChipPtr chip, std::unique_ptr<ports::DigitalOut> line) : chip_(std::move(chip)), line_(std::move(line)) {}

 private:
  Status doSet(bool asserted) override { return line_->set(asserted); }
  ChipPtr chip_;
  std::unique_ptr<ports::DigitalOut> line_;
};
}  // namespace

Result<std::unique_ptr<ports::DigitalOut>> GpiodLines::openOutput(const std::string& chip, const std::string& name,
                                                                  const std::string& consumer) {
  Result<ChipPtr> c = openChip(chip);
  if (!c) return c.status();
  Result<std::unique_ptr<ports::DigitalOut>> line = requestOut(c->get(), name, chip, consumer);
  if (!line) return line.status();
  return std::unique_ptr<ports::DigitalOut>(std::make_unique<OwnedOut>(std::move(*c), std::move(*line)));
}

}  // namespace alacs::drivers
