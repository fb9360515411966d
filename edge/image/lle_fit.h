// The curve fit of LLE, column = p(row), in fixed point (internal to alacs_image).
//
// Least squares by Forsythe's orthogonal polynomials: p_0 = 1, p_1 = t - α_1,
// p_k = (t - α_k)·p_{k-1} - β_k·p_{k-2}, orthogonal over the fitted rows, so every
// coefficient is one ratio of two sums and no linear system is solved. This is well
// conditioned (no normal equations) and maps onto integers: data in Q16.16, t in Q2.30,
// α and β in Q30, the coefficients c_k of the p_k in Q24, sums of products in __int128.
// Bit-exact on any platform with 64-bit integers and __int128 (gcc and clang on x86-64
// and aarch64).
#pragma once

#include <cstdint>

namespace alacs::image::detail {

__extension__ typedef __int128 Int128;

constexpr int kMaxFitOrder = 6;

// a / b rounded to nearest (halves away from zero), b > 0.
inline int64_t roundDiv(int64_t a, int64_t b) { return a >= 0 ? (a + b / 2) / b : -((-a + b / 2) / b); }

// The same in 128 bits. Most quotients of the fit have both terms within ±2^62, where
// roundDiv gives the same result as the 128-bit division (a library call, __divti3,
// several times slower); the others take the long path.
inline Int128 divRound(Int128 a, Int128 b) {
  constexpr Int128 kShort = Int128{1} << 62;
  if (a > -kShort && a < kShort && b < kShort) return roundDiv(static_cast<int64_t>(a), static_cast<int64_t>(b));
  return a >= 0 ? (a + b / 2) / b : -((-a + b / 2) / b);
}

struct FitQ {
  int order = -1;   // -1: no fit
  int first = 0;    // rows mapped to t = -1 and t = +1
  int last = 0;
  int64_t alpha[kMaxFitOrder + 1] = {};  // Q30, alpha[k] builds p_k (k >= 1)
  int64_t beta[kMaxFitOrder + 1] = {};   // Q30, beta[k] builds p_k (k >= 2)
  int64_t coef[kMaxFitOrder + 1] = {};   // Q24, coefficient of p_k

  // t(row) in Q30: (2·row - first - last) / (last - first), 0 when first == last.
  int64_t tQ30(int row) const;
  // The fitted column at `row`, Q16, rounded to nearest (clamped to int32).
  int32_t evalQ16(int row) const;
  // Monomial coefficients in t (double), coeffs[0..order].
  void monomial(double* coeffs) const;
};

// Fits rows[i] -> yQ16[i] over the i with use[i] != 0, order at most `order` (lowered when
// the points cannot support it). `scratch` holds 3·n int64. Returns false when fewer
// than one point is used.
bool fitPolyQ(const int32_t* rows, const int32_t* yQ16, const uint8_t* use, int n, int order, int first, int last,
              int64_t* scratch, FitQ& out);

}  // namespace alacs::image::detail
