#include "geometry/calibration.h"

#include <opencv2/core.hpp>

#include "common/json_file.h"
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>
#include <unistd.h>
#include <locale>
#include <utility>

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

Result<double> readNumber(const cv::FileNode& parent, const std::string& parentName,
                          const char* key) {
  const cv::FileNode n = parent[key];
  const std::string field = parentName + "." + key;
  if (n.empty() || n.isNone()) return fieldError(field, "is missing");
  if (!n.isReal() && !n.isInt()) return fieldError(field, "is not a number");
  const double v = n.real();
  if (!std::isfinite(v)) return fieldError(field, "is not finite");
  return v;
}

Status readVector3(const cv::FileNode& parent, const std::string& parentName, const char* key,
                   Eigen::Vector3d* out) {
  const cv::FileNode n = parent[key];
  const std::string field = parentName + "." + key;
  if (n.empty() || n.isNone()) return fieldError(field, "is missing");
  if (!n.isSeq() || n.size() != 3) return fieldError(field, "must be an array of 3 numbers");
  for (int i = 0; i < 3; ++i) {
    const cv::FileNode e = n[i];
    if (!e.isReal() && !e.isInt()) return fieldError(field, "must be an array of 3 numbers");
    (*out)(i) = e.real();
    if (!std::isfinite((*out)(i))) return fieldError(field, "holds a non-finite value");
  }
  return Status::ok();
}

const char* gateName(CalibrationQuality::Gate g) {
  switch (g) {
    case CalibrationQuality::Gate::kPassed: return "passed";
    case CalibrationQuality::Gate::kRefused: return "refused";
    case CalibrationQuality::Gate::kNotRun: return "not_run";
  }
  return "not_run";
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
  // Inconsistent distortion: the radial model must map radius to radius one-to-one over
  // the whole frame (and a margin), or undistortion has two answers.
  const double rMax = 1.3 * std::hypot(std::max(c.cxPx, c.widthPx - c.cxPx) / c.fxPx,
                                       std::max(c.cyPx, c.heightPx - c.cyPx) / c.fyPx);
  for (int i = 1; i <= 200; ++i) {
    const double r2 = std::pow(rMax * i / 200.0, 2);
    const double slope = 1.0 + 3.0 * c.distortion[0] * r2 + 5.0 * c.distortion[1] * r2 * r2 +
                         7.0 * c.distortion[4] * r2 * r2 * r2;
    if (!(slope > 0.05))
      return fieldError("camera.distortion", "folds the image: radial distortion is not monotonic within the frame");
  }
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

Result<Calibration> loadCalibration(const std::string& path) {
  Result<cv::FileStorage> file = openJsonFile(path, "calibration file");
  if (!file) return file.status();
  cv::FileStorage& fs = *file;
  Calibration cal;
  const cv::FileNode cam = fs["camera"];
  if (cam.empty() || !cam.isMap()) return fieldError("camera", "is missing");
  const cv::FileNode las = fs["laser"];
  if (las.empty() || !las.isMap()) return fieldError("laser", "is missing");

  struct NumField { const cv::FileNode* node; const char* parent; const char* key; double* out; };
  double width = 0;
  double height = 0;
  const NumField nums[] = {
      {&cam, "camera", "width_px", &width},          {&cam, "camera", "height_px", &height},
      {&cam, "camera", "fx_px", &cal.camera.fxPx},    {&cam, "camera", "fy_px", &cal.camera.fyPx},
      {&cam, "camera", "cx_px", &cal.camera.cxPx},    {&cam, "camera", "cy_px", &cal.camera.cyPx},
      {&las, "laser", "plane_offset_mm", &cal.laser.planeOffsetMm},
      {&las, "laser", "slide_scale", &cal.laser.slideScale},
  };
  for (const auto& f : nums) {
    Result<double> v = readNumber(*f.node, f.parent, f.key);
    if (!v) return v.status();
    *f.out = *v;
  }
  if (width != std::floor(width) || height != std::floor(height))
    return fieldError("camera.width_px", "must be an integer");
  cal.camera.widthPx = static_cast<int>(width);
  cal.camera.heightPx = static_cast<int>(height);
  const cv::FileNode dist = cam["distortion"];
  if (dist.empty()) return fieldError("camera.distortion", "is missing");
  if (!dist.isSeq() || dist.size() != 5) return fieldError("camera.distortion", "must be an array of 5 numbers (k1 k2 p1 p2 k3)");
  for (int i = 0; i < 5; ++i) {
    if (!dist[i].isReal() && !dist[i].isInt()) return fieldError("camera.distortion", "must hold numbers");
    cal.camera.distortion[static_cast<size_t>(i)] = dist[i].real();
  }
  if (Status s = readVector3(las, "laser", "plane_normal", &cal.laser.planeNormal); !s) return s;
  if (Status s = readVector3(las, "laser", "slide_axis", &cal.laser.slideAxis); !s) return s;
  if (const cv::FileNode fmt = fs["format"]; !fmt.empty()) {
    if (!fmt.isString() || static_cast<std::string>(fmt) != kCalibrationFormat)
      return fieldError("format", std::string("must be \"") + kCalibrationFormat + "\"");
  }
  // Quality figures: optional, but when present they must be numbers.
  const cv::FileNode q = fs["quality"];
  if (!q.empty() && !q.isNone()) {
    if (!q.isMap()) return fieldError("quality", "must be an object");
    auto& cq = cal.quality;
    struct OptNum { const char* key; double* out; };
    const OptNum optional[] = {
        {"reprojection_rms_px", &cq.reprojectionRmsPx}, {"fx_sigma_px", &cq.fxSigmaPx},
        {"fy_sigma_px", &cq.fySigmaPx},                 {"cx_sigma_px", &cq.cxSigmaPx},
        {"cy_sigma_px", &cq.cySigmaPx},                 {"plane_rms_mm", &cq.planeRmsMm},
        {"laser_rms_px", &cq.laserRmsPx},               {"inlier_share", &cq.inlierShare},
        {"normal_sigma_mrad", &cq.normalSigmaMrad},     {"offset_sigma_mm", &cq.offsetSigmaMm},
        {"scale_sigma", &cq.scaleSigma},                {"depth_sigma_mm_at_1000", &cq.depthSigmaMmAt1000},
        {"depth_sigma_mm_at_1600", &cq.depthSigmaMmAt1600},
        {"depth_sigma_total_mm_at_1000", &cq.depthSigmaTotalMmAt1000},
        {"depth_sigma_total_mm_at_1200", &cq.depthSigmaTotalMmAt1200},
        {"depth_sigma_total_mm_at_1400", &cq.depthSigmaTotalMmAt1400},
        {"depth_sigma_total_mm_at_1600", &cq.depthSigmaTotalMmAt1600},
        {"sigma_3d_total_mm_at_1000", &cq.sigma3dTotalMmAt1000},
        {"sigma_3d_total_mm_at_1200", &cq.sigma3dTotalMmAt1200},
        {"sigma_3d_total_mm_at_1400", &cq.sigma3dTotalMmAt1400},
        {"sigma_3d_total_mm_at_1600", &cq.sigma3dTotalMmAt1600},
    };
    for (const auto& f : optional) {
      if (q[f.key].empty()) continue;
      Result<double> v = readNumber(q, "quality", f.key);
      if (!v) return v.status();
      *f.out = *v;
    }
    struct OptInt { const char* key; int* out; };
    const OptInt counts[] = {{"camera_views", &cq.cameraViews},
                             {"target_placements", &cq.targetPlacements},
                             {"slide_positions", &cq.slidePositions}};
    for (const auto& f : counts) {
      if (q[f.key].empty()) continue;
      Result<double> v = readNumber(q, "quality", f.key);
      if (!v) return v.status();
      if (*v != std::floor(*v) || std::abs(*v) > 1e6) return fieldError(std::string("quality.") + f.key, "must be an integer");
      *f.out = static_cast<int>(*v);
    }
    if (const cv::FileNode b = q["from_truth"]; !b.empty()) {
      if (!b.isInt() || (static_cast<int>(b) != 0 && static_cast<int>(b) != 1))
        return fieldError("quality.from_truth", "must be true or false");
      cq.fromTruth = static_cast<int>(b) != 0;
    }
    if (const cv::FileNode g = q["gate"]; !g.empty()) {
      const std::string gate = g.isString() ? static_cast<std::string>(g) : std::string();
      if (gate == "passed") {
        cq.gate = CalibrationQuality::Gate::kPassed;
      } else if (gate == "refused") {
        // Kept for diagnosis; it must never drive the sensor.
        return fieldError("quality.gate", "is \"refused\": the quality gate rejected this calibration");
      } else if (gate != "not_run") {
        return fieldError("quality.gate", "must be \"passed\", \"refused\" or \"not_run\"");
      }
    }
  }
  if (Status s = validateCalibration(cal); !s) return s;
  return cal;
}

std::string calibrationJson(const Calibration& cal) {
  const auto& c = cal.camera;
  const auto& l = cal.laser;
  const auto& q = cal.quality;
  std::ostringstream o;
  o.imbue(std::locale::classic());
  o.precision(12);
  auto vec = [&o](const Eigen::Vector3d& v) { o << "[" << v.x() << ", " << v.y() << ", " << v.z() << "]"; };
  o << "{\n  \"format\": \"" << kCalibrationFormat << "\",\n";
  o << "  \"camera\": {\"width_px\": " << c.widthPx << ", \"height_px\": " << c.heightPx << ", \"fx_px\": " << c.fxPx
    << ", \"fy_px\": " << c.fyPx << ",\n             \"cx_px\": " << c.cxPx << ", \"cy_px\": " << c.cyPx
    << ",\n             \"distortion\": [" << c.distortion[0] << ", " << c.distortion[1] << ", " << c.distortion[2]
    << ", " << c.distortion[3] << ", " << c.distortion[4] << "]},\n";
  o << "  \"laser\": {\"plane_normal\": ";
  vec(l.planeNormal);
  o << ", \"plane_offset_mm\": " << l.planeOffsetMm << ",\n            \"slide_axis\": ";
  vec(l.slideAxis);
  o << ", \"slide_scale\": " << l.slideScale << "},\n";
  o.precision(6);
  o << "  \"quality\": {\"reprojection_rms_px\": " << q.reprojectionRmsPx << ", \"camera_views\": " << q.cameraViews
    << ",\n              \"fx_sigma_px\": " << q.fxSigmaPx << ", \"fy_sigma_px\": " << q.fySigmaPx
    << ", \"cx_sigma_px\": " << q.cxSigmaPx << ", \"cy_sigma_px\": " << q.cySigmaPx
    << ",\n              \"plane_rms_mm\": " << q.planeRmsMm << ", \"laser_rms_px\": " << q.laserRmsPx
    << ", \"inlier_share\": " << q.inlierShare << ",\n              \"target_placements\": " << q.targetPlacements
    << ", \"slide_positions\": " << q.slidePositions << ",\n              \"normal_sigma_mrad\": " << q.normalSigmaMrad
    << ", \"offset_sigma_mm\": " << q.offsetSigmaMm << ", \"scale_sigma\": " << q.scaleSigma
    << ",\n              \"depth_sigma_mm_at_1000\": " << q.depthSigmaMmAt1000
    << ", \"depth_sigma_mm_at_1600\": " << q.depthSigmaMmAt1600
    << ",\n              \"depth_sigma_total_mm_at_1000\": " << q.depthSigmaTotalMmAt1000
    << ", \"depth_sigma_total_mm_at_1200\": " << q.depthSigmaTotalMmAt1200
    << ", \"depth_sigma_total_mm_at_1400\": " << q.depthSigmaTotalMmAt1400
    << ", \"depth_sigma_total_mm_at_1600\": " << q.depthSigmaTotalMmAt1600
    << ",\n              \"sigma_3d_total_mm_at_1000\": " << q.sigma3dTotalMmAt1000
    << ", \"sigma_3d_total_mm_at_1200\": " << q.sigma3dTotalMmAt1200
    << ", \"sigma_3d_total_mm_at_1400\": " << q.sigma3dTotalMmAt1400
    << ", \"sigma_3d_total_mm_at_1600\": " << q.sigma3dTotalMmAt1600
    << ",\n              \"gate\": \"" << gateName(q.gate) << "\""
    << ", \"from_truth\": " << (q.fromTruth ? "true" : "false") << "}\n}\n";
  return o.str();
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
