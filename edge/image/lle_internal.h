// LLE internals shared by the driver (lle.cpp), the kernels and the tests. Not part of
// the component's interface: callers use image/lle.h.
//
// Fixed-point formats (Qm.n: n fraction bits):
//   red value, red excess              Q8.0  uint8 / int32 (exact)
//   excess weight (excess·span)        int32; sums int64 (exact)
//   column keys, for every decision    Q24.8 int32 (1/256 px), rounded from the exact sums
//   column values (centroid, smoothed, Q16.16 int32 (1/65536 px), rounded from the exact
//     fitted)                            sums; smoothing sums in __int128
//   reported column (RowSample)        Q24.8 int32 (columnQ8; column = columnQ8 / 256)
//   residual, tolerances, MAD          Q24.8 int32
//   fit: t = (row - centre)/half       Q2.30 int64
//   fit: α, β (recurrence)             Q34.30 int64
//   fit: orthogonal coefficients       Q40.24 int64; accumulations in __int128
//   confidence                         Q0.8 (0..256)
#pragma once

#include <cstddef>
#include <cstdint>

#include "image/lle.h"

namespace alacs::image::detail {

// Zero bytes before and after the red row: bRCE reads up to `step` (≤ 64) beyond each end,
// and a vector load from the last position reads up to 64 more.
constexpr int kRedPad = 128;

// The first pixel of ROI row y (0-based within the ROI) of a 3-byte-per-pixel frame, or
// nullptr without a frame (no laser-off frame).
inline const uint8_t* roiRow(const ImageView* frame, const Roi& roi, int y) {
  return frame != nullptr ? frame->row(roi.y + y) + static_cast<size_t>(roi.x) * 3U : nullptr;
}

// ROI width rounded up to whole 64-bit mask words (and so to whole SIMD vectors).
constexpr int paddedWidth(int w) { return (w + 63) & ~63; }

// Where the laser frame's red is at full scale (255) in a row: its first and last pixel
// (first < 0: nowhere).
struct FullScaleSpan {
  int first = -1;
  int last = -1;
  bool any() const { return first >= 0; }
  void add(int x0, int x1) {
    if (first < 0) first = x0;
    last = x1;
  }
};

// Red plane of one ROI row: red[x] = R(x), or max(0, R(x) - Roff(x)) with a laser-off row;
// `on`/`off` point at the ROI's first pixel (3 bytes per pixel), x in [0, w). Returns
// where the laser frame's red is at full scale, for clippedRunsRow.
FullScaleSpan redRowScalar(const uint8_t* on, const uint8_t* off, int redOffset, int w, uint8_t* red);

// bRCE over x in [0, wv) of a padded red row (the scalar reference): a candidate is
// x in [step, w - step) with the form's condition. Adds 1 (modulo 256) to counts8[x] per
// candidate, and writes the candidate bits, bit (x % 64) of bits[x / 64]. The caller
// moves counts8 into wider counters at least every 255 rows (flushCounts). Returns non-zero
// when the row has a candidate.
uint64_t brceRowScalar(const uint8_t* red, int w, int wv, int step, int threshold, BrceForm form, uint8_t* counts8,
                       uint64_t* bits);
// The [1 2 1]/4 average of three rows, rounded as two rounding halvings:
// out[x] = avg(avg(above[x], below[x]), mid[x]) with avg(a, b) = (a + b + 1) >> 1, x in [0, w).
void averageRowsScalar(const uint8_t* above, const uint8_t* mid, const uint8_t* below, int w, uint8_t* out);
// A line whose core clips wider than 2·step − 1 px has no pixel brighter than both pixels
// `step` away (they lie on the plateau or its bright shoulders), so bRCE misses it. Each
// run of the laser frame's red at 255 (`on`: the ROI row, 3 bytes per pixel) within
// `span` (where redRow saw full scale) is compared instead with the pixels `step` beyond
// its ends, in the red bRCE saw: its pixels with red[x] − red[a − step] and
// red[x] − red[b + step] both above `threshold` become candidates (bits; counts8 where bRCE
// had not set them), so that the peak is the whole plateau and its centroid rests on both
// shoulders, whether bRCE saw part of it or none. Skipped: a run where the laser-off frame
// (`off`, or nullptr) is at full scale, and one wider than kClippedRunMaxSteps·step px
// (glare, not a line). For the robust method only: the paper's bRCE is the paper's.
constexpr int kClippedRunMaxSteps = 4;
void clippedRunsRow(const uint8_t* on, const uint8_t* off, int redOffset, const uint8_t* red, int w, FullScaleSpan span,
                    int step, int threshold, uint8_t* counts8, uint64_t* bits);
// counts[x] += counts8[x], counts8[x] = 0, for x in [0, wv).
void flushCounts(uint8_t* counts8, uint16_t* counts, int wv);

// The SIMD kernels, with the contract of the scalar ones; bit-exact with them. brceRow
// takes `validLanes` (1 for x in [step, w - step), 0 elsewhere, wv bytes) instead of w.
struct SimdKernels {
  const char* name;
  FullScaleSpan (*redRow)(const uint8_t* on, const uint8_t* off, int redOffset, int w, uint8_t* red);
  uint64_t (*brceRow)(const uint8_t* red, const uint8_t* validLanes, int wv, int step, int threshold, BrceForm form,
                      uint8_t* counts8, uint64_t* bits);
  void (*averageRows)(const uint8_t* above, const uint8_t* mid, const uint8_t* below, int w, uint8_t* out);
};

// The best SIMD kernels this build and CPU can run, or nullptr (no SIMD in this build).
const SimdKernels* simdKernels();
// The baseline SIMD kernels (SSE2 / NEON), or nullptr; for tests that compare every path.
const SimdKernels* simdKernelsBaseline();
// The AVX2 / AVX-512 kernels when built and supported by the CPU, else nullptr.
const SimdKernels* simdKernelsAvx2();
const SimdKernels* simdKernelsAvx512();

// Stages 1-2 over the ROI: red extraction (minus the laser-off frame), bRCE, noise
// removal. Leaves the candidate mask in ws.bits (wv/64 words per ROI row) and which rows
// have any candidate in ws.rowAny. With a laser-off frame and `rows` 3, bRCE runs on the
// difference averaged over the rows above, at and below (averageRows; 1: the row alone).
// Inputs are validated by the caller. `kernels` nullptr: the scalar reference.
void candidateMask(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const LleParams& p,
                   const SimdKernels* kernels, LleWorkspace& ws, int rows);

// Checks params, frame(s) and ROI; the errors of extractLine.
Status validateInputs(const ImageView& frame, const Roi& roi, const LleParams& params, const ImageView* laserOff);
// Clears `out` and reserves what one extraction over `roi` can need.
void reserveOutput(const Roi& roi, const LleParams& p, LaserLine& out);

// The k-th smallest of v[0, n) (0-based): the value std::nth_element(v, v + k, v + n) puts at
// v[k], found in linear time on average. A histogram of 256 bins over [min, max] (bins a
// power of two wide: a shift, no division) finds the bin that holds it, and only that bin's
// values go through std::nth_element. The matched filter's median and MAD of ~350 responses per row
// cost two nth_elements, most of its time. `v` is reordered. Requires 0 <= k < n.
int32_t kthSmallest(int32_t* v, int n, int k);

}  // namespace alacs::image::detail
