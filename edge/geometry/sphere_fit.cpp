#include "geometry/sphere_fit.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

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

// The circle through a piece of one line: its plane (PCA), then an algebraic circle in it.
// The plane of one line's points and two unit vectors in it (u along the points' larger
// extent): the known plane normal when given (a short, nearly straight arc does not fix
// its plane), otherwise by PCA. False when the points do not span what is needed.
bool linePlane(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx, const Eigen::Vector3d& known,
               Eigen::Vector3d* mean, Eigen::Vector3d* normal, Eigen::Vector3d* u, Eigen::Vector3d* v) {
  if (idx.empty()) return false;
  *mean = Eigen::Vector3d::Zero();
  for (size_t i : idx) *mean += pts[i];
  *mean /= static_cast<double>(idx.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (size_t i : idx) cov += (pts[i] - *mean) * (pts[i] - *mean).transpose();
  if (known.norm() > 0.5) {
    *normal = known.normalized();
    // The in-plane direction of the largest extent.
    const Eigen::Matrix3d proj = Eigen::Matrix3d::Identity() - *normal * normal->transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(proj * cov * proj);
    if (eig.info() != Eigen::Success || !(eig.eigenvalues()(2) > 0.0)) return false;
    *u = eig.eigenvectors().col(2);
    *v = normal->cross(*u).normalized();
    return true;
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  if (eig.info() != Eigen::Success) return false;
  // An arc spans a plane: two clearly non-zero extents.
  if (!(eig.eigenvalues()(1) > 1e-6 * eig.eigenvalues()(2))) return false;
  *normal = eig.eigenvectors().col(0);
  *u = eig.eigenvectors().col(2);
  *v = eig.eigenvectors().col(1);
  return true;
}

bool circleOf(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx, const Eigen::Vector3d& known,
              Eigen::Vector3d* centre, double* radius, Eigen::Vector3d* normal) {
  if (idx.size() < 8) return false;
  Eigen::Vector3d mean;
  Eigen::Vector3d u;
  Eigen::Vector3d v;
  if (!linePlane(pts, idx, known, &mean, normal, &u, &v)) return false;
  Eigen::MatrixXd a(static_cast<Eigen::Index>(idx.size()), 3);
  Eigen::VectorXd b(static_cast<Eigen::Index>(idx.size()));
  for (size_t k = 0; k < idx.size(); ++k) {
    const Eigen::Vector3d q = pts[idx[k]] - mean;
    const double x = q.dot(u);
    const double y = q.dot(v);
    a.row(static_cast<Eigen::Index>(k)) << x, y, 1.0;
    b(static_cast<Eigen::Index>(k)) = -(x * x + y * y);
  }
  const Eigen::Vector3d s = a.colPivHouseholderQr().solve(b);
  const double cx = -0.5 * s(0);
  const double cy = -0.5 * s(1);
  const double r2 = cx * cx + cy * cy - s(2);
  if (!(r2 > 0.0) || !std::isfinite(r2)) return false;
  *centre = mean + cx * u + cy * v;
  *radius = std::sqrt(r2);
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

// Points that the camera (at the origin) could not see if the sphere (c, r − margin) were
// there: the sight line to them crosses it. Each counts by how deep the line passes.
double hiddenPoints(const std::vector<Eigen::Vector3d>& pts, const Eigen::Vector3d& c, double r,
                    const SphereFitParams& p) {
  if (!(p.freeSpacePoints > 0.0)) return 0.0;
  const double core = r * (1.0 - p.freeSpaceMarginShare) - p.freeSpaceMarginMm;
  if (!(core > 0.0)) return 0.0;
  const double cc = c.squaredNorm();
  double hidden = 0.0;
  for (const Eigen::Vector3d& q : pts) {
    const double qq = q.squaredNorm();
    if (!(qq > 0.0)) continue;
    // The sight line's point nearest the centre, within the segment from the camera to q.
    const double t = std::clamp(c.dot(q) / qq, 0.0, 1.0);
    const double d2 = cc - 2.0 * t * c.dot(q) + t * t * qq;
    if (d2 >= core * core) continue;
    const double depth = core - std::sqrt(std::max(0.0, d2));
    hidden += std::min(1.0, depth / std::max(1e-9, p.freeSpaceDepthMm));
  }
  return hidden;
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
    return s * centreFactor(c) * freeSpaceFactor(c, r);
  }

  // exp(−(weighted points the sphere would hide)/freeSpacePoints); see SphereFitParams.
  double freeSpaceFactor(const Eigen::Vector3d& c, double r) const {
    if (!(p_.freeSpacePoints > 0.0)) return 1.0;
    return std::exp(-hiddenPoints(pts_, c, r, p_) / p_.freeSpacePoints);
  }

  // Flat within 1.5σ of the rough position, then Gaussian: a target the rough position
  // missed by a typical error must not lose to a sphere that merely sits nearer to it
  // while explaining less; a neighbour an apple's width away still loses.
  double centreFactor(const Eigen::Vector3d& c) const {
    if (!(p_.priorCenterSigmaMm > 0.0)) return 1.0;
    const double sc = p_.priorCenterSigmaMm;
    const double excess = std::max(0.0, (c - p_.priorCenterMm).norm() - 1.5 * sc);
    return std::exp(-0.5 * excess * excess / (sc * sc));
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

// Huber-weighted Gauss–Newton over the points of `use` within `band` of the sphere. With
// `holdRadius` only the centre moves; `jtj` is the full information either way (for the
// covariance).
GaussNewton refine(const std::vector<Eigen::Vector3d>& pts, const std::vector<bool>& use, Eigen::Vector3d c,
                   double radius, double band, const SphereFitParams& p, bool holdRadius = false,
                   double maxStepMm = 0.0) {
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
    if (p.priorCenterSigmaMm > 0.0) {
      // The rough position, as weak: it fixes only what the lines leave open (the side and
      // offset of the centre when one line is all there is).
      const double wPrior = 1.0 / (p.priorCenterSigmaMm * p.priorCenterSigmaMm);
      out.jtj.topLeftCorner<3, 3>() += wPrior * Eigen::Matrix3d::Identity();
      jtr.head<3>() += wPrior * (c - p.priorCenterMm);
    }
    Eigen::Vector4d step = Eigen::Vector4d::Zero();
    if (holdRadius)
      step.head<3>() = out.jtj.topLeftCorner<3, 3>().ldlt().solve(-jtr.head<3>());
    else
      step = out.jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) return out;
    // A step held short (maxStepMm > 0): where the points leave a direction to the priors,
    // the linearised step overshoots beyond the band and loses them.
    if (maxStepMm > 0.0 && step.head<3>().norm() > maxStepMm) step *= maxStepMm / step.head<3>().norm();
    c += step.head<3>();
    radius += step(3);
    if (step.norm() < 1e-7) break;
  }
  out.c = c;
  out.radius = radius;
  out.ok = std::isfinite(radius) && c.allFinite();
  return out;
}

// Whether an arc bends at least half as much as the flattest fruit's circle would over the
// same chord (its sagitta: the farthest point from the chord between its ends), over a
// chord of kFlatArcMinChordMm or more. A leaf's straight cut does not; a lumpy fruit's arc,
// whose circle comes out flatter than any fruit's, does (docs/geometry.md, "A flat arc").
// Over a shorter chord that half bend is within a few times the line's depth noise (a few
// tenths of a millimetre): 1.75 mm at 40 mm for the largest fruit, 0.9 mm at 30 mm.
constexpr double kFlatArcMinChordMm = 40.0;
constexpr double kFlatArcStepMm = 2.0;  // finishFlatArc()'s refinement, held to short steps
bool curvesLikeFruit(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx,
                     const SphereFitParams& p) {
  if (idx.size() < 3) return false;
  const Eigen::Vector3d& a = pts[idx.front()];
  const Eigen::Vector3d chord = pts[idx.back()] - a;
  const double lengthMm = chord.norm();
  if (lengthMm < kFlatArcMinChordMm) return false;
  const Eigen::Vector3d along = chord / lengthMm;
  double sagittaMm = 0.0;
  for (size_t i : idx) {
    const Eigen::Vector3d d = pts[i] - a;
    sagittaMm = std::max(sagittaMm, (d - d.dot(along) * along).norm());
  }
  const double half = std::min(0.5 * lengthMm, p.maxRadiusMm);
  return sagittaMm >= 0.5 * (p.maxRadiusMm - std::sqrt(p.maxRadiusMm * p.maxRadiusMm - half * half));
}

struct Hypothesis {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double r = 0.0;
  double score = 0.0;
};

// Hypotheses from lines together (pairs of pieces on different lines, random samples
// across lines) or, with `singleLine`, from each piece alone with the radius prior.
Hypothesis search(const std::vector<Eigen::Vector3d>& pts, const Pieces& pieces, const Scorer& scorer,
                  const Eigen::Vector3d& mean, const SphereFitParams& p, bool singleLine) {
  Hypothesis best;
  auto offer = [&](const Eigen::Vector3d& c, double r, const Eigen::Vector3d& surface) {
    // The fruit lies behind its visible surface, as seen from the camera.
    if (c.norm() < surface.norm()) return;
    const double s = scorer.score(c, r);
    if (s > best.score) best = {c, r, s};
  };
  auto consider = [&](const std::vector<size_t>& idx) {
    Eigen::Vector3d c;
    double r = 0.0;
    if (algebraicSphere(pts, idx, mean, &c, &r)) offer(c, r, pts[idx.front()]);
  };
  if (singleLine) {
    // A piece alone is an arc of the circle where the laser plane cuts the fruit: the
    // centre lies sqrt(R0² − ρ²) off that plane, on either side.
    // Every sphere through the circle explains the piece equally well: the priors choose
    // the offset (the radius prior and, for the side and size of the offset, the rough
    // position). A grid of offsets, so the refinement starts near the best.
    if (!(p.priorRadiusMm > 0.0)) return best;
    for (const auto& piece : pieces.members) {
      Eigen::Vector3d c0;
      Eigen::Vector3d normal;
      double rho = 0.0;
      if (!circleOf(pts, piece, p.linePlaneNormal, &c0, &rho, &normal)) continue;
      const auto offerCircle = [&](const Eigen::Vector3d& centre, double inPlaneRadius) {
        for (int k = -24; k <= 24; ++k) {
          const double delta = 2.0 * k;  // mm
          offer(centre + delta * normal, std::sqrt(inPlaneRadius * inPlaneRadius + delta * delta), pts[piece.front()]);
        }
      };
      offerCircle(c0, rho);
      // An arc flatter than any fruit's: no sphere through its circle is fruit-sized. A
      // lumpy fruit's skin does that over a ridge (the circle of a short arc is ill
      // determined); so does a leaf. Fruit-sized circles through the arc's middle, on the
      // side of its own centre, are offered as well: the scorer keeps one only where it
      // explains the piece (a leaf's flat arc strays from it), and finishOneLine() then
      // fits the sphere with the priors (docs/geometry.md, "A flat arc").
      if (rho > p.maxRadiusMm && curvesLikeFruit(pts, piece, p)) {
        const Eigen::Vector3d& mid = pts[piece[piece.size() / 2]];
        const Eigen::Vector3d toward = (c0 - mid) - normal.dot(c0 - mid) * normal;
        if (toward.norm() > 1e-9)
          for (double shrunk : {0.8 * p.priorRadiusMm, p.priorRadiusMm, 1.2 * p.priorRadiusMm})
            offerCircle(mid + shrunk * toward.normalized(), shrunk);
      }
    }
    return best;
  }
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
  const size_t n = pts.size();
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
  return best;
}

// Refines a hypothesis over the pieces it explains and measures the result.
Result<SphereFit> finish(const std::vector<Eigen::Vector3d>& pts, const std::vector<int>* lineIds,
                         const Pieces& pieces, const Hypothesis& h, const SphereFitParams& params) {
  const size_t n = pts.size();
  // Lines on two planes or more fix the centre: the rough position (off by 20–30 mm at
  // 2σ) would only pull it along the direction the lines fix least. It ranked the
  // hypotheses; it stays out of the refinement.
  SphereFitParams p = params;
  p.priorCenterSigmaMm = 0.0;
  std::vector<bool> use(n, false);
  GaussNewton gn;
  // Twice more after the first pass: the refined sphere can explain a piece the
  // hypothesis only grazed, or stop explaining one. Pieces join on the hypothesis' own
  // terms (most of the piece within the tight band), so that a neighbour's piece grazing
  // the sphere cannot join and drag it; the refinement then uses the wider band within the
  // pieces it has. When that leaves the fruit's sizes (a leaf's points within the wide
  // band of a small cap), the refinement again within the tight band only.
  auto run = [&](double band, const Eigen::Vector3d& c0, double r0, bool holdRadius) {
    gn.c = c0;
    gn.radius = r0;
    gn.ok = true;
    for (int round = 0; round < 3; ++round) {
      std::fill(use.begin(), use.end(), false);
      for (const auto& piece : pieces.members) {
        size_t count = 0;
        for (size_t i : piece) count += std::abs((pts[i] - gn.c).norm() - gn.radius) <= p.ransacBandMm ? 1U : 0U;
        if (static_cast<double>(count) >= 0.5 * static_cast<double>(piece.size()))
          for (size_t i : piece) use[i] = true;
      }
      GaussNewton next = refine(pts, use, gn.c, gn.radius, band, p, holdRadius);
      if (!next.ok) {
        gn.ok = false;
        return;
      }
      gn = next;
    }
  };
  const double wideBandMm = std::max(p.outlierMm, 2.0 * p.ransacBandMm);
  run(wideBandMm, h.c, h.r, false);
  if (!gn.ok || gn.radius < p.minRadiusMm || gn.radius > p.maxRadiusMm) run(p.ransacBandMm, h.c, h.r, false);
  // A cap that curves tighter than any fruit of the kind is still a fruit's: an oblate
  // fruit seen at its equator, or a prolate one at its pole, curves tighter there than
  // its radius (three of the hard cases' occluded targets were lost this way, refined
  // 5–8 mm below the truth). The smallest fruit's radius is held and the centre refined
  // to it; the residuals of the pieces that still join widen σ. It starts from the tight
  // sphere grown about its face (the centre moved back along the sight line), so the
  // cap's pieces still join. A cap flatter than any fruit (a leaf) stays out.
  if (gn.ok && gn.radius < p.minRadiusMm && gn.c.norm() > 0.0)
    run(wideBandMm, gn.c + (p.minRadiusMm - gn.radius) * gn.c.normalized(), p.minRadiusMm, true);
  if (!gn.ok) return Status(Error::kBadInput, "sphere fit lost its points");
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
  for (const auto& piece : pieces.members) {
    size_t count = 0;
    for (size_t i : piece) count += out.inlier[i] ? 1U : 0U;
    if (count >= 4) ++out.groupsUsed;
  }
  std::vector<int> lines;
  for (size_t i = 0; i < n; ++i)
    if (out.inlier[i]) lines.push_back(lineIds != nullptr ? (*lineIds)[i] : 0);
  std::sort(lines.begin(), lines.end());
  out.linesUsed = static_cast<int>(std::unique(lines.begin(), lines.end()) - lines.begin());
  out.rmsMm = std::sqrt(sumSq / static_cast<double>(out.inliers));
  const double variance = sumSq / std::max(1.0, static_cast<double>(out.inliers) - 4.0);
  out.covariance = gn.jtj.inverse() * variance * std::max(1.0, p.pointsPerIndependent);
  if (!out.covariance.allFinite()) return Status(Error::kBadInput, "sphere fit is degenerate");
  out.centerSigmaMm = std::sqrt(std::max(0.0, out.covariance.topLeftCorner<3, 3>().trace()));
  out.radiusSigmaMm = std::sqrt(std::max(0.0, out.covariance(3, 3)));
  return out;
}

// The one line's points that the hypothesis explains: of the line whose pieces it
// explains best, the pieces it explains for the most part.
std::vector<size_t> oneLinePoints(const std::vector<Eigen::Vector3d>& pts, const Pieces& pieces, const Hypothesis& h,
                                  const SphereFitParams& p) {
  const double band = std::max(p.outlierMm, 2.0 * p.ransacBandMm);
  std::vector<size_t> idx;
  int line = -1;
  size_t bestCount = 0;
  for (size_t g = 0; g < pieces.members.size(); ++g) {
    size_t count = 0;
    for (size_t i : pieces.members[g]) count += std::abs((pts[i] - h.c).norm() - h.r) <= band ? 1U : 0U;
    if (count > bestCount) {
      bestCount = count;
      line = pieces.line[g];
    }
  }
  for (size_t g = 0; g < pieces.members.size(); ++g) {
    if (pieces.line[g] != line) continue;
    size_t count = 0;
    for (size_t i : pieces.members[g]) count += std::abs((pts[i] - h.c).norm() - h.r) <= band ? 1U : 0U;
    if (static_cast<double>(count) >= 0.5 * static_cast<double>(pieces.members[g].size()))
      idx.insert(idx.end(), pieces.members[g].begin(), pieces.members[g].end());
  }
  return idx;
}

// One line's sphere (centre, radius) with the points of `idx` it explains within the final
// band as its inliers and their RMS; the covariance is the caller's.
Result<SphereFit> oneLineSphere(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx,
                                const Eigen::Vector3d& centerMm, double radiusMm, const SphereFitParams& p) {
  SphereFit out;
  out.centerMm = centerMm;
  out.radiusMm = radiusMm;
  out.inlier.assign(pts.size(), false);
  double inSq = 0.0;
  for (size_t i : idx) {
    const double r = (pts[i] - out.centerMm).norm() - out.radiusMm;
    if (std::abs(r) <= p.outlierMm) {
      out.inlier[i] = true;
      ++out.inliers;
      inSq += r * r;
    }
  }
  if (out.inliers < p.minPoints) return Status(Error::kBadInput, "too few inliers on the one line");
  out.rmsMm = std::sqrt(inSq / static_cast<double>(out.inliers));
  out.groupsUsed = 1;
  out.linesUsed = 1;
  return out;
}

// One line whose circle is flatter than any fruit (see search()): the circle the points fix
// is not the fruit's, so the sphere is fitted to the points directly, its radius and
// centre held by their priors (the valley of equally good spheres that the δ search below
// walks is here bounded by the radius prior, which the flat circle cannot meet). The
// points' own scatter goes into the covariance with the priors', at least 1 mm² (the
// scale of a lumpy skin's departure, which made the arc flat).
Result<SphereFit> finishFlatArc(const std::vector<Eigen::Vector3d>& pts, const std::vector<size_t>& idx,
                                const Hypothesis& h, double arcRangeMm, const SphereFitParams& p) {
  if (!curvesLikeFruit(pts, idx, p)) return Status(Error::kOutOfRange, "the one line's arc is flat: no fruit");
  std::vector<bool> use(pts.size(), false);
  for (size_t i : idx) use[i] = true;
  const double bandMm = std::max(p.outlierMm, 2.0 * p.ransacBandMm);
  GaussNewton gn =
      refine(pts, use, h.c, std::clamp(h.r, p.minRadiusMm, p.maxRadiusMm), bandMm, p, false, kFlatArcStepMm);
  // Out of the fruit's sizes even with the radius prior's pull (the arc's flat bend drags
  // the radius on): the radius is held at the prior's, which the arc cannot tell, and the
  // centre fitted to it.
  if ((!gn.ok || !(gn.radius >= p.minRadiusMm && gn.radius <= p.maxRadiusMm)) && p.priorRadiusMm > 0.0) {
    // From the hypothesis' sphere moved about the arc's middle to that radius, so that the
    // arc lies on it.
    const Eigen::Vector3d& mid = pts[idx[idx.size() / 2]];
    const Eigen::Vector3d c1 = mid + p.priorRadiusMm * (h.c - mid).normalized();
    gn = refine(pts, use, c1, p.priorRadiusMm, bandMm, p, true, kFlatArcStepMm);
  }
  if (!gn.ok || !(gn.radius >= p.minRadiusMm && gn.radius <= p.maxRadiusMm) || gn.c.norm() < arcRangeMm)
    return Status(Error::kOutOfRange, "no fruit-sized sphere through the one line's flat arc");
  Result<SphereFit> fit = oneLineSphere(pts, idx, gn.c, gn.radius, p);
  if (!fit) return fit;
  SphereFit& out = *fit;
  const double inSq = out.rmsMm * out.rmsMm * static_cast<double>(out.inliers);
  const double variance = std::max(1.0, inSq / std::max(1.0, static_cast<double>(out.inliers) - 4.0));
  out.covariance = gn.jtj.inverse() * variance * std::max(1.0, p.pointsPerIndependent);
  if (!out.covariance.allFinite()) return Status(Error::kBadInput, "the one line's flat arc fit is degenerate");
  out.centerSigmaMm = std::sqrt(std::max(0.0, out.covariance.topLeftCorner<3, 3>().trace()));
  out.radiusSigmaMm = std::sqrt(std::max(0.0, out.covariance(3, 3)));
  return fit;
}

// One line: the points fix a circle in the laser plane and nothing else; every sphere
// through that circle fits them equally. The priors (radius, rough position) choose the
// centre's offset δ from the plane: c = c0 + δ·n, R = sqrt(ρ² + δ²), δ at the minimum of
//   (R(δ) − R0)²/σR² + |c(δ) − rough|²/σc²,
// its variance from that function's curvature. (Gauss–Newton on the sphere itself would
// wander along the valley of equally good spheres, driven by the noise.)
Result<SphereFit> finishOneLine(const std::vector<Eigen::Vector3d>& pts, const Pieces& pieces, const Hypothesis& h,
                                const SphereFitParams& p) {
  const std::vector<size_t> idx = oneLinePoints(pts, pieces, h, p);
  if (idx.size() < p.minPoints) return Status(Error::kBadInput, "too few points on the one line");
  // Plane and in-plane frame.
  Eigen::Vector3d mean;
  Eigen::Vector3d normal;
  Eigen::Vector3d u;
  Eigen::Vector3d v;
  if (!linePlane(pts, idx, p.linePlaneNormal, &mean, &normal, &u, &v))
    return Status(Error::kBadInput, "the one line's points do not fix its plane");
  // Geometric circle fit (Huber Gauss–Newton on |q − m| − ρ), from the hypothesis' circle.
  Eigen::Vector3d m3 = h.c - normal.dot(h.c - mean) * normal;
  Eigen::Vector3d x(u.dot(m3 - mean), v.dot(m3 - mean), std::sqrt(std::max(1.0, h.r * h.r - std::pow(normal.dot(h.c - mean), 2))));
  Eigen::Matrix3d jtj = Eigen::Matrix3d::Identity();
  double sumSq = 0.0;
  size_t used = 0;
  for (int it = 0; it < p.iterations; ++it) {
    jtj.setZero();
    Eigen::Vector3d jtr = Eigen::Vector3d::Zero();
    sumSq = 0.0;
    used = 0;
    for (size_t i : idx) {
      const Eigen::Vector2d q(u.dot(pts[i] - mean), v.dot(pts[i] - mean));
      const Eigen::Vector2d d = q - x.head<2>();
      const double dist = d.norm();
      if (dist < 1e-9) continue;
      const double r = dist - x(2);
      if (std::abs(r) > p.outlierMm) continue;
      const double w = std::abs(r) <= p.huberMm ? 1.0 : p.huberMm / std::abs(r);
      const Eigen::Vector3d j(-d.x() / dist, -d.y() / dist, -1.0);
      jtj += w * j * j.transpose();
      jtr += w * j * r;
      sumSq += r * r;
      ++used;
    }
    if (used < p.minPoints) return Status(Error::kBadInput, "circle fit lost its points");
    const Eigen::Vector3d step = jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) return Status(Error::kBadInput, "circle fit diverged");
    x += step;
    if (step.norm() < 1e-7) break;
  }
  const Eigen::Vector3d c0 = mean + x(0) * u + x(1) * v;
  const double rho = std::abs(x(2));
  const double sr = p.priorRadiusSigmaMm;
  const double sc = p.priorCenterSigmaMm > 0.0 ? p.priorCenterSigmaMm : 1e6;
  auto cost = [&](double delta) {
    const double r = std::sqrt(rho * rho + delta * delta);
    const Eigen::Vector3d c = c0 + delta * normal;
    return (r - p.priorRadiusMm) * (r - p.priorRadiusMm) / (sr * sr) + (c - p.priorCenterMm).squaredNorm() / (sc * sc);
  };
  // The other lines' points the camera saw choose the side and the offset too: the sphere
  // cannot hide them (−2·log of Scorer::freeSpaceFactor). Not in the curvature below: it is
  // a step, not a measurement.
  auto hiddenCost = [&](double delta) {
    const double r = std::sqrt(rho * rho + delta * delta);
    if (!(p.freeSpacePoints > 0.0)) return 0.0;
    return 2.0 * hiddenPoints(pts, c0 + delta * normal, r, p) / p.freeSpacePoints;
  };
  // The centre lies behind the visible arc: farther from the camera than its points.
  const double arcRange = mean.norm();
  double bestDelta = 0.0;
  double bestCost = 1e300;
  for (double delta = -p.maxRadiusMm; delta <= p.maxRadiusMm; delta += 0.25) {
    const Eigen::Vector3d c = c0 + delta * normal;
    const double r = std::sqrt(rho * rho + delta * delta);
    if (c.norm() < arcRange || r < p.minRadiusMm || r > p.maxRadiusMm) continue;
    const double f = cost(delta) + hiddenCost(delta);
    if (f < bestCost) {
      bestCost = f;
      bestDelta = delta;
    }
  }
  if (!(bestCost < 1e300))
    return rho > p.maxRadiusMm ? finishFlatArc(pts, idx, h, arcRange, p)
                               : Status(Error::kOutOfRange, "no fruit-sized sphere through the one line");
  // Curvature: f is −2·log posterior, so var(δ) = 2 / f''.
  const double hStep = 0.5;
  const double f2 = (cost(bestDelta + hStep) - 2.0 * cost(bestDelta) + cost(bestDelta - hStep)) / (hStep * hStep);
  const double varDelta = f2 > 1e-9 ? 2.0 / f2 : p.maxRadiusMm * p.maxRadiusMm;
  Result<SphereFit> fit =
      oneLineSphere(pts, idx, c0 + bestDelta * normal, std::sqrt(rho * rho + bestDelta * bestDelta), p);
  if (!fit) return fit;
  SphereFit& out = *fit;
  // Covariance of (c, R): the circle's (in-plane centre and ρ) and δ's, through
  // c = c0 + δ·n, R = sqrt(ρ² + δ²).
  const double variance = sumSq / std::max(1.0, static_cast<double>(used) - 3.0);
  const Eigen::Matrix3d covCircle = jtj.inverse() * variance * std::max(1.0, p.pointsPerIndependent);
  Eigen::Matrix4d covIn = Eigen::Matrix4d::Zero();  // (x0, y0, ρ, δ)
  covIn.topLeftCorner<3, 3>() = covCircle;
  covIn(3, 3) = varDelta;
  Eigen::Matrix4d j = Eigen::Matrix4d::Zero();
  j.block<3, 1>(0, 0) = u;
  j.block<3, 1>(0, 1) = v;
  j.block<3, 1>(0, 3) = normal;
  j(3, 2) = rho / out.radiusMm;
  j(3, 3) = bestDelta / out.radiusMm;
  out.covariance = j * covIn * j.transpose();
  out.centerSigmaMm = std::sqrt(std::max(0.0, out.covariance.topLeftCorner<3, 3>().trace()));
  out.radiusSigmaMm = std::sqrt(std::max(0.0, out.covariance(3, 3)));
  return fit;
}

// Points within `bandMm` of the hypothesis' sphere.
std::vector<bool> explainedPoints(const std::vector<Eigen::Vector3d>& pts, const Hypothesis& h, double bandMm) {
  std::vector<bool> out(pts.size(), false);
  for (size_t i = 0; i < pts.size(); ++i) out[i] = std::abs((pts[i] - h.c).norm() - h.r) <= bandMm;
  return out;
}

// The chosen fit with its score, the other objects whose centres are more than
// kRivalSeparationMm away (strongest first; one per place: an object within
// kRivalSeparationMm of a stronger one is that one), and the strongest of them, its rival.
Result<SphereFit> withRival(Result<SphereFit> chosen, double score,
                            std::vector<std::pair<double, Eigen::Vector3d>> objects) {
  if (!chosen) return chosen;
  chosen->score = score;
  std::stable_sort(objects.begin(), objects.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  for (const auto& object : objects) {
    const double sc = object.first;
    const Eigen::Vector3d& centre = object.second;
    if (!(sc > 0.0) || (centre - chosen->centerMm).norm() <= kRivalSeparationMm) continue;
    if (std::any_of(chosen->others.begin(), chosen->others.end(),
                    [&](const SphereFit::Other& o) { return (o.centerMm - centre).norm() <= kRivalSeparationMm; }))
      continue;
    chosen->others.push_back({centre, sc});
  }
  if (!chosen->others.empty()) {
    chosen->rivalScore = chosen->others.front().score;
    chosen->rivalCenterMm = chosen->others.front().centerMm;
  }
  return chosen;
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
  // Lines together first; when that cannot make a sphere on two lines or more, what one
  // line and the priors can say.
  Result<SphereFit> multi = Status(Error::kBadInput, "no sphere across the lines");
  double multiScore = 0.0;
  std::vector<std::pair<double, Eigen::Vector3d>> objects;  // every multi-line object: score, centre
  if (lineIds == nullptr) {
    const Hypothesis h = search(pts, pieces, scorer, mean, p, false);
    if (h.score > 0.0) multi = finish(pts, lineIds, pieces, h, p);
    return multi;
  }
  // The objects in the gate, one after the other by their own support (without the rough
  // position): each takes the pieces it explains. Only then does the rough position choose
  // among them. Ranking hypotheses by nearness from the start lets a sphere bent through
  // two arcs of a neighbour slide towards the rough position and win.
  {
    SphereFitParams free = p;
    free.priorCenterSigmaMm = 0.0;
    Pieces remaining = pieces;
    for (int object = 0; object < 4; ++object) {
      const Scorer objectScorer(pts, remaining, free);
      const Hypothesis h = search(pts, remaining, objectScorer, mean, free, false);
      if (!(h.score > 0.0)) break;
      Result<SphereFit> f = finish(pts, lineIds, remaining, h, p);
      // A hypothesis whose refinement fails (its sphere leaves the fruit's sizes, or loses
      // its points: often a sphere bent through a leaf and a piece of skin) is not an
      // object, but it must not end the search: the target may be the next one (a heavily
      // occluded target shows less skin than the leaves and neighbours round it). The
      // pieces it scored on are set aside: those it explains by at least half the
      // coherent share (a quarter of a full piece's weight in its score).
      const std::vector<bool> taken = f ? f->inlier : explainedPoints(pts, h, p.ransacBandMm);
      const double setAsideShare = f ? 0.5 : 0.5 * p.coherentShare;
      if (f && f->linesUsed >= 2) {
        const double sc = std::max(scorer.score(h.c, h.r), scorer.score(f->centerMm, f->radiusMm));
        objects.emplace_back(sc, f->centerMm);
        if (sc > multiScore) {
          multiScore = sc;
          multi = std::move(f);
        }
      }
      // Remove the pieces this object explains; stop when too little is left.
      Pieces rest;
      for (size_t g = 0; g < remaining.members.size(); ++g) {
        size_t count = 0;
        for (size_t i : remaining.members[g]) count += taken[i] ? 1U : 0U;
        if (static_cast<double>(count) >= setAsideShare * static_cast<double>(remaining.members[g].size())) continue;
        rest.members.push_back(remaining.members[g]);
        rest.line.push_back(remaining.line[g]);
      }
      std::vector<std::vector<size_t>> byLine;
      std::vector<int> lineKeys;
      for (size_t g = 0; g < rest.members.size(); ++g) {
        auto it = std::find(lineKeys.begin(), lineKeys.end(), rest.line[g]);
        if (it == lineKeys.end()) {
          lineKeys.push_back(rest.line[g]);
          byLine.emplace_back();
          it = lineKeys.end() - 1;
        }
        auto& dst = byLine[static_cast<size_t>(it - lineKeys.begin())];
        dst.insert(dst.end(), rest.members[g].begin(), rest.members[g].end());
      }
      rest.byLine = std::move(byLine);
      if (rest.byLine.size() < 2 || rest.members.size() == remaining.members.size()) break;
      remaining = std::move(rest);
    }
  }
  const Hypothesis one = search(pts, pieces, scorer, mean, p, true);
  Result<SphereFit> single = Status(Error::kBadInput, "no sphere through one line");
  if (one.score > 0.0) single = finishOneLine(pts, pieces, one, p);
  // Two lines or more that one plausible sphere explains win: what one line says rests on
  // the priors. Plausible: near the rough position (not a neighbour), two lines with a
  // real piece each, a well-determined centre (not two objects' pieces bent into one).
  if (multi) {
    int strongLines = 0;
    if (lineIds != nullptr) {
      std::vector<int> ids;
      for (size_t i = 0; i < n; ++i)
        if (multi->inlier[i]) ids.push_back((*lineIds)[i]);
      std::sort(ids.begin(), ids.end());
      for (size_t i = 0; i < ids.size();) {
        size_t j = i;
        while (j < ids.size() && ids[j] == ids[i]) ++j;
        strongLines += (j - i) >= 8 ? 1 : 0;
        i = j;
      }
    }
    if (scorer.centreFactor(multi->centerMm) >= 0.1 && strongLines >= 2 &&
        scorer.freeSpaceFactor(multi->centerMm, multi->radiusMm) >= 0.1 &&
        multi->centerSigmaMm <= p.maxPlausibleCenterSigmaMm)
      return withRival(std::move(multi), multiScore, objects);
  }
  // Otherwise both compete on the common score (support × priors), each by the better of its
  // hypothesis and its refinement (refining towards all the points can cost a sphere a
  // little of its coherent support): a sphere across two objects' lines far from the
  // rough position must not beat one line of the target near it.
  const double ss = single ? std::max(one.score, scorer.score(single->centerMm, single->radiusMm)) : 0.0;
  if (multi && single) {
    if (multiScore >= ss) return withRival(std::move(multi), multiScore, objects);
    objects.emplace_back(multiScore, multi->centerMm);
    return withRival(std::move(single), ss, objects);
  }
  if (multi) return withRival(std::move(multi), multiScore, objects);
  if (single) return withRival(std::move(single), ss, objects);
  return multi;
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
