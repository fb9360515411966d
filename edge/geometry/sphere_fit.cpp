#include "geometry/sphere_fit.h"

#include <Eigen/Dense>
#include <cmath>

namespace alacs::geometry {

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pts, const SphereFitParams& p) {
  const size_t n = pts.size();
  if (n < p.minPoints) return {Error::kBadInput, "too few points for a sphere fit: " + std::to_string(n)};
  // Algebraic start: |X|² + D·X + E = 0 is linear in (D, E).
  Eigen::MatrixXd a(static_cast<Eigen::Index>(n), 4);
  Eigen::VectorXd b(static_cast<Eigen::Index>(n));
  for (size_t i = 0; i < n; ++i) {
    const auto r = static_cast<Eigen::Index>(i);
    a.row(r) << pts[i].x(), pts[i].y(), pts[i].z(), 1.0;
    b(r) = -pts[i].squaredNorm();
  }
  const Eigen::Vector4d s = a.colPivHouseholderQr().solve(b);
  Eigen::Vector3d c = -0.5 * s.head<3>();
  double rad2 = c.squaredNorm() - s(3);
  double radius = rad2 > 0 ? std::sqrt(rad2) : 0.5 * (p.minRadiusMm + p.maxRadiusMm);
  if (!std::isfinite(radius) || radius < p.minRadiusMm || radius > p.maxRadiusMm) {
    // Points on a small cap make the algebraic radius unstable: start from the mid radius
    // behind the points' centroid, as seen from the camera.
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& q : pts) mean += q;
    mean /= static_cast<double>(n);
    radius = 0.5 * (p.minRadiusMm + p.maxRadiusMm);
    c = mean + radius * mean.normalized();
  }
  // Gauss–Newton with Huber weights on r_i = |X_i - c| - R.
  Eigen::Matrix4d jtj;
  for (int it = 0; it < p.iterations; ++it) {
    jtj.setZero();
    Eigen::Vector4d jtr = Eigen::Vector4d::Zero();
    for (const auto& q : pts) {
      const Eigen::Vector3d d = q - c;
      const double dist = d.norm();
      if (dist < 1e-9) continue;
      const double r = dist - radius;
      const double w = std::abs(r) <= p.huberMm ? 1.0 : p.huberMm / std::abs(r);
      Eigen::Vector4d j;
      j << -d / dist, -1.0;
      jtj += w * j * j.transpose();
      jtr += w * j * r;
    }
    const Eigen::Vector4d step = jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) return {Error::kBadInput, "sphere fit diverged"};
    c += step.head<3>();
    radius += step(3);
    if (step.norm() < 1e-6) break;
  }
  if (!std::isfinite(radius) || radius < p.minRadiusMm || radius > p.maxRadiusMm)
    return {Error::kOutOfRange, "fitted radius " + std::to_string(radius) + " mm is not a fruit"};
  SphereFit fit;
  fit.centerMm = c;
  fit.radiusMm = radius;
  double sumSq = 0.0;
  for (const auto& q : pts) {
    const double r = (q - c).norm() - radius;
    if (std::abs(r) <= p.outlierMm) {
      sumSq += r * r;
      ++fit.inliers;
    }
  }
  if (fit.inliers < p.minPoints) return {Error::kBadInput, "too few inliers for a sphere fit"};
  fit.rmsMm = std::sqrt(sumSq / static_cast<double>(fit.inliers));
  const Eigen::Matrix4d cov = jtj.inverse() * fit.rmsMm * fit.rmsMm;
  fit.centerSigmaMm = std::sqrt(std::max(0.0, cov.topLeftCorner<3, 3>().trace()));
  return fit;
}

}  // namespace alacs::geometry
