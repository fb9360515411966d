// Laser Line Extraction (LLE): from one frame to the sub-pixel column of the laser line
// in each row of a region of interest.
//
// Stages (paper §3, with what we changed, see docs/lle.md):
//   1. bRCE: a pixel is a laser candidate when its red value exceeds BOTH neighbours
//      `step` columns away by more than `threshold`. (Algorithm 1 as printed subtracts
//      the centre from its neighbours; on 8-bit data that wraps. We implement its
//      meaning; `BrceForm::kLiteral` keeps the printed form for comparison.)
//   2. Noise removal: the paper's sliding-window count (window W/4 × H/2, stride γ,
//      threshold θ) clears windows with too few candidates.
//   3. Line focusing: per row, each run of candidates is a peak; its centre is the
//      intensity-weighted centroid of the red excess over the local background (the
//      paper averages the candidate columns: integer-biased).
//   4. Curve fitting: column = p(row), 4th order, with iterative outlier rejection.
//
// All per-pixel work is integer. Buffers live in an `LleWorkspace` so that, after the
// first frame of a given ROI size, extraction allocates nothing.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "common/result.h"
#include "image/image_view.h"

namespace alacs::image {

enum class BrceForm : uint8_t {
  kMeaning,  // centre - neighbour > th, on both sides (default)
  kLiteral,  // the printed Algorithm 1 on uint8 (wrapping) arithmetic, for comparison
};

struct LleParams {
  int brceStep = 4;          // columns between a pixel and each neighbour it is compared with
  int brceThreshold = 40;    // red-level margin over both neighbours
  BrceForm brceForm = BrceForm::kMeaning;
  int noiseTheta = 8;        // θ: a window with at most this many candidates is cleared
  int noiseGamma = 3;        // γ: horizontal stride of the sliding window, px
  int polyOrder = 4;         // order of the fitted curve column = p(row)
  double outlierPx = 2.0;    // residual beyond which a row is rejected from the fit
  int minRows = 8;           // fewer accepted rows than this: no line

  Status validate() const;
};

// One row of the extracted line, in full-frame pixels.
struct RowSample {
  int row = 0;
  float column = 0.0F;      // sub-pixel centroid (pixel centres at integers)
  float confidence = 0.0F;  // 0..1: peak red excess / 255
  bool inlier = false;      // accepted by the curve fit
};

struct LaserLine {
  std::vector<RowSample> rows;   // rows where a peak was found, ascending
  // column = Σ coeffs[k] * t^k with t = (row - rowCenter) / rowHalfSpan
  std::array<double, 8> coeffs{};
  int order = 0;
  double rowCenter = 0.0;
  double rowHalfSpan = 1.0;
  bool valid = false;            // a curve was fitted
  int inliers = 0;
  double rmsResidualPx = 0.0;

  double columnAt(double row) const;
};

// Reusable buffers. Not thread-safe: one per worker.
struct LleWorkspace {
  std::vector<uint8_t> mask;         // candidate mask of the ROI, row-major
  std::vector<int32_t> columnCount;  // per column candidate counts of a row band
};

// bRCE on one row of red values with pixel pitch `pitch` (3 for RGB888): writes
// mask[x] = 1 for candidates, 0 otherwise, for x in [0, width). Scalar reference.
void brceRow(const uint8_t* red, int pitch, int width, int step, int threshold, BrceForm form,
             uint8_t* mask);

// Runs the four stages on `roi` of `frame`. Errors: kInvalidArgument for bad params,
// kBadInput for an empty frame or a ROI that leaves the frame.
Result<LaserLine> extractLine(const ImageView& frame, const Roi& roi, const LleParams& params,
                              LleWorkspace& ws);

}  // namespace alacs::image
