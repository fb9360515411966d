#include "lle_output.h"

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>

namespace alacs::tools {

namespace {

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

Json lleDocument(const LleRun& run, int frameWidth, int frameHeight, const image::LaserLine& line) {
  const image::LleParams& p = run.params;
  Json doc;
  doc["format"] = "alacs-lle/1";
  doc["image"] = run.image;
  doc["laser_off"] = run.laserOff.empty() ? Json(nullptr) : Json(run.laserOff);
  doc["width"] = frameWidth;
  doc["height"] = frameHeight;
  doc["roi"] = {run.roi.x, run.roi.y, run.roi.width, run.roi.height};
  doc["implementation"] = run.reference ? std::string("float-reference") : std::string("fixed-point/") + image::lleSimdName();
  doc["millis"] = jsonNumber(run.millis, "%.3f");
  doc["params"] = {{"method", methodName(p.method)},
                   {"brce_step", p.brceStep},
                   {"brce_threshold", p.brceThreshold},
                   {"brce_form", formName(p.brceForm)},
                   {"noise_theta", p.noiseTheta},
                   {"noise_gamma", p.noiseGamma},
                   {"poly_order", p.polyOrder},
                   {"outlier_px", jsonNumber(p.outlierPx, "%g")},
                   {"min_rows", p.minRows},
                   {"smooth_rows", p.smoothRows},
                   {"robust_threshold_pct", p.robustThresholdPct},
                   {"weak_line_excess_dn", p.weakLineExcessDn},
                   {"weak_line_threshold_pct", p.weakLineThresholdPct},
                   {"short_line_pct", p.shortLinePct},
                   {"subtracted_line_threshold_pct", p.subtractedLineThresholdPct},
                   {"subtracted_rows", p.subtractedRows},
                   {"rerun_others_firm", p.rerunOthersFirm},
                   {"matched_filter", p.matchedFilter},
                   {"edge_ratio", p.edgeRatio},
                   {"edge_agree_px", p.edgeAgreePx},
                   {"max_jump_px", jsonNumber(p.maxJumpPx, "%g")},
                   {"max_gap_rows", p.maxGapRows},
                   {"min_segment_rows", p.minSegmentRows},
                   {"centre_prior_share", jsonNumber(p.centrePriorShare, "%g")}};
  // Every ROI row: a row without a valid sample says so (column null, valid false). A row's
  // first sample (the line's when it has one) is the entry; further samples (other
  // segments crossing the row) are listed in its "others".
  auto sample = [](Json& o, const image::RowSample& r) {
    o["column"] = r.valid() ? jsonNumber(r.column, "%.6f") : Json(nullptr);
    o["confidence"] = jsonNumber(r.confidence, "%.4f");
    o["valid"] = r.valid();
    o["status"] = statusName(r.status);
    o["segment"] = r.segment;
    o["column_q8"] = r.columnQ8;
    o["centroid"] = jsonNumber(r.centroidQ8 / 256.0, "%.6f");
    o["saturated"] = r.saturated;
  };
  Json rows = Json::array();
  size_t k = 0;
  for (int y = run.roi.y; y < run.roi.y + run.roi.height; ++y) {
    while (k < line.rows.size() && line.rows[k].row < y) ++k;
    Json row;
    row["row"] = y;
    if (k >= line.rows.size() || line.rows[k].row != y) {
      row["column"] = nullptr;
      row["confidence"] = 0;
      row["valid"] = false;
      row["status"] = "none";
      rows.push_back(std::move(row));
      continue;
    }
    sample(row, line.rows[k]);
    Json others = Json::array();
    for (size_t j = k + 1; j < line.rows.size() && line.rows[j].row == y; ++j) {
      Json o;
      sample(o, line.rows[j]);
      others.push_back(std::move(o));
    }
    if (!others.empty()) row["others"] = std::move(others);
    rows.push_back(std::move(row));
  }
  doc["rows"] = std::move(rows);
  Json coeffs = Json::array();
  for (int i = 0; i <= std::max(0, line.order); ++i) coeffs.push_back(jsonNumber(line.coeffs[static_cast<size_t>(i)], "%.9g"));
  doc["polynomial"] = {{"valid", line.valid},
                       {"order", line.order},
                       {"row_center", jsonNumber(line.rowCenter, "%.3f")},
                       {"row_half_span", jsonNumber(line.rowHalfSpan, "%.3f")},
                       {"coeffs", std::move(coeffs)},
                       {"form", "column = sum(coeffs[k] * t^k), t = (row - row_center) / row_half_span"},
                       {"inliers", line.inliers},
                       {"rms_residual_px", jsonNumber(line.rmsResidualPx, "%.4f")}};
  Json segments = Json::array();
  for (const auto& s : line.segments)
    segments.push_back({{"first_row", s.firstRow}, {"last_row", s.lastRow}, {"rows", s.rows}, {"on_line", s.onLine}});
  doc["segments"] = std::move(segments);
  doc["coverage"] = {{"first_line_row", line.firstLineRow},
                     {"last_line_row", line.lastLineRow},
                     {"line_rows", line.inliers},
                     {"share", jsonNumber(line.coverage, "%.4f")}};
  return doc;
}

std::string lleJson(const LleRun& run, int frameWidth, int frameHeight, const image::LaserLine& line) {
  return jsonText(lleDocument(run, frameWidth, frameHeight, line), -1);
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
