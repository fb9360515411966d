// The quality gate: a calibration is accepted only when its residuals, its parameter
// uncertainties and its coverage are inside limits. The verdict names every figure that
// failed with its value and its limit, in the field names of calibration.json's
// "quality" object, so the person at the rig knows what to redo (docs/calibration.md).
#pragma once

#include <string>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"

namespace alacs::geometry {

struct CalibrationLimits {
  // Camera.
  double maxReprojectionRmsPx = 0.5;
  int minCameraViews = 8;
  double maxFocalSigmaPx = 4.0;      // fx, fy
  double maxPrincipalSigmaPx = 4.0;  // cx, cy
  // Laser and slide.
  double maxLaserRmsPx = 0.5;
  double maxPlaneRmsMm = 0.5;
  double minInlierShare = 0.8;
  int minTargetPlacements = 4;
  int minSlidePositions = 3;
  double maxNormalSigmaMrad = 0.5;
  double maxOffsetSigmaMm = 0.5;
  double maxScaleSigma = 0.002;
  double maxDepthSigmaMmAt1000 = 0.5;
  double maxDepthSigmaMmAt1600 = 1.0;
  // The total depth σ (intrinsics included), the figure that sees a depth-scale error.
  double maxDepthSigmaTotalMmAt1000 = 1.0;
  double maxDepthSigmaTotalMmAt1600 = 1.6;

  // Reads limits from a JSON object file; keys as in docs/calibration.md, missing keys
  // keep the defaults. Errors name the key.
  static Result<CalibrationLimits> load(const std::string& path);
  // Overrides the limits present in `json`; unknown keys are refused. Errors: kBadInput.
  static Status fromJson(const Json& json, CalibrationLimits& limits);
  OrderedJson toJson() const;
};

struct GateVerdict {
  std::vector<std::string> failures;  // "quality.laser_rms_px 0.81 exceeds 0.5"
  bool passed() const { return failures.empty(); }
  // kBadInput naming every failure, or ok.
  Status status() const;
};

GateVerdict checkCalibrationQuality(const CalibrationQuality& quality, const CalibrationLimits& limits = {});

// The verdict on a calibration some of whose stages could not be computed (the total σ,
// say): each failed stage's reason first, then every figure outside its limit, its
// figures (NaN) named "not measured". A stage's failure is a refusal with its reason,
// never an end before the gate speaks (docs/calibration.md, "The quality gate").
GateVerdict judgeCalibration(const CalibrationQuality& quality, const std::vector<std::string>& failedStages,
                             const CalibrationLimits& limits = {});

}  // namespace alacs::geometry
