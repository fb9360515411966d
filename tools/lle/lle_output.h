// What the `alacs_lle` command writes for one frame: the JSON document (every ROI row,
// with an explicit invalid marker, the polynomial, segments and coverage) and the
// overlay PNG. docs/lle.md describes both.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "image/lle.h"
#include "tool_common/json.h"

namespace alacs::tools {

struct LleRun {
  std::string image;        // the input file, as given
  std::string laserOff;     // the laser-off file, empty when none
  image::Roi roi;
  image::LleParams params;
  bool reference = false;   // the float reference produced `line`
  double millis = 0.0;      // time of the extraction
};

// The JSON document for one frame, and its text (one line).
Json lleDocument(const LleRun& run, int frameWidth, int frameHeight, const image::LaserLine& line);
std::string lleJson(const LleRun& run, int frameWidth, int frameHeight, const image::LaserLine& line);

// The frame with the ROI, the rows (line: green, outliers: magenta, other segments: cyan)
// and the fitted curve (yellow) drawn on it, BGR.
cv::Mat lleOverlay(const cv::Mat& bgr, const image::Roi& roi, const image::LaserLine& line);

const char* statusName(image::RowStatus s);

}  // namespace alacs::tools
