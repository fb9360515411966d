#include "sim/scene.h"

#include <opencv2/core.hpp>

#include "common/json_file.h"
#include <Eigen/Geometry>
#include <cmath>
#include <fstream>
#include <sstream>

#include "geometry/triangulation.h"

namespace alacs::sim {

Status SimScene::validate() const {
  if (Status s = geometry::validateCalibration(truth); !s) return s;
  for (const auto& a : apples) {
    if (!(a.radiusMm >= 20.0 && a.radiusMm <= 80.0)) return {Error::kBadInput, "apple radius must be in 20..80 mm"};
    if (!(a.centerMm.z() > 300.0 && a.centerMm.z() < backgroundDepthMm))
      return {Error::kBadInput, "apple must lie between 300 mm and the background"};
  }
  if (!(ambient >= 0.0 && ambient <= 4.0)) return {Error::kBadInput, "ambient must be in 0..4"};
  if (!(laserPeakDn >= 0.0 && laserPeakDn <= 2000.0)) return {Error::kBadInput, "laser_peak_dn must be in 0..2000"};
  if (!(sheetSigmaMmAt1200 > 0.05 && sheetSigmaMmAt1200 < 10.0)) return {Error::kBadInput, "sheet_sigma_mm must be in 0.05..10"};
  return Status::ok();
}

SimScene defaultScene() {
  SimScene s;
  auto& cam = s.truth.camera;
  cam.widthPx = 2048;
  cam.heightPx = 1536;
  cam.fxPx = 2400.0;
  cam.fyPx = 2402.0;
  cam.cxPx = 1026.3;
  cam.cyPx = 765.8;
  cam.distortion = {-0.08, 0.12, 0.0005, -0.0003, 0.0};
  // The laser sits 100 mm right of the camera at slide home and is yawed by 9.5° so that
  // at mid-stroke its sheet crosses the optical axis at 1.2 m; a slight roll (β) tilts it.
  const double yaw = 9.5 * M_PI / 180.0;
  auto& las = s.truth.laser;
  las.planeNormal = Eigen::Vector3d(std::cos(yaw), -0.02, std::sin(yaw)).normalized();
  las.slideAxis = Eigen::Vector3d(1.0, 0.012, 0.004).normalized();
  const Eigen::Vector3d laserAtHome(100.0, -60.0, 15.0);
  las.planeOffsetMm = las.planeNormal.dot(laserAtHome);
  las.slideScale = 1.003;
  s.truth.quality.fromTruth = true;
  SimApple apple;
  apple.id = 1;
  apple.centerMm = Eigen::Vector3d(10.0, -20.0, 1200.0);
  apple.radiusMm = 40.0;
  s.apples.push_back(apple);
  return s;
}

namespace {
double readOr(const cv::FileNode& n, const char* key, double fallback) {
  const cv::FileNode v = n[key];
  return (v.isReal() || v.isInt()) ? v.real() : fallback;
}
Eigen::Vector3d readVec3Or(const cv::FileNode& n, const char* key, const Eigen::Vector3d& fallback) {
  const cv::FileNode v = n[key];
  if (!v.isSeq() || v.size() != 3) return fallback;
  return {v[0].real(), v[1].real(), v[2].real()};
}
}  // namespace

Result<SimScene> loadScene(const std::string& path) {
  Result<cv::FileStorage> file = openJsonFile(path, "scene file");
  if (!file) return file.status();
  cv::FileStorage& fs = *file;
  SimScene s = defaultScene();
  const cv::FileNode root = fs.root();
  s.backgroundDepthMm = readOr(root, "background_depth_mm", s.backgroundDepthMm);
  s.ambient = readOr(root, "ambient", s.ambient);
  s.laserPeakDn = readOr(root, "laser_peak_dn", s.laserPeakDn);
  s.sheetSigmaMmAt1200 = readOr(root, "sheet_sigma_mm", s.sheetSigmaMmAt1200);
  s.readNoiseDn = readOr(root, "read_noise_dn", s.readNoiseDn);
  s.seed = static_cast<uint64_t>(readOr(root, "seed", static_cast<double>(s.seed)));
  const cv::FileNode apples = root["apples"];
  if (apples.isSeq()) {
    s.apples.clear();
    int id = 1;
    for (auto it = apples.begin(); it != apples.end(); ++it) {
      SimApple a;
      a.id = static_cast<int>(readOr(*it, "id", id));
      a.centerMm = readVec3Or(*it, "center_mm", a.centerMm);
      a.radiusMm = readOr(*it, "radius_mm", a.radiusMm);
      a.skinRgb = readVec3Or(*it, "skin_rgb", a.skinRgb);
      s.apples.push_back(a);
      ++id;
    }
  }
  if (Status st = s.validate(); !st) return st;
  return s;
}

Status saveSceneTruth(const SimScene& scene, const std::string& path) {
  std::ofstream out(path + ".tmp", std::ios::trunc);
  if (!out) return {Error::kIo, "cannot write '" + path + "'"};
  out.precision(10);
  out << "{\n  \"apples\": [";
  for (size_t i = 0; i < scene.apples.size(); ++i) {
    const auto& a = scene.apples[i];
    const Eigen::Vector3d ap = approachPoint(a);
    out << (i ? ",\n" : "\n") << "    {\"id\": " << a.id << ", \"center_mm\": [" << a.centerMm.x() << ", "
        << a.centerMm.y() << ", " << a.centerMm.z() << "], \"radius_mm\": " << a.radiusMm
        << ", \"approach_mm\": [" << ap.x() << ", " << ap.y() << ", " << ap.z() << "]}";
  }
  out << "\n  ],\n  \"background_depth_mm\": " << scene.backgroundDepthMm << "\n}\n";
  out.close();
  if (!out) return {Error::kIo, "cannot write '" + path + "'"};
  if (std::rename((path + ".tmp").c_str(), path.c_str()) != 0) return {Error::kIo, "cannot rename to '" + path + "'"};
  return Status::ok();
}

Eigen::Vector3d approachPoint(const SimApple& apple) {
  return apple.centerMm - apple.radiusMm * apple.centerMm.normalized();
}

namespace {
// Distance along the ray (origin at the camera) to the first hit with a sphere; <0: none.
double raySphere(const Eigen::Vector3d& dir, const Eigen::Vector3d& c, double r) {
  const double b = dir.dot(c);
  const double disc = b * b - dir.squaredNorm() * (c.squaredNorm() - r * r);
  if (disc < 0) return -1.0;
  return (b - std::sqrt(disc)) / dir.squaredNorm();
}
}  // namespace

std::vector<RowTruth> laserLineTruth(const SimScene& scene, const SimApple& apple, double slideMm) {
  std::vector<RowTruth> rows;
  const auto& las = scene.truth.laser;
  const Eigen::Vector3d n = las.planeNormal;
  const double d = las.planeOffsetAt(slideMm);
  const double delta = n.dot(apple.centerMm) - d;
  if (std::abs(delta) >= apple.radiusMm) return rows;
  const Eigen::Vector3d c0 = apple.centerMm - delta * n;
  const double rho = std::sqrt(apple.radiusMm * apple.radiusMm - delta * delta);
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  // Dense samples of the circle; keep those the camera sees (facing it, not hidden by
  // another apple), project them with distortion, and interpolate at integer rows.
  constexpr int kSamples = 8192;
  struct Sample { double u, v; bool visible; };
  std::vector<Sample> samples(kSamples);
  std::vector<Eigen::Vector3d> points(kSamples);
  for (int i = 0; i < kSamples; ++i) {
    const double phi = 2.0 * M_PI * i / kSamples;
    const Eigen::Vector3d p = c0 + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
    bool visible = (p - apple.centerMm).dot(-p) > 0.0;
    if (visible) {
      for (const auto& other : scene.apples) {
        if (&other == &apple) continue;
        const double t = raySphere(p, other.centerMm, other.radiusMm);
        if (t > 0.0 && t < 1.0 - 1e-9) visible = false;
      }
    }
    points[static_cast<size_t>(i)] = p;
    samples[static_cast<size_t>(i)].visible = visible;
  }
  const std::vector<geometry::PixelPoint> projected = geometry::projectPoints(scene.truth.camera, points);
  for (size_t i = 0; i < samples.size(); ++i) {
    samples[i].u = projected[i].columnPx;
    samples[i].v = projected[i].rowPx;
  }
  for (int i = 0; i < kSamples; ++i) {
    const Sample& a = samples[static_cast<size_t>(i)];
    const Sample& b = samples[static_cast<size_t>((i + 1) % kSamples)];
    if (!a.visible || !b.visible) continue;
    const double lo = std::min(a.v, b.v);
    const double hi = std::max(a.v, b.v);
    for (int row = static_cast<int>(std::ceil(lo)); row < hi; ++row) {
      if (row < 0 || row >= scene.truth.camera.heightPx) continue;
      const double t = (row - a.v) / (b.v - a.v);
      rows.push_back({row, a.u + t * (b.u - a.u)});
    }
  }
  std::sort(rows.begin(), rows.end(), [](const RowTruth& x, const RowTruth& y) { return x.row < y.row; });
  return rows;
}

}  // namespace alacs::sim
