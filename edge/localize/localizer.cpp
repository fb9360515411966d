#include "localize/localizer.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace alacs::localize {

Status ScanParams::validate() const {
  if (stops < 1 || stops > 15) return {Error::kInvalidArgument, "scan.stops must be in 1..15"};
  if (!(stopSpacingMm >= 0.5 && stopSpacingMm <= 50.0)) return {Error::kInvalidArgument, "scan.stop_spacing_mm must be in 0.5..50"};
  if (!(roiMarginMm >= 0.0 && roiMarginMm <= 300.0)) return {Error::kInvalidArgument, "scan.roi_margin_mm must be in 0..300"};
  if (!(gateMm > 10.0 && gateMm < 500.0)) return {Error::kInvalidArgument, "scan.gate_mm must be in 10..500"};
  return Status::ok();
}

Localizer::Localizer(const geometry::Calibration& cal, const image::LleParams& lle, const ScanParams& scan,
                     const geometry::WorkingRange& range)
    : cal_(cal), lle_(lle), scan_(scan), range_(range) {}

Result<ScanPlan> Localizer::plan(const Eigen::Vector3d& roughMm, double strokeMm) const {
  if (!(roughMm.z() >= range_.minDepthMm && roughMm.z() <= range_.maxDepthMm))
    return Status(Error::kOutOfRange, "rough z " + std::to_string(roughMm.z()) + " mm is outside the working range");
  const double centerMm = cal_.laser.slideForPoint(roughMm);
  if (!std::isfinite(centerMm)) return Status(Error::kNotCalibrated, "slide axis does not move the laser plane");
  ScanPlan plan;
  plan.roughMm = roughMm;
  const double half = 0.5 * (scan_.stops - 1) * scan_.stopSpacingMm;
  for (int i = 0; i < scan_.stops; ++i) {
    const double s = centerMm - half + i * scan_.stopSpacingMm;
    if (s >= 0.0 && s <= strokeMm) plan.stopsMm.push_back(s);
  }
  if (plan.stopsMm.empty())
    return Status(Error::kOutOfRange, "target needs the slide at " + std::to_string(centerMm) +
                                          " mm, outside the stroke [0, " + std::to_string(strokeMm) + "]");
  // ROI: the projected box of the rough centre ± (largest radius + margin).
  const auto& cam = cal_.camera;
  const double r = scan_.maxAppleRadiusMm + scan_.roiMarginMm;
  std::vector<Eigen::Vector3d> corners;
  for (int corner = 0; corner < 8; ++corner)
    corners.push_back(roughMm + r * Eigen::Vector3d((corner & 1) ? 1 : -1, (corner & 2) ? 1 : -1, (corner & 4) ? 1 : -1));
  double u0 = 1e9, v0 = 1e9, u1 = -1e9, v1 = -1e9;
  for (const geometry::PixelPoint& px : geometry::projectPoints(cam, corners)) {
    u0 = std::min(u0, px.columnPx);
    u1 = std::max(u1, px.columnPx);
    v0 = std::min(v0, px.rowPx);
    v1 = std::max(v1, px.rowPx);
  }
  const int x0 = std::clamp(static_cast<int>(std::floor(u0)), 0, cam.widthPx);
  const int x1 = std::clamp(static_cast<int>(std::ceil(u1)), 0, cam.widthPx);
  const int y0 = std::clamp(static_cast<int>(std::floor(v0)), 0, cam.heightPx);
  const int y1 = std::clamp(static_cast<int>(std::ceil(v1)), 0, cam.heightPx);
  plan.roi = {x0, y0, x1 - x0, y1 - y0};
  if (plan.roi.width < 16 || plan.roi.height < 16)
    return Status(Error::kOutOfRange, "target is outside the camera's view");
  return plan;
}

Result<LineObservation> Localizer::observe(const image::ImageView& frame, const ScanPlan& plan, double slideMm,
                                           image::LleWorkspace& ws) const {
  if (frame.width != cal_.camera.widthPx || frame.height != cal_.camera.heightPx)
    return Status(Error::kBadInput, "frame is " + std::to_string(frame.width) + "x" + std::to_string(frame.height) +
                                        " but the calibration is for " + std::to_string(cal_.camera.widthPx) + "x" +
                                        std::to_string(cal_.camera.heightPx));
  Result<image::LaserLine> line = image::extractLine(frame, plan.roi, lle_, ws);
  if (!line) return line.status();
  LineObservation obs;
  obs.slideMm = slideMm;
  obs.line = std::move(*line);
  std::vector<geometry::PixelPoint> pixels;
  pixels.reserve(obs.line.rows.size());
  for (const auto& r : obs.line.rows) pixels.push_back({r.column, static_cast<double>(r.row)});
  const std::vector<Eigen::Vector2d> xn = geometry::undistortPixels(cal_.camera, pixels);
  for (const auto& x : xn) {
    const geometry::TriangulatedPoint p = geometry::triangulate(cal_.laser, slideMm, x, range_);
    if (p.valid && (p.pointMm - plan.roughMm).norm() <= scan_.gateMm) obs.pointsMm.push_back(p.pointMm);
  }
  return obs;
}

Result<AppleEstimate> Localizer::estimate(const ScanPlan& plan, const std::vector<LineObservation>& lines) const {
  std::vector<Eigen::Vector3d> all;
  int linesWithPoints = 0;
  for (const auto& l : lines) {
    all.insert(all.end(), l.pointsMm.begin(), l.pointsMm.end());
    linesWithPoints += l.pointsMm.empty() ? 0 : 1;
  }
  if (all.empty()) return Status(Error::kNotFound, "no laser line hit the target");
  AppleEstimate est;
  est.linesUsed = linesWithPoints;
  geometry::SphereFitParams sp;
  Result<geometry::SphereFit> fit = geometry::fitSphere(all, sp);
  if (fit) {
    est.sphereFit = true;
    est.centerMm = fit->centerMm;
    est.diameterMm = 2.0 * fit->radiusMm;
    est.sigmaMm = fit->centerSigmaMm;
    est.pointsUsed = static_cast<int>(fit->inliers);
    const double inlierShare = static_cast<double>(fit->inliers) / static_cast<double>(all.size());
    est.confidencePct = std::clamp(100.0 * inlierShare * std::exp(-fit->rmsMm / 3.0), 0.0, 100.0);
    // Occlusion: rows expected from the fitted sphere's chord at each stop vs rows found.
    double expectedRows = 0.0;
    double foundRows = 0.0;
    for (const auto& l : lines) {
      const double delta = cal_.laser.planeNormal.dot(fit->centerMm) - cal_.laser.planeOffsetAt(l.slideMm);
      if (std::abs(delta) >= fit->radiusMm) continue;
      const double chord = 2.0 * std::sqrt(fit->radiusMm * fit->radiusMm - delta * delta);
      expectedRows += chord * cal_.camera.fyPx / fit->centerMm.z();
      foundRows += static_cast<double>(l.pointsMm.size());
    }
    est.occlusionPct = expectedRows > 0 ? std::clamp(100.0 * (1.0 - foundRows / expectedRows), 0.0, 100.0) : 0.0;
  } else {
    // The paper's single-line candidate: P = ω1·N − ω2·Δd, N the line's pixel count, Δd
    // the distance (px) of its middle from the expected centre; its middle point, pushed
    // one typical radius along the ray, stands for the centre.
    const geometry::PixelPoint expected = geometry::projectPoint(cal_.camera, plan.roughMm);
    const LineObservation* best = nullptr;
    double bestScore = -1e18;
    Eigen::Vector3d bestPoint = Eigen::Vector3d::Zero();
    for (const auto& l : lines) {
      if (l.pointsMm.empty()) continue;
      const Eigen::Vector3d mid = l.pointsMm[l.pointsMm.size() / 2];
      const geometry::PixelPoint px = geometry::projectPoint(cal_.camera, mid);
      const double dd = std::hypot(px.columnPx - expected.columnPx, px.rowPx - expected.rowPx);
      const double score = scan_.paperW1 * static_cast<double>(l.pointsMm.size()) - scan_.paperW2 * dd;
      if (score > bestScore) {
        bestScore = score;
        best = &l;
        bestPoint = mid;
      }
    }
    if (best == nullptr) return Status(Error::kNotFound, "no laser line hit the target");
    constexpr double kTypicalRadiusMm = 40.0;
    est.centerMm = bestPoint + kTypicalRadiusMm * bestPoint.normalized();
    est.diameterMm = 2.0 * kTypicalRadiusMm;
    est.sigmaMm = 10.0;
    est.pointsUsed = static_cast<int>(best->pointsMm.size());
    est.confidencePct = 20.0;
    est.occlusionPct = 0.0;
  }
  const double radius = 0.5 * est.diameterMm;
  const Eigen::Vector3d towardSensor = -est.centerMm.normalized();
  est.approachMm = est.centerMm + radius * towardSensor;
  est.approachNormal = towardSensor;
  return est;
}

}  // namespace alacs::localize
