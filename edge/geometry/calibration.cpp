#include "geometry/calibration.h"

#include <opencv2/core.hpp>

#include "common/json_file.h"
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <sstream>

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
  const cv::FileNode q = fs["quality"];
  if (q.isMap()) {
    if (!q["reprojection_rms_px"].empty()) cal.quality.reprojectionRmsPx = q["reprojection_rms_px"].real();
    if (!q["plane_rms_mm"].empty()) cal.quality.planeRmsMm = q["plane_rms_mm"].real();
    if (!q["from_truth"].empty()) cal.quality.fromTruth = static_cast<int>(q["from_truth"]) != 0;
  }
  if (Status s = validateCalibration(cal); !s) return s;
  return cal;
}

Status saveCalibration(const Calibration& cal, const std::string& path) {
  if (Status s = validateCalibration(cal); !s) return s;
  const auto& c = cal.camera;
  const auto& l = cal.laser;
  char buf[2048];
  const int n = std::snprintf(
      buf, sizeof buf,
      "{\n"
      "  \"format\": \"alacs-calibration/1\",\n"
      "  \"camera\": {\"width_px\": %d, \"height_px\": %d, \"fx_px\": %.9g, \"fy_px\": %.9g,\n"
      "             \"cx_px\": %.9g, \"cy_px\": %.9g,\n"
      "             \"distortion\": [%.9g, %.9g, %.9g, %.9g, %.9g]},\n"
      "  \"laser\": {\"plane_normal\": [%.12g, %.12g, %.12g], \"plane_offset_mm\": %.12g,\n"
      "            \"slide_axis\": [%.12g, %.12g, %.12g], \"slide_scale\": %.12g},\n"
      "  \"quality\": {\"reprojection_rms_px\": %.6g, \"plane_rms_mm\": %.6g, \"from_truth\": %d}\n"
      "}\n",
      c.widthPx, c.heightPx, c.fxPx, c.fyPx, c.cxPx, c.cyPx, c.distortion[0], c.distortion[1],
      c.distortion[2], c.distortion[3], c.distortion[4], l.planeNormal.x(), l.planeNormal.y(),
      l.planeNormal.z(), l.planeOffsetMm, l.slideAxis.x(), l.slideAxis.y(), l.slideAxis.z(),
      l.slideScale, cal.quality.reprojectionRmsPx, cal.quality.planeRmsMm,
      cal.quality.fromTruth ? 1 : 0);
  if (n <= 0 || static_cast<size_t>(n) >= sizeof buf) return {Error::kInternal, "calibration text overflow"};
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    if (!out) return {Error::kIo, "cannot write '" + tmp + "'"};
    out.write(buf, n);
    out.flush();
    if (!out) return {Error::kIo, "cannot write '" + tmp + "'"};
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return {Error::kIo, "cannot rename to '" + path + "'"};
  return Status::ok();
}

}  // namespace alacs::geometry
