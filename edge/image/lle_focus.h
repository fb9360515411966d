// LLE stages 3-5 (line focusing, continuity, curve fit, output), written once over an
// arithmetic: FixedArith (columns in Q16.16 int32, the product) or FloatArith (double, the
// reference). Decisions (which run, which segment, which row is an outlier) are made by
// the same code in both, on columns that differ only by the fixed-point rounding.
// The stages are in lle_focus.cpp, instantiated for both arithmetics. Internal to
// alacs_image; included by lle.cpp, lle_reference.cpp and lle_focus.cpp.
#pragma once

#include <cmath>
#include <cstdint>

#include "image/lle_fit.h"
#include "image/lle_internal.h"

namespace alacs::image::detail {

// Largest weight of a row in the smoothing along the line (Q0; lle_focus.cpp, stage 5b).
constexpr int64_t kMaxSmoothWeight = 4096;

// The product's values: columns in Q16.16 (1/65536 px; a 16384-px frame fits int32), so
// the fit and the smoothing see the centroids to 1/65536 px; reported in Q24.8.
struct FixedArith {
  static constexpr bool kFixed = true;
  using Col = int32_t;  // Q16.16
  static Col fromInt(int px) { return static_cast<Col>(px * 65536); }
  static double toPx(Col c) { return static_cast<double>(c) / 65536.0; }
  static int32_t toQ8(Col c) { return static_cast<int32_t>(roundDiv(c, 256)); }
  // The reported column: the Q24.8 result, exactly.
  static float toFloat(Col c) { return static_cast<float>(toQ8(c)) / 256.0F; }
  static Col ratio(int64_t num, int64_t den) {  // den > 0
    return static_cast<Col>(divRound(static_cast<Int128>(num) * 65536, den));
  }
  static Col absDiff(Col a, Col b) { return a > b ? a - b : b - a; }

  // The weighted least-squares quadratic through (u[i], c[i]) with integer weights wt[i]
  // evaluated at u = 0 (Cramer's rule over exact integer sums); linear, then the mean, when
  // the points cannot support it. Sums fit int64 (|u| <= 32, n <= 64, |c| < 2^31,
  // 1 <= wt <= kMaxSmoothWeight = 2^12: Σ w·u²·c < 2^59); the products of the 3x3 solve
  // need __int128 (< 2^118), those of the linear one only for t0·s2.
  static Col quadAtZero(const int* u, const Col* c, const int32_t* wt, int n, int order);

  struct Fit {
    FitQ q;
    int64_t* scratch = nullptr;  // 3n
    bool fit(const int32_t* rows, const Col* cols, const uint8_t* use, int n, int order, int first, int last) {
      return fitPolyQ(rows, cols, use, n, order, first, last, scratch, q);
    }
    Col eval(int row) const { return q.evalQ16(row); }
    void describe(LaserLine& line) const {
      line.order = q.order;
      double c[kMaxFitOrder + 1];
      q.monomial(c);
      for (int k = 0; k <= kMaxFitOrder; ++k) line.coeffs[static_cast<size_t>(k)] = k <= q.order ? c[k] : 0.0;
      line.rowCenter = 0.5 * (q.first + q.last);
      line.rowHalfSpan = q.last > q.first ? 0.5 * (q.last - q.first) : 1.0;
    }
  };
};

// The reference's values: columns in double, reported as they are.
struct FloatArith {
  static constexpr bool kFixed = false;
  using Col = double;
  static Col fromInt(int px) { return px; }
  static double toPx(Col c) { return c; }
  static int32_t toQ8(Col c) { return static_cast<int32_t>(std::lround(c * 256.0)); }
  static float toFloat(Col c) { return static_cast<float>(c); }
  static Col ratio(int64_t num, int64_t den) { return static_cast<double>(num) / static_cast<double>(den); }
  static Col absDiff(Col a, Col b) { return std::abs(a - b); }
  // Weighted least-squares polynomial of `order` (0..2) through (u[i], c[i]), at u = 0.
  static Col quadAtZero(const int* u, const Col* c, const int32_t* wt, int n, int order);

  // Declared here, defined in lle_reference.cpp (Eigen QR on the monomials of t).
  struct Fit {
    int order = -1;
    int first = 0;
    int last = 0;
    double coeffs[kMaxFitOrder + 1] = {};
    bool fit(const int32_t* rows, const Col* cols, const uint8_t* use, int n, int maxOrder, int first, int last);
    Col eval(int row) const;
    void describe(LaserLine& line) const;
  };
};

// kRobust from the bRCE candidate mask to `out` (stages 1-5): when the line found at the
// strong threshold is weak (its median peak excess below weakLineExcessDn, or no line) or
// short (fewer kLine rows than shortLinePct of the ROI's height), the frame is run again
// with the strong threshold at weakLineThresholdPct of brceThreshold (a short line's first
// pass kept, the rerun's segments beside it added). Inputs validated and `out` reserved by
// the caller (reserveOutput).
template <class A>
void extractRobust(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const LleParams& p,
                   const SimdKernels* kernels, LleWorkspace& ws, LaserLine& out);
// The paper's stages 3-4 over the candidate mask in ws.bits (candidateMask run before).
template <class A>
void focusPaper(const Roi& roi, const LleParams& p, LleWorkspace& ws, LaserLine& out);

extern template void extractRobust<FixedArith>(const ImageView&, const ImageView*, const Roi&, const LleParams&,
                                               const SimdKernels*, LleWorkspace&, LaserLine&);
extern template void extractRobust<FloatArith>(const ImageView&, const ImageView*, const Roi&, const LleParams&,
                                               const SimdKernels*, LleWorkspace&, LaserLine&);
extern template void focusPaper<FixedArith>(const Roi&, const LleParams&, LleWorkspace&, LaserLine&);
extern template void focusPaper<FloatArith>(const Roi&, const LleParams&, LleWorkspace&, LaserLine&);

}  // namespace alacs::image::detail
