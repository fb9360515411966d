// What the bus says about one localization estimate: its ResultStatus and ResultReason
// (docs/can-protocol.md "Result status and reason"). Pure: the worker calls it on the
// localizer's estimate; the unit tests call it on made-up ones.
#pragma once

#include "localize/localizer.h"
#include "protocol/codec.h"

namespace alacs::app {

struct ResultClass {
  protocol::ResultStatus status = protocol::ResultStatus::kMeasured;
  protocol::ResultReason reason = protocol::ResultReason::kNone;
};

// - no sphere fit: ROUGH_ONLY, TOO_FEW_LINES (the rough position or one line: never a
//   measurement); FAR_FROM_ROUGH when it is the rough position because the fit was more
//   likely another object (ScanParams::roughWhenFarFromRough);
// - a fit more likely another object than the target: AMBIGUOUS, with FAR_FROM_ROUGH or
//   TWO_SURFACES (the best guess still goes out, at its σ and low confidence);
// - a fit of the widened search: MEASURED, OUTSIDE_GATE;
// - otherwise MEASURED, NONE.
inline ResultClass classifyEstimate(const localize::AppleEstimate& est) {
  using localize::AppleEstimate;
  using protocol::ResultReason;
  using protocol::ResultStatus;
  if (!est.sphereFit)
    return {ResultStatus::kRoughOnly, est.doubt == AppleEstimate::Doubt::kFarFromRough ? ResultReason::kFarFromRough
                                                                                       : ResultReason::kTooFewLines};
  if (est.doubt == AppleEstimate::Doubt::kTwoSurfaces) return {ResultStatus::kAmbiguous, ResultReason::kTwoSurfaces};
  if (est.doubt == AppleEstimate::Doubt::kFarFromRough) return {ResultStatus::kAmbiguous, ResultReason::kFarFromRough};
  if (est.outsideGate) return {ResultStatus::kMeasured, ResultReason::kOutsideGate};
  return {};
}

}  // namespace alacs::app
