#include "sim/truth.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <functional>

#include "sim/raycast.h"

namespace alacs::sim {

namespace {

// Row crossings of a curve p(t), t in [t0, t1], restricted to the samples where
// `keep(p)` holds. Each crossing is refined by bisection on the projected row, so the
// column is exact to the projection's precision, not to the sampling.
template <typename Curve, typename Keep>
void rowCrossings(const geometry::CameraIntrinsics& cam, Curve curve, Keep keep, double t0, double t1, int samples,
                  bool closed, std::vector<std::pair<int, double>>* out) {
  std::vector<double> ts(static_cast<size_t>(samples));
  std::vector<double> vs(static_cast<size_t>(samples));
  std::vector<char> ok(static_cast<size_t>(samples));
  const int n = closed ? samples : samples - 1;
  for (int i = 0; i < samples; ++i) {
    const double t = t0 + (t1 - t0) * i / n;
    const Eigen::Vector3d p = curve(t);
    ts[static_cast<size_t>(i)] = t;
    ok[static_cast<size_t>(i)] = p.z() > 1.0 && keep(p);
    vs[static_cast<size_t>(i)] = ok[static_cast<size_t>(i)] ? projectPx(cam, p).y() : 0.0;
  }
  const int pairs = closed ? samples : samples - 1;
  for (int i = 0; i < pairs; ++i) {
    const auto a = static_cast<size_t>(i);
    const auto b = static_cast<size_t>((i + 1) % samples);
    if (!ok[a] || !ok[b]) continue;
    const double ta = ts[a];
    const double tb = (closed && b == 0) ? t1 : ts[b];
    const double va = vs[a];
    const double vb = vs[b];
    const double lo = std::min(va, vb);
    const double hi = std::max(va, vb);
    for (int row = static_cast<int>(std::ceil(lo)); row < hi; ++row) {
      if (row < 0 || row >= cam.heightPx) continue;
      // Bisection keeps the bracket [x, y] with v(x) - row and v(y) - row of opposite signs.
      double x = ta;
      double y = tb;
      double fx = va - row;
      for (int it = 0; it < 200 && std::abs(y - x) > 1e-13 * (1.0 + std::abs(x)); ++it) {
        const double m = 0.5 * (x + y);
        const double fm = projectPx(cam, curve(m)).y() - row;
        if ((fm < 0.0) == (fx < 0.0)) {
          x = m;
          fx = fm;
        } else {
          y = m;
        }
      }
      out->emplace_back(row, 0.5 * (x + y));
    }
  }
}

uint8_t laserFlags(const SimScene& scene, const SceneGeometry& geo, const Eigen::Vector3d& p,
                   const Eigen::Vector3d& normal, double slideMm, SurfaceKind kind, int index) {
  uint8_t flags = 0;
  const Eigen::Vector3d toCam = -p;
  const double camDist = toCam.norm();
  if (geo.blocked(p, toCam / camDist, 1e-6, camDist, kind, index)) flags |= kTruthHidden;
  const Eigen::Vector3d o = scene.laser.originAt(scene.truth.laser, slideMm);
  const Eigen::Vector3d toLaser = o - p;
  const double laserDist = toLaser.norm();
  if (normal.dot(toLaser) <= 0.0) flags |= kTruthUnlit;
  // Fan: the angle from the beam's central direction, within the plane.
  const Eigen::Vector3d n = scene.truth.laser.planeNormal;
  const Eigen::Vector3d beam = (Eigen::Vector3d(0, 0, 1) - n.z() * n).normalized();
  if ((-toLaser / laserDist).dot(beam) < std::cos(0.5 * scene.laser.fanDeg * M_PI / 180.0)) flags |= kTruthUnlit;
  if (geo.blocked(p, toLaser / laserDist, 1e-6, laserDist, kind, index)) flags |= kTruthShadowed;
  return flags;
}

// The laser plane's cut of a lumpy apple along u0 + r·w (scaled frame, r in [0, rMax]):
// the crossing of |u| = radialFactor(û), by bisection. NaN where u0 is not inside the cut
// (a plane grazing the fruit's edge), which the row sampling leaves out.
Eigen::Vector3d lumpyCut(const AppleShape& shape, const Eigen::Vector3d& u0, const Eigen::Vector3d& w, double rMax) {
  const auto g = [&](double r) {
    const Eigen::Vector3d u = u0 + r * w;
    const double len = u.norm();
    return len < 1e-12 ? -1.0 : len - shape.radialFactor(u / len);
  };
  if (!(g(0.0) < 0.0)) return Eigen::Vector3d::Constant(std::nan(""));
  double a = 0.0;
  double b = rMax;
  for (int it = 0; it < 60; ++it) {
    const double mid = 0.5 * (a + b);
    (g(mid) < 0.0 ? a : b) = mid;
  }
  return shape.fromScaled(u0 + 0.5 * (a + b) * w);
}

}  // namespace

std::vector<RowTruth> laserLineTruthAll(const SimScene& scene, const SimApple& apple, double slideMm) {
  std::vector<RowTruth> rows;
  const auto& las = scene.truth.laser;
  const Eigen::Vector3d n = las.planeNormal;
  const double d = las.planeOffsetAt(slideMm);
  // X = c + R·S·u with u on the unit sphere: the plane n·X = d becomes m·u = e, m = S·Rᵀ·n,
  // which cuts the unit sphere in a circle; mapped back, the laser line's ellipse.
  const Eigen::Matrix3d frame = appleFrame(apple);
  const Eigen::Vector3d axes(apple.radiusMm, apple.radiusMm, apple.radiusMm * apple.aspect);
  const Eigen::Vector3d m = (frame.transpose() * n).cwiseProduct(axes);
  const double e = (d - n.dot(apple.centerMm)) / m.norm();
  const AppleShape shape(apple);
  const double outer = 1.0 + shape.amplitude();
  if (std::abs(e) >= outer) return rows;
  const Eigen::Vector3d mu = m.normalized();
  const Eigen::Vector3d u0 = e * mu;
  const Eigen::Vector3d e1 = mu.unitOrthogonal();
  const Eigen::Vector3d e2 = mu.cross(e1);
  auto circle = [&](double phi) -> Eigen::Vector3d {
    const Eigen::Vector3d w = std::cos(phi) * e1 + std::sin(phi) * e2;
    if (!shape.lumpy()) return apple.centerMm + frame * (u0 + std::sqrt(1.0 - e * e) * w).cwiseProduct(axes);
    // A lumpy apple: along each ray from u0 in the plane, where |u| = radialFactor(û).
    return lumpyCut(shape, u0, w, std::sqrt(outer * outer - e * e));
  };
  auto normalAt = [&](const Eigen::Vector3d& p) { return shape.lumpy() ? shape.normal(p) : appleNormal(apple, p); };
  auto facesCamera = [&](const Eigen::Vector3d& p) { return normalAt(p).dot(-p) > 0.0; };
  std::vector<std::pair<int, double>> crossings;
  rowCrossings(scene.truth.camera, circle, facesCamera, 0.0, 2.0 * M_PI, 4096, true, &crossings);
  const SceneGeometry geo(scene);
  int appleIndex = 0;
  for (size_t i = 0; i < scene.apples.size(); ++i)
    if (&scene.apples[i] == &apple || scene.apples[i].id == apple.id) appleIndex = static_cast<int>(i);
  rows.reserve(crossings.size());
  for (const auto& [row, phi] : crossings) {
    RowTruth r;
    r.row = row;
    r.pointMm = circle(phi);
    r.column = projectPx(scene.truth.camera, r.pointMm).x();
    r.appleId = apple.id;
    const Eigen::Vector3d normal = normalAt(r.pointMm);
    r.flags = laserFlags(scene, geo, r.pointMm, normal, slideMm, SurfaceKind::kApple, appleIndex);
    if (r.column < -0.5 || r.column > scene.truth.camera.widthPx - 0.5) r.flags |= kTruthOutside;
    rows.push_back(r);
  }
  std::stable_sort(rows.begin(), rows.end(), [](const RowTruth& a, const RowTruth& b) { return a.row < b.row; });
  return rows;
}

std::vector<RowTruth> laserLineTruth(const SimScene& scene, const SimApple& apple, double slideMm) {
  std::vector<RowTruth> all = laserLineTruthAll(scene, apple, slideMm);
  std::vector<RowTruth> out;
  out.reserve(all.size());
  for (const auto& r : all)
    if (r.visibleLit()) out.push_back(r);
  return out;
}

std::vector<RowTruth> boardLineTruth(const SimScene& scene, double slideMm) {
  std::vector<RowTruth> rows;
  if (!scene.board) return rows;
  const auto& b = *scene.board;
  const auto& las = scene.truth.laser;
  const Eigen::Vector3d np = las.planeNormal;
  const double dp = las.planeOffsetAt(slideMm);
  const Eigen::Vector3d nb = b.rotation.col(2);
  const double db = nb.dot(b.originMm);
  const Eigen::Vector3d dir = np.cross(nb);
  if (dir.norm() < 1e-9) return rows;
  // A point on both planes: the one nearest the origin (solve in the span of the normals).
  const Eigen::Vector3d u = dir.normalized();
  Eigen::Matrix<double, 3, 3> m;
  m.row(0) = np.transpose();
  m.row(1) = nb.transpose();
  m.row(2) = u.transpose();
  const Eigen::Vector3d p0 = m.colPivHouseholderQr().solve(Eigen::Vector3d(dp, db, 0.0));
  // The parameter range that stays on the board.
  double tLo = -1e9;
  double tHi = 1e9;
  const Eigen::Vector3d l0 = b.rotation.transpose() * (p0 - b.originMm);
  const Eigen::Vector3d lu = b.rotation.transpose() * u;
  const double lim[2][2] = {{-b.marginMm, b.squaresX * b.squareMm + b.marginMm},
                            {-b.marginMm, b.squaresY * b.squareMm + b.marginMm}};
  for (int k = 0; k < 2; ++k) {
    if (std::abs(lu(k)) < 1e-12) {
      if (l0(k) < lim[k][0] || l0(k) > lim[k][1]) return rows;
      continue;
    }
    double a = (lim[k][0] - l0(k)) / lu(k);
    double c = (lim[k][1] - l0(k)) / lu(k);
    if (a > c) std::swap(a, c);
    tLo = std::max(tLo, a);
    tHi = std::min(tHi, c);
  }
  if (!(tHi > tLo)) return rows;
  auto line = [&](double t) -> Eigen::Vector3d { return p0 + t * u; };
  auto anywhere = [](const Eigen::Vector3d&) { return true; };
  std::vector<std::pair<int, double>> crossings;
  rowCrossings(scene.truth.camera, line, anywhere, tLo, tHi, 2048, false, &crossings);
  const SceneGeometry geo(scene);
  for (const auto& [row, t] : crossings) {
    RowTruth r;
    r.row = row;
    r.pointMm = line(t);
    r.column = projectPx(scene.truth.camera, r.pointMm).x();
    r.appleId = -1;
    Eigen::Vector3d normal = -nb;  // the board's front faces the camera
    if (normal.dot(-r.pointMm) < 0.0) normal = nb;
    r.flags = laserFlags(scene, geo, r.pointMm, normal, slideMm, SurfaceKind::kBoard, 0);
    if (r.column < -0.5 || r.column > scene.truth.camera.widthPx - 0.5) r.flags |= kTruthOutside;
    rows.push_back(r);
  }
  std::stable_sort(rows.begin(), rows.end(), [](const RowTruth& a, const RowTruth& c) { return a.row < c.row; });
  return rows;
}

std::vector<CornerTruth> boardCorners(const SimScene& scene) {
  std::vector<CornerTruth> out;
  if (!scene.board) return out;
  const auto& b = *scene.board;
  const SceneGeometry geo(scene);
  const auto& cam = scene.truth.camera;
  const Eigen::Vector3d nb = b.rotation.col(2);
  for (int j = 1; j < b.squaresY; ++j) {
    for (int i = 1; i < b.squaresX; ++i) {
      CornerTruth c;
      c.i = i;
      c.j = j;
      c.pointMm = b.rotation * Eigen::Vector3d(i * b.squareMm, j * b.squareMm, 0.0) + b.originMm;
      if (c.pointMm.z() > 1.0) {
        c.pixel = projectPx(cam, c.pointMm);
        const double dist = c.pointMm.norm();
        c.visible = c.pixel.x() >= 0 && c.pixel.x() <= cam.widthPx - 1 && c.pixel.y() >= 0 &&
                    c.pixel.y() <= cam.heightPx - 1 && nb.dot(c.pointMm) > 0.0 &&
                    !geo.blocked(Eigen::Vector3d::Zero(), c.pointMm / dist, 1e-6, dist - 1e-6, SurfaceKind::kBoard, 0);
      }
      out.push_back(c);
    }
  }
  return out;
}

double occlusionShare(const SimScene& scene, const SimApple& apple, int samples) {
  const SceneGeometry geo(scene);
  int appleObject = -1;
  for (size_t i = 0; i < geo.objects().size(); ++i) {
    const auto& o = geo.objects()[i];
    if (o.kind == SurfaceKind::kApple && scene.apples[static_cast<size_t>(o.index)].id == apple.id)
      appleObject = static_cast<int>(i);
  }
  if (appleObject < 0) return 0.0;
  // Rays through a square grid over the apple's angular disc; those that hit the apple
  // when it is alone count, and of these, those where something else is nearer.
  const Eigen::Vector3d c = apple.centerMm;
  const double dist = c.norm();
  const Eigen::Vector3d w = c / dist;
  const Eigen::Vector3d e1 = w.unitOrthogonal();
  const Eigen::Vector3d e2 = w.cross(e1);
  const double halfAngle = std::asin(std::min(1.0, appleBoundMm(apple) / dist));
  const int side = std::max(4, static_cast<int>(std::sqrt(static_cast<double>(samples))));
  int onApple = 0;
  int hidden = 0;
  for (int a = 0; a < side; ++a) {
    for (int b = 0; b < side; ++b) {
      const double x = std::tan(halfAngle) * (2.0 * (a + 0.5) / side - 1.0);
      const double y = std::tan(halfAngle) * (2.0 * (b + 0.5) / side - 1.0);
      const Eigen::Vector3d dir = (w + x * e1 + y * e2).normalized();
      Hit self;
      if (!geo.intersectObject(appleObject, Eigen::Vector3d::Zero(), dir, 1e-6, 1e12, &self)) continue;
      ++onApple;
      Hit nearest;
      if (geo.intersect(Eigen::Vector3d::Zero(), dir, 1e-6, self.t - 1e-6, &nearest)) ++hidden;
    }
  }
  return onApple > 0 ? static_cast<double>(hidden) / onApple : 0.0;
}

}  // namespace alacs::sim
