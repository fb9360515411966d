#include "image/lle.h"

#include <algorithm>
#include <string>

#include "image/lle_focus.h"
#include "image/lle_internal.h"

namespace alacs::image {

namespace {

Status bad(Error e, const char* what) { return {e, what}; }

}  // namespace

Status LleParams::validate() const {
  if (method != LleMethod::kRobust && method != LleMethod::kPaper) return bad(Error::kInvalidArgument, "unknown LLE method");
  if (brceStep < 1 || brceStep > 64) return bad(Error::kInvalidArgument, "brceStep must be in 1..64");
  if (brceThreshold < 0 || brceThreshold > 254) return bad(Error::kInvalidArgument, "brceThreshold must be in 0..254");
  if (brceForm != BrceForm::kMeaning && brceForm != BrceForm::kLiteral)
    return bad(Error::kInvalidArgument, "unknown bRCE form");
  if (noiseTheta < 0 || noiseTheta > 100000000) return bad(Error::kInvalidArgument, "noiseTheta must be in 0..1e8");
  if (noiseGamma < 1 || noiseGamma > 4096) return bad(Error::kInvalidArgument, "noiseGamma must be in 1..4096");
  if (polyOrder < 1 || polyOrder > 6) return bad(Error::kInvalidArgument, "polyOrder must be in 1..6");
  if (!(outlierPx >= 0.1 && outlierPx <= 100.0)) return bad(Error::kInvalidArgument, "outlierPx must be in 0.1..100");
  if (minRows < polyOrder + 1 || minRows > kLleMaxSidePx)
    return bad(Error::kInvalidArgument, "minRows must be in polyOrder+1..16384");
  if (robustThresholdPct < 10 || robustThresholdPct > 100)
    return bad(Error::kInvalidArgument, "robustThresholdPct must be in 10..100");
  if (weakLineThresholdPct < 10 || weakLineThresholdPct > 100)
    return bad(Error::kInvalidArgument, "weakLineThresholdPct must be in 10..100");
  if (subtractedLineThresholdPct < 10 || subtractedLineThresholdPct > 100)
    return bad(Error::kInvalidArgument, "subtractedLineThresholdPct must be in 10..100");
  if (subtractedRows != 1 && subtractedRows != 3) return bad(Error::kInvalidArgument, "subtractedRows must be 1 or 3");
  if (!(matchedSeedSigmas >= 2.0 && matchedSeedSigmas <= 50.0))
    return bad(Error::kInvalidArgument, "matchedSeedSigmas must be in 2..50");
  if (!(matchedJoinSigmas >= 1.0 && matchedJoinSigmas <= matchedSeedSigmas))
    return bad(Error::kInvalidArgument, "matchedJoinSigmas must be in 1..matchedSeedSigmas");
  if (shortLinePct < 0 || shortLinePct > 100) return bad(Error::kInvalidArgument, "shortLinePct must be in 0..100");
  if (weakLineExcessDn < 0 || weakLineExcessDn > 255)
    return bad(Error::kInvalidArgument, "weakLineExcessDn must be in 0..255");
  if (weakThresholdPct < 10 || weakThresholdPct > 100)
    return bad(Error::kInvalidArgument, "weakThresholdPct must be in 10..100");
  if (maxPeaksPerRow < 1 || maxPeaksPerRow > 8) return bad(Error::kInvalidArgument, "maxPeaksPerRow must be in 1..8");
  if (!(maxJumpPx >= 0.25 && maxJumpPx <= 64.0)) return bad(Error::kInvalidArgument, "maxJumpPx must be in 0.25..64");
  if (maxGapRows < 0 || maxGapRows > 64) return bad(Error::kInvalidArgument, "maxGapRows must be in 0..64");
  if (minSegmentRows < 1 || minSegmentRows > kLleMaxSidePx)
    return bad(Error::kInvalidArgument, "minSegmentRows must be in 1..16384");
  if (!(bridgePx >= 0.0 && bridgePx <= 256.0)) return bad(Error::kInvalidArgument, "bridgePx must be in 0..256");
  if (!(bridgePxPerRow >= 0.0 && bridgePxPerRow <= 16.0))
    return bad(Error::kInvalidArgument, "bridgePxPerRow must be in 0..16");
  if (!(centrePriorShare == 0.0 || (centrePriorShare >= 0.02 && centrePriorShare <= 10.0)))
    return bad(Error::kInvalidArgument, "centrePriorShare must be 0 or in 0.02..10");
  if (smoothOrder < 0 || smoothOrder > 2) return bad(Error::kInvalidArgument, "smoothOrder must be in 0..2");
  if (smoothRows < 0 || smoothRows > 32) return bad(Error::kInvalidArgument, "smoothRows must be in 0..32");
  if (edgeRatio != 0 && (edgeRatio < 2 || edgeRatio > 16))
    return bad(Error::kInvalidArgument, "edgeRatio must be 0 or in 2..16");
  if (!(edgeAgreePx >= 0.0 && edgeAgreePx <= 8.0)) return bad(Error::kInvalidArgument, "edgeAgreePx must be in 0..8");
  if (kernels != LleKernels::kAuto && kernels != LleKernels::kScalar)
    return bad(Error::kInvalidArgument, "unknown kernel choice");
  return Status::ok();
}

double LaserLine::columnAt(double row) const {
  const double t = (row - rowCenter) / rowHalfSpan;
  double value = 0.0;
  for (int k = order; k >= 0; --k) value = value * t + coeffs[static_cast<size_t>(k)];
  return value;
}

const RowSample* LaserLine::sampleAt(int row) const {
  auto it = std::lower_bound(rows.begin(), rows.end(), row, [](const RowSample& s, int r) { return s.row < r; });
  return it != rows.end() && it->row == row ? &*it : nullptr;
}

void LaserLine::clear() {
  rows.clear();
  segments.clear();
  coeffs = {};
  order = 0;
  rowCenter = 0.0;
  rowHalfSpan = 1.0;
  valid = false;
  inliers = 0;
  rmsResidualPx = 0.0;
  firstLineRow = 0;
  lastLineRow = -1;
  coverage = 0.0;
}

namespace detail {

Status validateFrame(const ImageView& f, const char* name) {
  if (f.data == nullptr || f.width <= 0 || f.height <= 0)
    return {Error::kBadInput, std::string(name) + " is empty"};
  if (f.width > kLleMaxSidePx || f.height > kLleMaxSidePx)
    return {Error::kBadInput, std::string(name) + " is " + std::to_string(f.width) + "x" + std::to_string(f.height) +
                                  ", larger than " + std::to_string(kLleMaxSidePx) + " px a side"};
  if (f.format != PixelFormat::kRgb888 && f.format != PixelFormat::kBgr888)
    return {Error::kBadInput, std::string(name) + ": unknown pixel format (RGB888 or BGR888 only)"};
  if (f.strideBytes < static_cast<size_t>(f.width) * 3U)
    return {Error::kBadInput, std::string(name) + ": stride " + std::to_string(f.strideBytes) + " is below width*3 = " +
                                  std::to_string(f.width * 3)};
  return Status::ok();
}

Status validateInputs(const ImageView& frame, const Roi& roi, const LleParams& params, const ImageView* laserOff) {
  if (Status s = params.validate(); !s) return s;
  if (Status s = validateFrame(frame, "frame"); !s) return s;
  if (laserOff != nullptr) {
    if (Status s = validateFrame(*laserOff, "laser-off frame"); !s) return s;
    if (laserOff->width != frame.width || laserOff->height != frame.height || laserOff->format != frame.format)
      return {Error::kBadInput, "laser-off frame differs from the frame in size or pixel format"};
  }
  if (roi.empty()) return {Error::kBadInput, "empty ROI"};
  const int64_t x1 = static_cast<int64_t>(roi.x) + roi.width;
  const int64_t y1 = static_cast<int64_t>(roi.y) + roi.height;
  if (roi.x < 0 || roi.y < 0 || x1 > frame.width || y1 > frame.height)
    return {Error::kBadInput, "ROI " + std::to_string(roi.x) + "," + std::to_string(roi.y) + " " +
                                  std::to_string(roi.width) + "x" + std::to_string(roi.height) + " leaves the " +
                                  std::to_string(frame.width) + "x" + std::to_string(frame.height) + " frame"};
  return Status::ok();
}

void reserveOutput(const Roi& roi, const LleParams& p, LaserLine& out) {
  out.clear();
  out.rows.reserve(static_cast<size_t>(roi.height) * static_cast<size_t>(p.maxPeaksPerRow));
  out.segments.reserve(static_cast<size_t>(roi.height * p.maxPeaksPerRow / p.minSegmentRows + 1));
}

}  // namespace detail

Status extractLine(const ImageView& frame, const Roi& roi, const LleParams& params, LleWorkspace& ws,
                   LaserLine& out, const ImageView* laserOff) {
  out.clear();
  if (Status s = detail::validateInputs(frame, roi, params, laserOff); !s) return s;
  detail::reserveOutput(roi, params, out);
  const detail::SimdKernels* kernels = params.kernels == LleKernels::kAuto ? detail::simdKernels() : nullptr;
  if (params.method == LleMethod::kPaper) {
    detail::candidateMask(frame, laserOff, roi, params, kernels, ws, 1);
    detail::focusPaper<detail::FixedArith>(roi, params, ws, out);
  } else {
    detail::extractRobust<detail::FixedArith>(frame, laserOff, roi, params, kernels, ws, out);
  }
  return Status::ok();
}

Result<LaserLine> extractLine(const ImageView& frame, const Roi& roi, const LleParams& params, LleWorkspace& ws) {
  LaserLine line;
  if (Status s = extractLine(frame, roi, params, ws, line); !s) return s;
  return line;
}

const char* lleSimdName() {
  const detail::SimdKernels* k = detail::simdKernels();
  return k != nullptr ? k->name : "scalar";
}

}  // namespace alacs::image
