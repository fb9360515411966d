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
  if (idx.size() < 4) return false;
  Eigen::MatrixXd a(static_cast<Eigen::Index>(idx.size()), 4);
  Eigen::VectorXd b(static_cast<Eigen::Index>(idx.size()));
  for (size_t i = 0; i < idx.size(); ++i) {
    const auto row = static_cast<Eigen::Index>(i);
    const Eigen::Vector3d q = pts[idx[i]] - origin;
    a.row(row) << q.x(), q.y(), q.z(), 1.0;
    b(row) = -q.squaredNorm();
  }
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  qr.setThreshold(1e-9);
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

struct Pieces {
  std::vector<std::vector<size_t>> members;  // per piece: point indices
  std::vector<int> line;                     // per piece: its line
  std::vector<std::vector<size_t>> byLine;   // per line: point indices
};

Pieces makePieces(size_t n, const std::vector<int>* lineIds, const std::vector<int>* groupIds) {
  Pieces p;
  std::vector<int> lines(n, 0);
  if (lineIds != nullptr) lines = *lineIds;
  std::vector<int> groups = lines;
  if (groupIds != nullptr && groupIds->size() == n) groups = *groupIds;
  int maxGroup = 0;
  int maxLine = 0;
  for (size_t i = 0; i < n; ++i) {
    maxGroup = std::max(maxGroup, groups[i]);
    maxLine = std::max(maxLine, lines[i]);
  }
  p.members.resize(static_cast<size_t>(maxGroup) + 1);
  p.line.assign(p.members.size(), -1);
  p.byLine.resize(static_cast<size_t>(maxLine) + 1);
  for (size_t i = 0; i < n; ++i) {
    const auto g = static_cast<size_t>(std::max(0, groups[i]));
    p.members[g].push_back(i);
    p.line[g] = lines[i];
    p.byLine[static_cast<size_t>(std::max(0, lines[i]))].push_back(i);
  }
  // Drop empty pieces and lines.
  Pieces out;
  for (size_t g = 0; g < p.members.size(); ++g) {
    if (p.members[g].empty()) continue;
    out.members.push_back(std::move(p.members[g]));
    out.line.push_back(p.line[g]);
  }
  for (auto& l : p.byLine)
    if (!l.empty()) out.byLine.push_back(std::move(l));
  return out;
}

class Scorer {
 public:
  Scorer(const std::vector<Eigen::Vector3d>& pts, const Pieces& pieces, const SphereFitParams& p)
      : pts_(pts), pieces_(pieces), p_(p) {}

  // Coherent support × priors; 0 for spheres no fruit has.
  double score(const Eigen::Vector3d& c, double r) const {
    if (!(r >= p_.minRadiusMm && r <= p_.maxRadiusMm) || !c.allFinite()) return 0.0;
    const double band2 = p_.ransacBandMm * p_.ransacBandMm;
    double support = 0.0;
    for (const auto& piece : pieces_.members) {
      double weight = 0.0;
      size_t count = 0;
      for (size_t i : piece) {
        const double d = (pts_[i] - c).norm() - r;
        if (d * d <= band2) {
          weight += 1.0 - d * d / band2;
          ++count;
        }
      }
      if (count == 0) continue;
      // A sphere that explains only part of a piece is cutting across surfaces.
      const double share = static_cast<double>(count) / static_cast<double>(piece.size());
      const double coherence = std::min(1.0, share / p_.coherentShare);
      support += weight * coherence * coherence;
    }
    double s = support;
    if (p_.priorRadiusMm > 0.0) {
      // 1.5σ: ranking needs only to rule out the radii no fruit of this kind has.
      const double z = (r - p_.priorRadiusMm) / (1.5 * p_.priorRadiusSigmaMm);
      s *= std::exp(-0.5 * z * z);
    }
    if (p_.priorCenterSigmaMm > 0.0) {
      const double d2 = (c - p_.priorCenterMm).squaredNorm();
      s *= std::exp(-0.5 * d2 / (p_.priorCenterSigmaMm * p_.priorCenterSigmaMm));
    }
    return s;
  }

 private:
  const std::vector<Eigen::Vector3d>& pts_;
  const Pieces& pieces_;
  const SphereFitParams& p_;
};

struct GaussNewton {
  Eigen::Vector3d c;
  double radius;
  Eigen::Matrix4d jtj = Eigen::Matrix4d::Identity();
  bool ok = false;
};

// Huber-weighted Gauss–Newton over the points of `use` within `band` of the sphere.
GaussNewton refine(const std::vector<Eigen::Vector3d>& pts, const std::vector<bool>& use, Eigen::Vector3d c,
                   double radius, double band, const SphereFitParams& p) {
  GaussNewton out;
  for (int it = 0; it < p.iterations; ++it) {
    out.jtj.setZero();
    Eigen::Vector4d jtr = Eigen::Vector4d::Zero();
    size_t used = 0;
    for (size_t i = 0; i < pts.size(); ++i) {
      if (!use[i]) continue;
      const Eigen::Vector3d d = pts[i] - c;
      const double dist = d.norm();
      if (dist < 1e-9) continue;
      const double r = dist - radius;
      if (std::abs(r) > band) continue;
      const double w = std::abs(r) <= p.huberMm ? 1.0 : p.huberMm / std::abs(r);
      Eigen::Vector4d j;
      j << -d / dist, -1.0;
      out.jtj += w * j * j.transpose();
      jtr += w * j * r;
      ++used;
    }
    if (used < 4) return out;
    if (p.priorRadiusMm > 0.0) {
      // Residual (R − R0)/σ_R against point residuals of about 1 mm: the prior weighs as
      // (1 mm / σ_R)² points.
      const double wPrior = 1.0 / (p.priorRadiusSigmaMm * p.priorRadiusSigmaMm);
      out.jtj(3, 3) += wPrior;
      jtr(3) += wPrior * (radius - p.priorRadiusMm);
    }
    const Eigen::Vector4d step = out.jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) return out;
    c += step.head<3>();
    radius += step(3);
    if (step.norm() < 1e-7) break;
  }
  out.c = c;
  out.radius = radius;
  out.ok = std::isfinite(radius) && c.allFinite();
  return out;
}

Result<SphereFit> fit(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>* lineIds,
                      const std::vector<int>* groupIds, const SphereFitParams& p) {
  const size_t n = pts.size();
  if (n < p.minPoints) return Status(Error::kBadInput, "too few points for a sphere fit: " + std::to_string(n));
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& q : pts) mean += q;
  mean /= static_cast<double>(n);
  if (!mean.allFinite()) return Status(Error::kBadInput, "non-finite points in the sphere fit");
  const Pieces pieces = makePieces(n, lineIds, groupIds);
  const Scorer scorer(pts, pieces, p);

  Eigen::Vector3d best = Eigen::Vector3d::Zero();
  double bestR = 0.0;
  double bestScore = 0.0;
  auto consider = [&](const std::vector<size_t>& idx) {
    Eigen::Vector3d c;
    double r = 0.0;
    if (!algebraicSphere(pts, idx, mean, &c, &r)) return;
    // The fruit lies behind its visible surface, as seen from the camera.
    if (c.norm() < pts[idx.front()].norm()) return;
    const double s = scorer.score(c, r);
    if (s > bestScore) {
      bestScore = s;
      best = c;
      bestR = r;
    }
  };
  // Every pair of pieces on different lines.
  std::vector<size_t> idx;
  for (size_t a = 0; a < pieces.members.size(); ++a) {
    for (size_t b = a + 1; b < pieces.members.size(); ++b) {
      if (pieces.line[a] == pieces.line[b]) continue;
      idx = pieces.members[a];
      idx.insert(idx.end(), pieces.members[b].begin(), pieces.members[b].end());
      consider(idx);
    }
  }
  // Random four-point samples: two points from each of two lines, or any four points
  // when the lines are not known.
  Rng rng{0x9E3779B97F4A7C15ULL ^ (p.seed * 0xBF58476D1CE4E5B9ULL) ^ n};
  std::vector<size_t> sample(4);
  for (int it = 0; it < p.ransacIterations; ++it) {
    if (pieces.byLine.size() >= 2) {
      const size_t l0 = rng.below(pieces.byLine.size());
      size_t l1 = rng.below(pieces.byLine.size() - 1);
      if (l1 >= l0) ++l1;
      for (size_t k = 0; k < 4; ++k) {
        const auto& line = pieces.byLine[k < 2 ? l0 : l1];
        sample[k] = line[rng.below(line.size())];
      }
    } else {
      for (auto& s : sample) s = rng.below(n);
    }
    consider(sample);
  }
  if (!(bestScore > 0.0)) {
    // No hypothesis: the algebraic fit of everything, or the prior radius behind the mean.
    std::vector<size_t> all(n);
    for (size_t i = 0; i < n; ++i) all[i] = i;
    if (!algebraicSphere(pts, all, mean, &best, &bestR) || bestR < p.minRadiusMm || bestR > p.maxRadiusMm) {
      bestR = p.priorRadiusMm > 0.0 ? p.priorRadiusMm : 0.5 * (p.minRadiusMm + p.maxRadiusMm);
      best = mean + bestR * mean.normalized();
    }
  }

  // Refinement over the pieces the sphere explains; twice, since the refined sphere can
  // explain a piece the hypothesis only grazed.
  std::vector<bool> use(n, false);
  GaussNewton gn;
  gn.c = best;
  gn.radius = bestR;
  const double band = std::max(p.outlierMm, 2.0 * p.ransacBandMm);
  for (int round = 0; round < 3; ++round) {
    std::fill(use.begin(), use.end(), false);
    for (const auto& piece : pieces.members) {
      size_t count = 0;
      for (size_t i : piece) count += std::abs((pts[i] - gn.c).norm() - gn.radius) <= band ? 1U : 0U;
      if (static_cast<double>(count) >= 0.5 * static_cast<double>(piece.size()))
        for (size_t i : piece) use[i] = true;
    }
    GaussNewton next = refine(pts, use, gn.c, gn.radius, band, p);
    if (!next.ok) return Status(Error::kBadInput, "sphere fit lost its points");
    gn = next;
  }
  const double radius = gn.radius;
  if (radius < p.minRadiusMm || radius > p.maxRadiusMm)
    return Status(Error::kOutOfRange, "fitted radius " + std::to_string(radius) + " mm is not a fruit");
  SphereFit out;
  out.centerMm = gn.c;
  out.radiusMm = radius;
  out.inlier.assign(n, false);
  double sumSq = 0.0;
  for (size_t i = 0; i < n; ++i) {
    if (!use[i]) continue;
    const double r = (pts[i] - gn.c).norm() - radius;
    if (std::abs(r) <= p.outlierMm) {
      sumSq += r * r;
      ++out.inliers;
      out.inlier[i] = true;
    }
  }
  if (out.inliers < p.minPoints) return Status(Error::kBadInput, "too few inliers for a sphere fit");
  std::vector<bool> lineUsed(pieces.byLine.size() + 1, false);
  for (size_t g = 0; g < pieces.members.size(); ++g) {
    size_t count = 0;
    for (size_t i : pieces.members[g]) count += out.inlier[i] ? 1U : 0U;
    if (count >= 4) ++out.groupsUsed;
  }
  {
    std::vector<int> lines;
    for (size_t i = 0; i < n; ++i)
      if (out.inlier[i]) lines.push_back(lineIds != nullptr ? (*lineIds)[i] : 0);
    std::sort(lines.begin(), lines.end());
    out.linesUsed = static_cast<int>(std::unique(lines.begin(), lines.end()) - lines.begin());
  }
  out.rmsMm = std::sqrt(sumSq / static_cast<double>(out.inliers));
  const double variance = sumSq / std::max(1.0, static_cast<double>(out.inliers) - 4.0);
  out.covariance = gn.jtj.inverse() * variance;
  if (!out.covariance.allFinite()) return Status(Error::kBadInput, "sphere fit is degenerate (one line?)");
  out.centerSigmaMm = std::sqrt(std::max(0.0, out.covariance.topLeftCorner<3, 3>().trace()));
  out.radiusSigmaMm = std::sqrt(std::max(0.0, out.covariance(3, 3)));
  return out;
}

}  // namespace

std::vector<int> splitPieces(const std::vector<Eigen::Vector3d>& pts, double breakMm, int firstId) {
  std::vector<int> out(pts.size(), firstId);
  int id = firstId;
  for (size_t i = 1; i < pts.size(); ++i) {
    if ((pts[i] - pts[i - 1]).norm() > breakMm) ++id;
    out[i] = id;
  }
  return out;
}

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pts, const SphereFitParams& p) {
  return fit(pts, nullptr, nullptr, p);
}

Result<SphereFit> fitSphere(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>& lineIds,
                            const std::vector<int>& groupIds, const SphereFitParams& p) {
  if (lineIds.size() != pts.size()) return Status(Error::kInvalidArgument, "one line id per point");
  if (!groupIds.empty() && groupIds.size() != pts.size())
    return Status(Error::kInvalidArgument, "one piece id per point");
  return fit(pts, &lineIds, groupIds.empty() ? nullptr : &groupIds, p);
}

}  // namespace alacs::geometry
