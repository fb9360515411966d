#include "image/lle.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>

namespace alacs::image {

Status LleParams::validate() const {
  if (brceStep < 1 || brceStep > 64) return {Error::kInvalidArgument, "brceStep must be in 1..64"};
  if (brceThreshold < 0 || brceThreshold > 254)
    return {Error::kInvalidArgument, "brceThreshold must be in 0..254"};
  if (noiseTheta < 0) return {Error::kInvalidArgument, "noiseTheta must be >= 0"};
  if (noiseGamma < 1) return {Error::kInvalidArgument, "noiseGamma must be >= 1"};
  if (polyOrder < 1 || polyOrder > 7) return {Error::kInvalidArgument, "polyOrder must be in 1..7"};
  if (!(outlierPx > 0.0)) return {Error::kInvalidArgument, "outlierPx must be > 0"};
  if (minRows < polyOrder + 1) return {Error::kInvalidArgument, "minRows must exceed polyOrder"};
  return Status::ok();
}

double LaserLine::columnAt(double row) const {
  const double t = (row - rowCenter) / rowHalfSpan;
  double value = 0.0;
  for (int k = order; k >= 0; --k) value = value * t + coeffs[static_cast<size_t>(k)];
  return value;
}

void brceRow(const uint8_t* red, int pitch, int width, int step, int threshold, BrceForm form,
             uint8_t* mask) {
  std::fill(mask, mask + width, uint8_t{0});
  for (int x = step; x < width - step; ++x) {
    const int c = red[x * pitch];
    const int l = red[(x - step) * pitch];
    const int r = red[(x + step) * pitch];
    bool hit = false;
    if (form == BrceForm::kMeaning) {
      hit = (c - l > threshold) && (c - r > threshold);
    } else {
      // Algorithm 1 verbatim on uint8: G1 = R[x-step] - R[x], G2 = R[x+step] - R[x], each
      // wrapping modulo 256; values <= th are zeroed; the product > 0 marks a pixel.
      const int g1 = static_cast<uint8_t>(l - c);
      const int g2 = static_cast<uint8_t>(r - c);
      hit = g1 > threshold && g2 > threshold;
    }
    mask[x] = hit ? 1 : 0;
  }
}

namespace {

// The paper's Algorithm 2 over the ROI mask, in O(W·H): per band of h rows, column
// counts and a prefix sum give every window's count; a column is cleared in that band
// when any window covering it holds at most θ candidates.
void removeNoise(std::vector<uint8_t>& mask, int width, int height, const LleParams& p,
                 std::vector<int32_t>& scratch) {
  const int w = width / 4;
  const int h = height / 2;
  if (w < 1 || h < 1) return;
  const int windows = (width - w) / p.noiseGamma;  // u in Algorithm 2
  const int bands = height / h;                    // v in Algorithm 2
  scratch.assign(static_cast<size_t>(2 * (width + 1)), 0);
  int32_t* prefix = scratch.data();
  int32_t* clearDiff = scratch.data() + width + 1;
  for (int band = 0; band < bands; ++band) {
    const int y0 = band * h;
    std::fill(prefix, prefix + width + 1, 0);
    std::fill(clearDiff, clearDiff + width + 1, 0);
    for (int y = y0; y < y0 + h; ++y) {
      const uint8_t* m = mask.data() + static_cast<size_t>(y) * static_cast<size_t>(width);
      for (int x = 0; x < width; ++x) prefix[x + 1] += m[x];
    }
    for (int x = 0; x < width; ++x) prefix[x + 1] += prefix[x];
    for (int i = 0; i < windows; ++i) {
      const int x0 = i * p.noiseGamma;
      if (prefix[x0 + w] - prefix[x0] <= p.noiseTheta) {
        clearDiff[x0] += 1;
        clearDiff[x0 + w] -= 1;
      }
    }
    int covering = 0;
    for (int x = 0; x < width; ++x) {
      covering += clearDiff[x];
      if (covering > 0) {
        for (int y = y0; y < y0 + h; ++y)
          mask[static_cast<size_t>(y) * static_cast<size_t>(width) + static_cast<size_t>(x)] = 0;
      }
    }
  }
}

struct Peak {
  double column = 0.0;
  int64_t weight = 0;
  int peakExcess = 0;
};

// Centre of one run [a, b] (ROI columns) of a row: centroid of the red excess over a
// background interpolated linearly between the two bRCE neighbours of the run.
Peak centroidOfRun(const uint8_t* red, int pitch, int width, int a, int b, int step) {
  const int xl = std::max(0, a - step);
  const int xr = std::min(width - 1, b + step);
  const int span = xr - xl;
  Peak peak;
  if (span <= 0) return peak;
  const int rl = red[xl * pitch];
  const int rr = red[xr * pitch];
  int64_t sumW = 0;
  int64_t sumXW = 0;
  int maxExcess = 0;
  for (int x = xl + 1; x < xr; ++x) {
    // excess * span, kept in integers: R(x)*span - (rl*(xr-x) + rr*(x-xl))
    const int64_t wq = static_cast<int64_t>(red[x * pitch]) * span -
                       (static_cast<int64_t>(rl) * (xr - x) + static_cast<int64_t>(rr) * (x - xl));
    if (wq <= 0) continue;
    sumW += wq;
    sumXW += wq * x;
    maxExcess = std::max(maxExcess, static_cast<int>(wq / span));
  }
  if (sumW == 0) return peak;
  peak.column = static_cast<double>(sumXW) / static_cast<double>(sumW);
  peak.weight = sumW / span;
  peak.peakExcess = maxExcess;
  return peak;
}

void fitCurve(LaserLine& line, const LleParams& p) {
  const size_t n = line.rows.size();
  if (n < static_cast<size_t>(p.minRows)) return;
  const int first = line.rows.front().row;
  const int last = line.rows.back().row;
  line.rowCenter = 0.5 * (first + last);
  line.rowHalfSpan = std::max(1.0, 0.5 * (last - first));
  const int order = p.polyOrder;
  for (auto& r : line.rows) r.inlier = true;
  Eigen::VectorXd coeffs;
  for (int iteration = 0; iteration < 6; ++iteration) {
    int count = 0;
    for (const auto& r : line.rows) count += r.inlier ? 1 : 0;
    if (count < p.minRows) return;
    Eigen::MatrixXd a(count, order + 1);
    Eigen::VectorXd b(count);
    int i = 0;
    for (const auto& r : line.rows) {
      if (!r.inlier) continue;
      const double t = (r.row - line.rowCenter) / line.rowHalfSpan;
      double tk = 1.0;
      for (int k = 0; k <= order; ++k) {
        a(i, k) = tk;
        tk *= t;
      }
      b(i) = static_cast<double>(r.column);
      ++i;
    }
    coeffs = a.colPivHouseholderQr().solve(b);
    line.order = order;
    for (int k = 0; k <= order; ++k) line.coeffs[static_cast<size_t>(k)] = coeffs(k);
    // Robust scale of the residuals of all rows, then re-select inliers.
    std::vector<double> absRes;
    absRes.reserve(n);
    for (const auto& r : line.rows) absRes.push_back(std::abs(static_cast<double>(r.column) - line.columnAt(r.row)));
    std::vector<double> sorted = absRes;
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(n / 2), sorted.end());
    const double mad = 1.4826 * sorted[n / 2];
    const double limit = std::max(p.outlierPx, 3.0 * mad);
    bool changed = false;
    for (size_t j = 0; j < n; ++j) {
      const bool in = absRes[j] <= limit;
      changed = changed || in != line.rows[j].inlier;
      line.rows[j].inlier = in;
    }
    if (!changed) break;
  }
  double sumSq = 0.0;
  int inliers = 0;
  for (const auto& r : line.rows) {
    if (!r.inlier) continue;
    const double d = static_cast<double>(r.column) - line.columnAt(r.row);
    sumSq += d * d;
    ++inliers;
  }
  line.inliers = inliers;
  line.valid = inliers >= p.minRows;
  line.rmsResidualPx = inliers > 0 ? std::sqrt(sumSq / inliers) : 0.0;
}

}  // namespace

Result<LaserLine> extractLine(const ImageView& frame, const Roi& roi, const LleParams& params,
                              LleWorkspace& ws) {
  if (Status s = params.validate(); !s) return s;
  if (frame.data == nullptr || frame.width <= 0 || frame.height <= 0)
    return {Error::kBadInput, "empty frame"};
  if (frame.strideBytes < static_cast<size_t>(frame.width) * 3U)
    return {Error::kBadInput, "stride smaller than width*3"};
  if (roi.empty()) return {Error::kBadInput, "empty ROI"};
  if (roi.x < 0 || roi.y < 0 || roi.x + roi.width > frame.width || roi.y + roi.height > frame.height)
    return {Error::kBadInput, "ROI " + std::to_string(roi.x) + "," + std::to_string(roi.y) + " " +
                                  std::to_string(roi.width) + "x" + std::to_string(roi.height) +
                                  " leaves the " + std::to_string(frame.width) + "x" +
                                  std::to_string(frame.height) + " frame"};

  const int w = roi.width;
  const int h = roi.height;
  const int pitch = 3;
  const int redOff = redOffset(frame.format);
  ws.mask.resize(static_cast<size_t>(w) * static_cast<size_t>(h));
  for (int y = 0; y < h; ++y) {
    const uint8_t* red = frame.row(roi.y + y) + static_cast<size_t>(roi.x) * 3U + redOff;
    brceRow(red, pitch, w, params.brceStep, params.brceThreshold, params.brceForm,
            ws.mask.data() + static_cast<size_t>(y) * static_cast<size_t>(w));
  }
  removeNoise(ws.mask, w, h, params, ws.columnCount);

  LaserLine line;
  line.rows.reserve(static_cast<size_t>(h));
  const int mergeGap = std::max(1, params.brceStep / 2);
  for (int y = 0; y < h; ++y) {
    const uint8_t* m = ws.mask.data() + static_cast<size_t>(y) * static_cast<size_t>(w);
    const uint8_t* red = frame.row(roi.y + y) + static_cast<size_t>(roi.x) * 3U + redOff;
    Peak best;
    int x = 0;
    while (x < w) {
      if (m[x] == 0) {
        ++x;
        continue;
      }
      const int a = x;
      int b = x;
      // A run may have small holes (speckle): merge candidates closer than mergeGap.
      while (x < w) {
        if (m[x] != 0) {
          b = x;
        } else if (x - b > mergeGap) {
          break;
        }
        ++x;
      }
      const Peak peak = centroidOfRun(red, pitch, w, a, b, params.brceStep);
      if (peak.weight > best.weight) best = peak;
    }
    if (best.weight > 0) {
      RowSample s;
      s.row = roi.y + y;
      s.column = static_cast<float>(best.column + roi.x);
      s.confidence = static_cast<float>(std::min(255, best.peakExcess)) / 255.0F;
      line.rows.push_back(s);
    }
  }
  fitCurve(line, params);
  return line;
}

}  // namespace alacs::image
