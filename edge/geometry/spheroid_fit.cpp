#include "geometry/spheroid_fit.h"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <cmath>

namespace alacs::geometry {

namespace {

using Vec7 = Eigen::Matrix<double, 7, 1>;
using Mat7 = Eigen::Matrix<double, 7, 7>;

struct Shape {
  Eigen::Vector3d c;
  double a;
  double k;
  Eigen::Vector3d s;  // unit stem axis
};

// Radial distance from the surface: |q| − R(q̂), R the spheroid's radius along q̂. For
// aspects near 1 this is the geometric distance to first order.
double radial(const Shape& sh, const Eigen::Vector3d& p) {
  const Eigen::Vector3d q = p - sh.c;
  const double len = q.norm();
  if (len < 1e-9) return -sh.a;
  const double cosT = q.dot(sh.s) / len;
  const double sin2 = std::max(0.0, 1.0 - cosT * cosT);
  const double b = sh.k * sh.a;
  const double inv2 = sin2 / (sh.a * sh.a) + cosT * cosT / (b * b);
  return len - 1.0 / std::sqrt(inv2);
}

// The Huber loss of a residual r (quadratic within h, linear beyond).
double huber(double r, double h) {
  const double ar = std::abs(r);
  return ar <= h ? r * r : h * (2.0 * ar - h);
}

// The points' Huber loss about a shape: the fit's data term without its weight and priors.
double huberSum(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx, const Shape& x, double h) {
  double total = 0.0;
  for (size_t i : idx) total += huber(radial(x, pts[i]), h);
  return total;
}

void stemBasis(const Eigen::Vector3d& s, Eigen::Vector3d* e1, Eigen::Vector3d* e2) {
  *e1 = s.unitOrthogonal();
  *e2 = s.cross(*e1);
}

// Parameters (δc 3, δa, δk, tilt α, β) applied to a shape.
Shape apply(const Shape& base, const Vec7& d) {
  Shape out = base;
  out.c += d.head<3>();
  out.a += d(3);
  out.k += d(4);
  Eigen::Vector3d e1;
  Eigen::Vector3d e2;
  stemBasis(base.s, &e1, &e2);
  out.s = (base.s + d(5) * e1 + d(6) * e2).normalized();
  return out;
}

}  // namespace

bool spheroidApproach(const Eigen::Vector3d& c, double a, double k, const Eigen::Vector3d& s, Eigen::Vector3d* point,
                      Eigen::Vector3d* normal) {
  const double dist = c.norm();
  if (!(dist > 0.0) || !(a > 0.0) || !(k > 0.0)) return false;
  const Eigen::Vector3d u = c / dist;
  // x = t·u; q = x − c = t·u − c. Quadratic form Q(q) = |q⊥|²/a² + (q·s)²/b² = 1.
  const double b = k * a;
  auto form = [&](const Eigen::Vector3d& v, const Eigen::Vector3d& w) {
    const double vs = v.dot(s);
    const double ws = w.dot(s);
    return (v.dot(w) - vs * ws) / (a * a) + vs * ws / (b * b);
  };
  const double qa = form(u, u);
  const double qb = -2.0 * form(u, c);
  const double qc = form(c, c) - 1.0;
  const double disc = qb * qb - 4.0 * qa * qc;
  if (!(disc >= 0.0) || !(qa > 0.0)) return false;
  const double t = (-qb - std::sqrt(disc)) / (2.0 * qa);  // the nearer root: where it enters
  *point = t * u;
  const Eigen::Vector3d q = *point - c;
  const double qs = q.dot(s);
  const Eigen::Vector3d grad = (q - qs * s) / (a * a) + qs * s / (b * b);
  *normal = grad.normalized();
  return point->allFinite() && normal->allFinite();
}

Result<SpheroidFit> refineSpheroid(const std::vector<Eigen::Vector3d>& pts, const std::vector<bool>& use,
                                   const SphereFit& sphere, const SpheroidPriors& pr) {
  if (use.size() != pts.size()) return Status(Error::kInvalidArgument, "one flag per point");
  std::vector<size_t> idx;
  for (size_t i = 0; i < pts.size(); ++i)
    if (use[i]) idx.push_back(i);
  if (idx.size() < 12) return Status(Error::kBadInput, "too few points for a spheroid");
  // Data weight: the points' own noise (from the sphere fit), fewer independent points
  // than rows.
  const double sigma2 = std::max(0.05 * 0.05, sphere.rmsMm * sphere.rmsMm) * std::max(1.0, pr.pointsPerIndependent);
  const double wData = 1.0 / sigma2;
  Eigen::Vector3d s0 = pr.stemAxis.normalized();
  Shape sh;
  sh.c = sphere.centerMm;
  sh.k = pr.aspect;
  // Start with the same volume-ish size: the sphere sits between the two radii.
  sh.a = sphere.radiusMm / std::cbrt(pr.aspect);
  sh.s = s0;

  auto cost = [&](const Shape& x, Mat7* jtj, Vec7* jtr) {
    double total = 0.0;
    if (jtj != nullptr) {
      jtj->setZero();
      jtr->setZero();
    }
    Eigen::Vector3d e1;
    Eigen::Vector3d e2;
    stemBasis(x.s, &e1, &e2);
    for (size_t i : idx) {
      const double r = radial(x, pts[i]);
      const double ar = std::abs(r);
      const double h = pr.huberMm;
      total += wData * huber(r, h);
      if (jtj == nullptr) continue;
      const double w = wData * (ar <= h ? 1.0 : h / ar);
      Vec7 g;
      for (int k = 0; k < 7; ++k) {
        const double step = (k == 4) ? 1e-6 : (k >= 5 ? 1e-6 : 1e-4);
        Vec7 d = Vec7::Zero();
        d(k) = step;
        const double rp = radial(apply(x, d), pts[i]);
        d(k) = -step;
        const double rm = radial(apply(x, d), pts[i]);
        g(k) = (rp - rm) / (2.0 * step);
      }
      *jtj += w * g * g.transpose();
      *jtr += w * g * r;
    }
    // Priors as residuals: size, aspect, and the stem's tilt from the prior axis.
    const double za = (x.a - pr.radiusMm) / pr.radiusSigmaMm;
    const double zk = (x.k - pr.aspect) / pr.aspectSigma;
    const Eigen::Vector3d tilt = x.s - s0.dot(x.s) * s0;  // component off the prior axis (~angle)
    total += za * za + zk * zk + tilt.squaredNorm() / (pr.stemTiltSigmaRad * pr.stemTiltSigmaRad);
    if (jtj != nullptr) {
      (*jtj)(3, 3) += 1.0 / (pr.radiusSigmaMm * pr.radiusSigmaMm);
      (*jtr)(3) += za / pr.radiusSigmaMm;
      (*jtj)(4, 4) += 1.0 / (pr.aspectSigma * pr.aspectSigma);
      (*jtr)(4) += zk / pr.aspectSigma;
      // d(tilt)/d(α, β) ≈ the basis vectors minus their part along s0.
      Eigen::Matrix<double, 3, 2> jt;
      jt.col(0) = e1 - s0.dot(e1) * s0;
      jt.col(1) = e2 - s0.dot(e2) * s0;
      const double ws = 1.0 / (pr.stemTiltSigmaRad * pr.stemTiltSigmaRad);
      jtj->block<2, 2>(5, 5) += ws * jt.transpose() * jt;
      jtr->segment<2>(5) += ws * jt.transpose() * tilt;
    }
    return total;
  };

  Mat7 jtj;
  Vec7 jtr;
  double f = cost(sh, &jtj, &jtr);
  double lambda = 1e-3;
  for (int it = 0; it < pr.iterations; ++it) {
    Mat7 a = jtj;
    for (int d = 0; d < 7; ++d) a(d, d) += lambda * std::max(jtj(d, d), 1e-9);
    const Vec7 step = a.ldlt().solve(-jtr);
    if (!step.allFinite()) break;
    Shape trial = apply(sh, step);
    if (trial.k < 0.5 || trial.k > 1.5 || trial.a < 10.0 || trial.a > 120.0) {
      lambda *= 10.0;
      if (lambda > 1e8) break;
      continue;
    }
    Mat7 jtj2;
    Vec7 jtr2;
    const double f2 = cost(trial, &jtj2, &jtr2);
    if (f2 < f) {
      const bool done = f - f2 < 1e-9 * (1.0 + f);
      sh = trial;
      f = f2;
      jtj = jtj2;
      jtr = jtr2;
      lambda = std::max(lambda / 10.0, 1e-9);
      if (done) break;
    } else {
      lambda *= 10.0;
      if (lambda > 1e8) break;
    }
  }
  if (!sh.c.allFinite() || !std::isfinite(sh.a) || !std::isfinite(sh.k))
    return Status(Error::kBadInput, "spheroid fit diverged");
  SpheroidFit out;
  out.centerMm = sh.c;
  out.radiusMm = sh.a;
  out.aspect = sh.k;
  out.stemAxis = sh.s;
  double sum = 0.0;
  for (size_t i : idx) sum += std::pow(radial(sh, pts[i]), 2);
  out.rmsMm = std::sqrt(sum / static_cast<double>(idx.size()));
  out.chiSquare = wData * huberSum(pts, idx, sh, pr.huberMm);
  out.sphereChiSquare = wData * huberSum(pts, idx, Shape{sphere.centerMm, sphere.radiusMm, 1.0, s0}, pr.huberMm);
  // The Hessian of the negative log posterior (data weighted by their variance, priors
  // by theirs) inverts to the covariance.
  out.covariance = jtj.inverse();
  if (!out.covariance.allFinite()) return Status(Error::kBadInput, "spheroid fit is degenerate");
  return out;
}

double spheroidWeight(const SpheroidFit& fit) {
  constexpr double kMoreParameters = 3.0;  // the aspect and the stem's tilt (two angles)
  const double gain = fit.sphereChiSquare - fit.chiSquare - 2.0 * kMoreParameters;
  return 1.0 / (1.0 + std::exp(-0.5 * gain));
}

double spheroidApproachSigma(const SpheroidFit& fit) {
  Shape base{fit.centerMm, fit.radiusMm, fit.aspect, fit.stemAxis};
  Eigen::Vector3d a0;
  Eigen::Vector3d n0;
  if (!spheroidApproach(base.c, base.a, base.k, base.s, &a0, &n0)) return 0.0;
  Eigen::Matrix<double, 3, 7> j;
  for (int k = 0; k < 7; ++k) {
    const double step = (k >= 4) ? 1e-6 : 1e-4;
    Vec7 d = Vec7::Zero();
    d(k) = step;
    const Shape p = apply(base, d);
    d(k) = -step;
    const Shape m = apply(base, d);
    Eigen::Vector3d ap;
    Eigen::Vector3d am;
    Eigen::Vector3d n;
    if (!spheroidApproach(p.c, p.a, p.k, p.s, &ap, &n) || !spheroidApproach(m.c, m.a, m.k, m.s, &am, &n)) return 0.0;
    j.col(k) = (ap - am) / (2.0 * step);
  }
  const Eigen::Matrix3d cov = j * fit.covariance * j.transpose();
  return std::sqrt(std::max(0.0, cov.trace()));
}

}  // namespace alacs::geometry
