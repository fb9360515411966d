#include "sim/raycast.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace alacs::sim {

namespace {

void boundsOf(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, SceneGeometry::Object* o) {
  o->aabbMin = lo;
  o->aabbMax = hi;
  o->boundCenter = 0.5 * (lo + hi);
  o->boundRadius = 0.5 * (hi - lo).norm();
}

// Does the ray pass within the object's bounding sphere inside (tMin, tMax)?
bool mayHit(const SceneGeometry::Object& o, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin,
            double tMax) {
  const Eigen::Vector3d oc = o.boundCenter - origin;
  const double tc = oc.dot(dir);
  const double d2 = oc.squaredNorm() - tc * tc;
  if (d2 > o.boundRadius * o.boundRadius) return false;
  return tc + o.boundRadius > tMin && tc - o.boundRadius < tMax;
}

}  // namespace

SceneGeometry::SceneGeometry(const SimScene& scene) : scene_(scene) {
  for (size_t i = 0; i < scene.apples.size(); ++i) {
    const auto& a = scene.apples[i];
    Object o{SurfaceKind::kApple, static_cast<int>(i), {}, 0, {}, {}};
    const Eigen::Vector3d r = Eigen::Vector3d::Constant(appleBoundMm(a));
    boundsOf(a.centerMm - r, a.centerMm + r, &o);
    objects_.push_back(o);
    appleToLocal_.push_back(appleFrame(a).transpose());
    appleInvAxes_.emplace_back(1.0 / a.radiusMm, 1.0 / a.radiusMm, 1.0 / (a.radiusMm * a.aspect));
    appleShapes_.emplace_back(a);
  }
  for (size_t i = 0; i < scene.leaves.size(); ++i) {
    const auto& l = scene.leaves[i];
    const Eigen::Vector3d side = l.normal.cross(l.axis);
    leafSide_.push_back(side);
    const Eigen::Vector3d ext = 0.5 * l.lengthMm * l.axis.cwiseAbs() + 0.5 * l.widthMm * side.cwiseAbs();
    Object o{SurfaceKind::kLeaf, static_cast<int>(i), {}, 0, {}, {}};
    boundsOf(l.centerMm - ext, l.centerMm + ext, &o);
    objects_.push_back(o);
  }
  for (size_t i = 0; i < scene.branches.size(); ++i) {
    const auto& b = scene.branches[i];
    const Eigen::Vector3d r = Eigen::Vector3d::Constant(b.radiusMm);
    Object o{SurfaceKind::kBranch, static_cast<int>(i), {}, 0, {}, {}};
    boundsOf(b.aMm.cwiseMin(b.bMm) - r, b.aMm.cwiseMax(b.bMm) + r, &o);
    objects_.push_back(o);
  }
  if (scene.board) {
    const auto& b = *scene.board;
    const double w = b.squaresX * b.squareMm;
    const double h = b.squaresY * b.squareMm;
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300);
    Eigen::Vector3d hi = Eigen::Vector3d::Constant(-1e300);
    for (int c = 0; c < 4; ++c) {
      const Eigen::Vector3d local((c & 1) ? w + b.marginMm : -b.marginMm, (c & 2) ? h + b.marginMm : -b.marginMm, 0.0);
      const Eigen::Vector3d p = b.rotation * local + b.originMm;
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    Object o{SurfaceKind::kBoard, 0, {}, 0, {}, {}};
    boundsOf(lo, hi, &o);
    objects_.push_back(o);
  }
}

bool SceneGeometry::intersectObject(int object, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin,
                                    double tMax, Hit* hit) const {
  const Object& o = objects_[static_cast<size_t>(object)];
  if (!mayHit(o, origin, dir, tMin, tMax)) return false;
  switch (o.kind) {
    case SurfaceKind::kApple: {
      // In the apple's scaled frame the ellipsoid is the unit sphere; t is unchanged.
      const auto i = static_cast<size_t>(o.index);
      const auto& a = scene_.apples[i];
      const Eigen::Vector3d& inv = appleInvAxes_[i];
      const Eigen::Vector3d ol = (appleToLocal_[i] * (origin - a.centerMm)).cwiseProduct(inv);
      const Eigen::Vector3d dl = (appleToLocal_[i] * dir).cwiseProduct(inv);
      const AppleShape& shape = appleShapes_[i];
      if (shape.lumpy()) {
        double t = 0.0;
        if (!shape.intersectScaled(ol, dl, tMin, tMax, &t)) return false;
        hit->t = t;
        hit->normal = shape.normal(origin + t * dir);
        if (hit->normal.dot(dir) > 0.0) hit->normal = -hit->normal;
        break;
      }
      const double qa = dl.squaredNorm();
      const double b = ol.dot(dl);
      const double c = ol.squaredNorm() - 1.0;
      const double disc = b * b - qa * c;
      if (disc < 0.0) return false;
      const double s = std::sqrt(disc);
      double t = (-b - s) / qa;
      if (t <= tMin) t = (-b + s) / qa;
      if (t <= tMin || t >= tMax) return false;
      hit->t = t;
      const Eigen::Vector3d u = (ol + t * dl).cwiseProduct(inv);  // gradient in the local frame
      hit->normal = (appleToLocal_[i].transpose() * u).normalized();
      if (hit->normal.dot(dir) > 0.0) hit->normal = -hit->normal;
      break;
    }
    case SurfaceKind::kLeaf: {
      const auto& l = scene_.leaves[static_cast<size_t>(o.index)];
      const double denom = dir.dot(l.normal);
      if (std::abs(denom) < 1e-12) return false;
      const double t = (l.centerMm - origin).dot(l.normal) / denom;
      if (t <= tMin || t >= tMax) return false;
      const Eigen::Vector3d q = origin + t * dir - l.centerMm;
      const double u = q.dot(l.axis) / (0.5 * l.lengthMm);
      if (std::abs(u) > 1.0) return false;
      const double w = std::abs(q.dot(leafSide_[static_cast<size_t>(o.index)]));
      if (w > 0.5 * l.widthMm * (1.0 - u * u)) return false;
      hit->t = t;
      hit->normal = denom > 0.0 ? Eigen::Vector3d(-l.normal) : l.normal;
      break;
    }
    case SurfaceKind::kBranch: {
      // Capsule intersection (after I. Quilez), for a unit direction.
      const auto& br = scene_.branches[static_cast<size_t>(o.index)];
      const Eigen::Vector3d ba = br.bMm - br.aMm;
      const Eigen::Vector3d oa = origin - br.aMm;
      const double baba = ba.dot(ba);
      const double bard = ba.dot(dir);
      const double baoa = ba.dot(oa);
      const double rdoa = dir.dot(oa);
      const double oaoa = oa.dot(oa);
      const double r2 = br.radiusMm * br.radiusMm;
      const double qa = baba - bard * bard;
      const double qb = baba * rdoa - baoa * bard;
      const double qc = baba * oaoa - baoa * baoa - r2 * baba;
      const double h = qb * qb - qa * qc;
      if (h < 0.0) return false;
      double t = qa > 1e-12 ? (-qb - std::sqrt(h)) / qa : -1.0;
      const double y = baoa + t * bard;
      if (!(qa > 1e-12 && y > 0.0 && y < baba)) {
        const Eigen::Vector3d oc = y <= 0.0 ? oa : Eigen::Vector3d(origin - br.bMm);
        const double b2 = dir.dot(oc);
        const double c2 = oc.dot(oc) - r2;
        const double h2 = b2 * b2 - c2;
        if (h2 <= 0.0) return false;
        t = -b2 - std::sqrt(h2);
      }
      if (t <= tMin || t >= tMax) return false;
      const Eigen::Vector3d p = origin + t * dir;
      const double k = std::clamp((p - br.aMm).dot(ba) / baba, 0.0, 1.0);
      hit->t = t;
      hit->normal = (p - br.aMm - k * ba).normalized();
      break;
    }
    case SurfaceKind::kBoard: {
      const auto& b = *scene_.board;
      const Eigen::Vector3d n = b.rotation.col(2);
      const double denom = dir.dot(n);
      if (std::abs(denom) < 1e-12) return false;
      const double t = (b.originMm - origin).dot(n) / denom;
      if (t <= tMin || t >= tMax) return false;
      const Eigen::Vector3d local = b.rotation.transpose() * (origin + t * dir - b.originMm);
      if (local.x() < -b.marginMm || local.x() > b.squaresX * b.squareMm + b.marginMm) return false;
      if (local.y() < -b.marginMm || local.y() > b.squaresY * b.squareMm + b.marginMm) return false;
      hit->t = t;
      hit->normal = denom > 0.0 ? Eigen::Vector3d(-n) : n;
      break;
    }
  }
  hit->kind = o.kind;
  hit->index = o.index;
  return true;
}

bool SceneGeometry::intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin, double tMax,
                              Hit* hit, const std::vector<int>* candidates) const {
  Hit best;
  best.t = tMax;
  bool any = false;
  auto test = [&](int i) {
    Hit h;
    if (intersectObject(i, origin, dir, tMin, best.t, &h)) {
      best = h;
      any = true;
    }
  };
  if (candidates != nullptr) {
    for (int i : *candidates) test(i);
  } else {
    for (int i = 0; i < static_cast<int>(objects_.size()); ++i) test(i);
  }
  if (any) *hit = best;
  return any;
}

bool SceneGeometry::blocked(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin, double tMax,
                            SurfaceKind skipKind, int skipIndex) const {
  for (int i = 0; i < static_cast<int>(objects_.size()); ++i) {
    const Object& o = objects_[static_cast<size_t>(i)];
    if (o.kind == skipKind && o.index == skipIndex) continue;
    if (!mayHit(o, origin, dir, tMin, tMax)) continue;
    Hit h;
    if (intersectObject(i, origin, dir, tMin, tMax, &h)) return true;
  }
  return false;
}

}  // namespace alacs::sim
