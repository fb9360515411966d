#include "image/lle_fit.h"

#include <algorithm>

namespace alacs::image::detail {

namespace {

constexpr int64_t kOneQ30 = int64_t{1} << 30;

// p_k from p_{k-1}, p_{k-2} at one t (all Q30); the one recurrence used by fit and eval.
int64_t nextP(int64_t t, int64_t alpha, int64_t beta, int64_t pCur, int64_t pPrev) {
  const Int128 a = (static_cast<Int128>(t - alpha) * pCur) >> 30;
  const Int128 b = (static_cast<Int128>(beta) * pPrev) >> 30;
  return static_cast<int64_t>(a - b);
}

}  // namespace

int64_t FitQ::tQ30(int row) const {
  const int64_t span = static_cast<int64_t>(last) - first;
  if (span <= 0) return 0;
  const int64_t num = 2 * static_cast<int64_t>(row) - first - last;
  return static_cast<int64_t>(divRound(static_cast<Int128>(num) * kOneQ30, span));
}

int32_t FitQ::evalQ16(int row) const {
  if (order < 0) return 0;
  const int64_t t = tQ30(row);
  int64_t pPrev = 0;
  int64_t pCur = kOneQ30;
  Int128 acc = static_cast<Int128>(coef[0]) * pCur;  // Q24 · Q30 = Q54
  for (int k = 1; k <= order; ++k) {
    const int64_t pNext = nextP(t, alpha[k], k >= 2 ? beta[k] : 0, pCur, pPrev);
    acc += static_cast<Int128>(coef[k]) * pNext;
    pPrev = pCur;
    pCur = pNext;
  }
  const Int128 q16 = (acc + (static_cast<Int128>(1) << 37)) >> 38;
  return static_cast<int32_t>(std::clamp<Int128>(q16, INT32_MIN, INT32_MAX));
}

void FitQ::monomial(double* coeffs) const {
  double p[kMaxFitOrder + 1][kMaxFitOrder + 1] = {};
  for (int j = 0; j <= kMaxFitOrder; ++j) coeffs[j] = 0.0;
  if (order < 0) return;
  constexpr double kQ30 = 1073741824.0;
  constexpr double kQ24 = 16777216.0;
  p[0][0] = 1.0;
  for (int k = 1; k <= order; ++k) {
    const double a = static_cast<double>(alpha[k]) / kQ30;
    const double b = k >= 2 ? static_cast<double>(beta[k]) / kQ30 : 0.0;
    for (int j = 0; j <= k; ++j) {
      const double shifted = j > 0 ? p[k - 1][j - 1] : 0.0;
      p[k][j] = shifted - a * p[k - 1][j] - (k >= 2 ? b * p[k - 2][j] : 0.0);
    }
  }
  for (int k = 0; k <= order; ++k)
    for (int j = 0; j <= k; ++j) coeffs[j] += static_cast<double>(coef[k]) / kQ24 * p[k][j];
}

bool fitPolyQ(const int32_t* rows, const int32_t* yQ16, const uint8_t* use, int n, int order, int first, int last,
              int64_t* scratch, FitQ& out) {
  out = FitQ{};
  out.first = first;
  out.last = last;
  int used = 0;
  for (int i = 0; i < n; ++i) used += use[i] != 0 ? 1 : 0;
  if (used < 1) return false;
  order = std::min({order, kMaxFitOrder, used - 1});
  const auto un = static_cast<size_t>(n);
  int64_t* t = scratch;
  int64_t* pPrev = scratch + un;
  int64_t* pCur = scratch + 2 * un;
  for (int i = 0; i < n; ++i) {
    t[i] = out.tQ30(rows[i]);
    pPrev[i] = 0;
    pCur[i] = kOneQ30;
  }
  // p_k vanishing on the points (fewer distinct rows than k + 1): stop below k.
  const Int128 degenerate = static_cast<Int128>(used) << 24;
  Int128 normPrev = 1;
  for (int k = 0;; ++k) {
    Int128 norm = 0;   // Σ p_k²      Q60
    Int128 tNorm = 0;  // Σ t·p_k²    Q60
    Int128 yDot = 0;   // Σ y·p_k     Q46
    for (int i = 0; i < n; ++i) {
      if (use[i] == 0) continue;
      const Int128 p2 = static_cast<Int128>(pCur[i]) * pCur[i];
      norm += p2;
      tNorm += (p2 >> 30) * t[i];
      yDot += static_cast<Int128>(yQ16[i]) * pCur[i];
    }
    if (norm < degenerate) break;
    out.coef[k] = static_cast<int64_t>(divRound(yDot * (static_cast<Int128>(1) << 38), norm));  // Q46+38-60 = Q24
    out.order = k;
    if (k == order) break;
    out.alpha[k + 1] = static_cast<int64_t>(divRound(tNorm * kOneQ30, norm));
    out.beta[k + 1] = k >= 1 ? static_cast<int64_t>(divRound(norm * kOneQ30, normPrev)) : 0;
    for (int i = 0; i < n; ++i) {
      const int64_t next = nextP(t[i], out.alpha[k + 1], out.beta[k + 1], pCur[i], pPrev[i]);
      pPrev[i] = pCur[i];
      pCur[i] = next;
    }
    normPrev = norm;
  }
  return out.order >= 0;
}

}  // namespace alacs::image::detail
