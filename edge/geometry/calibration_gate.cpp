#include "geometry/calibration_gate.h"

#include <cmath>
#include <locale>
#include <sstream>

#include "common/json_file.h"

namespace alacs::geometry {

namespace {

std::string describe(const char* field, double value, const char* relation, double limit) {
  std::ostringstream s;
  s.imbue(std::locale::classic());
  s.precision(3);
  if (std::isnan(value)) {
    s << "quality." << field << " not measured (limit " << limit << ")";  // its stage failed: see the log
  } else {
    s << "quality." << field << " " << value << " " << relation << " " << limit;
  }
  return s.str();
}

}  // namespace

Status GateVerdict::status() const {
  if (failures.empty()) return Status::ok();
  std::string text = "calibration refused by the quality gate: ";
  for (size_t i = 0; i < failures.size(); ++i) text += (i ? "; " : "") + failures[i];
  return {Error::kBadInput, text};
}

GateVerdict checkCalibrationQuality(const CalibrationQuality& q, const CalibrationLimits& l) {
  GateVerdict v;
  auto atMost = [&v](const char* field, double value, double limit) {
    if (!(value <= limit)) v.failures.push_back(describe(field, value, "exceeds", limit));
  };
  auto atLeast = [&v](const char* field, double value, double limit) {
    if (!(value >= limit)) v.failures.push_back(describe(field, value, "is below", limit));
  };
  atLeast("camera_views", q.cameraViews, l.minCameraViews);
  atMost("reprojection_rms_px", q.reprojectionRmsPx, l.maxReprojectionRmsPx);
  atMost("fx_sigma_px", q.fxSigmaPx, l.maxFocalSigmaPx);
  atMost("fy_sigma_px", q.fySigmaPx, l.maxFocalSigmaPx);
  atMost("cx_sigma_px", q.cxSigmaPx, l.maxPrincipalSigmaPx);
  atMost("cy_sigma_px", q.cySigmaPx, l.maxPrincipalSigmaPx);
  atLeast("target_placements", q.targetPlacements, l.minTargetPlacements);
  atLeast("slide_positions", q.slidePositions, l.minSlidePositions);
  atLeast("inlier_share", q.inlierShare, l.minInlierShare);
  atMost("laser_rms_px", q.laserRmsPx, l.maxLaserRmsPx);
  atMost("plane_rms_mm", q.planeRmsMm, l.maxPlaneRmsMm);
  atMost("normal_sigma_mrad", q.normalSigmaMrad, l.maxNormalSigmaMrad);
  atMost("offset_sigma_mm", q.offsetSigmaMm, l.maxOffsetSigmaMm);
  atMost("scale_sigma", q.scaleSigma, l.maxScaleSigma);
  atMost("depth_sigma_mm_at_1000", q.depthSigmaMmAt1000, l.maxDepthSigmaMmAt1000);
  atMost("depth_sigma_mm_at_1600", q.depthSigmaMmAt1600, l.maxDepthSigmaMmAt1600);
  atMost("depth_sigma_total_mm_at_1000", q.depthSigmaTotalMmAt1000, l.maxDepthSigmaTotalMmAt1000);
  atMost("depth_sigma_total_mm_at_1600", q.depthSigmaTotalMmAt1600, l.maxDepthSigmaTotalMmAt1600);
  return v;
}

GateVerdict judgeCalibration(const CalibrationQuality& quality, const std::vector<std::string>& failedStages,
                             const CalibrationLimits& limits) {
  GateVerdict v = checkCalibrationQuality(quality, limits);
  v.failures.insert(v.failures.begin(), failedStages.begin(), failedStages.end());
  return v;
}

Status CalibrationLimits::fromJson(const Json& json, CalibrationLimits& l) {
  JsonErrors errors("limits");
  JsonObjectReader root(errors, &json, "");
  struct Num { const char* key; double* out; };
  const Num nums[] = {
      {"max_reprojection_rms_px", &l.maxReprojectionRmsPx}, {"max_focal_sigma_px", &l.maxFocalSigmaPx},
      {"max_principal_sigma_px", &l.maxPrincipalSigmaPx},   {"max_laser_rms_px", &l.maxLaserRmsPx},
      {"max_plane_rms_mm", &l.maxPlaneRmsMm},               {"min_inlier_share", &l.minInlierShare},
      {"max_normal_sigma_mrad", &l.maxNormalSigmaMrad},     {"max_offset_sigma_mm", &l.maxOffsetSigmaMm},
      {"max_scale_sigma", &l.maxScaleSigma},                {"max_depth_sigma_mm_at_1000", &l.maxDepthSigmaMmAt1000},
      {"max_depth_sigma_mm_at_1600", &l.maxDepthSigmaMmAt1600},
      {"max_depth_sigma_total_mm_at_1000", &l.maxDepthSigmaTotalMmAt1000},
      {"max_depth_sigma_total_mm_at_1600", &l.maxDepthSigmaTotalMmAt1600},
  };
  for (const auto& f : nums) root.number(f.key, *f.out, Need::kOptional, 0.0, 1e9);
  struct Int { const char* key; int* out; };
  const Int ints[] = {{"min_camera_views", &l.minCameraViews},
                      {"min_target_placements", &l.minTargetPlacements},
                      {"min_slide_positions", &l.minSlidePositions}};
  for (const auto& f : ints) root.integer(f.key, *f.out, Need::kOptional, 0, 1000000);
  root.finish();
  return errors.status();
}

OrderedJson CalibrationLimits::toJson() const {
  return {{"max_reprojection_rms_px", maxReprojectionRmsPx},
          {"min_camera_views", minCameraViews},
          {"max_focal_sigma_px", maxFocalSigmaPx},
          {"max_principal_sigma_px", maxPrincipalSigmaPx},
          {"max_laser_rms_px", maxLaserRmsPx},
          {"max_plane_rms_mm", maxPlaneRmsMm},
          {"min_inlier_share", minInlierShare},
          {"min_target_placements", minTargetPlacements},
          {"min_slide_positions", minSlidePositions},
          {"max_normal_sigma_mrad", maxNormalSigmaMrad},
          {"max_offset_sigma_mm", maxOffsetSigmaMm},
          {"max_scale_sigma", maxScaleSigma},
          {"max_depth_sigma_mm_at_1000", maxDepthSigmaMmAt1000},
          {"max_depth_sigma_mm_at_1600", maxDepthSigmaMmAt1600},
          {"max_depth_sigma_total_mm_at_1000", maxDepthSigmaTotalMmAt1000},
          {"max_depth_sigma_total_mm_at_1600", maxDepthSigmaTotalMmAt1600}};
}

Result<CalibrationLimits> CalibrationLimits::load(const std::string& path) {
  Result<Json> file = readJsonFile(path, "calibration limits file", kCalibrationMaxBytes);
  if (!file) return file.status();
  CalibrationLimits l;
  if (Status s = fromJson(*file, l); !s) return s;
  return l;
}

}  // namespace alacs::geometry
