// Result and error codes shared by every component.
//
// No exception crosses a component boundary: functions that can fail return
// `Status` or `Result<T>`. The error enum maps one-to-one onto the reason codes the
// CAN protocol reports (see can_protocol/alacs.dbc, NackReason and EmcyReason), so a
// failure deep in a driver reaches the integrator's bus with its reason intact.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <variant>

namespace alacs {

enum class Error {
  kNone = 0,
  kInvalidArgument,   // a caller passed a value outside its documented range
  kBadInput,          // external data (frame, file, CAN frame) is malformed
  kNotFound,          // a device, line, file or camera does not exist
  kIo,                // the OS refused an operation
  kTimeout,           // a deadline passed
  kBusy,              // the component is doing something else
  kNotCalibrated,     // no valid calibration is loaded
  kNotHomed,          // the slide position is unknown
  kOutOfRange,        // a target lies outside the stroke or the working range
  kLimitHit,          // a limit switch fired unexpectedly
  kFault,             // the device is in the fault state
  kUnsupported,       // the build lacks the driver or feature
  kInternal,          // a bug: should never reach the bus
};

const char* errorName(Error e);

// An error code with a human-readable reason for the log and the docs.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(Error code, std::string reason) : code_(code), reason_(std::move(reason)) {}
  static Status ok() { return {}; }

  bool isOk() const { return code_ == Error::kNone; }
  explicit operator bool() const { return isOk(); }
  Error code() const { return code_; }
  const std::string& reason() const { return reason_; }
  std::string toString() const;

 private:
  Error code_ = Error::kNone;
  std::string reason_;
};

template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : value_(std::move(value)) {}  // NOLINT: implicit by design
  Result(Status error) : error_(std::move(error)) {}  // NOLINT
  Result(Error code, std::string reason) : error_(Status(code, std::move(reason))) {}

  bool isOk() const { return value_.has_value(); }
  explicit operator bool() const { return isOk(); }
  const T& value() const& { return *value_; }
  T& value() & { return *value_; }
  T&& value() && { return std::move(*value_); }
  const T* operator->() const { return &*value_; }
  T* operator->() { return &*value_; }
  const T& operator*() const { return *value_; }
  T& operator*() { return *value_; }
  const Status& status() const { return error_; }

 private:
  std::optional<T> value_;
  Status error_;
};

}  // namespace alacs
