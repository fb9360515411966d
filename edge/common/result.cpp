#include "common/result.h"

namespace alacs {

const char* errorName(Error e) {
  switch (e) {
    case Error::kNone: return "none";
    case Error::kInvalidArgument: return "invalid-argument";
    case Error::kBadInput: return "bad-input";
    case Error::kNotFound: return "not-found";
    case Error::kIo: return "io";
    case Error::kTimeout: return "timeout";
    case Error::kBusy: return "busy";
    case Error::kNotCalibrated: return "not-calibrated";
    case Error::kNotHomed: return "not-homed";
    case Error::kOutOfRange: return "out-of-range";
    case Error::kLimitHit: return "limit-hit";
    case Error::kFault: return "fault";
    case Error::kUnsupported: return "unsupported";
    case Error::kInternal: return "internal";
  }
  return "unknown";
}

std::string Status::toString() const {
  if (isOk()) return "ok";
  return std::string(errorName(code_)) + ": " + reason_;
}

}  // namespace alacs
