#include "geometry/laser_calibration.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <string>

namespace alacs::geometry {

namespace {

// One laser pixel with what the fit needs of its frame.
struct Pixel {
  Eigen::Vector3d ray;     // (x, y, 1), undistorted normalized
  Eigen::Vector3d point;   // ray ∩ target plane, mm
  Eigen::Vector3d targetNormal;
  double targetOffsetMm;
  double slideMm;
  int placement;
  size_t line;
};

// The parameters while fitting: n, d0, k with d(s) = d0 + k·s.
struct Plane {
  Eigen::Vector3d n = Eigen::Vector3d::UnitX();
  double d0 = 0.0;
  double k = 0.0;
};

// Tangent basis of the unit sphere at n; the same rule everywhere, so the covariance's
// (α, β) mean the same thing in calibrateLaser and depthSigmaOnAxis.
void tangentBasis(const Eigen::Vector3d& n, Eigen::Vector3d* e1, Eigen::Vector3d* e2) {
  *e1 = n.unitOrthogonal();
  *e2 = n.cross(*e1);
}

// Residual (px) and its gradient with respect to (α, β, d0, k).
double residual(const Plane& p, const Pixel& q, double focalPx, const Eigen::Vector3d& e1, const Eigen::Vector3d& e2,
                Eigen::Vector4d* grad) {
  const double d = p.d0 + p.k * q.slideMm;
  // The image line of laser ∩ target, in homogeneous normalized coordinates.
  const Eigen::Vector3d l = q.targetOffsetMm * p.n - d * q.targetNormal;
  const double norm2 = l.x() * l.x() + l.y() * l.y();
  if (!(norm2 > 1e-18)) {
    if (grad != nullptr) grad->setZero();
    return 0.0;
  }
  const double norm = std::sqrt(norm2);
  const double dot = l.dot(q.ray);
  const double r = focalPx * dot / norm;
  if (grad != nullptr) {
    // dr/dl = f·(ray/|l12| − (l·ray)·(l0, l1, 0)/|l12|³)
    const Eigen::Vector3d drdl =
        focalPx * (q.ray / norm - dot / (norm2 * norm) * Eigen::Vector3d(l.x(), l.y(), 0.0));
    (*grad)(0) = drdl.dot(q.targetOffsetMm * e1);
    (*grad)(1) = drdl.dot(q.targetOffsetMm * e2);
    (*grad)(2) = drdl.dot(-q.targetNormal);
    (*grad)(3) = drdl.dot(-q.slideMm * q.targetNormal);
  }
  return r;
}

// Least squares of n·X = d0 + k·s with |n| = 1 over `idx`: d0 and k are linear given n,
// so n is the smallest eigenvector of the reduced scatter matrix.
bool linearFit(const std::vector<Pixel>& px, const std::vector<size_t>& idx, const Eigen::Vector3d& axis, Plane* out) {
  Eigen::Matrix3d sxx = Eigen::Matrix3d::Zero();
  Eigen::Vector3d sx = Eigen::Vector3d::Zero();
  Eigen::Vector3d ssx = Eigen::Vector3d::Zero();
  double ss = 0.0;
  double s1 = 0.0;
  const double m = static_cast<double>(idx.size());
  // Centre the coordinates for conditioning (points sit ~1 m away, spread ~0.1 m).
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  double sMean = 0.0;
  for (size_t i : idx) {
    mean += px[i].point;
    sMean += px[i].slideMm;
  }
  mean /= m;
  sMean /= m;
  for (size_t i : idx) {
    const Eigen::Vector3d x = px[i].point - mean;
    const double s = px[i].slideMm - sMean;
    sxx += x * x.transpose();
    sx += x;
    ssx += s * x;
    ss += s * s;
    s1 += s;
  }
  Eigen::Matrix2d mtm;
  mtm << ss, s1, s1, m;
  if (!(mtm.determinant() > 1e-9 * (1.0 + ss * m))) return false;  // one slide position only
  Eigen::Matrix<double, 2, 3> mtx;
  mtx.row(0) = ssx.transpose();
  mtx.row(1) = sx.transpose();
  const Eigen::Matrix3d b = sxx - mtx.transpose() * mtm.inverse() * mtx;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(b);
  if (eig.info() != Eigen::Success) return false;
  Eigen::Vector3d n = eig.eigenvectors().col(0);
  const Eigen::Vector2d kd = mtm.inverse() * mtx * n;
  Plane p;
  p.n = n;
  p.k = kd(0);
  // Undo the centring: n·(X − mean) = d0' + k·(s − sMean).
  p.d0 = kd(1) + n.dot(mean) - p.k * sMean;
  if (p.n.dot(axis) < 0.0) {
    p.n = -p.n;
    p.d0 = -p.d0;
    p.k = -p.k;
  }
  if (!p.n.allFinite() || !std::isfinite(p.d0) || !std::isfinite(p.k)) return false;
  *out = p;
  return true;
}

double huberWeight(double r, double h) { return std::abs(r) <= h ? 1.0 : h / std::abs(r); }

double huberCost(double r, double h) {
  const double a = std::abs(r);
  return a <= h ? 0.5 * r * r : h * (a - 0.5 * h);
}

struct LmResult {
  Plane plane;
  Eigen::Matrix4d information = Eigen::Matrix4d::Zero();  // JᵀWJ at the solution
  double weightedSq = 0.0;
  size_t used = 0;
};

// Levenberg–Marquardt with Huber weights over the pixels of `use` whose residual stays
// inside `band` at the current estimate.
LmResult levenbergMarquardt(const std::vector<Pixel>& px, const std::vector<bool>& use, Plane start,
                            const LaserFitOptions& o) {
  LmResult out;
  Plane p = start;
  double lambda = 1e-3;
  auto evaluate = [&](const Plane& q, Eigen::Matrix4d* jtj, Eigen::Vector4d* jtr, double* wsq, size_t* count) {
    Eigen::Vector3d e1;
    Eigen::Vector3d e2;
    tangentBasis(q.n, &e1, &e2);
    double cost = 0.0;
    if (jtj != nullptr) jtj->setZero();
    if (jtr != nullptr) jtr->setZero();
    if (wsq != nullptr) *wsq = 0.0;
    if (count != nullptr) *count = 0;
    for (size_t i = 0; i < px.size(); ++i) {
      if (!use[i]) continue;
      Eigen::Vector4d g;
      const double r = residual(q, px[i], o.focalPx, e1, e2, jtj != nullptr ? &g : nullptr);
      // Points outside the band are outliers: they pay a constant, so they neither pull
      // the fit nor make leaving the band look like progress.
      if (std::abs(r) > o.inlierBandPx) {
        cost += huberCost(o.inlierBandPx, o.huberPx);
        continue;
      }
      cost += huberCost(r, o.huberPx);
      const double w = huberWeight(r, o.huberPx);
      if (jtj != nullptr) *jtj += w * g * g.transpose();
      if (jtr != nullptr) *jtr += w * g * r;
      if (wsq != nullptr) *wsq += w * r * r;
      if (count != nullptr) ++*count;
    }
    return cost;
  };
  Eigen::Matrix4d jtj;
  Eigen::Vector4d jtr;
  double cost = evaluate(p, &jtj, &jtr, nullptr, nullptr);
  for (int it = 0; it < o.maxIterations; ++it) {
    Eigen::Matrix4d a = jtj;
    for (int d = 0; d < 4; ++d) a(d, d) += lambda * std::max(jtj(d, d), 1e-12);
    const Eigen::Vector4d step = a.ldlt().solve(-jtr);
    if (!step.allFinite()) break;
    Eigen::Vector3d e1;
    Eigen::Vector3d e2;
    tangentBasis(p.n, &e1, &e2);
    Plane trial;
    trial.n = (p.n + step(0) * e1 + step(1) * e2).normalized();
    trial.d0 = p.d0 + step(2);
    trial.k = p.k + step(3);
    Eigen::Matrix4d jtj2;
    Eigen::Vector4d jtr2;
    const double cost2 = evaluate(trial, &jtj2, &jtr2, nullptr, nullptr);
    if (cost2 < cost) {
      const bool done = cost - cost2 < 1e-12 * (1.0 + cost) || step.head<2>().norm() < 1e-12;
      p = trial;
      cost = cost2;
      jtj = jtj2;
      jtr = jtr2;
      lambda = std::max(lambda / 10.0, 1e-12);
      if (done) break;
    } else {
      lambda *= 10.0;
      if (lambda > 1e12) break;
    }
  }
  out.plane = p;
  evaluate(p, &out.information, nullptr, &out.weightedSq, &out.used);
  return out;
}

uint64_t nextRandom(uint64_t* state) {
  uint64_t x = *state;
  x ^= x << 13;
  x ^= x >> 7;
  x ^= x << 17;
  *state = x;
  return x;
}

LaserGeometry toGeometry(const Plane& p, const Eigen::Vector3d& axis) {
  LaserGeometry g;
  g.planeNormal = p.n;
  g.planeOffsetMm = p.d0;
  g.slideAxis = axis;
  g.slideScale = p.k / p.n.dot(axis);
  return g;
}

Plane fromGeometry(const LaserGeometry& g) {
  Plane p;
  p.n = g.planeNormal;
  p.d0 = g.planeOffsetMm;
  p.k = g.slideScale * g.planeNormal.dot(g.slideAxis);
  return p;
}

// Every usable pixel of the samples with its ray's point on the target, grouped by line.
Status collectPixels(const std::vector<LaserLineSample>& samples, std::vector<Pixel>* pxOut,
                     std::vector<std::vector<size_t>>* linesOut, std::set<int>* placementsOut,
                     std::set<long long>* slidesOut, int* maxPlacementOut) {
  std::vector<Pixel>& px = *pxOut;
  std::vector<std::vector<size_t>>& lines = *linesOut;
  std::set<int>& placements = *placementsOut;
  std::set<long long>& slides = *slidesOut;
  int& maxPlacement = *maxPlacementOut;
  for (const auto& smp : samples) {
    if (smp.placement < 0) return Status(Error::kInvalidArgument, "placement ids must be non-negative");
    if (!smp.targetNormal.allFinite() || std::abs(smp.targetNormal.norm() - 1.0) > 1e-6 ||
        !std::isfinite(smp.targetOffsetMm) || !std::isfinite(smp.slideMm))
      return Status(Error::kBadInput, "laser sample with a bad target plane or slide position");
    std::vector<size_t> members;
    for (const auto& xn : smp.normalized) {
      const Eigen::Vector3d ray(xn.x(), xn.y(), 1.0);
      const double denom = smp.targetNormal.dot(ray);
      if (!ray.allFinite() || std::abs(denom) < 1e-6) continue;
      const double depth = smp.targetOffsetMm / denom;
      if (!(depth > 0.0)) continue;
      members.push_back(px.size());
      px.push_back({ray, depth * ray, smp.targetNormal, smp.targetOffsetMm, smp.slideMm, smp.placement, lines.size()});
    }
    if (members.empty()) continue;
    lines.push_back(std::move(members));
    placements.insert(smp.placement);
    slides.insert(std::llround(smp.slideMm * 1000.0));
    maxPlacement = std::max(maxPlacement, smp.placement);
  }
  return Status::ok();
}

}  // namespace

double laserResidualPx(const LaserGeometry& laser, const LaserLineSample& sample, const Eigen::Vector2d& xn,
                       double focalPx) {
  Pixel q;
  q.ray = Eigen::Vector3d(xn.x(), xn.y(), 1.0);
  q.targetNormal = sample.targetNormal;
  q.targetOffsetMm = sample.targetOffsetMm;
  q.slideMm = sample.slideMm;
  Eigen::Vector3d e1;
  Eigen::Vector3d e2;
  tangentBasis(laser.planeNormal, &e1, &e2);
  return residual(fromGeometry(laser), q, focalPx, e1, e2, nullptr);
}

double depthSigmaOnAxis(const LaserGeometry& laser, const Eigen::Matrix4d& covariance, double depthMm) {
  const Plane p = fromGeometry(laser);
  if (std::abs(p.k) < 1e-12 || std::abs(p.n.z()) < 1e-9) return 0.0;
  // Slide position that puts the plane through (0, 0, depth); then the depth the ray
  // (0, 0, 1) triangulates to, t = (d0 + k·s)/n_z, differentiated at fixed s.
  const double s = (p.n.z() * depthMm - p.d0) / p.k;
  Eigen::Vector3d e1;
  Eigen::Vector3d e2;
  tangentBasis(p.n, &e1, &e2);
  const double t = (p.d0 + p.k * s) / p.n.z();
  Eigen::Vector4d g;
  g << -t * e1.z() / p.n.z(), -t * e2.z() / p.n.z(), 1.0 / p.n.z(), s / p.n.z();
  return std::sqrt(std::max(0.0, g.dot(covariance * g)));
}

Result<LaserFit> calibrateLaser(const std::vector<LaserLineSample>& samples, const LaserFitOptions& o) {
  const Eigen::Vector3d axis = o.nominalSlideAxis.normalized();
  if (!axis.allFinite()) return Status(Error::kInvalidArgument, "nominal slide axis must be a non-zero vector");
  std::vector<Pixel> px;
  std::vector<std::vector<size_t>> lines;
  std::set<int> placements;
  std::set<long long> slides;
  int maxPlacement = 0;
  if (Status st = collectPixels(samples, &px, &lines, &placements, &slides, &maxPlacement); !st) return st;
  if (px.size() < o.minPoints)
    return Status(Error::kBadInput, "laser calibration: only " + std::to_string(px.size()) + " usable line pixels");
  if (slides.size() < 2)
    return Status(Error::kBadInput, "laser calibration needs lines at two or more slide positions");
  if (lines.size() < 4) return Status(Error::kBadInput, "laser calibration needs four or more lines");

  // RANSAC: four pixels from four different lines.
  uint64_t state = 0x9E3779B97F4A7C15ULL ^ o.seed;
  Plane best;
  size_t bestCount = 0;
  std::vector<size_t> sample(4);
  for (int it = 0; it < o.ransacIterations; ++it) {
    std::set<size_t> chosen;
    while (chosen.size() < 4) chosen.insert(static_cast<size_t>(nextRandom(&state) % lines.size()));
    size_t j = 0;
    for (size_t line : chosen) sample[j++] = lines[line][nextRandom(&state) % lines[line].size()];
    Plane cand;
    if (!linearFit(px, sample, axis, &cand)) continue;
    Eigen::Vector3d e1;
    Eigen::Vector3d e2;
    tangentBasis(cand.n, &e1, &e2);
    size_t count = 0;
    for (const auto& q : px) count += std::abs(residual(cand, q, o.focalPx, e1, e2, nullptr)) <= o.ransacBandPx ? 1U : 0U;
    if (count > bestCount) {
      bestCount = count;
      best = cand;
    }
  }
  if (bestCount < o.minPoints) return Status(Error::kBadInput, "laser calibration: no consensus among the lines");
  // Linear refit on the consensus, then LM on the image residual.
  {
    Eigen::Vector3d e1;
    Eigen::Vector3d e2;
    tangentBasis(best.n, &e1, &e2);
    std::vector<size_t> in;
    for (size_t i = 0; i < px.size(); ++i)
      if (std::abs(residual(best, px[i], o.focalPx, e1, e2, nullptr)) <= o.ransacBandPx) in.push_back(i);
    Plane refit;
    if (linearFit(px, in, axis, &refit)) best = refit;
  }
  const std::vector<bool> all(px.size(), true);
  const LmResult lm = levenbergMarquardt(px, all, best, o);
  if (lm.used < o.minPoints) return Status(Error::kBadInput, "laser calibration: too few inliers after refinement");
  const Plane& p = lm.plane;
  if (std::abs(p.n.dot(axis)) < 0.05)
    return Status(Error::kBadInput, "laser calibration: the fitted plane is nearly parallel to the slide axis");

  LaserFit fit;
  fit.laser = toGeometry(p, axis);
  fit.points = px.size();
  fit.inliers = lm.used;
  fit.placements = static_cast<int>(placements.size());
  fit.slidePositions = static_cast<int>(slides.size());
  Eigen::Vector3d e1;
  Eigen::Vector3d e2;
  tangentBasis(p.n, &e1, &e2);
  double sumPx = 0.0;
  double sumMm = 0.0;
  std::vector<double> placeSum(static_cast<size_t>(maxPlacement) + 1, 0.0);
  std::vector<size_t> placeCount(placeSum.size(), 0);
  for (const auto& q : px) {
    const double r = residual(p, q, o.focalPx, e1, e2, nullptr);
    const auto pl = static_cast<size_t>(q.placement);
    placeSum[pl] += r * r;
    ++placeCount[pl];
    if (std::abs(r) > o.inlierBandPx) continue;
    sumPx += r * r;
    const double dMm = p.n.dot(q.point) - p.d0 - p.k * q.slideMm;
    sumMm += dMm * dMm;
  }
  const auto nIn = static_cast<double>(fit.inliers);
  fit.rmsPx = std::sqrt(sumPx / nIn);
  fit.rmsMm = std::sqrt(sumMm / nIn);
  for (size_t i = 0; i < placeSum.size(); ++i)
    fit.placementRmsPx.push_back(placeCount[i] > 0 ? std::sqrt(placeSum[i] / static_cast<double>(placeCount[i])) : 0.0);

  // Formal covariance: σ²·(JᵀWJ)⁻¹, σ² the weighted residual variance.
  const double dof = std::max(1.0, nIn - 4.0);
  Eigen::Matrix4d cov = (lm.weightedSq / dof) * lm.information.inverse();
  // Jackknife over placements: what a different set of target poses would have given.
  if (placements.size() >= 3) {
    std::vector<Eigen::Vector4d> deltas;
    for (int leave : placements) {
      std::vector<bool> use(px.size());
      for (size_t i = 0; i < px.size(); ++i) use[i] = px[i].placement != leave;
      const LmResult sub = levenbergMarquardt(px, use, p, o);
      if (sub.used < o.minPoints) continue;
      const Eigen::Vector3d dn = sub.plane.n - p.n;
      deltas.emplace_back(dn.dot(e1), dn.dot(e2), sub.plane.d0 - p.d0, sub.plane.k - p.k);
    }
    if (deltas.size() >= 3) {
      Eigen::Vector4d mean = Eigen::Vector4d::Zero();
      for (const auto& d : deltas) mean += d;
      mean /= static_cast<double>(deltas.size());
      Eigen::Matrix4d jk = Eigen::Matrix4d::Zero();
      for (const auto& d : deltas) jk += (d - mean) * (d - mean).transpose();
      const auto g = static_cast<double>(deltas.size());
      cov += jk * (g - 1.0) / g;
    }
  }
  fit.covariance = cov;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> tilt(cov.topLeftCorner<2, 2>());
  fit.normalSigmaMrad = 1000.0 * std::sqrt(std::max(0.0, tilt.eigenvalues()(1)));
  fit.offsetSigmaMm = std::sqrt(std::max(0.0, cov(2, 2)));
  fit.scaleSigma = std::sqrt(std::max(0.0, cov(3, 3))) / std::abs(p.n.dot(axis));
  fit.depthSigmaMmAt1000 = depthSigmaOnAxis(fit.laser, cov, 1000.0);
  fit.depthSigmaMmAt1600 = depthSigmaOnAxis(fit.laser, cov, 1600.0);
  return fit;
}

}  // namespace alacs::geometry

namespace alacs::geometry {

Result<LaserGeometry> refineLaser(const std::vector<LaserLineSample>& samples, const LaserGeometry& start,
                                  const LaserFitOptions& o) {
  const Eigen::Vector3d axis = o.nominalSlideAxis.normalized();
  if (!axis.allFinite()) return Status(Error::kInvalidArgument, "nominal slide axis must be a non-zero vector");
  std::vector<Pixel> px;
  std::vector<std::vector<size_t>> lines;
  std::set<int> placements;
  std::set<long long> slides;
  int maxPlacement = 0;
  if (Status st = collectPixels(samples, &px, &lines, &placements, &slides, &maxPlacement); !st) return st;
  if (px.size() < o.minPoints)
    return Status(Error::kBadInput, "laser refinement: only " + std::to_string(px.size()) + " usable line pixels");
  const LmResult lm = levenbergMarquardt(px, std::vector<bool>(px.size(), true), fromGeometry(start), o);
  if (lm.used < o.minPoints) return Status(Error::kBadInput, "laser refinement: too few inliers");
  return toGeometry(lm.plane, axis);
}

LaserGeometry perturbLaser(const LaserGeometry& laser, const Eigen::Vector4d& delta) {
  const Plane p = fromGeometry(laser);
  Eigen::Vector3d e1;
  Eigen::Vector3d e2;
  tangentBasis(p.n, &e1, &e2);
  Plane q;
  q.n = (p.n + delta(0) * e1 + delta(1) * e2).normalized();
  q.d0 = p.d0 + delta(2);
  q.k = p.k + delta(3);
  return toGeometry(q, laser.slideAxis);
}

}  // namespace alacs::geometry
