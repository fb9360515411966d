#include "geometry/sphere_fit.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>

namespace alacs::geometry {

namespace {

// Sphere through the points by algebraic least squares: |X|² + D·X + E = 0, in
// coordinates relative to `origin` for conditioning (the points sit a metre away).
bool algebraicSphere(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx,
                     const Eigen::Vector3d& origin, Eigen::Vector3d* c, double* r) {
  Eigen::MatrixXd a(static_cast<Eigen::Index>(idx.size()), 4);
  Eigen::VectorXd b(static_cast<Eigen::Index>(idx.size()));
  for (size_t i = 0; i < idx.size(); ++i) {
    const auto row = static_cast<Eigen::Index>(i);
    const Eigen::Vector3d q = pts[idx[i]] - origin;
    a.row(row) << q.x(), q.y(), q.z(), 1.0;
    b(row) = -q.squaredNorm();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  if (qr.rank() < 4) return false;
  const Eigen::Vector4d s = qr.solve(b);
  const Eigen::Vector3d local = -0.5 * s.head<3>();
  const double r2 = local.squaredNorm() - s(3);
  if (!(r2 > 0.0) || !local.allFinite()) return false;
  *c = local + origin;
  *r = std::sqrt(r2);
  return true;
}

struct Rng {
  uint64_t state;
  size_t below(size_t n) {
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return static_cast<size_t>(state % n);
  }
};

Result<SphereFit> fit(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>* lineIds,
                      const SphereFitParams& p) {
  const size_t n = pts.size();
  if (n < p.minPoints) return Status(Error::kBadInput, "too few points for a sphere fit: " + std::to_string(n));
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& q : pts) mean += q;
  mean /= static_cast<double>(n);
  if (!mean.allFinite()) return Status(Error::kBadInput, "non-finite points in the sphere fit");

  // RANSAC (deterministic). Leaves and branches in front of the fruit form a large
  // minority that a least-squares start would follow.
  std::vector<std::vector<size_t>> byLine;
  if (lineIds != nullptr) {
    int maxId = 0;
    for (int id : *lineIds) maxId = std::max(maxId, id);
    byLine.resize(static_cast<size_t>(maxId) + 1);
    for (size_t i = 0; i < n; ++i) byLine[static_cast<size_t>(std::max(0, (*lineIds)[i]))].push_back(i);
    byLine.erase(std::remove_if(byLine.begin(), byLine.end(), [](const auto& v) { return v.empty(); }), byLine.end());
  }
  const bool spanLines = byLine.size() >= 2;
  Rng rng{0x9E3779B97F4A7C15ULL ^ (p.seed * 0xBF58476D1CE4E5B9ULL) ^ n};
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double radius = 0.0;
  double bestScore = -1.0;
  double bestSupport = 0.0;
  std::vector<size_t> sample(4);
  for (int it = 0; it < p.ransacIterations; ++it) {
    if (spanLines) {
      // Two points from each of two lines, or one line and two others.
      const size_t l0 = rng.below(byLine.size());
      size_t l1 = rng.below(byLine.size() - 1);
      if (l1 >= l0) ++l1;
      for (size_t k = 0; k < 4; ++k) {
        const auto& line = byLine[(k < 2) ? l0 : (k == 2 ? l1 : rng.below(byLine.size()))];
        sample[k] = line[rng.below(line.size())];
      }
    } else {
      for (auto& s : sample) s = rng.below(n);
    }
    Eigen::Vector3d cc;
    double rr = 0.0;
    if (!algebraicSphere(pts, sample, mean, &cc, &rr) || rr < p.minRadiusMm || rr > p.maxRadiusMm) continue;
    // The fruit lies behind its visible surface, as seen from the camera.
    if (cc.norm() < pts[sample[0]].norm()) continue;
    // Score: inliers, each counting more the closer it is (MSAC), so that among spheres
    // with equal support the tighter one wins.
    double support = 0.0;
    for (const auto& q : pts) {
      const double r = std::abs((q - cc).norm() - rr);
      if (r <= p.ransacBandMm) support += 1.0 - (r * r) / (p.ransacBandMm * p.ransacBandMm);
    }
    double score = support;
    if (p.priorRadiusMm > 0.0) {
      // Twice the prior's σ: selection only needs to rule out spheres no fruit has.
      const double z = (rr - p.priorRadiusMm) / (2.0 * p.priorRadiusSigmaMm);
      score *= std::exp(-0.5 * z * z);
    }
    if (p.priorCenterSigmaMm > 0.0) {
      const double d2 = (cc - p.priorCenterMm).squaredNorm();
      score *= std::exp(-0.5 * d2 / (p.priorCenterSigmaMm * p.priorCenterSigmaMm));
    }
    if (score > bestScore) {
      bestScore = score;
      bestSupport = support;
      c = cc;
      radius = rr;
    }
  }
  if (bestSupport < static_cast<double>(p.minPoints) / 2.0) {
    std::vector<size_t> all(n);
    for (size_t i = 0; i < n; ++i) all[i] = i;
    if (!algebraicSphere(pts, all, mean, &c, &radius) || radius < p.minRadiusMm || radius > p.maxRadiusMm) {
      radius = p.priorRadiusMm > 0.0 ? p.priorRadiusMm : 0.5 * (p.minRadiusMm + p.maxRadiusMm);
      c = mean + radius * mean.normalized();
    }
  }
  // Gauss–Newton with Huber weights on r_i = |X_i − c| − R over the points inside the
  // outlier band of the current estimate; the radius prior is one more residual.
  Eigen::Matrix4d jtj = Eigen::Matrix4d::Identity();
  double band = std::max(p.outlierMm, 2.0 * p.ransacBandMm);
  for (int it = 0; it < p.iterations; ++it) {
    jtj.setZero();
    Eigen::Vector4d jtr = Eigen::Vector4d::Zero();
    size_t used = 0;
    for (const auto& q : pts) {
      const Eigen::Vector3d d = q - c;
      const double dist = d.norm();
      if (dist < 1e-9) continue;
      const double r = dist - radius;
      if (std::abs(r) > band) continue;
      const double w = std::abs(r) <= p.huberMm ? 1.0 : p.huberMm / std::abs(r);
      Eigen::Vector4d j;
      j << -d / dist, -1.0;
      jtj += w * j * j.transpose();
      jtr += w * j * r;
      ++used;
    }
    if (used < 4) return Status(Error::kBadInput, "sphere fit lost its points");
    if (p.priorRadiusMm > 0.0) {
      // Residual (R − R0)/σ_R against point residuals of about 1 mm: the prior weighs as
      // (1 mm / σ_R)² points.
      const double wPrior = 1.0 / (p.priorRadiusSigmaMm * p.priorRadiusSigmaMm);
      jtj(3, 3) += wPrior;
      jtr(3) += wPrior * (radius - p.priorRadiusMm);
    }
    const Eigen::Vector4d step = jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) return Status(Error::kBadInput, "sphere fit diverged");
    c += step.head<3>();
    radius += step(3);
    // Tighten the band once converging: the start's band admits leaf points near the skin.
    band = std::max(p.outlierMm, band * 0.7);
    if (step.norm() < 1e-6 && band <= p.outlierMm) break;
  }
  if (!std::isfinite(radius) || radius < p.minRadiusMm || radius > p.maxRadiusMm)
    return Status(Error::kOutOfRange, "fitted radius " + std::to_string(radius) + " mm is not a fruit");
  SphereFit out;
  out.centerMm = c;
  out.radiusMm = radius;
  out.inlier.assign(n, false);
  double sumSq = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const double r = (pts[i] - c).norm() - radius;
    if (std::abs(r) <= p.outlierMm) {
      sumSq += r * r;
      ++out.inliers;
      out.inlier[i] = true;
    }
  }
  if (out.inliers < p.minPoints) return Status(Error::kBadInput, "too few inliers for a sphere fit");
  out.rmsMm = std::sqrt(sumSq / static_cast<double>(out.inliers));
  const double variance = sumSq / std::max(1.0, static_cast<double>(out.inliers) - 4.0);
  out.covariance = jtj.inverse() * variance;
  if (!out.covariance.allFinite()) return Status(Error::kBadInput, "sphere fit is degenerate (one line?)");
  out.centerSigmaMm = std::sqrt(std::max(0.0, out.covariance.topLeftCorner<3, 3>().trace()));
  out.radiusSigmaMm = std::sqrt(std::max(0.0, out.covariance(3, 3)));
  return out;
}

}  // namespace

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pts, const SphereFitParams& p) {
  return fit(pts, nullptr, p);
}

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>& lineIds,
                            const SphereFitParams& p) {
  if (lineIds.size() != pts.size()) return Status(Error::kInvalidArgument, "one line id per point");
  return fit(pts, &lineIds, p);
}

}  // namespace alacs::geometry
