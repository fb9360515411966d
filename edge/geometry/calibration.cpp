#include "geometry/calibration.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>
#include <vector>

namespace alacs::geometry {

double LaserGeometry::slideForPoint(const Eigen::Vector3d& point) const {
  const double k = slideScale * planeNormal.dot(slideAxis);
  if (std::abs(k) < 1e-9) return std::numeric_limits<double>::quiet_NaN();
  return (planeNormal.dot(point) - planeOffsetMm) / k;
}

namespace {

Status fieldError(const std::string& field, const std::string& what) {
  return {Error::kBadInput, "calibration field '" + field + "' " + what};
}

const char* gateName(CalibrationQuality::Gate g) {
  switch (g) {
    case CalibrationQuality::Gate::kPassed: return "passed";
    case CalibrationQuality::Gate::kRefused: return "refused";
    case CalibrationQuality::Gate::kNotRun: return "not_run";
  }
  return "not_run";
}

// The Brown–Conrady map (OpenCV's order k1 k2 p1 p2 k3) from undistorted to distorted
// normalized coordinates, and its Jacobian.
struct Distorted {
  double x, y;
  double dxdx, dxdy, dydx, dydy;
};

Distorted distort(const std::array<double, 5>& k, double x, double y) {
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]));
  const double dRadialDr2 = k[0] + r2 * (2.0 * k[1] + 3.0 * r2 * k[4]);
  Distorted d{};
  d.x = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x);
  d.y = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y;
  d.dxdx = radial + 2.0 * x * x * dRadialDr2 + 2.0 * k[2] * y + 6.0 * k[3] * x;
  d.dxdy = 2.0 * x * y * dRadialDr2 + 2.0 * k[2] * x + 2.0 * k[3] * y;
  d.dydx = 2.0 * x * y * dRadialDr2 + 2.0 * k[2] * x + 2.0 * k[3] * y;
  d.dydy = radial + 2.0 * y * y * dRadialDr2 + 6.0 * k[2] * y + 2.0 * k[3] * x;
  return d;
}

// Undistortion must have exactly one answer for every pixel of the frame: the distortion
// map must not fold (Jacobian determinant positive, x increasing along rows and y down
// columns), radial and tangential terms together. Checked on a 65 × 49 grid over the
// frame's extent in normalized coordinates with a 30 % margin (the border included), and
// at every pair of neighbours, so that a fold narrower than the grid's spacing between
// two points that both look fine is still seen as a reversal. The distortion must also
// stay within the model's range for this sensor: no point of the frame moved by more
// than half its distance from the principal point.
Status checkDistortion(const CameraIntrinsics& c) {
  constexpr int kCols = 65;
  constexpr int kRows = 49;
  constexpr double kMargin = 1.3;
  constexpr double kMinSlope = 0.05;
  constexpr double kMaxRadialChange = 0.5;
  const double x0 = -kMargin * c.cxPx / c.fxPx;
  const double x1 = kMargin * (c.widthPx - c.cxPx) / c.fxPx;
  const double y0 = -kMargin * c.cyPx / c.fyPx;
  const double y1 = kMargin * (c.heightPx - c.cyPx) / c.fyPx;
  std::vector<Distorted> grid(static_cast<size_t>(kCols * kRows));
  int folded = 0;        // grid points inside the frame
  int foldedMargin = 0;  // grid points in the margin
  int inFrame = 0;
  double worstChange = 0.0;
  for (int j = 0; j < kRows; ++j) {
    for (int i = 0; i < kCols; ++i) {
      const double x = x0 + (x1 - x0) * i / (kCols - 1);
      const double y = y0 + (y1 - y0) * j / (kRows - 1);
      const Distorted d = distort(c.distortion, x, y);
      grid[static_cast<size_t>(j * kCols + i)] = d;
      const double det = d.dxdx * d.dydy - d.dxdy * d.dydx;
      bool fold = !(det > kMinSlope * kMinSlope && d.dxdx > kMinSlope && d.dydy > kMinSlope);
      if (i > 0 && !(d.x > grid[static_cast<size_t>(j * kCols + i - 1)].x)) fold = true;
      if (j > 0 && !(d.y > grid[static_cast<size_t>((j - 1) * kCols + i)].y)) fold = true;
      // The frame itself: pixels whose undistorted position lies inside it.
      const double u = c.fxPx * x + c.cxPx;
      const double v = c.fyPx * y + c.cyPx;
      const bool inside = u >= 0.0 && u <= c.widthPx && v >= 0.0 && v <= c.heightPx;
      if (inside) {
        ++inFrame;
        if (fold) ++folded;
        const double r = std::hypot(x, y);
        if (r > 1e-9) worstChange = std::max(worstChange, std::abs(std::hypot(d.x, d.y) / r - 1.0));
      }
      if (fold && !inside) ++foldedMargin;
    }
  }
  if (folded > 0) {
    const int share = static_cast<int>(std::lround(100.0 * folded / std::max(inFrame, 1)));
    return fieldError("camera.distortion", "folds " + std::to_string(std::max(share, 1)) +
                                               " % of the frame: undistortion would have two answers there");
  }
  if (foldedMargin > 0)
    return fieldError("camera.distortion", "folds the image just outside the frame: undistortion near its edges would be ambiguous");
  if (!(worstChange <= kMaxRadialChange))
    return fieldError("camera.distortion", "moves points of the frame by " + std::to_string(std::lround(100.0 * worstChange)) +
                                               " % of their radius, more than 50 %: not a lens this model describes");
  return Status::ok();
}

}  // namespace

Status validateCalibration(const Calibration& cal) {
  const auto& c = cal.camera;
  if (c.widthPx < 16 || c.widthPx > 16384) return fieldError("camera.width_px", "must be in 16..16384");
  if (c.heightPx < 16 || c.heightPx > 16384) return fieldError("camera.height_px", "must be in 16..16384");
  if (!(c.fxPx > 10.0 && c.fxPx < 1e5)) return fieldError("camera.fx_px", "must be in 10..1e5");
  if (!(c.fyPx > 10.0 && c.fyPx < 1e5)) return fieldError("camera.fy_px", "must be in 10..1e5");
  if (std::abs(c.fxPx / c.fyPx - 1.0) > 0.2)
    return fieldError("camera.fy_px", "differs from fx_px by more than 20 % (inconsistent)");
  if (!(c.cxPx >= 0 && c.cxPx < c.widthPx)) return fieldError("camera.cx_px", "must lie inside the image");
  if (!(c.cyPx >= 0 && c.cyPx < c.heightPx)) return fieldError("camera.cy_px", "must lie inside the image");
  for (size_t i = 0; i < c.distortion.size(); ++i) {
    if (!(std::abs(c.distortion[i]) < 10.0))
      return fieldError("camera.distortion[" + std::to_string(i) + "]", "must be in -10..10");
  }
  if (Status st = checkDistortion(c); !st) return st;
  const auto& l = cal.laser;
  if (std::abs(l.planeNormal.norm() - 1.0) > 1e-3)
    return fieldError("laser.plane_normal", "must be a unit vector (norm " +
                                                std::to_string(l.planeNormal.norm()) + ")");
  if (std::abs(l.slideAxis.norm() - 1.0) > 1e-3)
    return fieldError("laser.slide_axis", "must be a unit vector");
  if (!(std::abs(l.planeOffsetMm) < 5000.0)) return fieldError("laser.plane_offset_mm", "must be in -5000..5000");
  if (!(l.slideScale > 0.5 && l.slideScale < 2.0)) return fieldError("laser.slide_scale", "must be in 0.5..2.0");
  if (std::abs(l.planeNormal.dot(l.slideAxis)) < 0.05)
    return fieldError("laser.slide_axis", "is nearly parallel to the laser plane: the slide would not move the line");
  const auto& q = cal.quality;
  const std::pair<const char*, double> figures[] = {
      {"quality.reprojection_rms_px", q.reprojectionRmsPx}, {"quality.fx_sigma_px", q.fxSigmaPx},
      {"quality.fy_sigma_px", q.fySigmaPx},                 {"quality.cx_sigma_px", q.cxSigmaPx},
      {"quality.cy_sigma_px", q.cySigmaPx},                 {"quality.plane_rms_mm", q.planeRmsMm},
      {"quality.laser_rms_px", q.laserRmsPx},               {"quality.normal_sigma_mrad", q.normalSigmaMrad},
      {"quality.offset_sigma_mm", q.offsetSigmaMm},         {"quality.scale_sigma", q.scaleSigma},
      {"quality.depth_sigma_mm_at_1000", q.depthSigmaMmAt1000},
      {"quality.depth_sigma_mm_at_1600", q.depthSigmaMmAt1600},
      {"quality.depth_sigma_total_mm_at_1000", q.depthSigmaTotalMmAt1000},
      {"quality.depth_sigma_total_mm_at_1200", q.depthSigmaTotalMmAt1200},
      {"quality.depth_sigma_total_mm_at_1400", q.depthSigmaTotalMmAt1400},
      {"quality.depth_sigma_total_mm_at_1600", q.depthSigmaTotalMmAt1600},
      {"quality.sigma_3d_total_mm_at_1000", q.sigma3dTotalMmAt1000},
      {"quality.sigma_3d_total_mm_at_1200", q.sigma3dTotalMmAt1200},
      {"quality.sigma_3d_total_mm_at_1400", q.sigma3dTotalMmAt1400},
      {"quality.sigma_3d_total_mm_at_1600", q.sigma3dTotalMmAt1600},
  };
  for (const auto& [name, v] : figures)
    if (!(v >= 0.0 && v < 1e6)) return fieldError(name, "must be a non-negative number");
  if (!(q.inlierShare >= 0.0 && q.inlierShare <= 1.0)) return fieldError("quality.inlier_share", "must be in 0..1");
  if (q.cameraViews < 0) return fieldError("quality.camera_views", "must be non-negative");
  if (q.targetPlacements < 0) return fieldError("quality.target_placements", "must be non-negative");
  if (q.slidePositions < 0) return fieldError("quality.slide_positions", "must be non-negative");
  return Status::ok();
}

namespace {

struct QualityNumber {
  const char* key;
  double CalibrationQuality::*field;
};
constexpr QualityNumber kQualityNumbers[] = {
    {"reprojection_rms_px", &CalibrationQuality::reprojectionRmsPx},
    {"fx_sigma_px", &CalibrationQuality::fxSigmaPx},
    {"fy_sigma_px", &CalibrationQuality::fySigmaPx},
    {"cx_sigma_px", &CalibrationQuality::cxSigmaPx},
    {"cy_sigma_px", &CalibrationQuality::cySigmaPx},
    {"plane_rms_mm", &CalibrationQuality::planeRmsMm},
    {"laser_rms_px", &CalibrationQuality::laserRmsPx},
    {"inlier_share", &CalibrationQuality::inlierShare},
    {"normal_sigma_mrad", &CalibrationQuality::normalSigmaMrad},
    {"offset_sigma_mm", &CalibrationQuality::offsetSigmaMm},
    {"scale_sigma", &CalibrationQuality::scaleSigma},
    {"depth_sigma_mm_at_1000", &CalibrationQuality::depthSigmaMmAt1000},
    {"depth_sigma_mm_at_1600", &CalibrationQuality::depthSigmaMmAt1600},
    {"depth_sigma_total_mm_at_1000", &CalibrationQuality::depthSigmaTotalMmAt1000},
    {"depth_sigma_total_mm_at_1200", &CalibrationQuality::depthSigmaTotalMmAt1200},
    {"depth_sigma_total_mm_at_1400", &CalibrationQuality::depthSigmaTotalMmAt1400},
    {"depth_sigma_total_mm_at_1600", &CalibrationQuality::depthSigmaTotalMmAt1600},
    {"sigma_3d_total_mm_at_1000", &CalibrationQuality::sigma3dTotalMmAt1000},
    {"sigma_3d_total_mm_at_1200", &CalibrationQuality::sigma3dTotalMmAt1200},
    {"sigma_3d_total_mm_at_1400", &CalibrationQuality::sigma3dTotalMmAt1400},
    {"sigma_3d_total_mm_at_1600", &CalibrationQuality::sigma3dTotalMmAt1600},
};
struct QualityCount {
  const char* key;
  int CalibrationQuality::*field;
};
constexpr QualityCount kQualityCounts[] = {
    {"camera_views", &CalibrationQuality::cameraViews},
    {"target_placements", &CalibrationQuality::targetPlacements},
    {"slide_positions", &CalibrationQuality::slidePositions},
};

void readQuality(JsonObjectReader& q, CalibrationQuality& cq) {
  for (const auto& f : kQualityNumbers) q.number(f.key, cq.*f.field);
  for (const auto& f : kQualityCounts) q.integer(f.key, cq.*f.field, Need::kOptional, -1000000, 1000000);
  q.boolean("from_truth", cq.fromTruth);
  std::string gate;
  if (q.text("gate", gate)) {
    if (gate == "passed") {
      cq.gate = CalibrationQuality::Gate::kPassed;
    } else if (gate == "not_run") {
      cq.gate = CalibrationQuality::Gate::kNotRun;
    } else if (gate == "refused") {
      cq.gate = CalibrationQuality::Gate::kRefused;
    } else {
      q.fail("gate", "must be \"passed\", \"refused\" or \"not_run\"");
    }
  }
  q.finish();
}

}  // namespace

void cameraFromJson(JsonObjectReader& cam, CameraIntrinsics& c) {
  cam.integer("width_px", c.widthPx, Need::kRequired, 16, 16384);
  cam.integer("height_px", c.heightPx, Need::kRequired, 16, 16384);
  cam.number("fx_px", c.fxPx, Need::kRequired);
  cam.number("fy_px", c.fyPx, Need::kRequired);
  cam.number("cx_px", c.cxPx, Need::kRequired);
  cam.number("cy_px", c.cyPx, Need::kRequired);
  cam.numbers("distortion", c.distortion, Need::kRequired);
  cam.finish();
}

void laserFromJson(JsonObjectReader& las, LaserGeometry& l) {
  std::array<double, 3> v{};
  if (las.numbers("plane_normal", v, Need::kRequired)) l.planeNormal = {v[0], v[1], v[2]};
  las.number("plane_offset_mm", l.planeOffsetMm, Need::kRequired);
  if (las.numbers("slide_axis", v, Need::kRequired)) l.slideAxis = {v[0], v[1], v[2]};
  las.number("slide_scale", l.slideScale, Need::kRequired);
  las.finish();
}

Status calibrationFromJson(const Json& json, Calibration& cal) {
  JsonErrors errors("calibration");
  JsonObjectReader root(errors, &json, "");
  std::string format = kCalibrationFormat;
  if (root.text("format", format) && format != kCalibrationFormat)
    errors.field("format", std::string("must be \"") + kCalibrationFormat + "\"");
  if (auto cam = root.object("camera", Need::kRequired)) cameraFromJson(*cam, cal.camera);
  if (auto las = root.object("laser", Need::kRequired)) laserFromJson(*las, cal.laser);
  if (auto q = root.object("quality")) readQuality(*q, cal.quality);
  root.finish();
  return errors.status();
}

OrderedJson cameraToJson(const CameraIntrinsics& c) {
  return {{"width_px", c.widthPx}, {"height_px", c.heightPx}, {"fx_px", c.fxPx},   {"fy_px", c.fyPx},
          {"cx_px", c.cxPx},       {"cy_px", c.cyPx},         {"distortion", c.distortion}};
}

OrderedJson laserToJson(const LaserGeometry& l) {
  return {{"plane_normal", {l.planeNormal.x(), l.planeNormal.y(), l.planeNormal.z()}},
          {"plane_offset_mm", l.planeOffsetMm},
          {"slide_axis", {l.slideAxis.x(), l.slideAxis.y(), l.slideAxis.z()}},
          {"slide_scale", l.slideScale}};
}

OrderedJson calibrationToJson(const Calibration& cal) {
  OrderedJson q;
  const CalibrationQuality& cq = cal.quality;
  q["reprojection_rms_px"] = cq.reprojectionRmsPx;
  for (const auto& f : kQualityCounts) q[f.key] = cq.*f.field;
  for (const auto& f : kQualityNumbers) q[f.key] = cq.*f.field;
  q["gate"] = gateName(cq.gate);
  q["from_truth"] = cq.fromTruth;
  return {{"format", kCalibrationFormat},
          {"camera", cameraToJson(cal.camera)},
          {"laser", laserToJson(cal.laser)},
          {"quality", std::move(q)}};
}

std::string calibrationJson(const Calibration& cal) { return jsonText(calibrationToJson(cal)); }

namespace {
Result<Calibration> calibrationOf(const Result<Json>& file) {
  if (!file) return file.status();
  Calibration cal;
  if (Status s = calibrationFromJson(*file, cal); !s) return s;
  if (cal.quality.gate == CalibrationQuality::Gate::kRefused)
    return fieldError("quality.gate", "is \"refused\": the quality gate rejected this calibration");
  if (Status s = validateCalibration(cal); !s) return s;
  return cal;
}
}  // namespace

Result<Calibration> loadCalibration(const std::string& path) {
  return calibrationOf(readJsonFile(path, "calibration file", kCalibrationMaxBytes));
}

Result<Calibration> loadCalibrationBeneath(const std::string& dir, const std::string& relPath) {
  return calibrationOf(readJsonFileBeneath(dir, relPath, "scan calibration", kCalibrationMaxBytes));
}

Status writeFileAtomically(const std::string& path, const std::string& text) {
  // Same directory as the target, so that rename() is atomic; fsync before the rename so
  // that a power cut leaves either the old file or the whole new one.
  const std::string tmp = path + ".tmp";
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (f == nullptr) return {Error::kIo, "cannot write '" + tmp + "'"};
  const bool written = std::fwrite(text.data(), 1, text.size(), f) == text.size() && std::fflush(f) == 0 &&
                       ::fsync(::fileno(f)) == 0;
  const bool closed = std::fclose(f) == 0;
  if (!written || !closed) {
    std::remove(tmp.c_str());
    return {Error::kIo, "cannot write '" + tmp + "'"};
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    return {Error::kIo, "cannot rename to '" + path + "'"};
  }
  return Status::ok();
}

Status saveCalibration(const Calibration& cal, const std::string& path) {
  if (Status s = validateCalibration(cal); !s) return s;
  return writeFileAtomically(path, calibrationJson(cal));
}

}  // namespace alacs::geometry
