#include "sim/scene.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>

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
    if (!(a.lumpAmplitude >= 0.0 && a.lumpAmplitude <= 0.15))
      return fieldError(f + ".lump_amplitude", "must be in 0..0.15");
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

double SimSensor::analogueGain() const { return std::pow(10.0, gainDb / 20.0); }

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

AppleShape::AppleShape(const SimApple& apple)
    : center_(apple.centerMm),
      frame_(appleFrame(apple)),
      axes_(apple.radiusMm, apple.radiusMm, apple.radiusMm * apple.aspect),
      amplitude_(apple.lumpAmplitude) {
  if (!lumpy()) return;
  // The pattern's own generator (not the scene's), so that a seed always means one shape.
  std::mt19937_64 rng(apple.lumpSeed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  ridgePhase_ = 2.0 * M_PI * unit(rng);
  for (int k = 0; k < kBumps; ++k) {
    const double z = 2.0 * unit(rng) - 1.0;
    const double phi = 2.0 * M_PI * unit(rng);
    const double rxy = std::sqrt(std::max(0.0, 1.0 - z * z));
    bumpDir_[static_cast<size_t>(k)] = Eigen::Vector3d(rxy * std::cos(phi), rxy * std::sin(phi), z);
    bumpSign_[static_cast<size_t>(k)] = (k % 2 == 0 ? 1.0 : -1.0) * (0.6 + 0.4 * unit(rng));
  }
}

double AppleShape::radialFactor(const Eigen::Vector3d& w) const {
  if (!lumpy()) return 1.0;
  // Five ridges round the stem (z), strongest at the equator: cos(5φ)·sin²θ.
  const double sin2 = std::max(0.0, 1.0 - w.z() * w.z());
  const double phi = std::atan2(w.y(), w.x());
  double h = 0.5 * std::cos(5.0 * phi + ridgePhase_) * sin2;
  // Bumps and dents about 20° across: exp(κ(cos γ - 1)), κ = 10.
  for (int k = 0; k < kBumps; ++k)
    h += 0.5 * bumpSign_[static_cast<size_t>(k)] * std::exp(10.0 * (w.dot(bumpDir_[static_cast<size_t>(k)]) - 1.0));
  return 1.0 + amplitude_ * std::tanh(h);  // |tanh| < 1 keeps the bound
}

Eigen::Vector3d AppleShape::toScaled(const Eigen::Vector3d& p) const {
  return (frame_.transpose() * (p - center_)).cwiseQuotient(axes_);
}

Eigen::Vector3d AppleShape::fromScaled(const Eigen::Vector3d& u) const {
  return center_ + frame_ * u.cwiseProduct(axes_);
}

Eigen::Vector3d AppleShape::normal(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d u = toScaled(p);
  Eigen::Vector3d grad = u;  // the ellipsoid: ∇|u| ∝ u
  if (lumpy()) {
    // F(u) = |u| - radialFactor(û), by central differences (h is smooth; 1e-6 of the unit radius).
    const auto f = [&](const Eigen::Vector3d& x) { return x.norm() - radialFactor(x.normalized()); };
    constexpr double kStep = 1e-6;
    for (int i = 0; i < 3; ++i) {
      Eigen::Vector3d a = u;
      Eigen::Vector3d b = u;
      a(i) += kStep;
      b(i) -= kStep;
      grad(i) = (f(a) - f(b)) / (2.0 * kStep);
    }
  }
  // p = c + R·S·u: ∇ₚF = R·S⁻¹·∇ᵤF.
  return (frame_ * grad.cwiseQuotient(axes_)).normalized();
}

namespace {
// Entry and exit of origin + t·dir through the sphere |u| = radius; false if it misses.
bool sphereSpan(const Eigen::Vector3d& ol, const Eigen::Vector3d& dl, double radius, double* t0, double* t1) {
  const double qa = dl.squaredNorm();
  const double b = ol.dot(dl);
  const double disc = b * b - qa * (ol.squaredNorm() - radius * radius);
  if (disc < 0.0) return false;
  const double s = std::sqrt(disc);
  *t0 = (-b - s) / qa;
  *t1 = (-b + s) / qa;
  return true;
}
}  // namespace

bool AppleShape::intersectScaled(const Eigen::Vector3d& ol, const Eigen::Vector3d& dl, double tMin, double tMax,
                                 double* t) const {
  double t0 = 0.0;
  double t1 = 0.0;
  if (!sphereSpan(ol, dl, 1.0 + amplitude_, &t0, &t1)) return false;
  if (!lumpy()) {
    *t = t0 > tMin ? t0 : t1;
    return *t > tMin && *t < tMax;
  }
  // The first sign change of G(t) = |u(t)| - radialFactor(û(t)) between the bounding
  // spheres, found by marching (32 steps over the span, finer than the pattern's 20°
  // features at any distance) and refined by bisection.
  const double lo = std::max(t0, tMin);
  const double hi = std::min(t1, tMax);
  if (!(lo < hi)) return false;
  const auto g = [&](double s) {
    const Eigen::Vector3d u = ol + s * dl;
    const double n = u.norm();
    return n < 1e-12 ? -1.0 : n - radialFactor(u / n);
  };
  constexpr int kSteps = 32;
  double a = lo;
  double ga = g(a);
  for (int k = 1; k <= kSteps; ++k) {
    double b = lo + (hi - lo) * k / kSteps;
    const double gb = g(b);
    if ((ga < 0.0) != (gb < 0.0)) {
      for (int it = 0; it < 60; ++it) {
        const double m = 0.5 * (a + b);
        const double gm = g(m);
        if ((gm < 0.0) == (ga < 0.0)) {
          a = m;
          ga = gm;
        } else {
          b = m;
        }
      }
      *t = 0.5 * (a + b);
      return *t > tMin && *t < tMax;
    }
    a = b;
    ga = gb;
  }
  return false;
}

Eigen::Vector3d appleNormal(const SimApple& apple, const Eigen::Vector3d& p) {
  if (apple.lumpAmplitude > 0.0) return AppleShape(apple).normal(p);
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
  // From the centre back along the sight line: |s·d| = radialFactor(-d̂) (1 on the ellipsoid).
  const double rho = apple.lumpAmplitude > 0.0 ? AppleShape(apple).radialFactor(-d.normalized()) : 1.0;
  return apple.centerMm - dir * rho / d.norm();
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

constexpr size_t kMaxApples = 1000;
constexpr size_t kMaxLeaves = 100000;
constexpr size_t kMaxBranches = 10000;

void vec3(JsonObjectReader& r, std::string_view key, Eigen::Vector3d& out) {
  std::array<double, 3> v{};
  if (r.numbers(key, v)) out = {v[0], v[1], v[2]};
}

// A direction: normalized, refused when zero (or its normalization is not finite).
void direction(JsonObjectReader& r, std::string_view key, Eigen::Vector3d& out) {
  Eigen::Vector3d v = out;
  vec3(r, key, v);
  if (!(v.norm() > 1e-9) || !v.normalized().allFinite()) {
    r.fail(key, "must be a non-zero vector");
    return;
  }
  out = v.normalized();
}

OrderedJson vec3Json(const Eigen::Vector3d& v) { return OrderedJson::array({v.x(), v.y(), v.z()}); }

void readLaser(JsonObjectReader& r, SimLaser& l) {
  vec3(r, "origin_at_home_mm", l.originAtHomeMm);
  r.number("power_mw", l.powerMw);
  r.number("fan_deg", l.fanDeg);
  r.number("sheet_sigma_mrad", l.sheetSigmaMrad);
  vec3(r, "channel_response", l.channelResponse);
  r.number("halo_share", l.haloShare);
  r.number("halo_length_mm", l.haloLengthMm);
  r.number("speckle_contrast", l.speckleContrast);
  r.number("speckle_cell_px", l.speckleCellPx);
  r.finish();
}

void readSensor(JsonObjectReader& r, SimSensor& x) {
  r.number("f_number", x.fNumber);
  r.number("lens_transmission", x.lensTransmission);
  r.number("electrons_per_lux_s", x.electronsPerLuxS);
  r.number("electrons_per_watt_s", x.electronsPerWattS);
  r.number("full_well_e", x.fullWellE);
  r.number("read_noise_e", x.readNoiseE);
  r.number("gain_db", x.gainDb);
  r.number("prnu", x.prnu);
  r.number("psf_sigma_px", x.psfSigmaPx);
  r.flag("bayer", x.bayer);
  r.flag("vignetting", x.vignetting);
  r.integer("exposure_us", x.exposureUs, Need::kOptional, 1, 1000000);
  r.number("bandpass_fwhm_nm", x.bandpassFwhmNm);
  r.number("bandpass_peak", x.bandpassPeak);
  r.number("bandpass_cwl_nm", x.bandpassCwlNm);
  r.number("bandpass_neff", x.bandpassNeff);
  r.finish();
}

void readLighting(JsonObjectReader& r, SimLighting& l) {
  r.text("name", l.name, Need::kOptional, 256);
  r.number("diffuse_lux", l.diffuseLux);
  r.number("direct_lux", l.directLux);
  direction(r, "direct_dir", l.directDir);
  vec3(r, "sky_rgb", l.skyRgb);
  r.number("sky_luminance_factor", l.skyLuminanceFactor);
  r.finish();
}

void readBackground(JsonObjectReader& r, SimBackground& b) {
  std::string kind;
  if (r.text("kind", kind)) {
    if (kind == "foliage") {
      b.kind = SimBackground::Kind::kFoliage;
    } else if (kind == "backdrop") {
      b.kind = SimBackground::Kind::kBackdrop;
    } else {
      r.fail("kind", "must be \"foliage\" or \"backdrop\"");
    }
  }
  r.number("depth_mm", b.depthMm);
  r.number("sky_share", b.skyShare);
  vec3(r, "albedo_rgb", b.albedoRgb);
  r.number("texture_cell_mm", b.textureCellMm);
  r.finish();
}

void readApple(JsonObjectReader& r, SimApple& a) {
  r.integer("id", a.id);
  vec3(r, "center_mm", a.centerMm);
  r.number("radius_mm", a.radiusMm);
  r.number("aspect", a.aspect);
  r.number("lump_amplitude", a.lumpAmplitude);
  r.unsignedInteger("lump_seed", a.lumpSeed);
  direction(r, "stem_axis", a.stemAxis);
  r.allow("approach_mm");  // written for people and the evaluation; derived, never read back
  vec3(r, "skin_rgb", a.skinRgb);
  vec3(r, "ground_rgb", a.groundRgb);
  r.number("blush", a.blush);
  vec3(r, "blush_axis", a.blushAxis);
  r.number("specular", a.specular);
  r.number("shininess", a.shininess);
  r.finish();
}

void readLeaf(JsonObjectReader& r, SimLeaf& l) {
  vec3(r, "center_mm", l.centerMm);
  direction(r, "normal", l.normal);
  vec3(r, "axis", l.axis);
  const Eigen::Vector3d along = l.axis - l.axis.dot(l.normal) * l.normal;
  if (r.ok() && !(along.norm() > 1e-9 * std::max(1.0, l.axis.norm())))
    r.fail("axis", "must not be parallel to the normal");
  else
    l.axis = along.normalized();
  r.number("length_mm", l.lengthMm);
  r.number("width_mm", l.widthMm);
  vec3(r, "albedo_rgb", l.albedoRgb);
  r.finish();
}

void readBranch(JsonObjectReader& r, SimBranch& b) {
  vec3(r, "a_mm", b.aMm);
  vec3(r, "b_mm", b.bMm);
  r.number("radius_mm", b.radiusMm);
  vec3(r, "albedo_rgb", b.albedoRgb);
  r.finish();
}

void readBoard(JsonObjectReader& r, SimBoard& b) {
  std::array<double, 9> rot{};
  if (r.numbers("rotation", rot))
    for (size_t i = 0; i < 9; ++i) b.rotation(static_cast<Eigen::Index>(i / 3), static_cast<Eigen::Index>(i % 3)) = rot[i];
  vec3(r, "origin_mm", b.originMm);
  r.integer("squares_x", b.squaresX, Need::kOptional, 2, 1000);
  r.integer("squares_y", b.squaresY, Need::kOptional, 2, 1000);
  r.number("square_mm", b.squareMm);
  r.number("margin_mm", b.marginMm);
  r.flag("checkerboard", b.checkerboard);
  r.number("white_albedo", b.whiteAlbedo);
  r.number("black_albedo", b.blackAlbedo);
  r.finish();
}

// An array of objects at `key`, each read by `read` into a default T.
template <typename T, typename Read>
void readList(JsonObjectReader& root, const char* key, size_t maxCount, std::vector<T>& out, Read read) {
  const Json* list = root.array(key, maxCount);
  if (list == nullptr) return;
  std::vector<T> items;
  items.reserve(list->size());
  for (size_t i = 0; i < list->size(); ++i) {
    JsonObjectReader e = root.element(key, *list, i);
    T item;
    if (e.ok()) read(e, item, i);
    items.push_back(item);
  }
  out = std::move(items);
}

}  // namespace

Status sceneFromJson(const Json& json, SimScene& s) {
  JsonErrors errors("scene");
  JsonObjectReader root(errors, &json, "");
  std::string format = "alacs-scene/1";
  if (root.text("format", format) && format != "alacs-scene/1") root.fail("format", "must be \"alacs-scene/1\"");
  root.unsignedInteger("seed", s.seed);
  // The camera and the laser plane follow the calibration's schema (geometry's reader):
  // when present, every field is required.
  if (auto cam = root.object("camera")) geometry::cameraFromJson(*cam, s.truth.camera);
  const bool hadPlane = root.has("laser_plane");
  if (auto plane = root.object("laser_plane")) geometry::laserFromJson(*plane, s.truth.laser);
  if (auto las = root.object("laser")) readLaser(*las, s.laser);
  if (!hadPlane) s.truth.laser.planeOffsetMm = s.truth.laser.planeNormal.dot(s.laser.originAtHomeMm);
  if (auto sen = root.object("sensor")) readSensor(*sen, s.sensor);
  if (auto li = root.object("lighting")) readLighting(*li, s.lighting);
  if (auto bg = root.object("background")) readBackground(*bg, s.background);
  // The first scene format had the wall's depth at the top level.
  root.number("background_depth_mm", s.background.depthMm);
  readList(root, "apples", kMaxApples, s.apples, [](JsonObjectReader& r, SimApple& a, size_t i) {
    a.id = static_cast<int>(i) + 1;
    readApple(r, a);
  });
  readList(root, "leaves", kMaxLeaves, s.leaves, [](JsonObjectReader& r, SimLeaf& l, size_t) { readLeaf(r, l); });
  readList(root, "branches", kMaxBranches, s.branches,
           [](JsonObjectReader& r, SimBranch& b, size_t) { readBranch(r, b); });
  if (auto board = root.object("board")) {
    SimBoard b;
    readBoard(*board, b);
    s.board = b;
  }
  root.finish();
  return errors.status();
}

Result<SimScene> loadScene(const std::string& path) {
  Result<Json> file = readJsonFile(path, "scene file", kSceneMaxBytes);
  if (!file) return file.status();
  SimScene s = defaultScene();
  if (Status st = sceneFromJson(*file, s); !st) return Status(st.code(), "scene file '" + path + "': " + st.reason());
  if (Status st = s.validate(); !st) return st;
  return s;
}

OrderedJson sceneToJson(const SimScene& s) {
  OrderedJson j;
  j["format"] = "alacs-scene/1";
  j["seed"] = s.seed;
  j["camera"] = geometry::cameraToJson(s.truth.camera);
  j["laser_plane"] = geometry::laserToJson(s.truth.laser);
  const auto& las = s.laser;
  j["laser"] = {{"origin_at_home_mm", vec3Json(las.originAtHomeMm)},
                {"power_mw", las.powerMw},
                {"fan_deg", las.fanDeg},
                {"sheet_sigma_mrad", las.sheetSigmaMrad},
                {"channel_response", vec3Json(las.channelResponse)},
                {"halo_share", las.haloShare},
                {"halo_length_mm", las.haloLengthMm},
                {"speckle_contrast", las.speckleContrast},
                {"speckle_cell_px", las.speckleCellPx}};
  const auto& x = s.sensor;
  j["sensor"] = {{"f_number", x.fNumber},
                 {"lens_transmission", x.lensTransmission},
                 {"electrons_per_lux_s", x.electronsPerLuxS},
                 {"electrons_per_watt_s", x.electronsPerWattS},
                 {"full_well_e", x.fullWellE},
                 {"read_noise_e", x.readNoiseE},
                 {"gain_db", x.gainDb},
                 {"prnu", x.prnu},
                 {"psf_sigma_px", x.psfSigmaPx},
                 {"bayer", x.bayer ? 1 : 0},
                 {"vignetting", x.vignetting ? 1 : 0},
                 {"exposure_us", x.exposureUs},
                 {"bandpass_fwhm_nm", x.bandpassFwhmNm},
                 {"bandpass_peak", x.bandpassPeak},
                 {"bandpass_cwl_nm", x.bandpassCwlNm},
                 {"bandpass_neff", x.bandpassNeff}};
  const auto& li = s.lighting;
  j["lighting"] = {{"name", li.name},
                   {"diffuse_lux", li.diffuseLux},
                   {"direct_lux", li.directLux},
                   {"direct_dir", vec3Json(li.directDir)},
                   {"sky_rgb", vec3Json(li.skyRgb)},
                   {"sky_luminance_factor", li.skyLuminanceFactor}};
  const auto& b = s.background;
  j["background"] = {{"kind", b.kind == SimBackground::Kind::kFoliage ? "foliage" : "backdrop"},
                     {"depth_mm", b.depthMm},
                     {"sky_share", b.skyShare},
                     {"albedo_rgb", vec3Json(b.albedoRgb)},
                     {"texture_cell_mm", b.textureCellMm}};
  OrderedJson apples = OrderedJson::array();
  for (const auto& a : s.apples)
    apples.push_back({{"id", a.id},
                      {"center_mm", vec3Json(a.centerMm)},
                      {"radius_mm", a.radiusMm},
                      {"aspect", a.aspect},
                      {"lump_amplitude", a.lumpAmplitude},
                      {"lump_seed", a.lumpSeed},
                      {"stem_axis", vec3Json(a.stemAxis)},
                      {"approach_mm", vec3Json(approachPoint(a))},
                      {"skin_rgb", vec3Json(a.skinRgb)},
                      {"ground_rgb", vec3Json(a.groundRgb)},
                      {"blush", a.blush},
                      {"blush_axis", vec3Json(a.blushAxis)},
                      {"specular", a.specular},
                      {"shininess", a.shininess}});
  j["apples"] = std::move(apples);
  OrderedJson leaves = OrderedJson::array();
  for (const auto& l : s.leaves)
    leaves.push_back({{"center_mm", vec3Json(l.centerMm)},
                      {"normal", vec3Json(l.normal)},
                      {"axis", vec3Json(l.axis)},
                      {"length_mm", l.lengthMm},
                      {"width_mm", l.widthMm},
                      {"albedo_rgb", vec3Json(l.albedoRgb)}});
  j["leaves"] = std::move(leaves);
  OrderedJson branches = OrderedJson::array();
  for (const auto& br : s.branches)
    branches.push_back({{"a_mm", vec3Json(br.aMm)},
                        {"b_mm", vec3Json(br.bMm)},
                        {"radius_mm", br.radiusMm},
                        {"albedo_rgb", vec3Json(br.albedoRgb)}});
  j["branches"] = std::move(branches);
  if (s.board) {
    const auto& bd = *s.board;
    OrderedJson rot = OrderedJson::array();
    for (int i = 0; i < 9; ++i) rot.push_back(bd.rotation(i / 3, i % 3));
    j["board"] = {{"rotation", std::move(rot)},
                  {"origin_mm", vec3Json(bd.originMm)},
                  {"squares_x", bd.squaresX},
                  {"squares_y", bd.squaresY},
                  {"square_mm", bd.squareMm},
                  {"margin_mm", bd.marginMm},
                  {"checkerboard", bd.checkerboard ? 1 : 0},
                  {"white_albedo", bd.whiteAlbedo},
                  {"black_albedo", bd.blackAlbedo}};
  }
  return j;
}

std::string sceneJson(const SimScene& s) { return jsonText(sceneToJson(s)); }

Status saveScene(const SimScene& scene, const std::string& path) {
  return geometry::writeFileAtomically(path, sceneJson(scene));
}

Status saveSceneTruth(const SimScene& scene, const std::string& path) { return saveScene(scene, path); }

}  // namespace alacs::sim
