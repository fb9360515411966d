// LLE stages 1 and 2: the candidate mask (bRCE) and the paper's noise removal. The row
// kernels here are the scalar reference; lle_simd.inl holds the vector ones.
#include <algorithm>
#include <cstring>

#include "image/lle_internal.h"

namespace alacs::image {

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

namespace detail {

FullScaleSpan redRowScalar(const uint8_t* on, const uint8_t* off, int redOffset, int w, uint8_t* red) {
  const auto ro = static_cast<size_t>(redOffset);
  FullScaleSpan full;
  for (int x = 0; x < w; ++x) {
    const size_t i = 3U * static_cast<size_t>(x) + ro;
    const int v = off == nullptr ? on[i] : std::max(0, on[i] - off[i]);
    red[x] = static_cast<uint8_t>(v);
    if (on[i] == 255) full.add(x, x);
  }
  return full;
}

void averageRowsScalar(const uint8_t* above, const uint8_t* mid, const uint8_t* below, int w, uint8_t* out) {
  for (int x = 0; x < w; ++x) {
    const int outer = (above[x] + below[x] + 1) >> 1;
    out[x] = static_cast<uint8_t>((outer + mid[x] + 1) >> 1);
  }
}

uint64_t brceRowScalar(const uint8_t* red, int w, int wv, int step, int threshold, BrceForm form, uint8_t* counts8,
                       uint64_t* bits) {
  std::fill(bits, bits + wv / 64, uint64_t{0});
  uint64_t any = 0;
  for (int x = step; x < w - step; ++x) {
    const int c = red[x];
    const int l = red[x - step];
    const int r = red[x + step];
    bool hit = false;
    if (form == BrceForm::kMeaning) {
      hit = (c - l > threshold) && (c - r > threshold);
    } else {
      hit = static_cast<uint8_t>(l - c) > threshold && static_cast<uint8_t>(r - c) > threshold;
    }
    if (hit) {
      counts8[x] = static_cast<uint8_t>(counts8[x] + 1);
      bits[x / 64] |= uint64_t{1} << (x % 64);
      any = 1;
    }
  }
  return any;
}

void clippedRunsRow(const uint8_t* on, const uint8_t* off, int redOffset, const uint8_t* red, int w, FullScaleSpan span,
                    int step, int threshold, uint8_t* counts8, uint64_t* bits) {
  const auto ro = static_cast<size_t>(redOffset);
  const auto at = [ro](const uint8_t* px, int x) { return px[3U * static_cast<size_t>(x) + ro]; };
  for (int x0 = std::max(0, span.first); x0 <= std::min(span.last, w - 1); ++x0) {
    if (at(on, x0) != 255) continue;
    const int first = x0;
    int b = first;
    while (b + 1 < w && at(on, b + 1) == 255) ++b;
    x0 = b;  // on after the run
    if (b - first + 1 > kClippedRunMaxSteps * step || first - step < 0 || b + step >= w) continue;
    bool ambientClipped = false;
    for (int x = first; off != nullptr && x <= b; ++x) ambientClipped = ambientClipped || at(off, x) == 255;
    if (ambientClipped) continue;
    const int l = red[first - step];
    const int r = red[b + step];
    for (int x = first; x <= b; ++x) {
      if (red[x] - l <= threshold || red[x] - r <= threshold) continue;
      uint64_t& word = bits[x / 64];
      const uint64_t bit = uint64_t{1} << (x % 64);
      if ((word & bit) == 0) counts8[x] = static_cast<uint8_t>(counts8[x] + 1);
      word |= bit;
    }
  }
}

void flushCounts(uint8_t* counts8, uint16_t* counts, int wv) {
  for (int x = 0; x < wv; ++x) {
    counts[x] = static_cast<uint16_t>(counts[x] + counts8[x]);
    counts8[x] = 0;
  }
}

namespace {

// The paper's Algorithm 2 for one band of rows [y0, y0 + bandRows), in O(W + rows·W/64):
// a prefix sum of the band's column counts gives every window's count; a column is cleared
// when any window covering it holds at most θ candidates.
void clearBand(const LleParams& p, int w, int wv, int y0, int bandRows, LleWorkspace& ws) {
  const int winW = w / 4;
  const int windows = (w - winW) / p.noiseGamma;  // u in Algorithm 2
  int32_t* prefix = ws.prefix.data();              // w + 1 prefix sums, then w + 1 coverage diffs
  int32_t* cover = prefix + (w + 1);
  prefix[0] = 0;
  for (int x = 0; x < w; ++x) prefix[x + 1] = prefix[x] + ws.counts[static_cast<size_t>(x)];
  std::fill(cover, cover + w + 1, 0);
  bool any = false;
  for (int i = 0; i < windows; ++i) {
    const int x0 = i * p.noiseGamma;
    if (prefix[x0 + winW] - prefix[x0] <= p.noiseTheta) {
      cover[x0] += 1;
      cover[x0 + winW] -= 1;
      any = true;
    }
  }
  if (!any) return;
  const int words = wv / 64;
  uint64_t* clear = ws.clearBits.data();
  std::fill(clear, clear + words, uint64_t{0});
  int covering = 0;
  for (int x = 0; x < w; ++x) {
    covering += cover[x];
    if (covering > 0) clear[x / 64] |= uint64_t{1} << (x % 64);
  }
  for (int y = y0; y < y0 + bandRows; ++y) {
    if (ws.rowAny[static_cast<size_t>(y)] == 0) continue;
    uint64_t* row = ws.bits.data() + static_cast<size_t>(y) * static_cast<size_t>(words);
    uint64_t left = 0;
    for (int k = 0; k < words; ++k) left |= (row[k] &= ~clear[k]);
    ws.rowAny[static_cast<size_t>(y)] = left != 0 ? 1 : 0;
  }
}

// The red rows bRCE compares, one ROI row at a time: the row's own red (minus the laser-off
// frame's), or with `rows` 3 and a laser-off frame, the difference averaged over the rows
// above, at and below (clamped to the ROI). Keeps the last three differences in ws.redRows.
class RedRows {
 public:
  RedRows(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const SimdKernels* kernels,
          LleWorkspace& ws, int rows)
      : frame_(frame),
        off_(laserOff),
        roi_(roi),
        kernels_(kernels),
        averaged_(laserOff != nullptr && rows == 3),
        redOff_(redOffset(frame.format)) {
    if (!averaged_) return;
    slots_ = ws.redRows.data();  // sized by candidateMask
    difference(0);
  }

  // Writes row y's red into red[0, w); rows are asked for in order 0, 1, ... Returns
  // where the laser frame's red in row y is at full scale.
  FullScaleSpan row(int y, uint8_t* red) {
    if (!averaged_) return difference(y, red);
    if (y + 1 < roi_.height) difference(y + 1);
    const uint8_t* mid = slot(y);
    const uint8_t* above = y > 0 ? slot(y - 1) : mid;
    const uint8_t* below = y + 1 < roi_.height ? slot(y + 1) : mid;
    if (kernels_ != nullptr)
      kernels_->averageRows(above, mid, below, roi_.width, red);
    else
      averageRowsScalar(above, mid, below, roi_.width, red);
    return full_[y % 3];
  }

 private:
  uint8_t* slot(int y) const { return slots_ + static_cast<size_t>(y % 3) * static_cast<size_t>(roi_.width); }
  void difference(int y) { full_[y % 3] = difference(y, slot(y)); }
  FullScaleSpan difference(int y, uint8_t* red) const {
    const uint8_t* on = roiRow(&frame_, roi_, y);
    const uint8_t* off = roiRow(off_, roi_, y);
    return kernels_ != nullptr ? kernels_->redRow(on, off, redOff_, roi_.width, red)
                               : redRowScalar(on, off, redOff_, roi_.width, red);
  }

  const ImageView& frame_;
  const ImageView* off_;
  const Roi& roi_;
  const SimdKernels* kernels_;
  bool averaged_;
  int redOff_;
  uint8_t* slots_ = nullptr;
  FullScaleSpan full_[3];  // per slot: where the laser frame's red is at full scale in that row
};

}  // namespace

void candidateMask(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const LleParams& p,
                   const SimdKernels* kernels, LleWorkspace& ws, int rows) {
  const int w = roi.width;
  const int h = roi.height;
  const int wv = paddedWidth(w);
  const int words = wv / 64;
  const int step = p.brceStep;
  // Sizes only grow: a smaller ROI reuses the buffers without allocating.
  const size_t redSize = static_cast<size_t>(wv + 2 * kRedPad);
  if (ws.red.size() < redSize) ws.red.resize(redSize);
  // Three rows of the difference for the averaged rerun, sized on every path so that a
  // workspace that has seen a ROI this size allocates nothing whatever the frame needs.
  if (ws.redRows.size() < 3U * static_cast<size_t>(w)) ws.redRows.resize(3U * static_cast<size_t>(w));
  if (ws.validLanes.size() < static_cast<size_t>(wv)) ws.validLanes.resize(static_cast<size_t>(wv));
  if (ws.counts.size() < static_cast<size_t>(wv)) ws.counts.resize(static_cast<size_t>(wv));
  if (ws.counts8.size() < static_cast<size_t>(wv)) ws.counts8.resize(static_cast<size_t>(wv));
  if (ws.prefix.size() < static_cast<size_t>(2 * (w + 1))) ws.prefix.resize(static_cast<size_t>(2 * (w + 1)));
  const size_t bitWords = static_cast<size_t>(words) * static_cast<size_t>(h);
  if (ws.bits.size() < bitWords) ws.bits.resize(bitWords);
  if (ws.clearBits.size() < static_cast<size_t>(words)) ws.clearBits.resize(static_cast<size_t>(words));
  if (ws.rowAny.size() < static_cast<size_t>(h)) ws.rowAny.resize(static_cast<size_t>(h));

  uint8_t* red = ws.red.data() + kRedPad;
  // The padding must read as zero; what a previous, wider ROI left there would not.
  std::memset(ws.red.data(), 0, static_cast<size_t>(kRedPad));
  std::memset(red + w, 0, redSize - static_cast<size_t>(kRedPad + w));
  if (ws.roiWidth != w || ws.brceStep != step) {
    std::fill(ws.validLanes.begin(), ws.validLanes.end(), uint8_t{0});
    // 1, not 0xFF: the SIMD bRCE counts min(d, validLanes) as the candidate's 0 or 1.
    for (int x = step; x < w - step; ++x) ws.validLanes[static_cast<size_t>(x)] = 1;
    ws.roiWidth = w;
    ws.brceStep = step;
  }

  // Bands of Algorithm 2: v = H / h bands of h = H/2 rows; a last odd row is in none.
  const int bandRows = h / 2;
  const bool denoise = bandRows >= 1 && w / 4 >= 1;
  const int bands = denoise ? h / bandRows : 0;
  const int threshold = p.detectionThreshold();
  RedRows source(frame, laserOff, roi, kernels, ws, rows);
  std::fill(ws.counts.begin(), ws.counts.begin() + wv, uint16_t{0});
  std::fill(ws.counts8.begin(), ws.counts8.begin() + wv, uint8_t{0});
  int pending = 0;  // rows in counts8
  for (int y = 0; y < h; ++y) {
    uint64_t* bits = ws.bits.data() + static_cast<size_t>(y) * static_cast<size_t>(words);
    const FullScaleSpan fullScale = source.row(y, red);
    uint64_t any = kernels != nullptr ? kernels->brceRow(red, ws.validLanes.data(), wv, step, threshold, p.brceForm,
                                                         ws.counts8.data(), bits)
                                      : brceRowScalar(red, w, wv, step, threshold, p.brceForm, ws.counts8.data(), bits);
    if (fullScale.any() && p.method == LleMethod::kRobust) {
      clippedRunsRow(roiRow(&frame, roi, y), roiRow(laserOff, roi, y), redOffset(frame.format), red, w, fullScale, step,
                     threshold, ws.counts8.data(), bits);
      for (int k = 0; k < words; ++k) any |= bits[k];
    }
    ws.rowAny[static_cast<size_t>(y)] = any != 0 ? 1 : 0;
    const bool bandEnds = denoise && (y + 1) % bandRows == 0 && (y + 1) / bandRows <= bands;
    if (++pending == 255 || bandEnds) {
      flushCounts(ws.counts8.data(), ws.counts.data(), wv);
      pending = 0;
    }
    if (bandEnds) {
      clearBand(p, w, wv, y + 1 - bandRows, bandRows, ws);
      std::fill(ws.counts.begin(), ws.counts.begin() + wv, uint16_t{0});
    }
  }
}

}  // namespace detail
}  // namespace alacs::image
