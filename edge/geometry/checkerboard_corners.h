// A checkerboard's inner corners in one image, by one of four measured detectors, and
// when the board is not found, why, in words for the person at the rig
// (docs/calibration.md, "Corner detection"). Pure functions of the image; thread-safe.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "common/result.h"

namespace alacs::geometry {

enum class CornerMethod {
  kSector,          // cv::findChessboardCornersSB (normalised, exhaustive)
  kSectorAccuracy,  // the same with CALIB_CB_ACCURACY (its own sub-pixel step)
  kClassicSubPix,   // cv::findChessboardCorners (adaptive threshold) + cv::cornerSubPix
  kSectorSubPix,    // found by kSector, refined by cv::cornerSubPix
};
inline constexpr CornerMethod kCornerMethods[] = {CornerMethod::kSector, CornerMethod::kSectorAccuracy,
                                                  CornerMethod::kClassicSubPix, CornerMethod::kSectorSubPix};
// The detector alacs_calibrate uses, chosen on the twin's tuning set (alacs-eval
// calibration; docs/calibration.md), never on the holdout, by what it does to the
// calibration: the 3D error at 1.6 m of two tuning sets was 0.84 and 0.25 mm with it,
// 1.82 and 1.26 mm with classic-subpix, which has the lower RMS over all corners (no
// outliers) but places the typical corner worse (median view RMS 0.17 against 0.11 px).
inline constexpr CornerMethod kDefaultCornerMethod = CornerMethod::kSectorAccuracy;

// "sb", "sb-accuracy", "classic-subpix", "sb-subpix".
const char* cornerMethodName(CornerMethod method);
// Errors: kInvalidArgument naming the known names.
Result<CornerMethod> parseCornerMethod(const std::string& name);

struct CornerOptions {
  CornerMethod method = kDefaultCornerMethod;
  // cv::cornerSubPix's half window as a share of the shortest corner spacing in the
  // image (clamped to 3..15 px): wide enough to see both edges through the blur, narrow
  // enough to stay inside the corner's four squares. 0.35: the middle of the tuning set's
  // plateau (0.25: 0.230 px RMS, 0.35: 0.212, 0.45: 0.209).
  double subPixWindowShare = 0.35;
};

// Inner corners of a board with `cols` × `rows` inner corners in `gray` (8-bit, one
// channel), in the row-major order cv::findChessboardCorners reports them, pixel centres
// at integers. Errors: kBadInput for another image type; kNotFound with the reason
// (explainMissingCheckerboard) when this method does not find the board.
Result<std::vector<Eigen::Vector2d>> findCheckerboardCorners(const cv::Mat& gray, int cols, int rows,
                                                             const CornerOptions& options = {});

// cv::cornerSubPix on corners found in `gray` (a grid of `cols` × `rows`, row-major), its
// window from `windowShare` as in CornerOptions. Errors: kBadInput for a wrong image type
// or corner count.
Status refineCheckerboardCorners(const cv::Mat& gray, int cols, int rows, double windowShare,
                                 std::vector<Eigen::Vector2d>& corners);

// What a view shows, for the reasons below.
struct ViewExposure {
  double brightLevel = 0.0;     // 99.9th percentile of the gray levels (0..255)
  double darkLevel = 0.0;       // 1st percentile
  double saturatedShare = 0.0;  // share of pixels at 250 or more
  double edgeSigmaPx = 0.0;     // blur of the sharpest strong edges (Gaussian σ), NaN without edges;
                                // true to ~±0.4 px up to 2.5 px, reads low beyond ~3 px
};
ViewExposure measureView(const cv::Mat& gray);

// Why a board of `cols` × `rows` inner corners is not found in `gray`, one sentence that
// says what to redo: too dark, overexposed, blurred, only part of the board (cut by the
// frame or covered), or none at all (wrong --board, too far or too steep), with the
// figures it is based on. Runs the detector again on a smaller pattern: call it only
// for a view that failed.
std::string explainMissingCheckerboard(const cv::Mat& gray, int cols, int rows);

}  // namespace alacs::geometry
