#include "geometry/calibration_uncertainty.h"

#include <Eigen/Dense>
#include <cmath>
#include <string>

namespace alacs::geometry {

namespace {

struct GridPixel {
  size_t depthIndex;
  double slideMm;
  PixelPoint pixel;
};

// Wide open: a perturbed calibration must triangulate every grid pixel, not clip it.
constexpr WorkingRange kAnyDepth{1.0, 1e6, 1e-3};

// Independent directions of a covariance: columns whose outer products sum to it. Taken
// from the correlation matrix so that parameters in px and in dimensionless distortion
// do not swamp one another numerically.
template <int N>
std::vector<Eigen::Matrix<double, N, 1>> sigmaDirections(const Eigen::Matrix<double, N, N>& cov) {
  using Vec = Eigen::Matrix<double, N, 1>;
  Vec scale;
  for (int i = 0; i < N; ++i) scale(i) = cov(i, i) > 0.0 ? std::sqrt(cov(i, i)) : 0.0;
  Eigen::Matrix<double, N, N> corr = Eigen::Matrix<double, N, N>::Identity();
  for (int i = 0; i < N; ++i)
    for (int j = 0; j < N; ++j)
      if (scale(i) > 0.0 && scale(j) > 0.0) corr(i, j) = cov(i, j) / (scale(i) * scale(j));
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig(corr);
  std::vector<Vec> out;
  if (eig.info() != Eigen::Success) return out;
  for (int i = 0; i < N; ++i) {
    const double lambda = eig.eigenvalues()(i);
    if (!(lambda > 1e-12)) continue;
    const Vec dir = scale.cwiseProduct(eig.eigenvectors().col(i)) * std::sqrt(lambda);
    if (dir.norm() > 0.0) out.push_back(dir);
  }
  return out;
}

// A standard normal deviate, the same on every platform (std::normal_distribution is not).
class Normal {
 public:
  explicit Normal(uint64_t seed) : state_(seed ^ 0x9E3779B97F4A7C15ULL) {}
  double next() {
    if (spare_) {
      spare_ = false;
      return spareValue_;
    }
    double u = 0.0;
    while (u <= 0.0) u = uniform();
    const double v = uniform();
    const double r = std::sqrt(-2.0 * std::log(u));
    spareValue_ = r * std::sin(2.0 * M_PI * v);
    spare_ = true;
    return r * std::cos(2.0 * M_PI * v);
  }

 private:
  double uniform() {
    // splitmix64
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    z ^= z >> 31;
    return static_cast<double>(z >> 11) * 0x1.0p-53;
  }
  uint64_t state_;
  bool spare_ = false;
  double spareValue_ = 0.0;
};

// The grid pixels triangulated with intrinsics `cam`: board poses solved again, laser
// plane refitted from the same line pixels, starting at `start`.
Result<std::vector<Eigen::Vector3d>> resolveAndTriangulate(const CameraIntrinsics& cam, const LaserGeometry& start,
                                                           const CalibrationObservations& obs,
                                                           const std::vector<GridPixel>& grid,
                                                           const std::vector<PixelPoint>& gridPx,
                                                           const UncertaintyOptions& o) {
  std::vector<TargetPose> poses;
  for (size_t p = 0; p < obs.placementViews.size(); ++p) {
    Result<TargetPose> pose = locateTarget(cam, obs.placementViews[p]);
    if (!pose) return Status(Error::kBadInput, "placement " + std::to_string(p) + ": " + pose.status().reason());
    poses.push_back(*pose);
  }
  std::vector<LaserLineSample> samples;
  samples.reserve(obs.lines.size());
  for (const auto& line : obs.lines) {
    if (line.placement < 0 || static_cast<size_t>(line.placement) >= poses.size())
      return Status(Error::kBadInput, "laser line of an unknown placement");
    const TargetPose& pose = poses[static_cast<size_t>(line.placement)];
    LaserLineSample s;
    s.placement = line.placement;
    s.targetNormal = pose.planeNormal();
    s.targetOffsetMm = pose.planeOffsetMm();
    s.slideMm = line.slideMm;
    s.normalized = undistortPixels(cam, line.pixels);
    samples.push_back(std::move(s));
  }
  LaserFitOptions lo = o.laser;
  lo.focalPx = cam.fxPx;
  Result<LaserGeometry> laser = refineLaser(samples, start, lo);
  if (!laser) return laser.status();
  const std::vector<Eigen::Vector2d> xn = undistortPixels(cam, gridPx);
  std::vector<Eigen::Vector3d> out;
  out.reserve(grid.size());
  for (size_t i = 0; i < grid.size(); ++i) {
    const TriangulatedPoint q = triangulate(*laser, grid[i].slideMm, xn[i], kAnyDepth);
    if (!q.valid) return Status(Error::kBadInput, "a grid pixel no longer meets the refitted laser plane");
    out.push_back(q.pointMm);
  }
  return out;
}

}  // namespace

Result<CalibrationUncertainty> propagateCalibrationUncertainty(const CameraIntrinsics& camera,
                                                               const IntrinsicsCovariance& intrinsicsCovariance,
                                                               const LaserFit& laserFit,
                                                               const CalibrationObservations& obs,
                                                               const UncertaintyOptions& o) {
  const LaserGeometry& laser = laserFit.laser;
  const Eigen::Vector3d& n = laser.planeNormal;
  if (std::abs(n.x()) < 0.1)
    return Status(Error::kBadInput, "uncertainty grid: the laser plane is not a vertical sheet across the image");
  // The grid: points on the estimated laser planes over the stroke, at each depth, across
  // the frame's height; kept where they land inside the frame (as check-calibration does
  // against the truth).
  std::vector<GridPixel> grid;
  for (size_t d = 0; d < o.depthsMm.size(); ++d) {
    const double z = o.depthsMm[d];
    for (int k = 0; k <= o.strokeSteps; ++k) {
      const double slide = o.strokeStartMm + (o.strokeEndMm - o.strokeStartMm) * k / std::max(1, o.strokeSteps);
      for (int j = -6; j <= 6; ++j) {
        const double y = o.heightSpan * z * j / 6.0;
        const double x = (laser.planeOffsetAt(slide) - n.y() * y - n.z() * z) / n.x();
        const PixelPoint px = projectPoint(camera, Eigen::Vector3d(x, y, z));
        if (px.columnPx < 0 || px.rowPx < 0 || px.columnPx > camera.widthPx - 1 || px.rowPx > camera.heightPx - 1)
          continue;
        grid.push_back({d, slide, px});
      }
    }
  }
  std::vector<int> perDepth(o.depthsMm.size(), 0);
  for (const auto& g : grid) ++perDepth[g.depthIndex];
  for (size_t d = 0; d < perDepth.size(); ++d)
    if (perDepth[d] == 0)
      return Status(Error::kBadInput, "uncertainty grid: nothing in the frame at " +
                                          std::to_string(static_cast<int>(o.depthsMm[d])) + " mm");
  std::vector<PixelPoint> gridPx;
  for (const auto& g : grid) gridPx.push_back(g.pixel);

  CalibrationUncertainty out;
  std::vector<Eigen::Matrix3d> covIntr(grid.size(), Eigen::Matrix3d::Zero());
  const auto dirs = sigmaDirections<9>(intrinsicsCovariance);
  if (o.draws <= 0) {
    for (const auto& dir : dirs) {
      auto plus = resolveAndTriangulate(perturbIntrinsics(camera, dir), laser, obs, grid, gridPx, o);
      if (!plus) return Status(Error::kBadInput, "uncertainty: " + plus.status().reason());
      auto minus = resolveAndTriangulate(perturbIntrinsics(camera, -dir), laser, obs, grid, gridPx, o);
      if (!minus) return Status(Error::kBadInput, "uncertainty: " + minus.status().reason());
      out.solves += 2;
      for (size_t i = 0; i < grid.size(); ++i) {
        const Eigen::Vector3d delta = 0.5 * ((*plus)[i] - (*minus)[i]);
        covIntr[i] += delta * delta.transpose();
      }
    }
  } else {
    Normal normal(o.seed);
    std::vector<Eigen::Vector3d> sum(grid.size(), Eigen::Vector3d::Zero());
    std::vector<Eigen::Matrix3d> sumSq(grid.size(), Eigen::Matrix3d::Zero());
    for (int k = 0; k < o.draws; ++k) {
      IntrinsicsVector delta = IntrinsicsVector::Zero();
      for (const auto& dir : dirs) delta += normal.next() * dir;
      auto pts = resolveAndTriangulate(perturbIntrinsics(camera, delta), laser, obs, grid, gridPx, o);
      if (!pts) return Status(Error::kBadInput, "uncertainty: " + pts.status().reason());
      ++out.solves;
      for (size_t i = 0; i < grid.size(); ++i) {
        sum[i] += (*pts)[i];
        sumSq[i] += (*pts)[i] * (*pts)[i].transpose();
      }
    }
    const auto m = static_cast<double>(o.draws);
    for (size_t i = 0; i < grid.size(); ++i) {
      const Eigen::Vector3d mean = sum[i] / m;
      covIntr[i] = (sumSq[i] - m * mean * mean.transpose()) / std::max(1.0, m - 1.0);
    }
  }

  // The laser parameters at fixed intrinsics: linear, so ±1σ along its own directions.
  std::vector<Eigen::Matrix3d> covLaser(grid.size(), Eigen::Matrix3d::Zero());
  const std::vector<Eigen::Vector2d> xn = undistortPixels(camera, gridPx);
  for (const auto& dir : sigmaDirections<4>(laserFit.covariance)) {
    const LaserGeometry plus = perturbLaser(laser, dir);
    const LaserGeometry minus = perturbLaser(laser, -dir);
    for (size_t i = 0; i < grid.size(); ++i) {
      const TriangulatedPoint a = triangulate(plus, grid[i].slideMm, xn[i], kAnyDepth);
      const TriangulatedPoint b = triangulate(minus, grid[i].slideMm, xn[i], kAnyDepth);
      if (!a.valid || !b.valid) return Status(Error::kBadInput, "uncertainty: a grid pixel misses the laser plane");
      const Eigen::Vector3d delta = 0.5 * (a.pointMm - b.pointMm);
      covLaser[i] += delta * delta.transpose();
    }
  }

  for (size_t d = 0; d < o.depthsMm.size(); ++d) {
    double zLaser = 0.0, zIntr = 0.0, trace = 0.0;
    for (size_t i = 0; i < grid.size(); ++i) {
      if (grid[i].depthIndex != d) continue;
      zLaser += covLaser[i](2, 2);
      zIntr += covIntr[i](2, 2);
      trace += (covLaser[i] + covIntr[i]).trace();
    }
    const auto m = static_cast<double>(perDepth[d]);
    DepthUncertainty u;
    u.depthMm = o.depthsMm[d];
    u.points = perDepth[d];
    u.depthSigmaLaserMm = std::sqrt(zLaser / m);
    u.depthSigmaIntrinsicsMm = std::sqrt(zIntr / m);
    u.depthSigmaTotalMm = std::sqrt((zLaser + zIntr) / m);
    u.sigma3dTotalMm = std::sqrt(trace / m);
    out.byDepth.push_back(u);
  }
  return out;
}

}  // namespace alacs::geometry
