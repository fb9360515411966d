#include "drivers/gpiod/gpiod_lines.h"

#include <gpiod.h>

#include <cerrno>
#include <cstring>
#include <dirent.h>
#include <vector>

namespace alacs::drivers {
namespace {

Status ioError(const std::string& what) { return {Error::kIo, what + ": " + std::strerror(errno)}; }

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

#if ALACS_GPIOD_API == 1
// ---------------------------------------------------------------- libgpiod 1.x
struct ChipDeleter { void operator()(gpiod_chip* c) const { gpiod_chip_close(c); } };
using ChipPtr = std::unique_ptr<gpiod_chip, ChipDeleter>;

Result<ChipPtr> openChip(const std::string& chip) {
  if (chip.rfind("/dev/", 0) == 0) {
    gpiod_chip* c = gpiod_chip_open(chip.c_str());
    if (c == nullptr) return Status(ioError("cannot open GPIO chip '" + chip + "'"));
    return ChipPtr(c);
  }
  for (const auto& path : chipPaths()) {
    gpiod_chip* c = gpiod_chip_open(path.c_str());
    if (c == nullptr) continue;
    if (chip == gpiod_chip_label(c) || chip == gpiod_chip_name(c)) return ChipPtr(c);
    gpiod_chip_close(c);
  }
  return Status(Error::kNotFound, "no GPIO chip labelled '" + chip + "'");
}

class V1Out final : public ports::DigitalOut {
 public:
  explicit V1Out(gpiod_line* line) : line_(line) {}
  ~V1Out() override { gpiod_line_release(line_); }
 private:
  Status doSet(bool asserted) override {
    if (gpiod_line_set_value(line_, asserted ? 1 : 0) < 0) return ioError("gpiod_line_set_value");
    return Status::ok();
  }
  gpiod_line* line_;
};

class V1In final : public ports::DigitalIn {
 public:
  explicit V1In(gpiod_line* line) : line_(line) {}
  ~V1In() override { gpiod_line_release(line_); }
 private:
  Result<bool> doGet() override {
    const int v = gpiod_line_get_value(line_);
    if (v < 0) return Status(ioError("gpiod_line_get_value"));
    return v != 0;
  }
  gpiod_line* line_;
};

class V1Lines final : public GpiodLines {
 public:
  static Result<std::unique_ptr<GpiodLines>> make(const std::string& chipSpec, const GpioLineNames& names,
                                                  const std::string& consumer) {
    Result<ChipPtr> chip = openChip(chipSpec);
    if (!chip) return chip.status();
    auto self = std::unique_ptr<V1Lines>(new V1Lines(std::move(*chip)));
    auto out = [&](const std::string& name, std::unique_ptr<ports::DigitalOut>* dst) -> Status {
      gpiod_line* l = gpiod_chip_find_line(self->chip_.get(), name.c_str());
      if (l == nullptr) return {Error::kNotFound, "GPIO line '" + name + "' not found on " + chipSpec};
      if (gpiod_line_request_output(l, consumer.c_str(), 0) < 0)
        return ioError("cannot request GPIO line '" + name + "' as output");
      *dst = std::make_unique<V1Out>(l);
      return Status::ok();
    };
    auto in = [&](const std::string& name, bool activeLow, std::unique_ptr<ports::DigitalIn>* dst) -> Status {
      gpiod_line* l = gpiod_chip_find_line(self->chip_.get(), name.c_str());
      if (l == nullptr) return {Error::kNotFound, "GPIO line '" + name + "' not found on " + chipSpec};
      const int flags = activeLow ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
      if (gpiod_line_request_input_flags(l, consumer.c_str(), flags) < 0)
        return ioError("cannot request GPIO line '" + name + "' as input");
      *dst = std::make_unique<V1In>(l);
      return Status::ok();
    };
    if (Status s = out(names.laser, &self->laser_); !s) return s;  // first: the laser is off from here on
    if (Status s = out(names.enable, &self->enable_); !s) return s;
    if (Status s = out(names.step, &self->step_); !s) return s;
    if (Status s = out(names.dir, &self->dir_); !s) return s;
    if (Status s = in(names.home, names.homeActiveLow, &self->home_); !s) return s;
    if (!names.end.empty()) {
      if (Status s = in(names.end, names.endActiveLow, &self->end_); !s) return s;
    }
    self->name_ = gpiod_chip_name(self->chip_.get());
    return std::unique_ptr<GpiodLines>(std::move(self));
  }
  ~V1Lines() override {
    makeSafe();
    // Lines must be released before the chip is closed.
    laser_.reset(); enable_.reset(); step_.reset(); dir_.reset(); home_.reset(); end_.reset();
  }
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
  explicit V1Lines(ChipPtr chip) : chip_(std::move(chip)) {}
  ChipPtr chip_;
  std::unique_ptr<ports::DigitalOut> laser_, enable_, step_, dir_;
  std::unique_ptr<ports::DigitalIn> home_, end_;
  std::string name_;
};
using Backend = V1Lines;

#else
// ---------------------------------------------------------------- libgpiod 2.x
struct ChipDeleter { void operator()(gpiod_chip* c) const { gpiod_chip_close(c); } };
struct RequestDeleter { void operator()(gpiod_line_request* r) const { gpiod_line_request_release(r); } };
using ChipPtr = std::unique_ptr<gpiod_chip, ChipDeleter>;
using RequestPtr = std::unique_ptr<gpiod_line_request, RequestDeleter>;

Result<ChipPtr> openChip(const std::string& chip) {
  if (chip.rfind("/dev/", 0) == 0) {
    gpiod_chip* c = gpiod_chip_open(chip.c_str());
    if (c == nullptr) return Status(ioError("cannot open GPIO chip '" + chip + "'"));
    return ChipPtr(c);
  }
  for (const auto& path : chipPaths()) {
    gpiod_chip* c = gpiod_chip_open(path.c_str());
    if (c == nullptr) continue;
    gpiod_chip_info* info = gpiod_chip_get_info(c);
    const bool match = info != nullptr && (chip == gpiod_chip_info_get_label(info) || chip == gpiod_chip_info_get_name(info));
    if (info != nullptr) gpiod_chip_info_free(info);
    if (match) return ChipPtr(c);
    gpiod_chip_close(c);
  }
  return Status(Error::kNotFound, "no GPIO chip labelled '" + chip + "'");
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

class V2Out final : public ports::DigitalOut {
 public:
  V2Out(RequestPtr req, unsigned int offset) : req_(std::move(req)), offset_(offset) {}
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

class V2In final : public ports::DigitalIn {
 public:
  V2In(RequestPtr req, unsigned int offset) : req_(std::move(req)), offset_(offset) {}
 private:
  Result<bool> doGet() override {
    const gpiod_line_value v = gpiod_line_request_get_value(req_.get(), offset_);
    if (v == GPIOD_LINE_VALUE_ERROR) return Status(ioError("gpiod_line_request_get_value"));
    return v == GPIOD_LINE_VALUE_ACTIVE;
  }
  RequestPtr req_;
  unsigned int offset_;
};

class V2Lines final : public GpiodLines {
 public:
  static Result<std::unique_ptr<GpiodLines>> make(const std::string& chipSpec, const GpioLineNames& names,
                                                  const std::string& consumer) {
    Result<ChipPtr> chip = openChip(chipSpec);
    if (!chip) return chip.status();
    auto self = std::unique_ptr<V2Lines>(new V2Lines(std::move(*chip)));
    auto offsetOf = [&](const std::string& name) -> Result<unsigned int> {
      const int off = gpiod_chip_get_line_offset_from_name(self->chip_.get(), name.c_str());
      if (off < 0) return Status(Error::kNotFound, "GPIO line '" + name + "' not found on " + chipSpec);
      return static_cast<unsigned int>(off);
    };
    auto out = [&](const std::string& name, std::unique_ptr<ports::DigitalOut>* dst) -> Status {
      Result<unsigned int> off = offsetOf(name);
      if (!off) return off.status();
      Result<RequestPtr> req = requestLine(self->chip_.get(), *off, true, false, consumer);
      if (!req) return req.status();
      *dst = std::make_unique<V2Out>(std::move(*req), *off);
      return Status::ok();
    };
    auto in = [&](const std::string& name, bool activeLow, std::unique_ptr<ports::DigitalIn>* dst) -> Status {
      Result<unsigned int> off = offsetOf(name);
      if (!off) return off.status();
      Result<RequestPtr> req = requestLine(self->chip_.get(), *off, false, activeLow, consumer);
      if (!req) return req.status();
      *dst = std::make_unique<V2In>(std::move(*req), *off);
      return Status::ok();
    };
    if (Status s = out(names.laser, &self->laser_); !s) return s;
    if (Status s = out(names.enable, &self->enable_); !s) return s;
    if (Status s = out(names.step, &self->step_); !s) return s;
    if (Status s = out(names.dir, &self->dir_); !s) return s;
    if (Status s = in(names.home, names.homeActiveLow, &self->home_); !s) return s;
    if (!names.end.empty()) {
      if (Status s = in(names.end, names.endActiveLow, &self->end_); !s) return s;
    }
    gpiod_chip_info* info = gpiod_chip_get_info(self->chip_.get());
    if (info != nullptr) {
      self->name_ = gpiod_chip_info_get_name(info);
      gpiod_chip_info_free(info);
    }
    return std::unique_ptr<GpiodLines>(std::move(self));
  }
  ~V2Lines() override {
    makeSafe();
    laser_.reset(); enable_.reset(); step_.reset(); dir_.reset(); home_.reset(); end_.reset();
  }
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
  explicit V2Lines(ChipPtr chip) : chip_(std::move(chip)) {}
  ChipPtr chip_;
  std::unique_ptr<ports::DigitalOut> laser_, enable_, step_, dir_;
  std::unique_ptr<ports::DigitalIn> home_, end_;
  std::string name_;
};
using Backend = V2Lines;
#endif

}  // namespace

Result<std::unique_ptr<GpiodLines>> GpiodLines::open(const std::string& chip, const GpioLineNames& names,
                                                     const std::string& consumer) {
  return Backend::make(chip, names, consumer);
}

}  // namespace alacs::drivers
