// The scan worker's two passes over a localize plan, for the twin's generator and
// `alacs-twin process` (twin.h).
#include "twin.h"

namespace alacs::twin {

TwoPassScan twoPassScan(const localize::Localizer& loc, const localize::ScanPlan& plan, double strokeMm, bool followUp,
                        const ObserveAt& observeAt) {
  TwoPassScan out;
  for (double s : plan.stopsMm)
    if (Result<localize::LineObservation> ob = observeAt(s, 1)) out.lines.push_back(std::move(*ob));
  out.firstPass = loc.estimate(plan, out.lines);
  out.estimate = out.firstPass;
  if (!followUp) return out;
  out.followUpMm = loc.followUpStops(plan, out.lines, out.firstPass, strokeMm);
  if (out.followUpMm.empty()) return out;
  for (double s : out.followUpMm)
    if (Result<localize::LineObservation> ob = observeAt(s, 2)) out.lines.push_back(std::move(*ob));
  out.estimate = loc.estimate(plan, out.lines);
  return out;
}

}  // namespace alacs::twin
