#include "geometry/checkerboard_corners.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace alacs::geometry {

namespace {

std::string patternText(int cols, int rows) { return std::to_string(cols) + "x" + std::to_string(rows); }

// The shortest distance between neighbouring corners of the grid (px).
double shortestSpacingPx(const std::vector<cv::Point2f>& c, int cols, int rows) {
  double best = std::numeric_limits<double>::infinity();
  for (int r = 0; r < rows; ++r) {
    for (int k = 0; k < cols; ++k) {
      const cv::Point2f& p = c[static_cast<size_t>(r * cols + k)];
      if (k + 1 < cols)
        best = std::min(best, static_cast<double>(cv::norm(c[static_cast<size_t>(r * cols + k + 1)] - p)));
      if (r + 1 < rows)
        best = std::min(best, static_cast<double>(cv::norm(c[static_cast<size_t>((r + 1) * cols + k)] - p)));
    }
  }
  return best;
}

void refineSubPix(const cv::Mat& gray, std::vector<cv::Point2f>& corners, int cols, int rows, double windowShare) {
  const double spacing = shortestSpacingPx(corners, cols, rows);
  const int half = std::clamp(static_cast<int>(std::lround(windowShare * spacing)), 3, 15);
  cv::cornerSubPix(gray, corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS | cv::TermCriteria::COUNT, 50, 0.001));
}

// The p-quantile (0..1) of a 256-bin histogram holding `total` samples.
double quantile(const std::vector<double>& hist, double total, double p) {
  double sum = 0.0;
  for (size_t i = 0; i < hist.size(); ++i) {
    sum += hist[i];
    if (sum >= p * total) return static_cast<double>(i);
  }
  return 255.0;
}

}  // namespace

const char* cornerMethodName(CornerMethod method) {
  switch (method) {
    case CornerMethod::kSector: return "sb";
    case CornerMethod::kSectorAccuracy: return "sb-accuracy";
    case CornerMethod::kClassicSubPix: return "classic-subpix";
    case CornerMethod::kSectorSubPix: return "sb-subpix";
  }
  return "?";
}

Result<CornerMethod> parseCornerMethod(const std::string& name) {
  for (CornerMethod m : kCornerMethods)
    if (name == cornerMethodName(m)) return m;
  return Status(Error::kInvalidArgument,
                "unknown corner detector '" + name + "' (sb, sb-accuracy, classic-subpix, sb-subpix)");
}

Result<std::vector<Eigen::Vector2d>> findCheckerboardCorners(const cv::Mat& gray, int cols, int rows,
                                                             const CornerOptions& options) {
  if (gray.empty() || gray.type() != CV_8UC1) return Status(Error::kBadInput, "not an 8-bit gray image");
  if (cols < 2 || rows < 2) return Status(Error::kInvalidArgument, "a checkerboard needs 2x2 inner corners or more");
  const cv::Size pattern(cols, rows);
  std::vector<cv::Point2f> corners;
  bool found = false;
  try {
    const int sb = cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE;
    switch (options.method) {
      case CornerMethod::kSector:
      case CornerMethod::kSectorSubPix: found = cv::findChessboardCornersSB(gray, pattern, corners, sb); break;
      case CornerMethod::kSectorAccuracy:
        found = cv::findChessboardCornersSB(gray, pattern, corners, sb | cv::CALIB_CB_ACCURACY);
        break;
      case CornerMethod::kClassicSubPix:
        found = cv::findChessboardCorners(gray, pattern, corners,
                                          cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE);
        break;
    }
    found = found && corners.size() == static_cast<size_t>(pattern.area());
    if (found && (options.method == CornerMethod::kClassicSubPix || options.method == CornerMethod::kSectorSubPix))
      refineSubPix(gray, corners, cols, rows, options.subPixWindowShare);
  } catch (const cv::Exception& e) {
    return Status(Error::kBadInput, std::string("corner detection failed: ") + e.what());
  }
  if (!found) return Status(Error::kNotFound, explainMissingCheckerboard(gray, cols, rows));
  std::vector<Eigen::Vector2d> out;
  out.reserve(corners.size());
  for (const auto& c : corners) out.emplace_back(c.x, c.y);
  return out;
}

Status refineCheckerboardCorners(const cv::Mat& gray, int cols, int rows, double windowShare,
                                 std::vector<Eigen::Vector2d>& corners) {
  if (gray.empty() || gray.type() != CV_8UC1) return {Error::kBadInput, "not an 8-bit gray image"};
  if (cols < 2 || rows < 2 || corners.size() != static_cast<size_t>(cols * rows))
    return {Error::kBadInput, "not a grid of " + patternText(cols, rows) + " corners"};
  std::vector<cv::Point2f> c;
  for (const auto& p : corners) c.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  try {
    refineSubPix(gray, c, cols, rows, windowShare);
  } catch (const cv::Exception& e) {
    return {Error::kBadInput, std::string("corner refinement failed: ") + e.what()};
  }
  for (size_t i = 0; i < c.size(); ++i) corners[i] = Eigen::Vector2d(c[i].x, c[i].y);
  return Status::ok();
}

ViewExposure measureView(const cv::Mat& gray) {
  ViewExposure v;
  if (gray.empty() || gray.type() != CV_8UC1) return v;
  std::vector<double> hist(256, 0.0);
  for (int r = 0; r < gray.rows; ++r) {
    const uint8_t* p = gray.ptr<uint8_t>(r);
    for (int c = 0; c < gray.cols; ++c) hist[p[c]] += 1.0;
  }
  const double total = static_cast<double>(gray.total());
  v.brightLevel = quantile(hist, total, 0.999);
  v.darkLevel = quantile(hist, total, 0.01);
  double saturated = 0.0;
  for (size_t i = 250; i < 256; ++i) saturated += hist[i];
  v.saturatedShare = saturated / total;
  // A step of contrast C blurred by a Gaussian of σ has the steepest slope C/(σ√(2π)):
  // σ from the local contrast (range over ±4 px) and the slope, at the steepest 0.2 %
  // of the pixels (the board's sharpest edges), median over them.
  cv::Mat f, gx, gy, mag, hi, lo;
  gray.convertTo(f, CV_32F);
  cv::Sobel(f, gx, CV_32F, 1, 0, 3, 1.0 / 8.0);
  cv::Sobel(f, gy, CV_32F, 0, 1, 3, 1.0 / 8.0);
  cv::magnitude(gx, gy, mag);
  const cv::Mat box = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(9, 9));
  cv::dilate(f, hi, box);
  cv::erode(f, lo, box);
  std::vector<float> slopes(mag.begin<float>(), mag.end<float>());
  const size_t keep = std::max<size_t>(1, slopes.size() / 500);
  std::nth_element(slopes.begin(), slopes.begin() + static_cast<std::ptrdiff_t>(keep - 1), slopes.end(),
                   std::greater<float>());
  const float threshold = std::max(slopes[keep - 1], 4.0f);  // below 4 levels/px there is no edge to speak of
  std::vector<double> sigmas;
  for (int r = 0; r < mag.rows; ++r) {
    const float* m = mag.ptr<float>(r);
    const float* h = hi.ptr<float>(r);
    const float* l = lo.ptr<float>(r);
    for (int c = 0; c < mag.cols; ++c)
      if (m[c] >= threshold)
        sigmas.push_back(static_cast<double>(h[c] - l[c]) / (std::sqrt(2.0 * M_PI) * static_cast<double>(m[c])));
  }
  if (sigmas.empty()) {
    v.edgeSigmaPx = std::numeric_limits<double>::quiet_NaN();
  } else {
    std::nth_element(sigmas.begin(), sigmas.begin() + static_cast<std::ptrdiff_t>(sigmas.size() / 2), sigmas.end());
    v.edgeSigmaPx = sigmas[sigmas.size() / 2];
  }
  return v;
}

std::string explainMissingCheckerboard(const cv::Mat& gray, int cols, int rows) {
  const std::string none = "no " + patternText(cols, rows) + " checkerboard found";
  if (gray.empty() || gray.type() != CV_8UC1) return none;
  const ViewExposure v = measureView(gray);
  char figures[160];
  std::snprintf(figures, sizeof figures, "levels %.0f..%.0f, %.1f %% saturated, edge blur sigma %.1f px", v.darkLevel,
                v.brightLevel, 100.0 * v.saturatedShare, v.edgeSigmaPx);
  if (v.brightLevel < 60.0) return none + ": too dark (" + figures + "); expose longer or add light";
  if (v.saturatedShare > 0.02) return none + ": overexposed (" + figures + "); expose shorter";
  if (v.brightLevel - v.darkLevel < 60.0) return none + ": too little contrast (" + figures + ")";
  // A smaller part of the pattern: the board is there but cut off, covered or in glare.
  for (const cv::Size part : {cv::Size(cols - 1, rows), cv::Size(cols, rows - 1), cv::Size(cols - 2, rows - 2)}) {
    if (part.width < 3 || part.height < 3) continue;
    std::vector<cv::Point2f> c;
    bool found = false;
    try {
      found = cv::findChessboardCornersSB(gray, part, c, cv::CALIB_CB_NORMALIZE_IMAGE);
    } catch (const cv::Exception&) {
      found = false;
    }
    if (found)
      return none + ": only a " + patternText(part.width, part.height) +
             " part of it (cut by the frame's edge, covered, in glare, or not this --board; " + figures + ")";
  }
  if (v.edgeSigmaPx > 1.6) return none + ": blurred (" + figures + "); refocus, or hold the board still";
  return none + " (" + figures + "): too far, too steep a tilt, or not this --board";
}

}  // namespace alacs::geometry
