#include "lle_output.h"

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstdio>
#include <sstream>

namespace alacs::tools {

namespace {

std::string quoted(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", c);
      out += buf;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

std::string num(double v, const char* fmt = "%.6f") {
  if (!std::isfinite(v)) return "null";
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
}

const char* methodName(image::LleMethod m) { return m == image::LleMethod::kPaper ? "paper" : "robust"; }
const char* formName(image::BrceForm f) { return f == image::BrceForm::kLiteral ? "literal" : "meaning"; }

}  // namespace

const char* statusName(image::RowStatus s) {
  switch (s) {
    case image::RowStatus::kLine: return "line";
    case image::RowStatus::kOutlier: return "outlier";
    case image::RowStatus::kSegment: return "segment";
    case image::RowStatus::kEdge: return "edge";
  }
  return "?";
}

std::string lleJson(const LleRun& run, int frameWidth, int frameHeight, const image::LaserLine& line) {
  const image::LleParams& p = run.params;
  std::ostringstream o;
  o << "{\n  \"format\": \"alacs-lle/1\",\n  \"image\": " << quoted(run.image) << ",\n";
  o << "  \"laser_off\": " << (run.laserOff.empty() ? "null" : quoted(run.laserOff)) << ",\n";
  o << "  \"width\": " << frameWidth << ", \"height\": " << frameHeight << ",\n";
  o << "  \"roi\": [" << run.roi.x << ", " << run.roi.y << ", " << run.roi.width << ", " << run.roi.height << "],\n";
  o << "  \"implementation\": " << quoted(run.reference ? "float-reference" : std::string("fixed-point/") + image::lleSimdName())
    << ", \"millis\": " << num(run.millis, "%.3f") << ",\n";
  o << "  \"params\": {\"method\": \"" << methodName(p.method) << "\", \"brce_step\": " << p.brceStep
    << ", \"brce_threshold\": " << p.brceThreshold << ", \"brce_form\": \"" << formName(p.brceForm)
    << "\", \"noise_theta\": " << p.noiseTheta << ", \"noise_gamma\": " << p.noiseGamma
    << ", \"poly_order\": " << p.polyOrder << ", \"outlier_px\": " << num(p.outlierPx, "%g")
    << ", \"min_rows\": " << p.minRows << ", \"smooth_rows\": " << p.smoothRows << ", \"robust_threshold_pct\": " << p.robustThresholdPct << ", \"weak_line_excess_dn\": " << p.weakLineExcessDn << ", \"weak_line_threshold_pct\": " << p.weakLineThresholdPct << ", \"edge_ratio\": " << p.edgeRatio << ", \"edge_agree_px\": " << p.edgeAgreePx
    << ", \"max_jump_px\": " << num(p.maxJumpPx, "%g") << ", \"max_gap_rows\": " << p.maxGapRows
    << ", \"min_segment_rows\": " << p.minSegmentRows << "},\n";
  // Every ROI row: a row without a valid sample says so (column null, valid false). A row's
  // first sample (the line's when it has one) is the entry; further samples (other
  // segments crossing the row) are listed in its "others".
  o << "  \"rows\": [";
  size_t k = 0;
  auto sample = [&](const image::RowSample& r) {
    o << "\"column\": " << (r.valid() ? num(r.column) : "null") << ", \"confidence\": " << num(r.confidence, "%.4f")
      << ", \"valid\": " << (r.valid() ? "true" : "false") << ", \"status\": \"" << statusName(r.status)
      << "\", \"segment\": " << r.segment << ", \"column_q8\": " << r.columnQ8
      << ", \"centroid\": " << num(r.centroidQ8 / 256.0) << ", \"saturated\": " << (r.saturated ? "true" : "false");
  };
  for (int y = run.roi.y; y < run.roi.y + run.roi.height; ++y) {
    while (k < line.rows.size() && line.rows[k].row < y) ++k;
    o << (y == run.roi.y ? "\n    " : ",\n    ");
    if (k >= line.rows.size() || line.rows[k].row != y) {
      o << "{\"row\": " << y << ", \"column\": null, \"confidence\": 0, \"valid\": false, \"status\": \"none\"}";
      continue;
    }
    o << "{\"row\": " << y << ", ";
    sample(line.rows[k]);
    size_t j = k + 1;
    if (j < line.rows.size() && line.rows[j].row == y) {
      o << ", \"others\": [";
      for (bool first = true; j < line.rows.size() && line.rows[j].row == y; ++j, first = false) {
        o << (first ? "{" : ", {");
        sample(line.rows[j]);
        o << "}";
      }
      o << "]";
    }
    o << "}";
  }
  o << "\n  ],\n";
  o << "  \"polynomial\": {\"valid\": " << (line.valid ? "true" : "false") << ", \"order\": " << line.order
    << ", \"row_center\": " << num(line.rowCenter, "%.3f") << ", \"row_half_span\": " << num(line.rowHalfSpan, "%.3f")
    << ", \"coeffs\": [";
  for (int i = 0; i <= std::max(0, line.order); ++i)
    o << (i ? ", " : "") << num(line.coeffs[static_cast<size_t>(i)], "%.9g");
  o << "], \"form\": \"column = sum(coeffs[k] * t^k), t = (row - row_center) / row_half_span\", \"inliers\": "
    << line.inliers << ", \"rms_residual_px\": " << num(line.rmsResidualPx, "%.4f") << "},\n";
  o << "  \"segments\": [";
  for (size_t i = 0; i < line.segments.size(); ++i) {
    const auto& s = line.segments[i];
    o << (i ? ", " : "") << "{\"first_row\": " << s.firstRow << ", \"last_row\": " << s.lastRow << ", \"rows\": " << s.rows
      << ", \"on_line\": " << (s.onLine ? "true" : "false") << "}";
  }
  o << "],\n";
  o << "  \"coverage\": {\"first_line_row\": " << line.firstLineRow << ", \"last_line_row\": " << line.lastLineRow
    << ", \"line_rows\": " << line.inliers << ", \"share\": " << num(line.coverage, "%.4f") << "}\n}\n";
  return o.str();
}

cv::Mat lleOverlay(const cv::Mat& bgr, const image::Roi& roi, const image::LaserLine& line) {
  cv::Mat out = bgr.clone();
  cv::rectangle(out, cv::Rect(roi.x, roi.y, roi.width, roi.height), {255, 255, 255}, 1);
  constexpr int kShift = 4;  // sub-pixel drawing: coordinates in 1/16 px
  constexpr double kScale = 16.0;
  if (line.valid && line.lastLineRow >= line.firstLineRow) {
    std::vector<cv::Point> curve;
    for (int y = line.firstLineRow; y <= line.lastLineRow; ++y)
      curve.emplace_back(static_cast<int>(std::lround(line.columnAt(y) * kScale)), static_cast<int>(y * kScale));
    cv::polylines(out, curve, false, {0, 255, 255}, 1, cv::LINE_AA, kShift);
  }
  for (const auto& s : line.rows) {
    const cv::Scalar colour = s.status == image::RowStatus::kLine      ? cv::Scalar(0, 255, 0)
                              : s.status == image::RowStatus::kOutlier ? cv::Scalar(255, 0, 255)
                              : s.status == image::RowStatus::kEdge    ? cv::Scalar(0, 128, 255)
                                                                        : cv::Scalar(255, 255, 0);
    const cv::Point p(static_cast<int>(std::lround((s.column - 3.0F) * kScale)), static_cast<int>(s.row * kScale));
    const cv::Point q(static_cast<int>(std::lround((s.column - 1.5F) * kScale)), static_cast<int>(s.row * kScale));
    cv::line(out, p, q, colour, 1, cv::LINE_AA, kShift);  // a tick left of the line, not over it
  }
  return out;
}

}  // namespace alacs::tools
