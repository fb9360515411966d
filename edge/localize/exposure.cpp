#include "localize/exposure.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace alacs::localize {

namespace {
int64_t roundUs(double us) { return static_cast<int64_t>(std::llround(us)); }
}  // namespace

Status MeteringParams::validate() const {
  if (!(percentile >= 50.0 && percentile <= 100.0))
    return {Error::kInvalidArgument, "metering.percentile must be in 50..100"};
  if (targetDn < 1 || targetDn > 254) return {Error::kInvalidArgument, "metering.target_dn must be in 1..254"};
  if (saturatedDn < 2 || saturatedDn > 255) return {Error::kInvalidArgument, "metering.saturated_dn must be in 2..255"};
  if (targetDn >= saturatedDn)
    return {Error::kInvalidArgument, "metering.target_dn must be below metering.saturated_dn"};
  if (!(brightDnPerMs >= 1.0 && brightDnPerMs <= 1e6))
    return {Error::kInvalidArgument, "metering.bright_dn_per_ms must be in 1..1e6"};
  if (!(stepDown >= 1.5 && stepDown <= 64.0)) return {Error::kInvalidArgument, "metering.step_down must be in 1.5..64"};
  if (maxFrames < 1 || maxFrames > 8) return {Error::kInvalidArgument, "metering.max_frames must be in 1..8"};
  if (subtractAboveDn < 0 || subtractAboveDn > 255)
    return {Error::kInvalidArgument, "metering.subtract_above_dn must be in 0..255"};
  if (minExposureUs < 1 || minExposureUs > 1000000)
    return {Error::kInvalidArgument, "metering.min_exposure_us must be in 1..1000000"};
  if (!(brightAnalogueGain == 0.0 || (brightAnalogueGain >= 1.0 && brightAnalogueGain <= 64.0)))
    return {Error::kInvalidArgument, "metering.bright_analogue_gain must be 0 (never changed) or in 1..64"};
  if (!(secondExposureFactor == 0.0 || (secondExposureFactor >= 1.25 && secondExposureFactor <= 8.0)))
    return {Error::kInvalidArgument, "metering.second_exposure_factor must be 0 (never) or in 1.25..8"};
  return Status::ok();
}

Result<int> redPercentileDn(const image::ImageView& frame, const image::Roi& roi, double percentile) {
  if (roi.empty() || roi.x < 0 || roi.y < 0 || roi.x + roi.width > frame.width || roi.y + roi.height > frame.height ||
      frame.data == nullptr)
    return Status(Error::kBadInput, "metering: the ROI is empty or leaves the frame");
  std::array<uint64_t, 256> histogram{};
  const int red = image::redOffset(frame.format);
  for (int y = roi.y; y < roi.y + roi.height; ++y) {
    const uint8_t* px = frame.row(y) + static_cast<size_t>(roi.x) * 3U + static_cast<size_t>(red);
    for (int x = 0; x < roi.width; ++x) ++histogram[px[3 * x]];
  }
  const uint64_t n = static_cast<uint64_t>(roi.width) * static_cast<uint64_t>(roi.height);
  // The smallest level that at least `percentile` % of the pixels do not exceed.
  const auto rank =
      std::clamp<uint64_t>(static_cast<uint64_t>(std::ceil(percentile / 100.0 * static_cast<double>(n))), 1, n);
  uint64_t below = 0;
  for (int v = 0; v < 256; ++v) {
    below += histogram[static_cast<size_t>(v)];
    if (below >= rank) return v;
  }
  return 255;
}

ExposureMeter::ExposureMeter(const MeteringParams& params, int64_t startExposureUs, int64_t maxExposureUs)
    : p_(params),
      startUs_(std::max<int64_t>(1, startExposureUs)),
      maxUs_(maxExposureUs > 0 ? maxExposureUs : startUs_),
      nextUs_(params.enabled ? startUs_ : 0) {
  decision_.exposureUs = startUs_;
  // A shortest exposure above the longest is the longest.
  p_.minExposureUs = std::min(p_.minExposureUs, maxUs_);
}

Status ExposureMeter::add(const image::ImageView& frame, const image::Roi& roi, int64_t exposureUs,
                          double analogueGain) {
  if (nextUs_ == 0) return {Error::kInvalidArgument, "metering is over"};
  if (exposureUs <= 0) return {Error::kBadInput, "metering: the frame's exposure must be positive"};
  if (!(analogueGain >= 0.0) || !std::isfinite(analogueGain))
    return {Error::kBadInput, "metering: the frame's analogue gain must be 0 (not known) or positive"};
  Result<int> level = redPercentileDn(frame, roi, p_.percentile);
  if (!level) return level.status();
  MeteringDecision& d = decision_;
  if (d.frames == 0) firstUs_ = exposureUs;
  ++d.frames;
  d.meteredDn = *level;
  d.meteredUs = exposureUs;
  d.meteredGain = analogueGain;
  const auto us = static_cast<double>(exposureUs);
  // (Clipped, the rate is a lower bound.)
  d.bright = *level * 1000.0 / us >= p_.brightDnPerMs;
  if (*level >= p_.saturatedDn) {
    // Clipped: the level is at least what was read. Ask again, shorter, while frames and
    // the shortest exposure allow; else guess it one step further down and say so.
    const int64_t shorter = std::max(p_.minExposureUs, roundUs(us / p_.stepDown));
    d.saturated = true;
    choose(us * p_.targetDn / (*level * p_.stepDown), p_.minExposureUs, maxUs_);
    d.ambientDn = p_.targetDn;
    d.subtract = d.ambientDn > p_.subtractAboveDn;
    chooseSecond();
    nextUs_ = d.frames < p_.maxFrames && shorter < exposureUs ? shorter : 0;
    return Status::ok();
  }
  d.saturated = false;
  // Not bright: never longer than the first metering frame as taken (the start; a replayed
  // camera reports the exposure it recorded, so a replay decides as the scan did).
  const int64_t longest = d.bright ? maxUs_ : std::min(maxUs_, firstUs_);
  choose(us * p_.targetDn / std::max(1, *level), std::min(p_.minExposureUs, longest), longest);
  // Within 10 % of the metered exposure at its gain: keep it, so that the metering frame
  // can serve as the laser-off frame (one exposure less).
  if (d.analogueGain == 0.0 && std::abs(static_cast<double>(d.exposureUs) - us) <= 0.1 * us && exposureUs <= longest)
    d.exposureUs = exposureUs;
  const double gainRatio = d.analogueGain > 0.0 ? d.analogueGain / analogueGain : 1.0;
  d.ambientDn = static_cast<int>(std::lround(*level * static_cast<double>(d.exposureUs) / us * gainRatio));
  d.subtract = d.ambientDn > p_.subtractAboveDn;
  chooseSecond();
  nextUs_ = 0;
  return Status::ok();
}

void ExposureMeter::chooseSecond() {
  MeteringDecision& d = decision_;
  d.secondExposureUs = 0;
  if (!(d.bright && d.subtract && p_.secondExposureFactor > 0.0)) return;
  const int64_t us = std::min(maxUs_, roundUs(static_cast<double>(d.exposureUs) * p_.secondExposureFactor));
  if (static_cast<double>(us) >= 1.25 * static_cast<double>(d.exposureUs)) d.secondExposureUs = us;
}

void ExposureMeter::choose(double wantedUs, int64_t shortestUs, int64_t longestUs) {
  MeteringDecision& d = decision_;
  d.analogueGain = 0.0;
  const double gain = d.meteredGain;
  if (d.bright && p_.brightAnalogueGain > 0.0 && gain > p_.brightAnalogueGain) {
    // The same level at a lower gain: the exposure longer by the ratio, the gain lowered
    // only as far as the longest exposure allows.
    const double lowest = std::max(p_.brightAnalogueGain, gain * wantedUs / static_cast<double>(longestUs));
    if (lowest < gain * 0.95) {
      d.analogueGain = lowest;
      wantedUs *= gain / lowest;
    }
  }
  d.exposureUs = std::clamp(roundUs(wantedUs), shortestUs, longestUs);
}

MeteringRun runMetering(const MeteringParams& params, int64_t startExposureUs, int64_t maxExposureUs,
                        const image::Roi& roi, const TakeLaserOffFrame& take) {
  MeteringRun out;
  ExposureMeter meter(params, startExposureUs, maxExposureUs);
  const MeteringDecision start = meter.decision();  // what a failed metering falls back to
  out.decision = start;
  const auto fail = [&](Status s) {
    out.status = std::move(s);
    out.decision = start;
    return out;
  };
  while (const int64_t us = meter.nextMeteringUs()) {
    Result<LaserOffFrame> f = take(us, 0.0, LaserOffUse::kMetering);
    if (!f) return fail(f.status());
    ++out.frames;
    if (Status s = meter.add(f->view, roi, f->exposureUs, f->analogueGain); !s) return fail(s);
    out.laserOff = *f;
  }
  out.decision = meter.decision();
  if (!out.decision.subtract) return out;
  if (meter.lastFrameAtDecision()) {
    out.hasLaserOff = true;
    return out;
  }
  Result<LaserOffFrame> f = take(out.decision.exposureUs, out.decision.analogueGain, LaserOffUse::kSubtraction);
  if (!f) {
    // Metered, but nothing to subtract: the exposure stands, without subtraction.
    out.status = f.status();
    out.decision.subtract = false;
    return out;
  }
  ++out.frames;
  out.laserOff = *f;
  out.hasLaserOff = true;
  return out;
}

}  // namespace alacs::localize
