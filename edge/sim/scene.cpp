#include "sim/scene.h"

#include <opencv2/core.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "common/json_file.h"

namespace alacs::sim {

namespace {
Status fieldError(const std::string& field, const std::string& what) {
  return {Error::kBadInput, "scene field '" + field + "' " + what};
}
bool finite3(const Eigen::Vector3d& v) { return v.allFinite(); }
}  // namespace

Status SimScene::validate() const {
  if (Status s = geometry::validateCalibration(truth); !s) return s;
  for (size_t i = 0; i < apples.size(); ++i) {
    const auto& a = apples[i];
    const std::string f = "apples[" + std::to_string(i) + "]";
    if (!(a.radiusMm >= 20.0 && a.radiusMm <= 80.0)) return fieldError(f + ".radius_mm", "must be in 20..80");
    if (!finite3(a.centerMm) || !(a.centerMm.z() > 300.0 && a.centerMm.z() < background.depthMm))
      return fieldError(f + ".center_mm", "must lie between 300 mm and the background");
    if (!(a.blush >= 0.0 && a.blush <= 1.0)) return fieldError(f + ".blush", "must be in 0..1");
    if (!(a.blushAxis.norm() > 1e-6)) return fieldError(f + ".blush_axis", "must not be zero");
    if (!(a.aspect >= 0.5 && a.aspect <= 1.5)) return fieldError(f + ".aspect", "must be in 0.5..1.5");
    if (std::abs(a.stemAxis.norm() - 1.0) > 1e-6) return fieldError(f + ".stem_axis", "must be a unit vector");
    for (int c = 0; c < 3; ++c)
      if (!(a.skinRgb(c) >= 0.0 && a.skinRgb(c) <= 1.0 && a.groundRgb(c) >= 0.0 && a.groundRgb(c) <= 1.0))
        return fieldError(f + ".skin_rgb", "albedos must be in 0..1");
  }
  for (size_t i = 0; i < leaves.size(); ++i) {
    const auto& l = leaves[i];
    const std::string f = "leaves[" + std::to_string(i) + "]";
    if (std::abs(l.normal.norm() - 1.0) > 1e-6 || std::abs(l.axis.norm() - 1.0) > 1e-6 || std::abs(l.normal.dot(l.axis)) > 1e-6)
      return fieldError(f, "normal and axis must be perpendicular unit vectors");
    if (!(l.lengthMm > 1.0 && l.widthMm > 1.0)) return fieldError(f + ".length_mm", "must be positive");
    if (!(l.centerMm.z() > 100.0)) return fieldError(f + ".center_mm", "must lie in front of the camera");
  }
  for (size_t i = 0; i < branches.size(); ++i) {
    const auto& b = branches[i];
    if (!(b.radiusMm > 0.5)) return fieldError("branches[" + std::to_string(i) + "].radius_mm", "must be > 0.5");
  }
  if (board) {
    const auto& b = *board;
    if (b.squaresX < 2 || b.squaresY < 2 || !(b.squareMm > 1.0)) return fieldError("board", "needs at least 2×2 squares of > 1 mm");
    if (!(std::abs(b.rotation.determinant() - 1.0) < 1e-6)) return fieldError("board.rotation", "must be a rotation");
  }
  if (!(background.depthMm > 500.0 && background.depthMm < 100000.0)) return fieldError("background.depth_mm", "must be in 500..100000");
  if (!(background.skyShare >= 0.0 && background.skyShare < 1.0)) return fieldError("background.sky_share", "must be in 0..1");
  if (!(lighting.diffuseLux >= 0.0 && lighting.directLux >= 0.0 && lighting.totalLux() < 200000.0))
    return fieldError("lighting", "illuminances must be in 0..200000 lux");
  if (std::abs(lighting.directDir.norm() - 1.0) > 1e-6) return fieldError("lighting.direct_dir", "must be a unit vector");
  const auto& las = laser;
  if (!(las.powerMw >= 0.0 && las.powerMw <= 1000.0)) return fieldError("laser.power_mw", "must be in 0..1000");
  if (!(las.fanDeg > 1.0 && las.fanDeg < 170.0)) return fieldError("laser.fan_deg", "must be in 1..170");
  if (!(las.sheetSigmaMrad > 0.01 && las.sheetSigmaMrad < 20.0)) return fieldError("laser.sheet_sigma_mrad", "must be in 0.01..20");
  if (!(las.haloShare >= 0.0 && las.haloShare < 1.0) || !(las.haloLengthMm > 0.01))
    return fieldError("laser.halo", "share must be in 0..1 and length > 0");
  if (!(las.speckleContrast >= 0.0 && las.speckleContrast <= 1.0)) return fieldError("laser.speckle_contrast", "must be in 0..1");
  if (std::abs(truth.laser.planeNormal.dot(las.originAtHomeMm) - truth.laser.planeOffsetMm) > 1e-3)
    return fieldError("laser.origin_at_home_mm", "must lie on the laser plane at home");
  const auto& s = sensor;
  if (!(s.fNumber >= 0.7 && s.fNumber <= 32.0)) return fieldError("sensor.f_number", "must be in 0.7..32");
  if (!(s.fullWellE > 100.0) || !(s.readNoiseE >= 0.0) || !(s.electronsPerLuxS > 0.0) || !(s.electronsPerWattS > 0.0))
    return fieldError("sensor", "needs positive full well, sensitivities and a non-negative read noise");
  if (!(s.gainDb >= 0.0 && s.gainDb <= 48.0)) return fieldError("sensor.gain_db", "must be in 0..48");
  if (!(s.psfSigmaPx >= 0.0 && s.psfSigmaPx <= 5.0)) return fieldError("sensor.psf_sigma_px", "must be in 0..5");
  if (s.exposureUs <= 0 || s.exposureUs > 1000000) return fieldError("sensor.exposure_us", "must be in 1..1000000");
  if (!(s.bandpassFwhmNm == 0.0 || (s.bandpassFwhmNm >= 5.0 && s.bandpassFwhmNm <= 80.0)))
    return fieldError("sensor.bandpass_fwhm_nm", "must be 0 (no filter) or in 5..80");
  if (!(s.bandpassPeak > 0.0 && s.bandpassPeak <= 1.0)) return fieldError("sensor.bandpass_peak", "must be in (0, 1]");
  if (!(s.bandpassCwlNm >= 600.0 && s.bandpassCwlNm <= 680.0))
    return fieldError("sensor.bandpass_cwl_nm", "must be in 600..680");
  if (!(s.bandpassNeff >= 1.0 && s.bandpassNeff <= 3.0)) return fieldError("sensor.bandpass_neff", "must be in 1..3");
  return Status::ok();
}

double SimSensor::laserFilter(double sin2Theta) const {
  if (bandpassFwhmNm <= 0.0) return 1.0;
  const double cwl = bandpassCwlNm * std::sqrt(std::max(0.0, 1.0 - sin2Theta / (bandpassNeff * bandpassNeff)));
  const double d = std::abs(635.0 - cwl) - (0.5 * bandpassFwhmNm - 1.0);  // beyond the flat top
  return bandpassPeak * std::clamp(1.0 - 0.5 * d, 0.0, 1.0);  // peak inside, 1/2 at FWHM/2, 0 beyond FWHM/2 + 1 nm
}

Eigen::Vector3d SimSensor::ambientFilterRgb() const {
  if (bandpassFwhmNm <= 0.0) return Eigen::Vector3d::Ones();
  // A flat-topped pass band of FWHM nm at 635 nm over a daylight spectrum that is flat
  // (±10 %) across 550-700 nm: channel c keeps peak · FWHM · s_c(635) / B_c of its ambient
  // signal, s_c(635) its response at 635 nm relative to its peak (the laser's channel
  // response 1, 0.08, 0.04) and B_c its equivalent bandwidth (∫ s_c dλ): red 80 nm
  // (575-655 nm between the colour filter's rise and the IR-cut filter), green and blue
  // 100 nm. Capped at 1.
  const double bw[3] = {80.0, 100.0, 100.0};
  const double resp[3] = {1.0, 0.08, 0.04};
  Eigen::Vector3d f;
  for (int c = 0; c < 3; ++c) f(c) = std::min(1.0, bandpassPeak * bandpassFwhmNm * resp[c] / bw[c]);
  return f;
}

const SimApple* SimScene::apple(int id) const {
  for (const auto& a : apples)
    if (a.id == id) return &a;
  return nullptr;
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
  s.laser.originAtHomeMm = Eigen::Vector3d(100.0, -60.0, 15.0);
  las.planeOffsetMm = las.planeNormal.dot(s.laser.originAtHomeMm);
  las.slideScale = 1.003;
  s.truth.quality.fromTruth = true;
  // A bright lab: a key lamp above, left and in front of the apple, and the room's light.
  s.lighting.name = "lab";
  s.lighting.diffuseLux = 900.0;
  s.lighting.directLux = 1100.0;
  s.lighting.directDir = Eigen::Vector3d(-0.3, -0.5, -0.8).normalized();
  s.background.kind = SimBackground::Kind::kBackdrop;
  s.background.depthMm = 2000.0;
  s.background.albedoRgb = Eigen::Vector3d(0.10, 0.16, 0.08);
  SimApple apple;
  apple.id = 1;
  apple.centerMm = Eigen::Vector3d(10.0, -20.0, 1200.0);
  apple.radiusMm = 40.0;
  s.apples.push_back(apple);
  return s;
}

Eigen::Matrix3d appleFrame(const SimApple& apple) {
  const Eigen::Vector3d z = apple.stemAxis.normalized();
  const Eigen::Vector3d x = z.unitOrthogonal();
  Eigen::Matrix3d r;
  r.col(0) = x;
  r.col(1) = z.cross(x);
  r.col(2) = z;
  return r;
}

Eigen::Vector3d appleNormal(const SimApple& apple, const Eigen::Vector3d& p) {
  const Eigen::Matrix3d r = appleFrame(apple);
  const Eigen::Vector3d l = r.transpose() * (p - apple.centerMm);
  const double a2 = apple.radiusMm * apple.radiusMm;
  const double c2 = a2 * apple.aspect * apple.aspect;
  return (r * Eigen::Vector3d(l.x() / a2, l.y() / a2, l.z() / c2)).normalized();
}

Eigen::Vector3d approachPoint(const SimApple& apple) {
  // Where the sight line to the centre enters the surface: x = t·ĉ with |S⁻¹Rᵀ(x - c)| = 1.
  const Eigen::Vector3d dir = apple.centerMm.normalized();
  const Eigen::Matrix3d r = appleFrame(apple);
  const Eigen::Vector3d inv(1.0 / apple.radiusMm, 1.0 / apple.radiusMm, 1.0 / (apple.radiusMm * apple.aspect));
  const Eigen::Vector3d d = (r.transpose() * dir).cwiseProduct(inv);
  // From the centre back along the sight line: |s·d| = 1.
  return apple.centerMm - dir / d.norm();
}

Eigen::Vector2d projectPx(const geometry::CameraIntrinsics& cam, const Eigen::Vector3d& p) {
  const double x = p.x() / p.z();
  const double y = p.y() / p.z();
  const double r2 = x * x + y * y;
  const auto& k = cam.distortion;  // k1 k2 p1 p2 k3
  const double radial = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]));
  const double xd = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x);
  const double yd = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y;
  return {cam.fxPx * xd + cam.cxPx, cam.fyPx * yd + cam.cyPx};
}

// ---- JSON -------------------------------------------------------------------------

namespace {

struct Reader {
  std::string error;
  double num(const cv::FileNode& n, const char* key, double fallback, const std::string& where) {
    const cv::FileNode v = n[key];
    if (v.empty() || v.isNone()) return fallback;
    if (!v.isReal() && !v.isInt()) {
      if (error.empty()) error = where + "." + key + " is not a number";
      return fallback;
    }
    return v.real();
  }
  Eigen::Vector3d vec3(const cv::FileNode& n, const char* key, const Eigen::Vector3d& fallback, const std::string& where) {
    const cv::FileNode v = n[key];
    if (v.empty() || v.isNone()) return fallback;
    if (!v.isSeq() || v.size() != 3 || !(v[0].isReal() || v[0].isInt()) || !(v[1].isReal() || v[1].isInt()) ||
        !(v[2].isReal() || v[2].isInt())) {
      if (error.empty()) error = where + "." + key + " must be an array of 3 numbers";
      return fallback;
    }
    return {v[0].real(), v[1].real(), v[2].real()};
  }
  std::string str(const cv::FileNode& n, const char* key, const std::string& fallback) {
    const cv::FileNode v = n[key];
    return v.isString() ? static_cast<std::string>(v) : fallback;
  }
};

void readCalibration(Reader& r, const cv::FileNode& root, geometry::Calibration& cal) {
  const cv::FileNode cam = root["camera"];
  if (cam.isMap()) {
    auto& c = cal.camera;
    c.widthPx = static_cast<int>(r.num(cam, "width_px", c.widthPx, "camera"));
    c.heightPx = static_cast<int>(r.num(cam, "height_px", c.heightPx, "camera"));
    c.fxPx = r.num(cam, "fx_px", c.fxPx, "camera");
    c.fyPx = r.num(cam, "fy_px", c.fyPx, "camera");
    c.cxPx = r.num(cam, "cx_px", c.cxPx, "camera");
    c.cyPx = r.num(cam, "cy_px", c.cyPx, "camera");
    const cv::FileNode d = cam["distortion"];
    if (d.isSeq() && d.size() == 5)
      for (int i = 0; i < 5; ++i) c.distortion[static_cast<size_t>(i)] = d[i].real();
  }
  const cv::FileNode las = root["laser_plane"];
  if (las.isMap()) {
    auto& l = cal.laser;
    l.planeNormal = r.vec3(las, "plane_normal", l.planeNormal, "laser_plane");
    l.planeOffsetMm = r.num(las, "plane_offset_mm", l.planeOffsetMm, "laser_plane");
    l.slideAxis = r.vec3(las, "slide_axis", l.slideAxis, "laser_plane");
    l.slideScale = r.num(las, "slide_scale", l.slideScale, "laser_plane");
  }
}

}  // namespace

Result<SimScene> loadScene(const std::string& path) {
  Result<cv::FileStorage> file = openJsonFile(path, "scene file");
  if (!file) return file.status();
  cv::FileStorage& fs = *file;
  SimScene s = defaultScene();
  const cv::FileNode root = fs.root();
  Reader r;
  s.seed = static_cast<uint64_t>(r.num(root, "seed", static_cast<double>(s.seed), "scene"));
  const bool hadPlane = root["laser_plane"].isMap();
  readCalibration(r, root, s.truth);
  const cv::FileNode las = root["laser"];
  if (las.isMap()) {
    auto& l = s.laser;
    l.originAtHomeMm = r.vec3(las, "origin_at_home_mm", l.originAtHomeMm, "laser");
    l.powerMw = r.num(las, "power_mw", l.powerMw, "laser");
    l.fanDeg = r.num(las, "fan_deg", l.fanDeg, "laser");
    l.sheetSigmaMrad = r.num(las, "sheet_sigma_mrad", l.sheetSigmaMrad, "laser");
    l.channelResponse = r.vec3(las, "channel_response", l.channelResponse, "laser");
    l.haloShare = r.num(las, "halo_share", l.haloShare, "laser");
    l.haloLengthMm = r.num(las, "halo_length_mm", l.haloLengthMm, "laser");
    l.speckleContrast = r.num(las, "speckle_contrast", l.speckleContrast, "laser");
    l.speckleCellPx = r.num(las, "speckle_cell_px", l.speckleCellPx, "laser");
  }
  if (!hadPlane) s.truth.laser.planeOffsetMm = s.truth.laser.planeNormal.dot(s.laser.originAtHomeMm);
  const cv::FileNode sen = root["sensor"];
  if (sen.isMap()) {
    auto& x = s.sensor;
    x.fNumber = r.num(sen, "f_number", x.fNumber, "sensor");
    x.lensTransmission = r.num(sen, "lens_transmission", x.lensTransmission, "sensor");
    x.electronsPerLuxS = r.num(sen, "electrons_per_lux_s", x.electronsPerLuxS, "sensor");
    x.electronsPerWattS = r.num(sen, "electrons_per_watt_s", x.electronsPerWattS, "sensor");
    x.fullWellE = r.num(sen, "full_well_e", x.fullWellE, "sensor");
    x.readNoiseE = r.num(sen, "read_noise_e", x.readNoiseE, "sensor");
    x.gainDb = r.num(sen, "gain_db", x.gainDb, "sensor");
    x.prnu = r.num(sen, "prnu", x.prnu, "sensor");
    x.psfSigmaPx = r.num(sen, "psf_sigma_px", x.psfSigmaPx, "sensor");
    x.bayer = r.num(sen, "bayer", x.bayer ? 1 : 0, "sensor") != 0.0;
    x.vignetting = r.num(sen, "vignetting", x.vignetting ? 1 : 0, "sensor") != 0.0;
    x.exposureUs = static_cast<int64_t>(r.num(sen, "exposure_us", static_cast<double>(x.exposureUs), "sensor"));
    x.bandpassFwhmNm = r.num(sen, "bandpass_fwhm_nm", x.bandpassFwhmNm, "sensor");
    x.bandpassPeak = r.num(sen, "bandpass_peak", x.bandpassPeak, "sensor");
    x.bandpassCwlNm = r.num(sen, "bandpass_cwl_nm", x.bandpassCwlNm, "sensor");
    x.bandpassNeff = r.num(sen, "bandpass_neff", x.bandpassNeff, "sensor");
  }
  const cv::FileNode li = root["lighting"];
  if (li.isMap()) {
    auto& l = s.lighting;
    l.name = r.str(li, "name", l.name);
    l.diffuseLux = r.num(li, "diffuse_lux", l.diffuseLux, "lighting");
    l.directLux = r.num(li, "direct_lux", l.directLux, "lighting");
    l.directDir = r.vec3(li, "direct_dir", l.directDir, "lighting").normalized();
    l.skyRgb = r.vec3(li, "sky_rgb", l.skyRgb, "lighting");
    l.skyLuminanceFactor = r.num(li, "sky_luminance_factor", l.skyLuminanceFactor, "lighting");
  }
  const cv::FileNode bg = root["background"];
  if (bg.isMap()) {
    auto& b = s.background;
    const std::string kind = r.str(bg, "kind", b.kind == SimBackground::Kind::kFoliage ? "foliage" : "backdrop");
    if (kind != "foliage" && kind != "backdrop") return fieldError("background.kind", "must be \"foliage\" or \"backdrop\"");
    b.kind = kind == "foliage" ? SimBackground::Kind::kFoliage : SimBackground::Kind::kBackdrop;
    b.depthMm = r.num(bg, "depth_mm", b.depthMm, "background");
    b.skyShare = r.num(bg, "sky_share", b.skyShare, "background");
    b.albedoRgb = r.vec3(bg, "albedo_rgb", b.albedoRgb, "background");
    b.textureCellMm = r.num(bg, "texture_cell_mm", b.textureCellMm, "background");
  }
  // The first scene format had the wall's depth at the top level.
  s.background.depthMm = r.num(root, "background_depth_mm", s.background.depthMm, "scene");
  const cv::FileNode apples = root["apples"];
  if (apples.isSeq()) {
    s.apples.clear();
    int id = 1;
    for (auto it = apples.begin(); it != apples.end(); ++it, ++id) {
      SimApple a;
      const std::string w = "apples[" + std::to_string(id - 1) + "]";
      a.id = static_cast<int>(r.num(*it, "id", id, w));
      a.centerMm = r.vec3(*it, "center_mm", a.centerMm, w);
      a.radiusMm = r.num(*it, "radius_mm", a.radiusMm, w);
      a.aspect = r.num(*it, "aspect", a.aspect, w);
      a.stemAxis = r.vec3(*it, "stem_axis", a.stemAxis, w).normalized();
      a.skinRgb = r.vec3(*it, "skin_rgb", a.skinRgb, w);
      a.groundRgb = r.vec3(*it, "ground_rgb", a.groundRgb, w);
      a.blush = r.num(*it, "blush", a.blush, w);
      a.blushAxis = r.vec3(*it, "blush_axis", a.blushAxis, w);
      a.specular = r.num(*it, "specular", a.specular, w);
      a.shininess = r.num(*it, "shininess", a.shininess, w);
      s.apples.push_back(a);
    }
  }
  const cv::FileNode leaves = root["leaves"];
  if (leaves.isSeq()) {
    int i = 0;
    for (auto it = leaves.begin(); it != leaves.end(); ++it, ++i) {
      SimLeaf l;
      const std::string w = "leaves[" + std::to_string(i) + "]";
      l.centerMm = r.vec3(*it, "center_mm", l.centerMm, w);
      l.normal = r.vec3(*it, "normal", l.normal, w).normalized();
      l.axis = r.vec3(*it, "axis", l.axis, w);
      l.axis = (l.axis - l.axis.dot(l.normal) * l.normal).normalized();
      l.lengthMm = r.num(*it, "length_mm", l.lengthMm, w);
      l.widthMm = r.num(*it, "width_mm", l.widthMm, w);
      l.albedoRgb = r.vec3(*it, "albedo_rgb", l.albedoRgb, w);
      s.leaves.push_back(l);
    }
  }
  const cv::FileNode branches = root["branches"];
  if (branches.isSeq()) {
    int i = 0;
    for (auto it = branches.begin(); it != branches.end(); ++it, ++i) {
      SimBranch b;
      const std::string w = "branches[" + std::to_string(i) + "]";
      b.aMm = r.vec3(*it, "a_mm", b.aMm, w);
      b.bMm = r.vec3(*it, "b_mm", b.bMm, w);
      b.radiusMm = r.num(*it, "radius_mm", b.radiusMm, w);
      b.albedoRgb = r.vec3(*it, "albedo_rgb", b.albedoRgb, w);
      s.branches.push_back(b);
    }
  }
  const cv::FileNode board = root["board"];
  if (board.isMap()) {
    SimBoard b;
    const cv::FileNode rot = board["rotation"];
    if (rot.isSeq() && rot.size() == 9)
      for (int i = 0; i < 9; ++i) b.rotation(i / 3, i % 3) = rot[i].real();
    b.originMm = r.vec3(board, "origin_mm", b.originMm, "board");
    b.squaresX = static_cast<int>(r.num(board, "squares_x", b.squaresX, "board"));
    b.squaresY = static_cast<int>(r.num(board, "squares_y", b.squaresY, "board"));
    b.squareMm = r.num(board, "square_mm", b.squareMm, "board");
    b.marginMm = r.num(board, "margin_mm", b.marginMm, "board");
    b.checkerboard = r.num(board, "checkerboard", b.checkerboard ? 1 : 0, "board") != 0.0;
    b.whiteAlbedo = r.num(board, "white_albedo", b.whiteAlbedo, "board");
    b.blackAlbedo = r.num(board, "black_albedo", b.blackAlbedo, "board");
    s.board = b;
  }
  if (!r.error.empty()) return Status(Error::kBadInput, "scene file '" + path + "': " + r.error);
  if (Status st = s.validate(); !st) return st;
  return s;
}

namespace {
std::string v3(const Eigen::Vector3d& v) {
  char buf[128];
  std::snprintf(buf, sizeof buf, "[%.10g, %.10g, %.10g]", v.x(), v.y(), v.z());
  return buf;
}
}  // namespace

std::string sceneJson(const SimScene& s) {
  std::ostringstream o;
  o.precision(10);
  const auto& c = s.truth.camera;
  const auto& l = s.truth.laser;
  o << "{\n  \"format\": \"alacs-scene/1\",\n  \"seed\": " << s.seed << ",\n";
  o << "  \"camera\": {\"width_px\": " << c.widthPx << ", \"height_px\": " << c.heightPx << ", \"fx_px\": " << c.fxPx
    << ", \"fy_px\": " << c.fyPx << ", \"cx_px\": " << c.cxPx << ", \"cy_px\": " << c.cyPx << ", \"distortion\": ["
    << c.distortion[0] << ", " << c.distortion[1] << ", " << c.distortion[2] << ", " << c.distortion[3] << ", "
    << c.distortion[4] << "]},\n";
  o.precision(14);
  o << "  \"laser_plane\": {\"plane_normal\": " << v3(l.planeNormal) << ", \"plane_offset_mm\": " << l.planeOffsetMm
    << ", \"slide_axis\": " << v3(l.slideAxis) << ", \"slide_scale\": " << l.slideScale << "},\n";
  o.precision(10);
  const auto& las = s.laser;
  o << "  \"laser\": {\"origin_at_home_mm\": " << v3(las.originAtHomeMm) << ", \"power_mw\": " << las.powerMw
    << ", \"fan_deg\": " << las.fanDeg << ", \"sheet_sigma_mrad\": " << las.sheetSigmaMrad
    << ", \"channel_response\": " << v3(las.channelResponse) << ", \"halo_share\": " << las.haloShare
    << ", \"halo_length_mm\": " << las.haloLengthMm << ", \"speckle_contrast\": " << las.speckleContrast
    << ", \"speckle_cell_px\": " << las.speckleCellPx << "},\n";
  const auto& x = s.sensor;
  o << "  \"sensor\": {\"f_number\": " << x.fNumber << ", \"lens_transmission\": " << x.lensTransmission
    << ", \"electrons_per_lux_s\": " << x.electronsPerLuxS << ", \"electrons_per_watt_s\": " << x.electronsPerWattS
    << ", \"full_well_e\": " << x.fullWellE << ", \"read_noise_e\": " << x.readNoiseE << ", \"gain_db\": " << x.gainDb
    << ", \"prnu\": " << x.prnu << ", \"psf_sigma_px\": " << x.psfSigmaPx << ", \"bayer\": " << (x.bayer ? 1 : 0)
    << ", \"vignetting\": " << (x.vignetting ? 1 : 0) << ", \"exposure_us\": " << x.exposureUs
    << ", \"bandpass_fwhm_nm\": " << x.bandpassFwhmNm << ", \"bandpass_peak\": " << x.bandpassPeak
    << ", \"bandpass_cwl_nm\": " << x.bandpassCwlNm << ", \"bandpass_neff\": " << x.bandpassNeff << "},\n";
  const auto& li = s.lighting;
  o << "  \"lighting\": {\"name\": \"" << li.name << "\", \"diffuse_lux\": " << li.diffuseLux
    << ", \"direct_lux\": " << li.directLux << ", \"direct_dir\": " << v3(li.directDir) << ", \"sky_rgb\": "
    << v3(li.skyRgb) << ", \"sky_luminance_factor\": " << li.skyLuminanceFactor << "},\n";
  const auto& b = s.background;
  o << "  \"background\": {\"kind\": \"" << (b.kind == SimBackground::Kind::kFoliage ? "foliage" : "backdrop")
    << "\", \"depth_mm\": " << b.depthMm << ", \"sky_share\": " << b.skyShare << ", \"albedo_rgb\": " << v3(b.albedoRgb)
    << ", \"texture_cell_mm\": " << b.textureCellMm << "},\n";
  o << "  \"apples\": [";
  for (size_t i = 0; i < s.apples.size(); ++i) {
    const auto& a = s.apples[i];
    o << (i ? ",\n" : "\n") << "    {\"id\": " << a.id << ", \"center_mm\": " << v3(a.centerMm)
      << ", \"radius_mm\": " << a.radiusMm << ", \"aspect\": " << a.aspect << ", \"stem_axis\": " << v3(a.stemAxis)
      << ", \"approach_mm\": " << v3(approachPoint(a))
      << ", \"skin_rgb\": " << v3(a.skinRgb) << ", \"ground_rgb\": " << v3(a.groundRgb) << ", \"blush\": " << a.blush
      << ", \"blush_axis\": " << v3(a.blushAxis) << ", \"specular\": " << a.specular << ", \"shininess\": "
      << a.shininess << "}";
  }
  o << (s.apples.empty() ? "],\n" : "\n  ],\n");
  o << "  \"leaves\": [";
  for (size_t i = 0; i < s.leaves.size(); ++i) {
    const auto& l2 = s.leaves[i];
    o << (i ? ",\n" : "\n") << "    {\"center_mm\": " << v3(l2.centerMm) << ", \"normal\": " << v3(l2.normal)
      << ", \"axis\": " << v3(l2.axis) << ", \"length_mm\": " << l2.lengthMm << ", \"width_mm\": " << l2.widthMm
      << ", \"albedo_rgb\": " << v3(l2.albedoRgb) << "}";
  }
  o << (s.leaves.empty() ? "],\n" : "\n  ],\n");
  o << "  \"branches\": [";
  for (size_t i = 0; i < s.branches.size(); ++i) {
    const auto& br = s.branches[i];
    o << (i ? ",\n" : "\n") << "    {\"a_mm\": " << v3(br.aMm) << ", \"b_mm\": " << v3(br.bMm)
      << ", \"radius_mm\": " << br.radiusMm << ", \"albedo_rgb\": " << v3(br.albedoRgb) << "}";
  }
  o << (s.branches.empty() ? "]" : "\n  ]");
  if (s.board) {
    const auto& bd = *s.board;
    o << ",\n  \"board\": {\"rotation\": [";
    for (int i = 0; i < 9; ++i) o << (i ? ", " : "") << bd.rotation(i / 3, i % 3);
    o << "], \"origin_mm\": " << v3(bd.originMm) << ", \"squares_x\": " << bd.squaresX << ", \"squares_y\": "
      << bd.squaresY << ", \"square_mm\": " << bd.squareMm << ", \"margin_mm\": " << bd.marginMm
      << ", \"checkerboard\": " << (bd.checkerboard ? 1 : 0) << ", \"white_albedo\": " << bd.whiteAlbedo
      << ", \"black_albedo\": " << bd.blackAlbedo << "}";
  }
  o << "\n}\n";
  return o.str();
}

Status saveScene(const SimScene& scene, const std::string& path) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    if (!out) return {Error::kIo, "cannot write '" + tmp + "'"};
    out << sceneJson(scene);
    out.flush();
    if (!out) return {Error::kIo, "cannot write '" + tmp + "'"};
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return {Error::kIo, "cannot rename to '" + path + "'"};
  return Status::ok();
}

Status saveSceneTruth(const SimScene& scene, const std::string& path) { return saveScene(scene, path); }

}  // namespace alacs::sim
