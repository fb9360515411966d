#include "sim/renderer.h"

#include <opencv2/calib3d.hpp>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace alacs::sim {

namespace {

// SplitMix64: a small, fast, well-mixed generator; the render must be reproducible.
struct Rng {
  uint64_t state;
  uint64_t next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  // Approximately standard normal (Irwin–Hall of 4 uniforms, rescaled).
  float normal() {
    const uint64_t r = next();
    const float s = static_cast<float>(r & 0xFFFF) + static_cast<float>((r >> 16) & 0xFFFF) +
                    static_cast<float>((r >> 32) & 0xFFFF) + static_cast<float>((r >> 48) & 0xFFFF);
    return (s / 65536.0F - 2.0F) * 1.7320508F;
  }
};

// Value noise in [0, 1) on a lattice of `cellMm`, for skin and leaf texture.
float hashNoise(double x, double y, double cellMm, uint64_t salt) {
  const auto ix = static_cast<int64_t>(std::floor(x / cellMm));
  const auto iy = static_cast<int64_t>(std::floor(y / cellMm));
  uint64_t h = static_cast<uint64_t>(ix) * 0x9E3779B97F4A7C15ULL ^ static_cast<uint64_t>(iy) * 0xC2B2AE3D27D4EB4FULL ^ salt;
  h ^= h >> 33;
  h *= 0xFF51AFD7ED558CCDULL;
  h ^= h >> 33;
  return static_cast<float>(h & 0xFFFFFF) / 16777216.0F;
}

}  // namespace

Renderer::Renderer(const SimScene& scene) : scene_(scene) {
  const auto& cam = scene_.truth.camera;
  std::vector<cv::Point2f> pixels;
  pixels.reserve(static_cast<size_t>(cam.widthPx) * static_cast<size_t>(cam.heightPx));
  for (int v = 0; v < cam.heightPx; ++v)
    for (int u = 0; u < cam.widthPx; ++u) pixels.emplace_back(static_cast<float>(u), static_cast<float>(v));
  const cv::Matx33d k(cam.fxPx, 0, cam.cxPx, 0, cam.fyPx, cam.cyPx, 0, 0, 1);
  const cv::Vec<double, 5> dist(cam.distortion[0], cam.distortion[1], cam.distortion[2], cam.distortion[3],
                                cam.distortion[4]);
  cv::undistortPoints(pixels, rays_, k, dist, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 20, 1e-10));
}

void Renderer::render(double slideMm, double laserFraction, uint64_t frameIndex, cv::Mat& out) {
  const auto& cam = scene_.truth.camera;
  out.create(cam.heightPx, cam.widthPx, CV_8UC3);
  Rng rng{scene_.seed * 0x100000001B3ULL + frameIndex * 0x9E3779B97F4A7C15ULL + 12345};
  const Eigen::Vector3d n = scene_.truth.laser.planeNormal;
  const double d = scene_.truth.laser.planeOffsetAt(slideMm);
  const Eigen::Vector3d light = scene_.lightDir.normalized();
  const double laserAmp = scene_.laserPeakDn * std::clamp(laserFraction, 0.0, 1.0);
  // Direction of the light within the sheet (horizontal in the plane), for the incidence.
  const Eigen::Vector3d beamDir = n.cross(Eigen::Vector3d(0, 1, 0)).normalized();
  for (int v = 0; v < cam.heightPx; ++v) {
    auto* row = out.ptr<uint8_t>(v);
    for (int u = 0; u < cam.widthPx; ++u) {
      const cv::Point2f& xn = rays_[static_cast<size_t>(v) * static_cast<size_t>(cam.widthPx) + static_cast<size_t>(u)];
      const Eigen::Vector3d ray(xn.x, xn.y, 1.0);
      // Nearest apple along the ray, else the foliage wall.
      double bestT = scene_.backgroundDepthMm;
      const SimApple* hit = nullptr;
      for (const auto& a : scene_.apples) {
        const double b = ray.dot(a.centerMm);
        const double disc = b * b - ray.squaredNorm() * (a.centerMm.squaredNorm() - a.radiusMm * a.radiusMm);
        if (disc < 0) continue;
        const double t = (b - std::sqrt(disc)) / ray.squaredNorm();
        if (t > 0 && t < bestT) {
          bestT = t;
          hit = &a;
        }
      }
      const Eigen::Vector3d p = bestT * ray;
      Eigen::Vector3d albedo;
      Eigen::Vector3d normal;
      double specular = 0.0;
      double halo = 0.0;
      if (hit != nullptr) {
        normal = (p - hit->centerMm) / hit->radiusMm;
        const float tex = hashNoise(p.x() + p.z(), p.y(), 4.0, 17) * 0.25F + 0.85F;
        albedo = hit->skinRgb * static_cast<double>(tex);
        const Eigen::Vector3d view = -p.normalized();
        const Eigen::Vector3d h = (light + view).normalized();
        specular = 0.35 * std::pow(std::max(0.0, normal.dot(h)), 60.0);
        halo = scene_.haloFraction;
      } else {
        normal = Eigen::Vector3d(0, 0, -1);
        const float leaf = hashNoise(p.x(), p.y(), 35.0, 99);
        const float fine = hashNoise(p.x(), p.y(), 6.0, 7);
        albedo = Eigen::Vector3d(0.10, 0.22, 0.08) * (0.5 + 0.8 * leaf) * (0.85 + 0.3 * fine);
      }
      const double shade = 0.35 + 0.65 * std::max(0.0, normal.dot(light));
      double rgb[3];
      for (int c = 0; c < 3; ++c) rgb[c] = 255.0 * scene_.ambient * (albedo(c) * shade + specular);
      if (laserAmp > 0.0) {
        // Distance of the surface point from the laser sheet; the sheet thickens with range.
        const double dist = n.dot(p) - d;
        const double sigma = scene_.sheetSigmaMmAt1200 * p.norm() / 1200.0;
        const double core = std::exp(-0.5 * dist * dist / (sigma * sigma));
        const double haloTerm = halo * std::exp(-0.5 * dist * dist / (scene_.haloSigmaMm * scene_.haloSigmaMm));
        double intensity = core + haloTerm;
        if (intensity > 1e-4) {
          const double incidence = std::max(0.15, std::abs(normal.dot(beamDir)));
          const double range = 1200.0 / p.norm();
          intensity *= laserAmp * incidence * range * range * (hit ? 1.0 : 0.6);
          intensity *= std::max(0.0, 1.0 + scene_.speckle * static_cast<double>(rng.normal()));
          // 635 nm: mostly red, a little leaks into the green and blue filters.
          rgb[0] += intensity;
          rgb[1] += 0.08 * intensity;
          rgb[2] += 0.04 * intensity;
        }
      }
      for (int c = 0; c < 3; ++c) {
        const double noisy = rgb[c] + std::sqrt(std::max(0.0, rgb[c]) * scene_.shotNoiseGain +
                                                scene_.readNoiseDn * scene_.readNoiseDn) *
                                          static_cast<double>(rng.normal());
        // BGR memory order, as OpenCV writes PNGs.
        row[3 * u + (2 - c)] = static_cast<uint8_t>(std::clamp(std::lround(noisy), 0L, 255L));
      }
    }
  }
}

}  // namespace alacs::sim
