#include "localize/localizer.h"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <limits>

#include "geometry/spheroid_fit.h"
#include "localize/leaf_colour.h"
#include "localize/weak_arc.h"

namespace alacs::localize {

namespace {

// P(|e| <= x) for a 3D error with isotropic Gaussian components whose total 1σ is
// sigma3d (Maxwell distribution).
double withinProbability(double x, double sigma3d) {
  if (!(sigma3d > 0.0)) return 1.0;
  const double a = sigma3d / std::sqrt(3.0);
  const double u = x / a;
  return std::clamp(std::erf(u / std::sqrt(2.0)) - std::sqrt(2.0 / M_PI) * u * std::exp(-0.5 * u * u), 0.0, 1.0);
}

// The chance that an object whose centre lies dMm from the rough position is the target:
// under "the target" the distance follows the rough position's error (Maxwell, sigmaMm per
// axis); under "another object" it is uniform in the ball of radius ballMm; `otherPrior`
// is the prior share of the latter. Both densities carry d² (the shell's area), which
// cancels in their ratio and is left out of both.
double targetProbability(double dMm, double sigmaMm, double ballMm, double otherPrior) {
  if (!(sigmaMm > 0.0) || !(otherPrior > 0.0)) return 1.0;
  const double ball = std::max(ballMm, dMm + 1.0);
  const double logTarget = 0.5 * std::log(2.0 / M_PI) - 3.0 * std::log(sigmaMm) - 0.5 * dMm * dMm / (sigmaMm * sigmaMm);
  const double logOther = std::log(3.0) - 3.0 * std::log(ball);
  const double a = std::log1p(-otherPrior) + logTarget;
  const double b = std::log(otherPrior) + logOther;
  return 1.0 / (1.0 + std::exp(std::clamp(b - a, -700.0, 700.0)));
}

constexpr double kToleranceMm = 20.0;  // the vacuum end effector's tolerance (paper)
constexpr double kSingleLineSigmaMm = 15.0;  // 3D 1σ of what one line says (see estimateSingleLine)
constexpr double kPieceBreakMm = 6.0;
// Lines from which a fit leaves little room for a sphere through two objects' pieces (or for
// one line on a leaf); fewer, and another object is the likelier (otherObjectPrior).
constexpr int kFirmLines = 3;

// One line per stop: a replay may serve the same recorded frame for two planned stops.
std::vector<LineObservation> uniqueStops(const std::vector<LineObservation>& observed) {
  constexpr double kSameStopMm = 0.05;
  std::vector<LineObservation> lines;
  lines.reserve(observed.size());
  for (const LineObservation& o : observed)
    if (std::none_of(lines.begin(), lines.end(),
                     [&](const LineObservation& l) { return std::abs(l.slideMm - o.slideMm) < kSameStopMm; }))
      lines.push_back(o);
  return lines;
}

// The spheroid refinement and the sphere it came from, weighed by the evidence for the
// spheroid (geometry::spheroidWeight, Akaike's weights): `est` holds the sphere's estimate
// and leaves with the weighted mean of the two. σ stays the spheroid's, which reckons with
// the aspect the lines may not fix (a round fit where they cannot tell is not a round
// fruit), widened by the two estimates' spread under the weights (docs/geometry.md, "The
// fruit's shape: round unless the lines say otherwise").
void blendSpheroid(const geometry::SpheroidFit& sf, const Eigen::Vector3d& approachMm, const Eigen::Vector3d& normal,
                   AppleEstimate& est) {
  const double w = geometry::spheroidWeight(sf);
  const double spreadVar = w * (1.0 - w);
  const Eigen::Vector3d dApproach = approachMm - est.approachMm;
  const Eigen::Vector3d dCentre = sf.centerMm - est.centerMm;
  const double dDiameter = 2.0 * sf.radiusMm - est.diameterMm;
  est.centerMm += w * dCentre;
  est.approachMm += w * dApproach;
  est.approachNormal = (w * normal + (1.0 - w) * est.approachNormal).normalized();
  est.diameterMm += w * dDiameter;
  est.aspect = 1.0 + w * (sf.aspect - 1.0);
  est.rmsMm += w * (sf.rmsMm - est.rmsMm);
  est.sphereWeight = 1.0 - w;
  const double approachSigma = geometry::spheroidApproachSigma(sf);
  const double centreSigma = std::sqrt(std::max(0.0, sf.covariance.topLeftCorner<3, 3>().trace()));
  const double diameterSigma = 2.0 * std::sqrt(std::max(0.0, sf.covariance(3, 3)));
  est.sigmaMm = std::sqrt(approachSigma * approachSigma + spreadVar * dApproach.squaredNorm());
  est.centerSigmaMm = std::sqrt(centreSigma * centreSigma + spreadVar * dCentre.squaredNorm());
  est.diameterSigmaMm = std::sqrt(diameterSigma * diameterSigma + spreadVar * dDiameter * dDiameter);
}

// The sphere fit takes spheres up to ScanParams::sphereMaxRadiusMm, larger than any fruit's
// equatorial radius, because a prolate or lumpy fruit curves flatter along the vertical
// lines than across. Where the spheroid refinement does not carry the estimate, such a
// sphere's diameter is not the fruit's width: the diameter is held to the largest fruit's,
// and what the sphere said beyond it goes into its σ (docs/geometry.md, "A large prolate
// fruit").
void holdDiameterToLargestFruit(double maxRadiusMm, AppleEstimate& est) {
  const double excessMm = est.diameterMm - 2.0 * maxRadiusMm;
  if (!(excessMm > 0.0)) return;
  est.diameterMm = 2.0 * maxRadiusMm;
  est.diameterHeldMm = excessMm;
  est.diameterSigmaMm = std::hypot(est.diameterSigmaMm, excessMm);
}

}  // namespace

double ScanParams::sphereMaxRadiusMm() const {
  return maxRadiusMm * std::max(1.0, priorAspect + 2.0 * priorAspectSigma);
}

Status ScanParams::validate() const {
  if (stops < 1 || stops > 15) return {Error::kInvalidArgument, "scan.stops must be in 1..15"};
  if (!(stopSpacingMm >= 0.5 && stopSpacingMm <= 50.0)) return {Error::kInvalidArgument, "scan.stop_spacing_mm must be in 0.5..50"};
  if (!(roiMarginMm >= 0.0 && roiMarginMm <= 300.0)) return {Error::kInvalidArgument, "scan.roi_margin_mm must be in 0..300"};
  if (!(gateMm > 10.0 && gateMm < 500.0)) return {Error::kInvalidArgument, "scan.gate_mm must be in 10..500"};
  if (!(searchMm == 0.0 || (searchMm > gateMm && searchMm <= 1000.0)))
    return {Error::kInvalidArgument, "scan.search_mm must be 0 (off) or above scan.gate_mm, up to 1000"};
  if (!(outsideGateConfidencePct >= 0.0 && outsideGateConfidencePct <= 100.0))
    return {Error::kInvalidArgument, "scan.outside_gate_confidence_pct must be in 0..100"};
  // (Not configuration keys: the paper's method is chosen by code, not by the file.)
  if (!(paperW1 >= 0.0 && paperW2 >= 0.0 && paperW1 + paperW2 > 0.0))
    return {Error::kInvalidArgument, "ScanParams::paperW1 and paperW2 must be non-negative, not both zero"};
  if (!(priorRadiusMm >= 20.0 && priorRadiusMm <= 80.0)) return {Error::kInvalidArgument, "scan.prior_radius_mm must be in 20..80"};
  if (!(priorRadiusSigmaMm >= 0.5 && priorRadiusSigmaMm <= 100.0))
    return {Error::kInvalidArgument, "scan.prior_radius_sigma_mm must be in 0.5..100"};
  if (!(minRadiusMm >= 10.0 && maxRadiusMm > minRadiusMm && maxRadiusMm <= 60.0))
    return {Error::kInvalidArgument, "scan.min_radius_mm/max_radius_mm must satisfy 10 <= min < max <= 60"};
  if (!(priorRadiusMm >= minRadiusMm && priorRadiusMm <= maxRadiusMm))
    return {Error::kInvalidArgument, "scan.prior_radius_mm must lie within scan.min_radius_mm..max_radius_mm"};
  if (!(priorAspect >= 0.7 && priorAspect <= 1.2))
    return {Error::kInvalidArgument, "scan.prior_aspect must be in 0.7..1.2"};
  if (!(priorAspectSigma >= 0.01 && priorAspectSigma <= 0.2))
    return {Error::kInvalidArgument, "scan.prior_aspect_sigma must be in 0.01..0.2"};
  // The largest sphere the fit takes (sphereMaxRadiusMm) follows the aspect's 2σ: past the
  // spheroid refinement's largest aspect no sphere that large would ever be refined.
  if (!(priorAspect + 2.0 * priorAspectSigma < 1.25))
    return {Error::kInvalidArgument,
            "scan.prior_aspect + 2 x scan.prior_aspect_sigma must stay below 1.25 (the "
            "spheroid refinement's largest aspect)"};
  if (!(stemTiltSigmaDeg >= 1.0 && stemTiltSigmaDeg <= 90.0))
    return {Error::kInvalidArgument, "scan.stem_tilt_sigma_deg must be in 1..90"};
  if (!(roughSigmaMm >= 0.0 && roughSigmaMm <= 500.0)) return {Error::kInvalidArgument, "scan.rough_sigma_mm must be in 0..500"};
  if (!(roughGateSigmas >= 0.0 && roughGateSigmas <= 100.0))
    return {Error::kInvalidArgument, "ScanParams::roughGateSigmas must be in 0..100"};
  // The gate must hold the largest fruit's face when the rough position is 2σ off: a
  // narrower one leaves the target outside it on ordinary scans (docs/daemon.md).
  if (const double leastGateMm = maxRadiusMm + 2.0 * roughSigmaMm; !(gateMm >= leastGateMm))
    return {Error::kInvalidArgument, "scan.gate_mm must be at least scan.max_radius_mm + 2 x scan.rough_sigma_mm (" +
                                         std::to_string(static_cast<int>(std::ceil(leastGateMm))) +
                                         " mm): the largest fruit with the rough position 2 sigma off"};
  if (followUpMinLines < 1 || followUpMinLines > 15) return {Error::kInvalidArgument, "scan.follow_up_min_lines must be in 1..15"};
  if (followUpMaxStops < 0 || followUpMaxStops > 16) return {Error::kInvalidArgument, "scan.follow_up_max_stops must be in 0..16"};
  if (followUpUnseenMaxStops < 0 || followUpUnseenMaxStops > 32)
    return {Error::kInvalidArgument, "scan.follow_up_unseen_max_stops must be in 0..32"};
  if (!(followUpFarSigmas == 0.0 || (followUpFarSigmas >= 1.0 && followUpFarSigmas <= 10.0)))
    return {Error::kInvalidArgument, "scan.follow_up_far_sigmas must be 0 (off) or in 1..10"};
  if (!(weakArcMinZ == 0.0 || (weakArcMinZ >= 4.0 && weakArcMinZ <= 100.0)))
    return {Error::kInvalidArgument, "scan.weak_arc_min_z must be 0 (off) or in 4..100"};
  if (!(leafGreenRatio == 0.0 || (leafGreenRatio >= 1.1 && leafGreenRatio <= 10.0)))
    return {Error::kInvalidArgument, "scan.leaf_green_ratio must be 0 (off) or in 1.1..10"};
  if (!(followUpHiddenPct >= 0.0 && followUpHiddenPct <= 100.0))
    return {Error::kInvalidArgument, "scan.follow_up_hidden_pct must be in 0..100"};
  if (!(otherObjectPrior >= 0.0 && otherObjectPrior < 1.0))
    return {Error::kInvalidArgument, "scan.other_object_prior must be in 0..1 (1 excluded)"};
  if (!(followUpDiameterSigmaMm >= 0.0 && followUpDiameterSigmaMm <= 100.0))
    return {Error::kInvalidArgument, "scan.follow_up_diameter_sigma_mm must be in 0..100"};
  if (!(lineBiasPx >= 0.0 && lineBiasPx <= 5.0)) return {Error::kInvalidArgument, "scan.line_bias_px must be in 0..5"};
  if (!(shapeIrregularityPct >= 0.0 && shapeIrregularityPct <= 20.0))
    return {Error::kInvalidArgument, "scan.shape_irregularity_pct must be in 0..20"};
  return Status::ok();
}

Localizer::Localizer(const geometry::Calibration& cal, const image::LleParams& lle, const ScanParams& scan,
                     const geometry::WorkingRange& range)
    : cal_(cal), lle_(lle), scan_(scan), range_(range) {}

Result<ScanPlan> Localizer::plan(const Eigen::Vector3d& roughMm, double strokeMm, PlanRefusal* why) const {
  PlanRefusal ignored;
  PlanRefusal& refusal = why != nullptr ? *why : ignored;
  refusal = {};
  if (!(roughMm.z() >= range_.minDepthMm && roughMm.z() <= range_.maxDepthMm)) {
    refusal = {PlanRefusal::Limit::kDepth, roughMm.z(),
               roughMm.z() < range_.minDepthMm ? range_.minDepthMm : range_.maxDepthMm};
    return Status(Error::kOutOfRange, "rough z " + std::to_string(roughMm.z()) + " mm is outside the working range [" +
                                          std::to_string(range_.minDepthMm) + ", " + std::to_string(range_.maxDepthMm) + "]");
  }
  const double centerMm = cal_.laser.slideForPoint(roughMm);
  if (!std::isfinite(centerMm)) return Status(Error::kNotCalibrated, "slide axis does not move the laser plane");
  ScanPlan plan;
  plan.roughMm = roughMm;
  // The window of stops around the target; where it would leave the stroke it is shifted
  // back inside (keeping every stop) as long as the target stays within reach.
  const double span = (scan_.stops - 1) * scan_.stopSpacingMm;
  double first = centerMm - 0.5 * span;
  if (span <= strokeMm && centerMm >= -scan_.maxAppleRadiusMm && centerMm <= strokeMm + scan_.maxAppleRadiusMm)
    first = std::clamp(first, 0.0, strokeMm - span);
  for (int i = 0; i < scan_.stops; ++i) {
    const double s = first + i * scan_.stopSpacingMm;
    if (s >= 0.0 && s <= strokeMm) plan.stopsMm.push_back(s);
  }
  if (plan.stopsMm.empty()) {
    refusal = {PlanRefusal::Limit::kStroke, centerMm, centerMm < 0.0 ? 0.0 : strokeMm};
    return Status(Error::kOutOfRange, "target needs the slide at " + std::to_string(centerMm) +
                                          " mm, outside the stroke [0, " + std::to_string(strokeMm) + "]");
  }
  // ROI: the projected box of the rough centre ± (largest radius + margin).
  const auto& cam = cal_.camera;
  const double r = scan_.maxAppleRadiusMm + scan_.roiMarginMm;
  std::vector<Eigen::Vector3d> corners;
  for (int corner = 0; corner < 8; ++corner)
    corners.push_back(roughMm + r * Eigen::Vector3d((corner & 1) ? 1 : -1, (corner & 2) ? 1 : -1, (corner & 4) ? 1 : -1));
  double u0 = 1e9, v0 = 1e9, u1 = -1e9, v1 = -1e9;
  for (const geometry::PixelPoint& px : geometry::projectPoints(cam, corners)) {
    u0 = std::min(u0, px.columnPx);
    u1 = std::max(u1, px.columnPx);
    v0 = std::min(v0, px.rowPx);
    v1 = std::max(v1, px.rowPx);
  }
  const int x0 = std::clamp(static_cast<int>(std::floor(u0)), 0, cam.widthPx);
  const int x1 = std::clamp(static_cast<int>(std::ceil(u1)), 0, cam.widthPx);
  const int y0 = std::clamp(static_cast<int>(std::floor(v0)), 0, cam.heightPx);
  const int y1 = std::clamp(static_cast<int>(std::ceil(v1)), 0, cam.heightPx);
  plan.roi = {x0, y0, x1 - x0, y1 - y0};
  if (plan.roi.width < 16 || plan.roi.height < 16) {
    refusal = {PlanRefusal::Limit::kFrame, static_cast<double>(std::min(plan.roi.width, plan.roi.height)), 16.0};
    return Status(Error::kOutOfRange, "target is outside the camera's view");
  }
  return plan;
}

namespace {

// Why a first pass is not enough (ScanParams "Adaptive scan"); none: it is.
struct FollowUpNeed {
  bool fewLines = false;     // fewer than followUpMinLines lines reached the fit
  bool unsureSize = false;   // the diameter's σ above followUpDiameterSigmaMm
  bool hidden = false;       // the fruit's expected rows mostly hidden
  bool twoSurfaces = false;  // another object explains the lines about as well
  bool farFromRough = false;  // the fit is more likely another object, away from the rough position
  bool any() const { return fewLines || unsureSize || hidden || twoSurfaces || farFromRough; }
  // Only the size in doubt: the fit is trusted where the fruit is.
  bool sizeOnly() const { return unsureSize && !fewLines && !hidden && !twoSurfaces; }
};

// Points of a line on a surface from which it counts as having seen it: the fruit, for
// where the second pass goes (followUpStops); anything off the widened search's fruit, for
// the gate to count as occupied (kOccupiedGatePoints).
constexpr size_t kMinPointsSeen = 3;

// The second pass's candidate stops: the two thirds between each pair of the first pass's
// (sorted) stops, and two thirds of a spacing beyond either end.
std::vector<double> thirdsBetween(const std::vector<double>& taken, double spacingMm) {
  std::vector<double> out;
  out.push_back(taken.front() - 2.0 * spacingMm / 3.0);
  out.push_back(taken.front() - spacingMm / 3.0);
  for (size_t i = 0; i + 1 < taken.size(); ++i) {
    const double gap = taken[i + 1] - taken[i];
    out.push_back(taken[i] + gap / 3.0);
    out.push_back(taken[i] + 2.0 * gap / 3.0);
  }
  out.push_back(taken.back() + spacingMm / 3.0);
  out.push_back(taken.back() + 2.0 * spacingMm / 3.0);
  return out;
}

}  // namespace

std::vector<double> Localizer::followUpStops(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                             const Result<AppleEstimate>& first, double strokeMm) const {
  if (scan_.followUpMaxStops <= 0 || plan.stopsMm.empty()) return {};
  // A scan that found nothing, or failed, gets none: no line lit anything near the rough
  // position at the first pass's stops, more in between will not.
  if (!first) return {};
  // The second pass follows what the lines saw. An estimate the sunlit arcs made (the lines
  // alone left the target unseen) does not place it: the lines' own estimate does, and the
  // arcs weigh in again at the end, with every line (estimate()).
  if (first->fromWeakArcs) return followUpStops(plan, lines, estimateLines(plan, uniqueStops(lines)), strokeMm);
  FollowUpNeed need;
  need.fewLines = first->linesUsed < scan_.followUpMinLines;
  need.unsureSize = scan_.followUpDiameterSigmaMm > 0.0 && first->diameterSigmaMm > scan_.followUpDiameterSigmaMm;
  need.hidden = scan_.followUpHiddenPct > 0.0 && first->sphereFit && first->occlusionPct >= scan_.followUpHiddenPct;
  need.twoSurfaces = first->doubt == AppleEstimate::Doubt::kTwoSurfaces;
  need.farFromRough = first->doubt == AppleEstimate::Doubt::kFarFromRough ||
                      (scan_.followUpFarSigmas > 0.0 && first->sphereFit &&
                       (first->centerMm - plan.roughMm).norm() > scan_.followUpFarSigmas * scan_.roughSigmaMm);
  if (!need.any()) return {};
  std::vector<double> taken = plan.stopsMm;
  std::sort(taken.begin(), taken.end());
  const double spacingMm = taken.size() > 1 ? taken[1] - taken[0] : scan_.stopSpacingMm;
  // Where the fruit was seen: the first pass's stops whose line put points on it (on the
  // fitted surface when there is a fit; else any gated point). Its lines cut the fruit
  // through the gaps in the leaves; the new stops go there and one spacing round it, not
  // where a leaf hid it at every stop.
  const Eigen::Vector3d& n = cal_.laser.planeNormal;
  const double radius = first->sphereFit ? first->surfaceRadiusMm() : scan_.maxAppleRadiusMm;
  const Eigen::Vector3d centre = first->sphereFit ? first->centerMm : plan.roughMm;
  const double onSurfaceMm = std::max(5.0, 3.0 * first->rmsMm);
  double seenLo = std::numeric_limits<double>::infinity();
  double seenHi = -std::numeric_limits<double>::infinity();
  double seenSum = 0.0;
  std::vector<double> seenAtMm;  // the stops that saw the fruit
  for (const LineObservation& l : lines) {
    size_t on = 0;
    for (const Eigen::Vector3d& p : l.pointsMm)
      if (!first->sphereFit || first->offSurfaceMm(p) < onSurfaceMm) ++on;
    if (on < kMinPointsSeen) continue;
    seenLo = std::min(seenLo, l.slideMm);
    seenHi = std::max(seenHi, l.slideMm);
    seenSum += l.slideMm;
    seenAtMm.push_back(l.slideMm);
  }
  double fromMm = -std::numeric_limits<double>::infinity();
  double toMm = std::numeric_limits<double>::infinity();
  // The rough position stands in, and one line alone put points in the gate: too few for a
  // sphere of their own, so whose they are rests on one line. They may be the target's at
  // the pass's edge, the rough position off along the slide by more than the pass's span.
  const bool loneLine = need.farFromRough && !first->sphereFit && seenAtMm.size() == 1;
  if (need.farFromRough) {
    // What the lines saw is likely another object (a neighbour): the target may show
    // through the gaps round the rough position instead, across a fruit's width.
    const double a = cal_.laser.slideForPoint(plan.roughMm - scan_.maxAppleRadiusMm * n);
    const double b = cal_.laser.slideForPoint(plan.roughMm + scan_.maxAppleRadiusMm * n);
    if (std::isfinite(a) && std::isfinite(b)) {
      fromMm = std::min(a, b);
      toMm = std::max(a, b);
    }
    // A lone line: up to one spacing round it as well (and what lies between).
    if (loneLine) {
      fromMm = std::min(fromMm, seenLo - spacingMm);
      toMm = std::max(toMm, seenHi + spacingMm);
    }
    seenAtMm.clear();  // (nearest the rough position's slide first, below; or the lone line's)
  } else if (!seenAtMm.empty()) {
    fromMm = seenLo - spacingMm;
    toMm = seenHi + spacingMm;
  }
  // Only the size in doubt (the fit rests on enough lines, so its centre is known to a few
  // millimetres): the stops whose plane cuts the fruit well inside its limb are the ones
  // that add to it; the others would cost a slide move and show leaves.
  if (need.sizeOnly()) {
    const double a = cal_.laser.slideForPoint(centre - 0.8 * radius * n);
    const double b = cal_.laser.slideForPoint(centre + 0.8 * radius * n);
    if (std::isfinite(a) && std::isfinite(b)) {
      fromMm = std::max(fromMm, std::min(a, b));
      toMm = std::min(toMm, std::max(a, b));
    }
  }
  // Inside the stroke and not (nearly) a stop already taken: a clamped end stop can land
  // on the first pass's.
  const double minApartMm = std::max(spacingMm / 6.0, 0.25);
  std::vector<double> out;
  for (double s : thirdsBetween(taken, spacingMm)) {
    if (s < fromMm || s > toMm) continue;
    s = std::clamp(s, 0.0, strokeMm);
    const auto near = [&](double t) { return std::abs(t - s) < minApartMm; };
    if (std::none_of(taken.begin(), taken.end(), near) && std::none_of(out.begin(), out.end(), near)) out.push_back(s);
  }
  // When there are more than allowed: first the thirds beside a stop that saw the fruit
  // (the gap in the leaves it saw through; a stop between two that saw it, where a leaf
  // hid it, comes after them), then nearest the middle of where the fruit was seen (else
  // the rough position's slide, or a lone line, whichever is nearer); of two as near, the
  // lower slide position (stable: `out` is ascending). Then one sweep back from where the
  // first pass ended (it went forward: from the far end down).
  const double middleMm =
      seenAtMm.empty() ? cal_.laser.slideForPoint(plan.roughMm) : seenSum / static_cast<double>(seenAtMm.size());
  const double loneMm = loneLine ? seenLo : middleMm;
  const auto away = [&](double s) { return std::min(std::abs(s - middleMm), std::abs(s - loneMm)); };
  const auto besideSeen = [&](double s) {
    return std::any_of(seenAtMm.begin(), seenAtMm.end(), [&](double t) { return std::abs(s - t) <= 0.5 * spacingMm; });
  };
  std::stable_sort(out.begin(), out.end(), [&](double a, double b) {
    const bool besideA = besideSeen(a);
    const bool besideB = besideSeen(b);
    return besideA != besideB ? besideA : away(a) < away(b);
  });
  // Nothing of the fruit seen: no span to follow, the gaps across its width are all
  // candidates (ScanParams::followUpUnseenMaxStops).
  const size_t cap = static_cast<size_t>(seenAtMm.empty() ? scan_.followUpUnseenMaxStops : scan_.followUpMaxStops);
  if (out.size() > cap) out.resize(cap);
  if (plan.stopsMm.back() >= plan.stopsMm.front())
    std::sort(out.begin(), out.end(), std::greater<>());
  else
    std::sort(out.begin(), out.end());
  return out;
}

image::Roi Localizer::stopRoi(const ScanPlan& plan, double slideMm) const {
  // The part of the laser plane within the gate around the rough position is a disc; its
  // image is a narrow band (the plane is seen nearly edge-on). Surfaces much nearer or
  // farther than the target light the plane elsewhere in the row, so LLE, which keeps
  // one peak per row, is not drawn to them.
  const Eigen::Vector3d n = cal_.laser.planeNormal;
  const double delta = n.dot(plan.roughMm) - cal_.laser.planeOffsetAt(slideMm);
  if (!(std::abs(delta) < scan_.gateMm)) return {};
  const Eigen::Vector3d centre = plan.roughMm - delta * n;
  const double rho = std::sqrt(scan_.gateMm * scan_.gateMm - delta * delta);
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  std::vector<Eigen::Vector3d> rim;
  for (int i = 0; i < 48; ++i) {
    const double phi = 2.0 * M_PI * i / 48.0;
    const Eigen::Vector3d q = centre + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
    if (q.z() > 1.0) rim.push_back(q);
  }
  if (rim.empty()) return {};
  // Margin: the line's width and bRCE's reach on each side.
  const double margin = 2.0 * lle_.brceStep + 4.0;
  double u0 = 1e9, v0 = 1e9, u1 = -1e9, v1 = -1e9;
  for (const geometry::PixelPoint& px : geometry::projectPoints(cal_.camera, rim)) {
    u0 = std::min(u0, px.columnPx - margin);
    u1 = std::max(u1, px.columnPx + margin);
    v0 = std::min(v0, px.rowPx - margin);
    v1 = std::max(v1, px.rowPx + margin);
  }
  const image::Roi& r = plan.roi;
  const int x0 = std::max(r.x, static_cast<int>(std::floor(u0)));
  const int x1 = std::min(r.x + r.width, static_cast<int>(std::ceil(u1)));
  const int y0 = std::max(r.y, static_cast<int>(std::floor(v0)));
  const int y1 = std::min(r.y + r.height, static_cast<int>(std::ceil(v1)));
  if (x1 - x0 < 16 || y1 - y0 < 16) return {};
  return {x0, y0, x1 - x0, y1 - y0};
}

Result<LineObservation> Localizer::observe(const image::ImageView& frame, const ScanPlan& plan, double slideMm,
                                           image::LleWorkspace& ws, const image::ImageView* laserOff,
                                           double slideMmPerRow, bool brightAmbient) const {
  if (frame.width != cal_.camera.widthPx || frame.height != cal_.camera.heightPx)
    return Status(Error::kBadInput, "frame is " + std::to_string(frame.width) + "x" + std::to_string(frame.height) +
                                        " but the calibration is for " + std::to_string(cal_.camera.widthPx) + "x" +
                                        std::to_string(cal_.camera.heightPx));
  LineObservation obs;
  obs.slideMm = slideMm;
  const image::Roi roi = stopRoi(plan, slideMm);
  if (roi.empty()) return obs;  // the plane misses the gate: nothing of the target can be lit
  image::LleParams lle = lle_;
  lle.matchedFilter = lle_.matchedFilter && brightAmbient;
  if (Status s = image::extractLine(frame, roi, lle, ws, obs.line, laserOff); !s) return s;
  // Every valid row (the line's and the other surfaces' segments), not only the fitted
  // curve: a leaf can make the line, the fruit another segment; the 3D gate and the
  // robust fit sort the rows out.
  std::vector<geometry::PixelPoint> pixels;
  std::vector<geometry::PixelPoint> leafPixels;
  pixels.reserve(obs.line.rows.size());
  const std::vector<bool> onLeaf = leafSamples(obs.line, laserOff, scan_.leafGreenRatio);
  for (size_t i = 0; i < obs.line.rows.size(); ++i) {
    const image::RowSample& r = obs.line.rows[i];
    if (!r.valid()) continue;
    const geometry::PixelPoint px{static_cast<double>(r.column), static_cast<double>(r.row)};
    (onLeaf[i] ? leafPixels : pixels).push_back(px);
  }
  triangulateRows(plan, slideMm, slideMmPerRow, pixels, &obs.pointsMm, &obs.pixels, &obs.outsidePointsMm);
  if (!leafPixels.empty())
    triangulateRows(plan, slideMm, slideMmPerRow, leafPixels, &obs.leafPointsMm, nullptr, &obs.leafOutsidePointsMm);
  if (laserOff != nullptr && scan_.weakArcMinZ > 0.0) {
    WeakArcParams wp;
    wp.minZ = scan_.weakArcMinZ;
    const WeakArc arc = findWeakArc(frame, *laserOff, roi, cal_, slideMm, plan.roughMm, obs.line,
                                    static_cast<int>(obs.line.segments.size()), wp);
    std::vector<geometry::PixelPoint> arcPixels;
    for (const auto& r : arc.samples) arcPixels.push_back({static_cast<double>(r.column), static_cast<double>(r.row)});
    triangulateRows(plan, slideMm, slideMmPerRow, arcPixels, &obs.arcPointsMm, &obs.arcPixels, nullptr);
  }
  return obs;
}

size_t Localizer::mergeSecondExposure(LineObservation& first, const LineObservation& second) {
  std::vector<int> rowsSeen;
  for (const image::RowSample& r : first.line.rows)
    if (r.valid()) rowsSeen.push_back(r.row);
  for (const geometry::PixelPoint& px : first.pixels) rowsSeen.push_back(static_cast<int>(std::lround(px.rowPx)));
  std::sort(rowsSeen.begin(), rowsSeen.end());
  std::vector<std::pair<geometry::PixelPoint, Eigen::Vector3d>> merged;
  merged.reserve(first.pixels.size() + second.pixels.size());
  for (size_t i = 0; i < first.pixels.size(); ++i) merged.emplace_back(first.pixels[i], first.pointsMm[i]);
  // Only the second frame's fitted line (its inliers), not its other segments.
  std::vector<std::pair<int, double>> lineSamples;
  for (const image::RowSample& r : second.line.rows)
    if (r.inlier) lineSamples.emplace_back(r.row, static_cast<double>(r.column));
  std::sort(lineSamples.begin(), lineSamples.end());
  size_t joined = 0;
  for (size_t i = 0; i < second.pixels.size(); ++i) {
    const int row = static_cast<int>(std::lround(second.pixels[i].rowPx));
    if (std::binary_search(rowsSeen.begin(), rowsSeen.end(), row)) continue;
    if (!std::binary_search(lineSamples.begin(), lineSamples.end(), std::pair{row, second.pixels[i].columnPx}))
      continue;
    merged.emplace_back(second.pixels[i], second.pointsMm[i]);
    ++joined;
  }
  if (joined > 0) {
    std::stable_sort(merged.begin(), merged.end(),
                     [](const auto& a, const auto& b) { return a.first.rowPx < b.first.rowPx; });
    first.pixels.clear();
    first.pointsMm.clear();
    for (const auto& [px, p] : merged) {
      first.pixels.push_back(px);
      first.pointsMm.push_back(p);
    }
  }
  if (first.arcPointsMm.empty() && !second.arcPointsMm.empty()) {
    first.arcPointsMm = second.arcPointsMm;
    first.arcPixels = second.arcPixels;
  }
  return joined;
}

void Localizer::triangulateRows(const ScanPlan& plan, double slideMm, double slideMmPerRow,
                                const std::vector<geometry::PixelPoint>& pixels, std::vector<Eigen::Vector3d>* gatedMm,
                                std::vector<geometry::PixelPoint>* gatedPixels,
                                std::vector<Eigen::Vector3d>* outsideMm) const {
  const std::vector<Eigen::Vector2d> xn = geometry::undistortPixels(cal_.camera, pixels);
  const double middleRow = plan.roi.y + 0.5 * plan.roi.height;
  for (size_t i = 0; i < xn.size(); ++i) {
    const double rowSlideMm = slideMm + (pixels[i].rowPx - middleRow) * slideMmPerRow;
    const geometry::TriangulatedPoint p = geometry::triangulate(cal_.laser, rowSlideMm, xn[i], range_);
    if (!p.valid) continue;
    const double fromRoughMm = (p.pointMm - plan.roughMm).norm();
    if (fromRoughMm <= scan_.gateMm) {
      gatedMm->push_back(p.pointMm);
      if (gatedPixels != nullptr) gatedPixels->push_back(pixels[i]);
    } else if (outsideMm != nullptr && fromRoughMm <= scan_.searchMm) {
      outsideMm->push_back(p.pointMm);
    }
  }
}

std::vector<PaperCandidate> Localizer::paperCandidates(const ScanPlan& plan,
                                                       const std::vector<LineObservation>& lines) const {
  std::vector<PaperCandidate> out;
  // The expected centre in the image: the detector's (here: the rough position's).
  const geometry::PixelPoint expected = geometry::projectPoint(cal_.camera, plan.roughMm);
  for (size_t i = 0; i < lines.size(); ++i) {
    const LineObservation& l = lines[i];
    if (l.pointsMm.empty() || l.pixels.size() != l.pointsMm.size()) continue;
    // The line's middle: its median row (rows ascend in observe's output).
    const size_t mid = l.pointsMm.size() / 2;
    PaperCandidate c;
    c.line = i;
    c.pixelCount = static_cast<double>(l.pointsMm.size());
    c.distancePx = std::hypot(l.pixels[mid].columnPx - expected.columnPx, l.pixels[mid].rowPx - expected.rowPx);
    c.middleMm = l.pointsMm[mid];
    out.push_back(c);
  }
  return out;
}

size_t Localizer::selectCandidate(const std::vector<PaperCandidate>& candidates, double w1, double w2) {
  size_t best = 0;
  double bestScore = -1e300;
  for (size_t i = 0; i < candidates.size(); ++i) {
    const double score = w1 * candidates[i].pixelCount - w2 * candidates[i].distancePx;
    if (score > bestScore) {
      bestScore = score;
      best = i;
    }
  }
  return best;
}

Result<AppleEstimate> Localizer::estimateSingleLine(const ScanPlan& plan, const std::vector<LineObservation>& lines) const {
  const std::vector<PaperCandidate> candidates = paperCandidates(plan, lines);
  if (candidates.empty()) return Status(Error::kNotFound, "no laser line hit the target");
  const PaperCandidate& best = candidates[selectCandidate(candidates, scan_.paperW1, scan_.paperW2)];
  AppleEstimate est;
  // The paper triangulates the middle of the best line: a point of the surface, which
  // stands for the approach point; the centre is one (prior) radius behind it.
  const Eigen::Vector3d towardSensor = -best.middleMm.normalized();
  est.approachMm = best.middleMm;
  est.approachNormal = towardSensor;
  est.centerMm = best.middleMm - scan_.priorRadiusMm * towardSensor;
  est.diameterMm = 2.0 * scan_.priorRadiusMm;
  // The middle of a line is off the approach point by up to half a stop spacing across
  // and what that costs in depth; the radius is only the prior's.
  // That geometry alone gives a few millimetres; what one line misses in practice is
  // larger: on the benchmark world the single-line estimate's error is 13-16 mm mean
  // (docs/evaluation.md, "Single line"), so its σ is never below that.
  est.sigmaMm = std::max(kSingleLineSigmaMm, 0.5 * scan_.stopSpacingMm);
  est.centerSigmaMm = std::hypot(est.sigmaMm, scan_.priorRadiusSigmaMm);
  est.diameterSigmaMm = 2.0 * scan_.priorRadiusSigmaMm;
  est.linesUsed = 1;
  est.pointsUsed = static_cast<int>(best.pixelCount);
  est.confidencePct = 100.0 * 0.5 * withinProbability(kToleranceMm, est.sigmaMm);
  est.sphereFit = false;
  return est;
}

AppleEstimate Localizer::roughEstimate(const ScanPlan& plan) const {
  AppleEstimate est;
  const Eigen::Vector3d u = plan.roughMm.normalized();
  est.centerMm = plan.roughMm;
  est.approachMm = plan.roughMm - scan_.priorRadiusMm * u;
  est.approachNormal = -u;
  est.diameterMm = 2.0 * scan_.priorRadiusMm;
  est.centerSigmaMm = std::sqrt(3.0) * scan_.roughSigmaMm;
  est.sigmaMm = std::hypot(est.centerSigmaMm, scan_.priorRadiusSigmaMm);
  est.diameterSigmaMm = 2.0 * scan_.priorRadiusSigmaMm;
  est.occlusionPct = 100.0;
  est.confidencePct = 100.0 * 0.5 * withinProbability(kToleranceMm, est.sigmaMm);
  est.fitSigmaMm = est.sigmaMm;
  return est;
}

namespace {
// Points within the gate, off the fruit the widened search found, from which the rough
// position's surroundings count as occupied: estimate(). The second pass's own bar for a line
// that saw the fruit: a few rows of a target's skin through a gap are something there, not
// empty air (issue 17; it was 8, a line's worth).
constexpr size_t kOccupiedGatePoints = kMinPointsSeen;
// Off that fruit: farther from its fitted sphere than this (its spheroid's shape, lumps).
constexpr double kOffFruitMm = 6.0;

size_t otherPointsInGate(const std::vector<LineObservation>& lines, const AppleEstimate& found) {
  size_t n = 0;
  for (const LineObservation& l : lines) {
    for (const Eigen::Vector3d& p : l.pointsMm) n += found.offSurfaceMm(p) > kOffFruitMm ? 1U : 0U;
    n += l.leafPointsMm.size();  // leaves, told by their colour
  }
  return n;
}

// The confidence is the chance of the end effector's tolerance: it cannot exceed that chance
// at the σ the estimate reports. (Until here it was the fit's chance at the fit's own σ, times
// the support and the chance of the target; the systematic, shape and mixture terms widen the
// σ after it.) It bites only where σ is past about 10 mm (the chance is 99 % at 10 mm, 80 %
// at 16 mm).
Result<AppleEstimate> boundedBySigma(Result<AppleEstimate> est) {
  if (est) est->confidencePct = std::min(est->confidencePct, 100.0 * withinProbability(kToleranceMm, est->sigmaMm));
  return est;
}
}  // namespace

Result<AppleEstimate> Localizer::estimate(const ScanPlan& plan, const std::vector<LineObservation>& observed) const {
  std::vector<LineObservation> lines = uniqueStops(observed);
  Result<AppleEstimate> est = boundedBySigma(estimateLines(plan, lines));
  // The lines left the target unseen (the rough position stands in, or one line at most):
  // the sunlit arcs the subtracted frames showed (ScanParams::weakArcMinZ) join them, and
  // that estimate goes out when it rests on more lines and is more confident.
  const int linesBefore = est ? est->linesUsed : 0;
  const bool anyArc =
      std::any_of(lines.begin(), lines.end(), [](const LineObservation& l) { return !l.arcPointsMm.empty(); });
  if (!anyArc || linesBefore >= 2) return est;
  for (LineObservation& l : lines) {
    l.pointsMm.insert(l.pointsMm.end(), l.arcPointsMm.begin(), l.arcPointsMm.end());
    l.pixels.insert(l.pixels.end(), l.arcPixels.begin(), l.arcPixels.end());
  }
  Result<AppleEstimate> withArcs = boundedBySigma(estimateLines(plan, lines));
  if (withArcs && withArcs->linesUsed > linesBefore && withArcs->confidencePct > (est ? est->confidencePct : 0.0)) {
    withArcs->fromWeakArcs = true;
    return withArcs;
  }
  return est;
}

Result<AppleEstimate> Localizer::estimateLines(const ScanPlan& plan, const std::vector<LineObservation>& lines) const {
  // More likely another object than the target: where that object is says nothing better
  // about the target than the rough position does.
  const auto targetOrRough = [&](Result<AppleEstimate> e) -> Result<AppleEstimate> {
    if (!e || e->doubt != AppleEstimate::Doubt::kFarFromRough || !scan_.roughWhenFarFromRough) return e;
    // The target may be in what the lines saw beside that object, before the rough position
    // stands in.
    if (e->sphereFit) {
      Result<AppleEstimate> beside = estimateBesideOther(plan, lines, *e);
      if (beside) return beside;
    }
    AppleEstimate rough = roughEstimate(plan);
    rough.doubt = AppleEstimate::Doubt::kFarFromRough;
    rough.targetPct = e->targetPct;
    return rough;
  };
  Result<AppleEstimate> est = estimateFused(plan, lines, scan_.roughSigmaMm);
  // Nothing within the gate, or one line only: the lines the scan saw, tested against the
  // fruit model wherever they are (within searchMm).
  if (scan_.searchMm > 0.0 && (!est || !est->sphereFit)) {
    Result<AppleEstimate> wide = estimateWidened(plan, lines);
    if (wide) {
      // When the gate saw nothing but the fruit found, the rough position is in empty air: it
      // is off, and that fruit goes out as found, however far (issue 16). When the lines lit
      // something else round it (leaves, another fruit's skin), the target may well be
      // there, hidden, and a fruit far beyond is more likely a neighbour.
      // There, the fruit beyond is weighed as the gate's own fits are: against another object
      // within the gate's ball, for in a cluster a neighbour is that near (issue 17).
      const bool occupied = otherPointsInGate(lines, *wide) >= kOccupiedGatePoints;
      weighDoubt(plan, occupied ? scan_.gateMm : scan_.searchMm, *wide);
      return occupied ? targetOrRough(std::move(wide)) : wide;
    }
  }
  // The lines in the gate fell on leaves alone (told by their colour): the target may be
  // behind them. The rough position stands in, as for a line that fits nothing there, and
  // the second pass looks between the leaves (followUpStops: too few lines).
  if (!est && std::any_of(lines.begin(), lines.end(), [](const LineObservation& l) { return !l.leafPointsMm.empty(); }))
    return roughEstimate(plan);
  // One line (or the paper's candidate) that puts the centre far beyond the rough
  // position's error is not the target (a leaf's edge, a neighbour's limb).
  if (est && !est->sphereFit && scan_.roughGateSigmas > 0.0 && scan_.roughSigmaMm > 0.0 &&
      (est->centerMm - plan.roughMm).norm() > scan_.roughGateSigmas * scan_.roughSigmaMm)
    return roughEstimate(plan);
  // What one line says may be another surface just as a fit may be another object.
  if (est) weighDoubt(plan, scan_.gateMm, *est);
  Result<AppleEstimate> out = targetOrRough(likelierOfRival(plan, lines, std::move(est)));
  if (out) weighRivalFruit(plan, lines, *out);
  return out;
}

namespace {
struct OtherChance {
  double pct = 0.0;
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
};

// Each other object weighed as weighDoubt() weighs the fit; the likeliest. Each share is
// the object's against the fit's alone, as the rival's is (not normalised over them all).
OtherChance likeliestOther(const ScanPlan& plan, const AppleEstimate& est, double roughSigmaMm, double ballMm,
                           double otherPrior) {
  OtherChance best;
  if (!est.sphereFit || !(otherPrior > 0.0) || !(roughSigmaMm > 0.0)) return best;
  const auto weigh = [&](const Eigen::Vector3d& centerMm, double share) {
    if (!(share > 0.0)) return;
    const double pct =
        100.0 * targetProbability((centerMm - plan.roughMm).norm(), roughSigmaMm, ballMm, otherPrior) * share;
    if (pct > best.pct) best = {pct, centerMm};
  };
  for (const AppleEstimate::Other& o : est.others) weigh(o.centerMm, o.share);
  if (est.others.empty()) weigh(est.rivalCenterMm, est.rivalShare);  // an estimate made without the list
  return best;
}
}  // namespace

double Localizer::rivalTargetPct(const ScanPlan& plan, const AppleEstimate& est) const {
  return likeliestOther(plan, est, scan_.roughSigmaMm, scan_.gateMm, otherObjectPrior(est.linesUsed)).pct;
}

Eigen::Vector3d Localizer::likeliestOtherMm(const ScanPlan& plan, const AppleEstimate& est) const {
  return likeliestOther(plan, est, scan_.roughSigmaMm, scan_.gateMm, otherObjectPrior(est.linesUsed)).centerMm;
}

double Localizer::otherObjectPrior(int linesUsed) const {
  // Fewer than three lines leave more room for a sphere through two objects' pieces (or
  // for one line on a leaf): three times the prior. Chosen on the benchmark's hard cases.
  return linesUsed >= kFirmLines ? scan_.otherObjectPrior : std::min(0.9, 3.0 * scan_.otherObjectPrior);
}

Result<AppleEstimate> Localizer::likelierOfRival(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                                 Result<AppleEstimate> est) const {
  if (!est) return est;
  const OtherChance other =
      likeliestOther(plan, *est, scan_.roughSigmaMm, scan_.gateMm, otherObjectPrior(est->linesUsed));
  if (!(other.pct > est->targetPct)) return est;
  // That object's own estimate: the same lines, the rough position's prior on it. It may
  // rest on one line only (the object's other lines short): it is weighed alike.
  ScanPlan around = plan;
  around.roughMm = other.centerMm;
  Result<AppleEstimate> rival = estimateFused(around, lines, scan_.roughSigmaMm);
  if (!rival || (rival->centerMm - around.roughMm).norm() > geometry::kRivalSeparationMm) return est;
  weighDoubt(plan, scan_.gateMm, *rival);
  return rival->targetPct > est->targetPct ? std::move(rival) : std::move(est);
}

double Localizer::systematicSigmaMm(const Eigen::Vector3d& approachMm) const {
  double lineMm = 0.0;
  const double z = approachMm.z();
  if (scan_.lineBiasPx > 0.0 && z > 0.0) {
    // The approach point's pixel, moved across the line by the bias, back onto the laser
    // plane through the point (pinhole: the distortion changes the derivative little).
    const geometry::CameraIntrinsics& c = cal_.camera;
    const Eigen::Vector3d& n = cal_.laser.planeNormal;
    const double offset = n.dot(approachMm);
    const Eigen::Vector3d ray(approachMm.x() / z + scan_.lineBiasPx / c.fxPx, approachMm.y() / z, 1.0);
    const double along = n.dot(ray);
    // A plane seen edge-on: no depth from it (the localizer never plans such a view).
    lineMm = std::abs(along) > 1e-6 ? (offset / along * ray - approachMm).norm() : 0.0;
  }
  // The calibration's 3D error, between its depths (held beyond them).
  const geometry::CalibrationQuality& q = cal_.quality;
  const std::array<double, 4> depthsMm{1000.0, 1200.0, 1400.0, 1600.0};
  const std::array<double, 4> sigmasMm{q.sigma3dTotalMmAt1000, q.sigma3dTotalMmAt1200, q.sigma3dTotalMmAt1400,
                                       q.sigma3dTotalMmAt1600};
  double calMm = z <= depthsMm.front() ? sigmasMm.front() : sigmasMm.back();
  for (size_t i = 0; i + 1 < depthsMm.size(); ++i)
    if (z > depthsMm[i] && z <= depthsMm[i + 1]) {
      const double t = (z - depthsMm[i]) / (depthsMm[i + 1] - depthsMm[i]);
      calMm = sigmasMm[i] + t * (sigmasMm[i + 1] - sigmasMm[i]);
    }
  return std::hypot(lineMm, std::max(0.0, calMm));
}

double Localizer::mixtureSigmaMm(const ScanPlan& plan, const AppleEstimate& est, double p) const {
  constexpr double kUncoveredShare = 0.05;
  const double dMm = (est.centerMm - plan.roughMm).norm();
  const double sr2 = 3.0 * scan_.roughSigmaMm * scan_.roughSigmaMm;
  double other2 = dMm * dMm + sr2;
  if (est.rivalShare > 0.0) other2 = std::max(other2, (est.rivalCenterMm - est.centerMm).squaredNorm());
  const double w = std::max(0.0, (1.0 - p) - kUncoveredShare) / (1.0 - kUncoveredShare);
  return std::sqrt((1.0 - w) * est.fitSigmaMm * est.fitSigmaMm + w * other2);
}

void Localizer::weighRivalFruit(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                AppleEstimate& est) const {
  est.rivalFruitIdentity = 1.0;
  if (!est.sphereFit || est.linesUsed == 0 || !(est.rivalShare > 0.0) || !(scan_.roughSigmaMm > 0.0) ||
      !(scan_.otherObjectPrior > 0.0))
    return;
  // The rival's own estimate: the same lines, the rough position's prior moved onto it.
  ScanPlan around = plan;
  around.roughMm = est.rivalCenterMm;
  Result<AppleEstimate> rival = estimateFused(around, lines, scan_.roughSigmaMm);
  if (!rival || !rival->sphereFit || (rival->centerMm - around.roughMm).norm() > geometry::kRivalSeparationMm ||
      (rival->centerMm - est.centerMm).norm() <= geometry::kRivalSeparationMm)
    return;
  // Two fruit, one rough position: which of them it was made for, by its error alone (the
  // density of the rough position's error at each centre; the support says how much of
  // each the lines saw, not which the arm meant).
  const double s2 = 2.0 * scan_.roughSigmaMm * scan_.roughSigmaMm;
  const double dOwn2 = (est.centerMm - plan.roughMm).squaredNorm();
  const double dRival2 = (rival->centerMm - plan.roughMm).squaredNorm();
  est.rivalFruitIdentity = 1.0 / (1.0 + std::exp((dOwn2 - dRival2) / s2));
  // Its rival term becomes the smaller of the two; the choice made stands (what goes out,
  // where), what it says of itself follows.
  const double pShare = 1.0 - est.rivalShare;
  if (!(est.rivalFruitIdentity < pShare) || !(pShare > 0.0)) return;
  const double pBefore = 0.01 * est.targetPct;
  const double p = pBefore * est.rivalFruitIdentity / pShare;
  est.targetPct = 100.0 * p;
  if (pBefore > 0.0) est.confidencePct *= p / pBefore;
  est.sigmaMm = mixtureSigmaMm(plan, est, p);
  if (p < 0.5 && est.doubt == AppleEstimate::Doubt::kNone) est.doubt = AppleEstimate::Doubt::kTwoSurfaces;
}

void Localizer::weighDoubt(const ScanPlan& plan, double ballMm, AppleEstimate& est) const {
  // The fit's σ holds the points' scatter, not what they share (docs/geometry.md).
  // (It moves the whole fruit: the centre's σ takes it too.)
  const double sharedMm = systematicSigmaMm(est.approachMm);
  // The fitted shape is a spheroid with an aspect prior; a prolate, lumpy or rounder fruit
  // has its face elsewhere than the fit's by about as much as the radius is unsure, most
  // of all when the lines saw only its side. The approach point takes the radius's σ as
  // well, as if it were not tied to the centre's. Chosen on the benchmark's hard cases
  // (seed 3, both passes): within 2σ 94.6 % -> 99.5 %, the median σ 1.1 -> 1.7 mm.
  // Nor is a fruit a spheroid: its skin departs from the fitted shape by a share of the
  // radius (ScanParams::shapeIrregularityPct), which moves the face and the centre alike.
  const double irregularMm = 0.01 * scan_.shapeIrregularityPct * 0.5 * est.diameterMm;
  const double shapeMm = std::hypot(0.5 * est.diameterSigmaMm, irregularMm);
  est.sigmaMm = std::sqrt(est.sigmaMm * est.sigmaMm + sharedMm * sharedMm + shapeMm * shapeMm);
  est.centerSigmaMm = std::hypot(est.centerSigmaMm, sharedMm, irregularMm);
  // The width across the fruit departs from the fitted shape's on either side: twice the
  // radius's share (after shapeMm, which took the fit's own diameter σ).
  est.diameterSigmaMm = std::hypot(est.diameterSigmaMm, 2.0 * irregularMm);
  est.fitSigmaMm = est.sigmaMm;
  if (!(scan_.otherObjectPrior > 0.0) || !(scan_.roughSigmaMm > 0.0)) return;
  const double dMm = (est.centerMm - plan.roughMm).norm();
  const double prior = otherObjectPrior(est.linesUsed);
  const double pRough = targetProbability(dMm, scan_.roughSigmaMm, ballMm, prior);
  // A rival object that explains the lines about as well takes its share.
  const double pRival = 1.0 - est.rivalShare;
  const double p = pRough * pRival;
  // σ² of the mixture: the fit's own when it is the target; when it is another object, the
  // target is where the rough position says (its error about it), so the error is the
  // distance between them. The rival's centre, when there is one, is such another place.
  // A 2σ bound may leave 5 % of the results outside: that much of the other-object chance
  // does not widen σ (else every σ would carry a few % of a neighbour's distance and stop
  // telling good fits from poor ones).
  est.sigmaMm = mixtureSigmaMm(plan, est, p);
  est.targetPct = 100.0 * p;
  est.confidencePct = std::clamp(est.confidencePct * p, 0.0, 100.0);
  if (p < 0.5) est.doubt = pRival < pRough ? AppleEstimate::Doubt::kTwoSurfaces : AppleEstimate::Doubt::kFarFromRough;
}

namespace {
// Each line's slide with the 3D points `pick` gives it (no pixels, no samples), for a fit
// of other points than the gate's; `pick` returns how many of them count (adds to `counted`).
template <class Pick>
std::vector<LineObservation> slidesWithPoints(const std::vector<LineObservation>& lines, Pick pick, size_t& counted) {
  std::vector<LineObservation> out;
  out.reserve(lines.size());
  counted = 0;
  for (const LineObservation& l : lines) {
    LineObservation o;
    o.slideMm = l.slideMm;
    counted += pick(l, o.pointsMm);
    out.push_back(std::move(o));
  }
  return out;
}
}  // namespace

Result<AppleEstimate> Localizer::estimateBesideOther(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                                     const AppleEstimate& other) const {
  const double bandMm = std::max(kOffFruitMm, 3.0 * other.rmsMm);
  size_t left = 0;
  const std::vector<LineObservation> rest = slidesWithPoints(
      lines,
      [&](const LineObservation& l, std::vector<Eigen::Vector3d>& pointsMm) {
        for (const Eigen::Vector3d& p : l.pointsMm)
          if (other.offSurfaceMm(p) > bandMm) pointsMm.push_back(p);
        return pointsMm.size();
      },
      left);
  if (left == 0) return Status(Error::kNotFound, "nothing beside the other object");
  Result<AppleEstimate> est = estimateFused(plan, rest, scan_.roughSigmaMm);
  if (!est) return est;
  if (est->linesUsed < kFirmLines)
    return Status(Error::kNotFound, "no fruit on " + std::to_string(kFirmLines) + " lines beside the other object");
  weighDoubt(plan, scan_.gateMm, *est);
  if (est->doubt != AppleEstimate::Doubt::kNone) return Status(Error::kNotFound, "what is beside it is no likelier");
  return est;
}

Result<AppleEstimate> Localizer::estimateWidened(const ScanPlan& plan,
                                                 const std::vector<LineObservation>& lines) const {
  size_t outside = 0;
  const std::vector<LineObservation> wide = slidesWithPoints(
      lines,
      [](const LineObservation& l, std::vector<Eigen::Vector3d>& pointsMm) {
        pointsMm = l.pointsMm;
        pointsMm.insert(pointsMm.end(), l.outsidePointsMm.begin(), l.outsidePointsMm.end());
        return l.outsidePointsMm.size();
      },
      outside);
  if (outside == 0) return Status(Error::kNotFound, "no laser line within the widened search");
  // The centre's prior is only that it lies within the search: the gate's rough position
  // was wrong, or there would have been a fit inside it.
  Result<AppleEstimate> est = estimateFused(plan, wide, scan_.searchMm);
  if (!est) return est;
  if (!est->sphereFit) return Status(Error::kNotFound, "the widened search fitted no fruit on two lines or more");
  est->outsideGate = true;
  est->confidencePct = std::min(est->confidencePct, scan_.outsideGateConfidencePct);
  return est;
}

Result<AppleEstimate> Localizer::estimateFused(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                               double priorCenterSigmaMm) const {
  std::vector<Eigen::Vector3d> all;
  std::vector<int> lineIds;
  std::vector<int> pieceIds;
  int nextPiece = 0;
  for (size_t i = 0; i < lines.size(); ++i) {
    all.insert(all.end(), lines[i].pointsMm.begin(), lines[i].pointsMm.end());
    lineIds.insert(lineIds.end(), lines[i].pointsMm.size(), static_cast<int>(i));
    // Pieces continuous in 3D: one surface each (kPieceBreakMm exceeds the step between
    // rows on skin up to near the limb, and is less than the gap to a leaf in front).
    const std::vector<int> pieces = geometry::splitPieces(lines[i].pointsMm, kPieceBreakMm, nextPiece);
    pieceIds.insert(pieceIds.end(), pieces.begin(), pieces.end());
    if (!pieces.empty()) nextPiece = pieces.back() + 1;
  }
  if (all.empty()) return Status(Error::kNotFound, "no laser line hit the target");
  geometry::SphereFitParams sp;
  sp.priorRadiusMm = scan_.priorRadiusMm;
  sp.priorRadiusSigmaMm = scan_.priorRadiusSigmaMm;
  // LLE smooths each row's column over ±smoothRows rows: that many rows share an error.
  sp.pointsPerIndependent = 2.0 * std::max(0, lle_.smoothRows) + 1.0;
  sp.minRadiusMm = scan_.minRadiusMm;
  sp.maxRadiusMm = scan_.sphereMaxRadiusMm();
  sp.priorCenterMm = plan.roughMm;
  sp.priorCenterSigmaMm = priorCenterSigmaMm;
  sp.linePlaneNormal = cal_.laser.planeNormal;
  Result<geometry::SphereFit> fit = geometry::fitSphere(all, lineIds, pieceIds, sp);
  // Lines whose points reached the fit. One line alone leaves the sphere's offset from
  // that line's plane to the priors: still better than the paper's line middle, but
  // partial.
  std::vector<int> inliersPerLine(lines.size(), 0);
  if (fit) {
    for (size_t i = 0; i < all.size(); ++i)
      if (fit->inlier[i]) ++inliersPerLine[static_cast<size_t>(lineIds[i])];
  }
  const auto linesWithInliers = static_cast<int>(
      std::count_if(inliersPerLine.begin(), inliersPerLine.end(), [](int n) { return n >= 8; }));
  if (!fit || linesWithInliers < 1) return estimateSingleLine(plan, lines);

  AppleEstimate est;
  est.sphereFit = linesWithInliers >= 2;
  est.linesUsed = linesWithInliers;
  est.pointsUsed = static_cast<int>(fit->inliers);
  est.centerMm = fit->centerMm;
  est.diameterMm = 2.0 * fit->radiusMm;
  est.rmsMm = fit->rmsMm;
  if (fit->rivalScore > 0.0 && fit->score > 0.0) {
    est.rivalShare = fit->rivalScore / (fit->score + fit->rivalScore);
    est.rivalCenterMm = fit->rivalCenterMm;
    for (const geometry::SphereFit::Other& o : fit->others)
      est.others.push_back({o.centerMm, o.score / (fit->score + o.score)});
  }
  const double radius = fit->radiusMm;
  const double dist = est.centerMm.norm();
  const Eigen::Vector3d u = est.centerMm / dist;  // from the sensor towards the centre
  est.approachMm = est.centerMm - radius * u;
  est.approachNormal = -u;
  // Uncertainty: the approach point A = c − R·c/|c| through the fit's covariance.
  Eigen::Matrix<double, 3, 4> j;
  j.leftCols<3>() = Eigen::Matrix3d::Identity() - (radius / dist) * (Eigen::Matrix3d::Identity() - u * u.transpose());
  j.col(3) = -u;
  const Eigen::Matrix3d covA = j * fit->covariance * j.transpose();
  est.sigmaMm = std::sqrt(std::max(0.0, covA.trace()));
  est.centerSigmaMm = fit->centerSigmaMm;
  est.diameterSigmaMm = 2.0 * fit->radiusSigmaMm;
  if (scan_.spheroid && est.sphereFit) {
    // The same points as a spheroid about the stem: the sphere's centre and diameter are
    // off by millimetres on an oblate fruit.
    geometry::SpheroidPriors pr;
    pr.radiusMm = scan_.priorRadiusMm;
    pr.radiusSigmaMm = scan_.priorRadiusSigmaMm;
    pr.aspect = scan_.priorAspect;
    pr.aspectSigma = scan_.priorAspectSigma;
    pr.stemTiltSigmaRad = scan_.stemTiltSigmaDeg * M_PI / 180.0;
    pr.pointsPerIndependent = sp.pointsPerIndependent;
    Result<geometry::SpheroidFit> sf = geometry::refineSpheroid(all, fit->inlier, *fit, pr);
    Eigen::Vector3d approach;
    Eigen::Vector3d normal;
    if (sf && sf->radiusMm >= scan_.minRadiusMm && sf->radiusMm <= scan_.maxRadiusMm && sf->aspect > 0.6 &&
        sf->aspect < 1.25 &&
        geometry::spheroidApproach(sf->centerMm, sf->radiusMm, sf->aspect, sf->stemAxis, &approach, &normal)) {
      blendSpheroid(*sf, approach, normal, est);
    }
  }
  holdDiameterToLargestFruit(scan_.maxRadiusMm, est);
  // Occlusion: rows expected from the fitted sphere's chord at each stop vs rows that
  // reached the fit.
  double expectedRows = 0.0;
  double foundRows = 0.0;
  for (size_t i = 0; i < lines.size(); ++i) {
    const double delta = cal_.laser.planeNormal.dot(fit->centerMm) - cal_.laser.planeOffsetAt(lines[i].slideMm);
    if (std::abs(delta) >= radius) continue;
    const double chord = 2.0 * std::sqrt(radius * radius - delta * delta);
    expectedRows += chord * cal_.camera.fyPx / fit->centerMm.z();
    foundRows += static_cast<double>(inliersPerLine[i]);
  }
  est.occlusionPct = expectedRows > 0 ? std::clamp(100.0 * (1.0 - foundRows / expectedRows), 0.0, 100.0) : 0.0;
  // Confidence: the chance that the approach point is inside the end effector's
  // tolerance, times the support (lines and the share of points the fit kept).
  const double inlierShare = static_cast<double>(fit->inliers) / static_cast<double>(all.size());
  const double support = std::min(1.0, linesWithInliers / 3.0) * std::min(1.0, inlierShare / 0.6);
  est.confidencePct = std::clamp(100.0 * support * withinProbability(kToleranceMm, est.sigmaMm), 0.0, 100.0);
  return est;
}

}  // namespace alacs::localize
