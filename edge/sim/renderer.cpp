#include "sim/renderer.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace alacs::sim {

namespace {

constexpr double kPi = 3.14159265358979323846;

// SplitMix64's finaliser: a well-mixed hash, so that every pixel's noise is a pure
// function of (seed, frame, pixel, channel).
inline uint64_t mix64(uint64_t z) {
  z += 0x9E3779B97F4A7C15ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}
inline double u01(uint64_t h) { return (static_cast<double>(h >> 11) + 0.5) * (1.0 / 9007199254740992.0); }
// Approximately standard normal: the sum of four 16-bit uniforms (Irwin–Hall), rescaled.
// Tails end at ±3.46σ, which sensor noise does not miss; no transcendental per pixel.
inline double gauss(uint64_t key) {
  const uint64_t r = mix64(key);
  const double s = static_cast<double>(r & 0xFFFF) + static_cast<double>((r >> 16) & 0xFFFF) +
                   static_cast<double>((r >> 32) & 0xFFFF) + static_cast<double>((r >> 48) & 0xFFFF);
  return (s / 65536.0 - 2.0) * 1.7320508075688772;
}
inline uint64_t latticeKey(int64_t ix, int64_t iy, uint64_t salt) {
  return static_cast<uint64_t>(ix) * 0x9E3779B97F4A7C15ULL ^ static_cast<uint64_t>(iy) * 0xC2B2AE3D27D4EB4FULL ^
         salt * 0x165667B19E3779F9ULL;
}
inline double smooth(double t) { return t * t * (3.0 - 2.0 * t); }

// Smooth value noise in [0, 1) at lattice coordinates (x, y).
double valueNoise(double x, double y, uint64_t salt) {
  const double fx = std::floor(x);
  const double fy = std::floor(y);
  const auto ix = static_cast<int64_t>(fx);
  const auto iy = static_cast<int64_t>(fy);
  const double tx = smooth(x - fx);
  const double ty = smooth(y - fy);
  const double a = u01(mix64(latticeKey(ix, iy, salt)));
  const double b = u01(mix64(latticeKey(ix + 1, iy, salt)));
  const double c = u01(mix64(latticeKey(ix, iy + 1, salt)));
  const double d = u01(mix64(latticeKey(ix + 1, iy + 1, salt)));
  return (a + (b - a) * tx) + ((c + (d - c) * tx) - (a + (b - a) * tx)) * ty;
}
double fbm(double x, double y, uint64_t salt) {
  return (0.6 * valueNoise(x, y, salt) + 0.3 * valueNoise(2.03 * x, 2.03 * y, salt + 1) +
          0.1 * valueNoise(4.1 * x, 4.1 * y, salt + 2));
}

// Speckle: a lattice of gamma-distributed intensities (mean 1, contrast ≈ C), one node
// per speckle grain, interpolated bilinearly.
double speckleNode(int64_t ix, int64_t iy, uint64_t salt, int looks) {
  uint64_t h = latticeKey(ix, iy, salt);
  double sum = 0.0;
  for (int k = 0; k < looks; ++k) {
    h = mix64(h + static_cast<uint64_t>(k));
    sum += -std::log(u01(h));
  }
  return sum / looks;
}
double speckle(double u, double v, double cellPx, uint64_t salt, int looks) {
  const double x = u / cellPx;
  const double y = v / cellPx;
  const double fx = std::floor(x);
  const double fy = std::floor(y);
  const auto ix = static_cast<int64_t>(fx);
  const auto iy = static_cast<int64_t>(fy);
  const double tx = x - fx;
  const double ty = y - fy;
  const double a = speckleNode(ix, iy, salt, looks);
  const double b = speckleNode(ix + 1, iy, salt, looks);
  const double c = speckleNode(ix, iy + 1, salt, looks);
  const double d = speckleNode(ix + 1, iy + 1, salt, looks);
  return (a + (b - a) * tx) * (1.0 - ty) + (c + (d - c) * tx) * ty;
}

struct Surface {
  Eigen::Vector3d albedo = Eigen::Vector3d::Zero();
  double laserAlbedo = 0.0;  // at 635 nm
  double specular = 0.0;     // Fresnel reflectance at normal incidence
  double shininess = 1.0;
  double halo = 0.0;         // share of laser light re-emerging from under the surface
  bool twoSided = false;
};

double skinBlushMask(const SimApple& a, const Eigen::Vector3d& nrm) {
  if (a.blush >= 1.0) return 1.0;
  if (a.blush <= 0.0) return 0.0;
  // A spherical cap {n·axis >= τ} covers (1 - τ)/2 of the sphere; streaks along the
  // meridians (around the stem, the y axis) break its edge as on a real bicolour apple.
  const double tau = 1.0 - 2.0 * a.blush;
  const double azimuth = std::atan2(nrm.x(), nrm.z());
  const double streak = valueNoise(azimuth * 9.0, nrm.y() * 1.5, 501 + static_cast<uint64_t>(a.id)) - 0.5;
  const double x = nrm.dot(a.blushAxis.normalized()) + 0.45 * streak;
  return smooth(std::clamp((x - (tau - 0.2)) / 0.4, 0.0, 1.0));
}

// The surface of the object hit at p (normal nrm): albedo with its texture, gloss, halo.
Surface objectSurface(const SimScene& s, const Hit& hit, const Eigen::Vector3d& p, const Eigen::Vector3d& nrm) {
  Surface surf;
  switch (hit.kind) {
    case SurfaceKind::kApple: {
      const SimApple& a = s.apples[static_cast<size_t>(hit.index)];
      // A lumpy apple's outward normal is the hit's (seen from outside), already marched.
      const Eigen::Vector3d outward = a.lumpAmplitude > 0.0 ? nrm : appleNormal(a, p);
      const double blush = skinBlushMask(a, outward);
      const double fine = 0.9 + 0.2 * fbm((p.x() + 0.7 * p.z()) / 3.0, p.y() / 3.0, 17 + static_cast<uint64_t>(a.id));
      surf.albedo = (blush * a.skinRgb + (1.0 - blush) * a.groundRgb) * fine;
      surf.laserAlbedo = surf.albedo.x();
      surf.specular = a.specular;
      surf.shininess = a.shininess;
      surf.halo = s.laser.haloShare;
      break;
    }
    case SurfaceKind::kLeaf: {
      const SimLeaf& l = s.leaves[static_cast<size_t>(hit.index)];
      const Eigen::Vector3d q = p - l.centerMm;
      const double vein = std::abs(q.dot(l.normal.cross(l.axis))) < 1.0 ? 1.25 : 1.0;
      surf.albedo = l.albedoRgb * (0.85 + 0.3 * valueNoise(q.dot(l.axis) / 6.0, q.dot(l.normal.cross(l.axis)) / 6.0, 31 + static_cast<uint64_t>(hit.index))) * vein;
      surf.laserAlbedo = surf.albedo.x();
      surf.specular = 0.03;
      surf.shininess = 25.0;
      surf.twoSided = true;
      break;
    }
    case SurfaceKind::kBranch: {
      const SimBranch& b = s.branches[static_cast<size_t>(hit.index)];
      const Eigen::Vector3d ax = (b.bMm - b.aMm).normalized();
      surf.albedo = b.albedoRgb * (0.75 + 0.5 * valueNoise((p - b.aMm).dot(ax) / 12.0, std::atan2(nrm.y(), nrm.x()) * 3.0, 41 + static_cast<uint64_t>(hit.index)));
      surf.laserAlbedo = surf.albedo.x();
      break;
    }
    case SurfaceKind::kBoard: {
      const SimBoard& b = *s.board;
      const Eigen::Vector3d local = b.rotation.transpose() * (p - b.originMm);
      double alb = b.whiteAlbedo;
      if (b.checkerboard && local.x() >= 0 && local.y() >= 0 && local.x() < b.squaresX * b.squareMm &&
          local.y() < b.squaresY * b.squareMm) {
        const auto cx = static_cast<int64_t>(std::floor(local.x() / b.squareMm));
        const auto cy = static_cast<int64_t>(std::floor(local.y() / b.squareMm));
        if ((cx + cy) % 2 == 0) alb = b.blackAlbedo;
      }
      surf.albedo = Eigen::Vector3d::Constant(alb);
      surf.laserAlbedo = alb;
      surf.twoSided = false;
      break;
    }
  }
  return surf;
}

// The background's surface at p: foliage or a backdrop. False where the foliage is sky
// (value noise below skyThreshold): no surface.
bool backgroundSurface(const SimBackground& bgd, const Eigen::Vector3d& p, double skyThreshold, Surface* surf) {
  if (bgd.kind == SimBackground::Kind::kFoliage) {
    const double gap = fbm(p.x() / (3.0 * bgd.textureCellMm), p.y() / (3.0 * bgd.textureCellMm), 1234);
    if (gap < skyThreshold) return false;
    const double clump = valueNoise(p.x() / bgd.textureCellMm, p.y() / bgd.textureCellMm, 99);
    const double fine = valueNoise(p.x() / 6.0, p.y() / 6.0, 7);
    surf->albedo = bgd.albedoRgb * (0.5 + 0.8 * clump) * (0.85 + 0.3 * fine);
  } else {
    surf->albedo = bgd.albedoRgb * (0.9 + 0.2 * valueNoise(p.x() / 20.0, p.y() / 20.0, 8));
  }
  return true;
}

// Specular illuminance (lux) of a glossy surface (surf.specular > 0) seen along dir: the
// sun's highlight when the sun reaches it (directE > 0), and the sky reflected in the wax.
double specularLux(const SimLighting& light, const Surface& surf, const Eigen::Vector3d& nrm,
                   const Eigen::Vector3d& dir, const Eigen::Vector3d& sun, double directE, double cosSun) {
  double specE = 0.0;
  const Eigen::Vector3d view = -dir;
  const double cosView = std::max(0.0, nrm.dot(view));
  if (directE > 0.0) {
    const Eigen::Vector3d h = (sun + view).normalized();
    const double fres = surf.specular + (1.0 - surf.specular) * std::pow(1.0 - std::max(0.0, h.dot(view)), 5);
    specE += light.directLux * fres * (surf.shininess + 8.0) / 8.0 * std::pow(std::max(0.0, nrm.dot(h)), surf.shininess) * (cosSun > 0 ? 1.0 : 0.0);
  }
  // The sky (or room) reflected in the wax: Fresnel rises towards the limb.
  const double fresView = surf.specular + (1.0 - surf.specular) * std::pow(1.0 - cosView, 5);
  specE += 0.5 * fresView * light.skyLuminanceFactor * light.diffuseLux;
  return specE;
}

// One position of the laser during the exposure: its origin and its plane's offset.
struct LaserSub {
  Eigen::Vector3d origin;
  double offset;
};

// Laser: sub-positions across the exposure, so that a moving slide smears the line (none
// with the laser off).
std::vector<LaserSub> laserSubs(const SimScene& s, const FrameRequest& request) {
  const auto& las = s.truth.laser;
  const double sigmaRef = s.laser.sheetSigmaMrad * 1.2;  // mm at 1.2 m
  const double travel = std::abs(las.planeOffsetAt(request.slideEndMm) - las.planeOffsetAt(request.slideStartMm));
  const int subSamples = request.laserFraction > 0.0 ? std::clamp(static_cast<int>(std::ceil(travel / (0.25 * sigmaRef))), 1, 64) : 0;
  std::vector<LaserSub> subs;
  for (int k = 0; k < subSamples; ++k) {
    const double sl = request.slideStartMm + (request.slideEndMm - request.slideStartMm) * (k + 0.5) / subSamples;
    subs.push_back({s.laser.originAt(las, sl), las.planeOffsetAt(sl)});
  }
  return subs;
}

// A rolling shutter's row v: its exposure saw the laser where the slide was then.
std::vector<LaserSub> laserSubsAtRow(const SimScene& s, const FrameRequest& request, int v) {
  FrameRequest row = request;
  row.slideStartMm += v * request.slideMmPerRow;
  row.slideEndMm += v * request.slideMmPerRow;
  return laserSubs(s, row);
}

}  // namespace

RayTable::RayTable(const geometry::CameraIntrinsics& cam) : cam_(cam) {
  std::vector<cv::Point2f> pixels;
  pixels.reserve(static_cast<size_t>(cam.widthPx) * static_cast<size_t>(cam.heightPx));
  for (int v = 0; v < cam.heightPx; ++v)
    for (int u = 0; u < cam.widthPx; ++u) pixels.emplace_back(static_cast<float>(u), static_cast<float>(v));
  const cv::Matx33d k(cam.fxPx, 0, cam.cxPx, 0, cam.fyPx, cam.cyPx, 0, 0, 1);
  const cv::Vec<double, 5> dist(cam.distortion[0], cam.distortion[1], cam.distortion[2], cam.distortion[3],
                                cam.distortion[4]);
  cv::undistortPoints(pixels, rays_, k, dist, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 20, 1e-10));
  tilesX_ = (cam.widthPx + kTile - 1) / kTile;
  tilesY_ = (cam.heightPx + kTile - 1) / kTile;
  tiles_.resize(static_cast<size_t>(tilesX_ * tilesY_));
  for (int tv = 0; tv < tilesY_; ++tv) {
    for (int tu = 0; tu < tilesX_; ++tu) {
      Box b{1e9F, 1e9F, -1e9F, -1e9F};
      for (int v = tv * kTile; v < std::min(cam.heightPx, (tv + 1) * kTile); ++v) {
        for (int u = tu * kTile; u < std::min(cam.widthPx, (tu + 1) * kTile); ++u) {
          const cv::Point2f& r = ray(u, v);
          b.x0 = std::min(b.x0, r.x);
          b.y0 = std::min(b.y0, r.y);
          b.x1 = std::max(b.x1, r.x);
          b.y1 = std::max(b.y1, r.y);
        }
      }
      tiles_[static_cast<size_t>(tv * tilesX_ + tu)] = b;
    }
  }
}

Renderer::Renderer(const SimScene& scene, std::shared_ptr<const RayTable> rays)
    : scene_(scene), rays_(std::move(rays)), geometry_(scene_) {
  if (!rays_) rays_ = std::make_shared<const RayTable>(scene_.truth.camera);
  // Which objects may cover each tile: the pinhole image of an object's box is inside
  // the box of its projected corners (all in front of the camera), compared in
  // undistorted normalised coordinates with the tile's rays.
  tileObjects_.resize(static_cast<size_t>(rays_->tilesX() * rays_->tilesY()));
  for (size_t i = 0; i < geometry_.objects().size(); ++i) {
    const auto& o = geometry_.objects()[i];
    double x0 = 1e18, y0 = 1e18, x1 = -1e18, y1 = -1e18;
    bool everywhere = false;
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d p((c & 1) ? o.aabbMax.x() : o.aabbMin.x(), (c & 2) ? o.aabbMax.y() : o.aabbMin.y(),
                              (c & 4) ? o.aabbMax.z() : o.aabbMin.z());
      if (p.z() <= 1.0) {
        everywhere = true;
        break;
      }
      x0 = std::min(x0, p.x() / p.z());
      x1 = std::max(x1, p.x() / p.z());
      y0 = std::min(y0, p.y() / p.z());
      y1 = std::max(y1, p.y() / p.z());
    }
    for (int tv = 0; tv < rays_->tilesY(); ++tv) {
      for (int tu = 0; tu < rays_->tilesX(); ++tu) {
        const RayTable::Box& b = rays_->tile(tu, tv);
        if (everywhere || (b.x1 >= x0 && b.x0 <= x1 && b.y1 >= y0 && b.y0 <= y1))
          tileObjects_[static_cast<size_t>(tv * rays_->tilesX() + tu)].push_back(static_cast<int>(i));
      }
    }
  }
  // The sky's share of the foliage: the quantile of the gap noise.
  if (scene_.background.kind == SimBackground::Kind::kFoliage && scene_.background.skyShare > 0.0) {
    std::vector<double> v;
    v.reserve(4096);
    for (int i = 0; i < 4096; ++i) v.push_back(fbm(0.37 * i + 0.11, 0.53 * (i % 97) + 0.29 * i, 1234));
    std::sort(v.begin(), v.end());
    skyThreshold_ = v[static_cast<size_t>(std::clamp(scene_.background.skyShare, 0.0, 1.0) * 4095.0)];
  } else {
    skyThreshold_ = -1.0;
  }
}

void Renderer::render(double slideMm, double laserFraction, uint64_t frameIndex, cv::Mat& out) {
  FrameRequest r;
  r.slideStartMm = slideMm;
  r.slideEndMm = slideMm;
  r.laserFraction = laserFraction;
  r.frameIndex = frameIndex;
  render(r, out);
}

void Renderer::render(const FrameRequest& request, cv::Mat& out) {
  const auto& cam = scene_.truth.camera;
  out.create(cam.heightPx, cam.widthPx, CV_8UC3);
  cv::Mat crop;
  renderRegion(request, cv::Rect(0, 0, cam.widthPx, cam.heightPx), crop);
  crop.copyTo(out);
}

void Renderer::renderRegion(const FrameRequest& request, const cv::Rect& roi, cv::Mat& crop) {
  const auto& cam = scene_.truth.camera;
  const cv::Rect frame(0, 0, cam.widthPx, cam.heightPx);
  const cv::Rect r = roi & frame;
  if (r.empty()) {
    crop.create(0, 0, CV_8UC3);
    return;
  }
  // Render a margin around the region so that the lens blur and the demosaic see the
  // same neighbours as in a full frame; start on even pixels so the RGGB phase holds.
  const int margin = static_cast<int>(std::ceil(3.0 * scene_.sensor.psfSigmaPx)) + 3;
  int x0 = std::max(0, r.x - margin);
  int y0 = std::max(0, r.y - margin);
  x0 -= x0 % 2;
  y0 -= y0 % 2;
  const int x1 = std::min(cam.widthPx, r.x + r.width + margin);
  const int y1 = std::min(cam.heightPx, r.y + r.height + margin);
  const cv::Rect region(x0, y0, x1 - x0, y1 - y0);
  cv::Mat electrons(region.height, region.width, CV_32FC3);
  shadeRegion(request, region, electrons);
  cv::Mat bgr;
  sensorRegion(request, region, electrons, bgr);
  bgr(cv::Rect(r.x - region.x, r.y - region.y, r.width, r.height)).copyTo(crop);
}

void Renderer::shadeRegion(const FrameRequest& request, const cv::Rect& region, cv::Mat& electrons) const {
  const SimScene& s = scene_;
  const auto& las = s.truth.laser;
  const auto& sen = s.sensor;
  const auto& light = s.lighting;
  const double exposureS = static_cast<double>(request.exposureUs > 0 ? request.exposureUs : sen.exposureUs) * 1e-6;
  // Image-plane illuminance of a Lambertian surface: ρ·E·T / (4 N²) · cos⁴θ.
  const double lensK = sen.lensTransmission / (4.0 * sen.fNumber * sen.fNumber);
  const double ambientK = lensK * exposureS * sen.electronsPerLuxS;
  const double laserK = lensK * exposureS * sen.electronsPerWattS * std::clamp(request.laserFraction, 0.0, 1.0);
  const Eigen::Vector3d ambientFilter = sen.ambientFilterRgb();  // the band-pass filter, if any
  const Eigen::Vector3d up(0.0, -1.0, 0.0);
  const Eigen::Vector3d sun = light.directDir.normalized();
  const bool haveSun = light.directLux > 0.0;
  std::vector<LaserSub> subs = laserSubs(s, request);
  const Eigen::Vector3d n = las.planeNormal;
  const Eigen::Vector3d beam = (Eigen::Vector3d(0, 0, 1) - n.z() * n).normalized();
  const double cosHalfFan = std::cos(0.5 * s.laser.fanDeg * kPi / 180.0);
  const double powerW = s.laser.powerMw * 1e-3;
  const double fanRad = s.laser.fanDeg * kPi / 180.0;
  const double haloL = s.laser.haloLengthMm;
  const int looks = std::max(1, static_cast<int>(std::lround(1.0 / std::max(1e-3, s.laser.speckleContrast * s.laser.speckleContrast))));
  const uint64_t speckleIndex =
      request.speckleFrameIndex >= 0 ? static_cast<uint64_t>(request.speckleFrameIndex) : request.frameIndex;
  const uint64_t speckleSalt = mix64(s.seed * 0x2545F4914F6CDD1DULL + speckleIndex * 0x9E3779B97F4A7C15ULL + 77);
  const auto& bgd = s.background;

  for (int row = 0; row < region.height; ++row) {
    const int v = region.y + row;
    auto* out = electrons.ptr<float>(row);
    if (request.slideMmPerRow != 0.0) subs = laserSubsAtRow(s, request, v);
    for (int col = 0; col < region.width; ++col) {
      const int u = region.x + col;
      const cv::Point2f& xn = rays_->ray(u, v);
      const Eigen::Vector3d rayUn(xn.x, xn.y, 1.0);
      const double rayLen = rayUn.norm();
      const Eigen::Vector3d dir = rayUn / rayLen;
      const double c2 = 1.0 / (rayLen * rayLen);
      const double cos4 = sen.vignetting ? c2 * c2 : 1.0;
      const std::vector<int>& cands =
          tileObjects_[static_cast<size_t>((v / RayTable::kTile) * rays_->tilesX() + u / RayTable::kTile)];
      Hit hit;
      const double wallT = bgd.depthMm / dir.z();
      const bool onObject = !cands.empty() && geometry_.intersect(Eigen::Vector3d::Zero(), dir, 1e-6, wallT, &hit, &cands);
      double e[3] = {0.0, 0.0, 0.0};
      Eigen::Vector3d p;
      Eigen::Vector3d nrm;
      Surface surf;
      SurfaceKind kind = SurfaceKind::kApple;
      int index = -1;
      if (onObject) {
        p = hit.t * dir;
        nrm = hit.normal;
        kind = hit.kind;
        index = hit.index;
        surf = objectSurface(s, hit, p, nrm);
      } else {
        p = wallT * dir;
        nrm = Eigen::Vector3d(0.0, 0.0, -1.0);
        index = -1;
        if (!backgroundSurface(bgd, p, skyThreshold_, &surf)) {
          // Sky: luminance factor · E_diffuse / π, tinted.
          const double k = light.skyLuminanceFactor * light.diffuseLux * ambientK * cos4;
          for (int c = 0; c < 3; ++c) out[3 * col + c] = static_cast<float>(k * light.skyRgb(c) * ambientFilter(c));
          continue;
        }
        surf.laserAlbedo = surf.albedo.x();
      }

      // Ambient: the diffuse part by how much of the sky (or ceiling) the surface faces;
      // the direct part unless something casts a shadow.
      const double diffuseE = light.diffuseLux * (0.5 + 0.5 * std::clamp(nrm.dot(up), -1.0, 1.0));
      double directE = 0.0;
      const double cosSun = nrm.dot(sun);
      if (haveSun && cosSun > 0.0 && !geometry_.blocked(p, sun, 1e-3, 1e9, kind, index)) directE = light.directLux * cosSun;
      const double specE = surf.specular > 0.0 ? specularLux(light, surf, nrm, dir, sun, directE, cosSun) : 0.0;
      for (int c = 0; c < 3; ++c) e[c] = (surf.albedo(c) * (diffuseE + directE) + specE) * ambientK * cos4 * ambientFilter(c);

      // Laser.
      if (!subs.empty() && surf.laserAlbedo > 0.0) {
        double irr = 0.0;  // W/m², averaged over the exposure's sub-positions
        const double cosPlane = n.dot(nrm);
        const double g = std::max(0.2, std::sqrt(std::max(0.0, 1.0 - cosPlane * cosPlane)));
        for (const LaserSub& sub : subs) {
          const double delta = n.dot(p) - sub.offset;
          const Eigen::Vector3d toLaser = sub.origin - p;
          const double range = toLaser.norm();
          const double sigma = s.laser.sheetSigmaMrad * 1e-3 * range;
          const double reach = surf.halo > 0.0 ? std::max(5.0 * sigma, 8.0 * haloL * g) : 5.0 * sigma;
          if (std::abs(delta) > reach) continue;
          const Eigen::Vector3d fromLaser = -toLaser / range;
          if (fromLaser.dot(beam) < cosHalfFan) continue;
          double cosI = nrm.dot(toLaser) / range;
          if (cosI <= 0.0) {
            if (!surf.twoSided) continue;
            cosI = -0.1 * cosI;  // a leaf lit from behind passes a little red light through
          }
          if (geometry_.blocked(p, toLaser / range, 1e-3, range - 1e-3, kind, index)) continue;
          const double lineDensity = powerW / (fanRad * range);  // W per mm of line
          const double core = std::exp(-0.5 * delta * delta / (sigma * sigma)) / (std::sqrt(2.0 * kPi) * sigma);
          double profile = (1.0 - surf.halo) * core;
          if (surf.halo > 0.0) {
            const double ds = std::abs(delta) / g;
            profile += surf.halo * std::exp(-ds / haloL) / (2.0 * haloL) / g;
          }
          irr += lineDensity * profile * cosI * 1e6;  // W/mm² -> W/m²
        }
        irr /= static_cast<double>(subs.size());
        if (irr > 0.0) {
          double sp = 1.0;
          if (s.laser.speckleContrast > 0.0) sp = speckle(u, v, s.laser.speckleCellPx, speckleSalt, looks);
          // The band-pass filter (if any) at this pixel's angle of incidence: 1 - c2 = sin²θ.
          const double red = surf.laserAlbedo * irr * laserK * cos4 * sp * sen.laserFilter(1.0 - c2);
          for (int c = 0; c < 3; ++c) e[c] += red * s.laser.channelResponse(c);
        }
      }
      for (int c = 0; c < 3; ++c) out[3 * col + c] = static_cast<float>(e[c]);
    }
  }
}

void Renderer::sensorRegion(const FrameRequest& request, const cv::Rect& region, cv::Mat& electrons,
                            cv::Mat& bgr) const {
  const auto& sen = scene_.sensor;
  if (sen.psfSigmaPx > 0.0) {
    const int k = 2 * static_cast<int>(std::ceil(3.0 * sen.psfSigmaPx)) + 1;
    cv::GaussianBlur(electrons, electrons, cv::Size(k, k), sen.psfSigmaPx, sen.psfSigmaPx, cv::BORDER_REFLECT_101);
  }
  const double gain = request.analogueGain > 0.0 ? request.analogueGain : sen.analogueGain();
  const double eDn = sen.fullWellE / 4095.0 / gain;  // electrons per 12-bit DN
  const uint64_t frameKey = mix64(scene_.seed * 0x100000001B3ULL) ^ mix64(request.frameIndex + 0x632BE59BD9B4E019ULL);
  const int width = scene_.truth.camera.widthPx;
  auto digitise = [&](double meanE, int u, int v, int c) -> uint16_t {
    const uint64_t pix = (static_cast<uint64_t>(v) * static_cast<uint64_t>(width) + static_cast<uint64_t>(u)) * 4 + static_cast<uint64_t>(c);
    double e = meanE * (1.0 + sen.prnu * gauss(pix ^ 0xA0761D6478BD642FULL));  // fixed pattern: no frame key
    e += std::sqrt(std::max(0.0, e)) * gauss(pix ^ frameKey);                   // shot noise
    e = std::clamp(e, 0.0, sen.fullWellE);                                       // full well
    e += sen.readNoiseE * gauss(pix ^ frameKey ^ 0xE7037ED1A0B428DBULL);
    return static_cast<uint16_t>(std::clamp(std::lround(e / eDn), 0L, 4095L));
  };
  cv::Mat raw;
  if (sen.bayer) {
    // RGGB: (even row, even col) red, (odd, odd) blue, green elsewhere.
    raw.create(region.height, region.width, CV_16UC1);
    for (int row = 0; row < region.height; ++row) {
      const int v = region.y + row;
      const auto* in = electrons.ptr<float>(row);
      auto* o = raw.ptr<uint16_t>(row);
      for (int col = 0; col < region.width; ++col) {
        const int u = region.x + col;
        const int c = (v % 2 == 0) ? (u % 2 == 0 ? 0 : 1) : (u % 2 == 0 ? 1 : 2);
        o[col] = digitise(in[3 * col + c], u, v, c);
      }
    }
    cv::Mat demosaiced;
    // OpenCV names Bayer patterns by the second row: an RGGB sensor is "BayerBG".
    cv::demosaicing(raw, demosaiced, cv::COLOR_BayerBG2BGR);
    demosaiced.convertTo(bgr, CV_8UC3, 1.0 / 16.0);
  } else {
    raw.create(region.height, region.width, CV_16UC3);
    for (int row = 0; row < region.height; ++row) {
      const int v = region.y + row;
      const auto* in = electrons.ptr<float>(row);
      auto* o = raw.ptr<uint16_t>(row);
      for (int col = 0; col < region.width; ++col) {
        const int u = region.x + col;
        // BGR memory order, as OpenCV writes PNGs.
        for (int c = 0; c < 3; ++c) o[3 * col + (2 - c)] = digitise(in[3 * col + c], u, v, c);
      }
    }
    raw.convertTo(bgr, CV_8UC3, 1.0 / 16.0);
  }
}

}  // namespace alacs::sim
