#include "geometry/sphere_fit.h"

#include <Eigen/Dense>
#include <cmath>

namespace alacs::geometry {

namespace {

// Sphere through the points by algebraic least squares: |X|² + D·X + E = 0.
bool algebraicSphere(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx,
                     Eigen::Vector3d* c, double* r) {
  Eigen::MatrixXd a(static_cast<Eigen::Index>(idx.size()), 4);
  Eigen::VectorXd b(static_cast<Eigen::Index>(idx.size()));
  for (size_t i = 0; i < idx.size(); ++i) {
    const auto row = static_cast<Eigen::Index>(i);
    const Eigen::Vector3d& q = pts[idx[i]];
    a.row(row) << q.x(), q.y(), q.z(), 1.0;
    b(row) = -q.squaredNorm();
  }
  const Eigen::Vector4d s = a.colPivHouseholderQr().solve(b);
  *c = -0.5 * s.head<3>();
  const double r2 = c->squaredNorm() - s(3);
  if (!(r2 > 0.0) || !c->allFinite()) return false;
  *r = std::sqrt(r2);
  return true;
}

}  // namespace

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pts, const SphereFitParams& p) {
  const size_t n = pts.size();
  if (n < p.minPoints) return {Error::kBadInput, "too few points for a sphere fit: " + std::to_string(n)};
  // RANSAC start (deterministic): leaves and branches in front of the fruit form a
  // large minority that a least-squares start would follow.
  uint64_t state = 0x9E3779B97F4A7C15ULL ^ n;
  auto nextIndex = [&]() {
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return static_cast<size_t>(state % n);
  };
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double radius = 0.0;
  size_t bestCount = 0;
  const double ransacBandMm = std::max(1.0, p.huberMm);
  std::vector<size_t> sample(4);
  for (int it = 0; it < 300; ++it) {
    for (auto& s : sample) s = nextIndex();
    Eigen::Vector3d cc;
    double rr = 0.0;
    if (!algebraicSphere(pts, sample, &cc, &rr) || rr < p.minRadiusMm || rr > p.maxRadiusMm) continue;
    // The fruit lies behind its visible surface, as seen from the camera.
    if (cc.norm() < pts[sample[0]].norm()) continue;
    size_t count = 0;
    for (const auto& q : pts) count += std::abs((q - cc).norm() - rr) <= ransacBandMm ? 1U : 0U;
    if (count > bestCount) {
      bestCount = count;
      c = cc;
      radius = rr;
    }
  }
  if (bestCount < p.minPoints) {
    std::vector<size_t> all(n);
    for (size_t i = 0; i < n; ++i) all[i] = i;
    if (!algebraicSphere(pts, all, &c, &radius) || radius < p.minRadiusMm || radius > p.maxRadiusMm) {
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const auto& q : pts) mean += q;
      mean /= static_cast<double>(n);
      radius = 0.5 * (p.minRadiusMm + p.maxRadiusMm);
      c = mean + radius * mean.normalized();
    }
  }
  // Gauss–Newton with Huber weights on r_i = |X_i - c| - R, over the points inside the
  // outlier band of the current estimate.
  Eigen::Matrix4d jtj = Eigen::Matrix4d::Identity();
  for (int it = 0; it < p.iterations; ++it) {
    jtj.setZero();
    Eigen::Vector4d jtr = Eigen::Vector4d::Zero();
    for (const auto& q : pts) {
      const Eigen::Vector3d d = q - c;
      const double dist = d.norm();
      if (dist < 1e-9) continue;
      const double r = dist - radius;
      if (std::abs(r) > p.outlierMm) continue;
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
