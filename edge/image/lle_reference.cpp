// The floating-point reference of LLE: the same stages as extractLine with the columns,
// predictions and curve fit in double precision. The fit here is an independent method
// (Householder QR on the monomials of t, Eigen) rather than the fixed-point Forsythe
// recurrence, so the comparison also checks that recurrence.
#include <Eigen/Dense>

#include <algorithm>

#include "image/lle_focus.h"
#include "image/lle_internal.h"

namespace alacs::image {

namespace detail {

bool FloatArith::Fit::fit(const int32_t* rows, const Col* cols, const uint8_t* use, int n, int maxOrder, int firstRow,
                          int lastRow) {
  first = firstRow;
  last = lastRow;
  int used = 0;
  for (int i = 0; i < n; ++i) used += use[i] != 0 ? 1 : 0;
  order = -1;
  if (used < 1) return false;
  const int ord = std::min({maxOrder, kMaxFitOrder, used - 1});
  Eigen::MatrixXd a(used, ord + 1);
  Eigen::VectorXd b(used);
  const double center = 0.5 * (first + last);
  const double half = last > first ? 0.5 * (last - first) : 1.0;
  int r = 0;
  for (int i = 0; i < n; ++i) {
    if (use[i] == 0) continue;
    const double t = last > first ? (rows[i] - center) / half : 0.0;
    double tk = 1.0;
    for (int k = 0; k <= ord; ++k) {
      a(r, k) = tk;
      tk *= t;
    }
    b(r) = cols[i];
    ++r;
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  const Eigen::VectorXd x = qr.solve(b);
  order = ord;
  for (int k = 0; k <= kMaxFitOrder; ++k) coeffs[k] = k <= ord ? x(k) : 0.0;
  return true;
}

FloatArith::Col FloatArith::Fit::eval(int row) const {
  if (order < 0) return 0.0;
  const double t = last > first ? (row - 0.5 * (first + last)) / (0.5 * (last - first)) : 0.0;
  double v = 0.0;
  for (int k = order; k >= 0; --k) v = v * t + coeffs[k];
  return v;
}

void FloatArith::Fit::describe(LaserLine& line) const {
  line.order = order;
  for (int k = 0; k <= kMaxFitOrder; ++k) line.coeffs[static_cast<size_t>(k)] = coeffs[k];
  line.rowCenter = 0.5 * (first + last);
  line.rowHalfSpan = last > first ? 0.5 * (last - first) : 1.0;
}

}  // namespace detail

Status extractLineReference(const ImageView& frame, const Roi& roi, const LleParams& params, LaserLine& out,
                            const ImageView* laserOff) {
  out.clear();
  if (Status s = detail::validateInputs(frame, roi, params, laserOff); !s) return s;
  detail::reserveOutput(roi, params, out);
  LleWorkspace ws;
  if (params.method == LleMethod::kPaper) {
    detail::candidateMask(frame, laserOff, roi, params, nullptr, ws, 1);
    detail::focusPaper<detail::FloatArith>(roi, params, ws, out);
  } else {
    detail::extractRobust<detail::FloatArith>(frame, laserOff, roi, params, nullptr, ws, out);
  }
  return Status::ok();
}

}  // namespace alacs::image
