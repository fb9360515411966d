#include "calibrate/calibrate_scans.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "geometry/triangulation.h"

namespace alacs::calib {

namespace {

image::ImageView viewOf(const cv::Mat& m) {
  return {m.data, m.cols, m.rows, m.step[0], image::PixelFormat::kBgr888};
}

std::string fmt(const char* f, double a) {
  char buf[256];
  std::snprintf(buf, sizeof buf, f, a);
  return buf;
}

}  // namespace

Result<geometry::TargetView> detectCheckerboard(const cv::Mat& bgr, const BoardSpec& board,
                                                const geometry::CornerOptions& options) {
  if (bgr.empty() || bgr.type() != CV_8UC3) return Status(Error::kBadInput, "not an 8-bit BGR image");
  cv::Mat gray;
  cv::cvtColor(bgr, gray, cv::COLOR_BGR2GRAY);
  const int cols = board.squaresX - 1;
  const int rows = board.squaresY - 1;
  Result<std::vector<Eigen::Vector2d>> corners = geometry::findCheckerboardCorners(gray, cols, rows, options);
  if (!corners) return corners.status();
  geometry::TargetView view;
  view.objectMm = geometry::checkerboardCorners(cols, rows, board.squareMm);
  view.imagePx = std::move(*corners);
  return view;
}

Result<CalibrationRun> runCalibration(const CalibrationInput& in, const ImageLoader& load) {
  CalibrationRun run;
  if (in.widthPx < 16 || in.heightPx < 16) return Status(Error::kBadInput, "image size is not set");
  // 1. Every image of the board with the laser off is a camera view.
  std::vector<std::string> names = in.cameraViews;
  std::vector<int> placementView(in.placements.size(), -1);
  for (size_t p = 0; p < in.placements.size(); ++p) {
    placementView[p] = static_cast<int>(names.size());
    names.push_back(in.placements[p].boardImage);
  }
  std::vector<geometry::TargetView> views;
  std::vector<int> viewOfName(names.size(), -1);
  std::vector<std::string> nameOfView;
  for (size_t i = 0; i < names.size(); ++i) {
    Result<cv::Mat> img = load(names[i]);
    if (!img) return img.status();
    if (img->cols != in.widthPx || img->rows != in.heightPx)
      return Status(Error::kBadInput, names[i] + ": image is " + std::to_string(img->cols) + "x" +
                                          std::to_string(img->rows) + ", expected " + std::to_string(in.widthPx) +
                                          "x" + std::to_string(in.heightPx));
    Result<geometry::TargetView> v = detectCheckerboard(*img, in.board, in.corners);
    if (!v) {
      run.skippedViews.push_back(names[i] + ": " + v.status().reason());
      run.log.push_back(names[i] + ": skipped (" + v.status().reason() + ")");
      if (in.onSkipped) in.onSkipped(names[i], v.status().reason());
      continue;
    }
    viewOfName[i] = static_cast<int>(views.size());
    nameOfView.push_back(names[i]);
    views.push_back(std::move(*v));
  }
  Result<geometry::CameraFit> cam = geometry::calibrateCamera(views, in.widthPx, in.heightPx, in.cameraOptions);
  if (!cam) return Status(cam.status().code(), "camera: " + cam.status().reason());
  run.camera = *cam;
  if (cam->outliers.count() > 0) {
    // The placements' poses below are taken from the same corners the camera was solved on.
    views = geometry::withoutCorners(views, cam->outliers);
    for (size_t v = 0; v < cam->outliers.perView.size(); ++v)
      if (!cam->outliers.perView[v].empty())
        run.log.push_back("camera: " + nameOfView[v] + ": " + std::to_string(cam->outliers.perView[v].size()) + " of " +
                          std::to_string(views[v].objectMm.size() + cam->outliers.perView[v].size()) +
                          " corners left out as misplaced");
  }
  run.log.push_back("camera: " + std::to_string(views.size()) +
                    " views (corners: " + geometry::cornerMethodName(in.corners.method) + "), reprojection RMS " +
                    fmt("%.3f px", cam->rmsPx));
  {
    // The full covariance must agree with calib3d's σ on its diagonal; its off-diagonal
    // fx–fy term is what turns a focal error into a depth-scale error.
    const auto& c = cam->covariance;
    std::ostringstream msg;
    msg.precision(3);
    msg << "camera: σ fx " << std::sqrt(c(0, 0)) << " px (calib3d " << cam->sigmaPx[0] << "), σ fy "
        << std::sqrt(c(1, 1)) << " px (calib3d " << cam->sigmaPx[1] << "), corr(fx, fy) "
        << c(0, 1) / std::sqrt(c(0, 0) * c(1, 1));
    run.log.push_back(msg.str());
  }

  // 2. Per placement: the board's plane, then the laser line on it at every slide position.
  const BoardSpec& b = in.board;
  const double x0 = -b.squareMm - b.marginMm + in.boardEdgeGuardMm;
  const double x1 = (b.squaresX - 1) * b.squareMm + b.marginMm - in.boardEdgeGuardMm;
  const double y0 = -b.squareMm - b.marginMm + in.boardEdgeGuardMm;
  const double y1 = (b.squaresY - 1) * b.squareMm + b.marginMm - in.boardEdgeGuardMm;
  std::vector<geometry::LaserLineSample> samples;
  // The same lines in pixels, with the board's corners, for the total σ.
  geometry::CalibrationObservations observations;
  std::vector<int> observedPlacement(in.placements.size(), -1);
  image::LleWorkspace ws;
  for (size_t p = 0; p < in.placements.size(); ++p) {
    const PlacementRef& pl = in.placements[p];
    const int vi = viewOfName[static_cast<size_t>(placementView[p])];
    if (vi < 0) {
      run.log.push_back(pl.name + ": skipped (no board in " + pl.boardImage + ")");
      if (in.onSkipped) in.onSkipped(pl.name, "placement not used: no board in its laser-off frame " + pl.boardImage);
      continue;
    }
    Result<geometry::TargetPose> pose = geometry::locateTarget(cam->camera, views[static_cast<size_t>(vi)]);
    if (!pose) {
      run.log.push_back(pl.name + ": skipped (" + pose.status().reason() + ")");
      if (in.onSkipped) in.onSkipped(pl.name, "placement not used: " + pose.status().reason());
      continue;
    }
    Result<cv::Mat> off = load(pl.boardImage);
    if (!off) return off.status();
    // ROI: the board's outline in the image.
    std::vector<Eigen::Vector3d> outline;
    for (const auto& c : {Eigen::Vector3d(x0, y0, 0), Eigen::Vector3d(x1, y0, 0), Eigen::Vector3d(x1, y1, 0),
                          Eigen::Vector3d(x0, y1, 0)})
      outline.push_back(pose->rotation * c + pose->translationMm);
    double u0 = 1e9, v0 = 1e9, u1 = -1e9, v1 = -1e9;
    for (const auto& q : geometry::projectPoints(cam->camera, outline)) {
      u0 = std::min(u0, q.columnPx);
      u1 = std::max(u1, q.columnPx);
      v0 = std::min(v0, q.rowPx);
      v1 = std::max(v1, q.rowPx);
    }
    image::Roi roi;
    roi.x = std::clamp(static_cast<int>(std::floor(u0)), 0, in.widthPx);
    roi.y = std::clamp(static_cast<int>(std::floor(v0)), 0, in.heightPx);
    roi.width = std::clamp(static_cast<int>(std::ceil(u1)), 0, in.widthPx) - roi.x;
    roi.height = std::clamp(static_cast<int>(std::ceil(v1)), 0, in.heightPx) - roi.y;
    if (roi.width < 16 || roi.height < 16) {
      run.log.push_back(pl.name + ": skipped (board outside the frame)");
      if (in.onSkipped) in.onSkipped(pl.name, "placement not used: board outside the frame");
      continue;
    }
    const Eigen::Matrix3d rt = pose->rotation.transpose();
    int used = 0;
    for (const LaserFrameRef& f : pl.laserFrames) {
      Result<cv::Mat> on = load(f.image);
      if (!on) return on.status();
      // Laser on minus laser off: the board's print and the ambient light cancel, the
      // line stays, also across the black squares.
      cv::Mat diff;
      cv::subtract(*on, *off, diff);
      Result<image::LaserLine> line = image::extractLine(viewOf(diff), roi, in.lle, ws);
      if (!line || line->rows.empty()) {
        run.log.push_back(f.image + ": no laser line on the board");
        continue;
      }
      std::vector<geometry::PixelPoint> px;
      for (const auto& r : line->rows) px.push_back({static_cast<double>(r.column), static_cast<double>(r.row)});
      const std::vector<Eigen::Vector2d> xn = geometry::undistortPixels(cam->camera, px);
      if (observedPlacement[p] < 0) {
        observedPlacement[p] = static_cast<int>(observations.placementViews.size());
        observations.placementViews.push_back(views[static_cast<size_t>(vi)]);
      }
      geometry::LaserPixelLine pixelLine;
      pixelLine.placement = observedPlacement[p];
      pixelLine.slideMm = f.slideMm;
      geometry::LaserLineSample s;
      s.placement = static_cast<int>(p);
      s.targetNormal = pose->planeNormal();
      s.targetOffsetMm = pose->planeOffsetMm();
      s.slideMm = f.slideMm;
      for (size_t i = 0; i < xn.size(); ++i) {
        const Eigen::Vector2d& x = xn[i];
        const Eigen::Vector3d ray(x.x(), x.y(), 1.0);
        const double t = s.targetOffsetMm / s.targetNormal.dot(ray);
        if (!(t > 0.0)) continue;
        const Eigen::Vector3d onBoard = rt * (t * ray - pose->translationMm);
        if (onBoard.x() < x0 || onBoard.x() > x1 || onBoard.y() < y0 || onBoard.y() > y1) continue;
        s.normalized.push_back(x);
        pixelLine.pixels.push_back(px[i]);
      }
      used += static_cast<int>(s.normalized.size());
      if (!s.normalized.empty()) {
        samples.push_back(std::move(s));
        observations.lines.push_back(std::move(pixelLine));
      }
    }
    std::ostringstream msg;
    msg << pl.name << ": board at " << std::lround(pose->translationMm.z()) << " mm, "
        << pl.laserFrames.size() << " laser frames, " << used << " line pixels on the board";
    run.log.push_back(msg.str());
  }
  geometry::LaserFitOptions lo;
  lo.focalPx = cam->camera.fxPx;
  lo.nominalSlideAxis = in.nominalSlideAxis;
  Result<geometry::LaserFit> laser = geometry::calibrateLaser(samples, lo);
  if (!laser) return Status(laser.status().code(), "laser: " + laser.status().reason());
  run.laser = *laser;

  // 3. The total σ: the intrinsics' covariance carried through the poses and the laser
  // refit, over the working distances and the stroke the scans covered.
  geometry::UncertaintyOptions uo;
  uo.laser = lo;
  uo.draws = in.uncertaintyDraws;
  uo.strokeStartMm = 1e9;
  uo.strokeEndMm = -1e9;
  for (const auto& line : observations.lines) {
    uo.strokeStartMm = std::min(uo.strokeStartMm, line.slideMm);
    uo.strokeEndMm = std::max(uo.strokeEndMm, line.slideMm);
  }
  Result<geometry::CalibrationUncertainty> unc =
      geometry::propagateCalibrationUncertainty(cam->camera, cam->covariance, *laser, observations, uo);
  if (!unc) {
    run.uncertaintyError = "total σ: " + unc.status().reason();
    run.log.push_back(run.uncertaintyError + " (the gate refuses a calibration without it)");
  } else {
    run.uncertainty = *unc;
    std::ostringstream msg;
    msg << "total σ: " << unc->solves << " re-solves of poses and laser plane ("
        << (uo.draws > 0 ? "Monte Carlo" : "±1σ per direction") << "), stroke " << uo.strokeStartMm << ".."
        << uo.strokeEndMm << " mm";
    run.log.push_back(msg.str());
  }

  geometry::Calibration& cal = run.calibration;
  cal.camera = cam->camera;
  cal.laser = laser->laser;
  geometry::CalibrationQuality& q = cal.quality;
  q.reprojectionRmsPx = cam->rmsPx;
  q.cameraViews = static_cast<int>(views.size());
  q.fxSigmaPx = cam->sigmaPx[0];
  q.fySigmaPx = cam->sigmaPx[1];
  q.cxSigmaPx = cam->sigmaPx[2];
  q.cySigmaPx = cam->sigmaPx[3];
  q.planeRmsMm = laser->rmsMm;
  q.laserRmsPx = laser->rmsPx;
  q.inlierShare = laser->points > 0 ? static_cast<double>(laser->inliers) / static_cast<double>(laser->points) : 0.0;
  q.targetPlacements = laser->placements;
  q.slidePositions = laser->slidePositions;
  q.normalSigmaMrad = laser->normalSigmaMrad;
  q.offsetSigmaMm = laser->offsetSigmaMm;
  q.scaleSigma = laser->scaleSigma;
  q.depthSigmaMmAt1000 = laser->depthSigmaMmAt1000;
  q.depthSigmaMmAt1600 = laser->depthSigmaMmAt1600;
  if (!unc) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    for (double* f : {&q.depthSigmaTotalMmAt1000, &q.depthSigmaTotalMmAt1200, &q.depthSigmaTotalMmAt1400,
                      &q.depthSigmaTotalMmAt1600, &q.sigma3dTotalMmAt1000, &q.sigma3dTotalMmAt1200,
                      &q.sigma3dTotalMmAt1400, &q.sigma3dTotalMmAt1600})
      *f = nan;
  }
  for (const auto& u : unc ? unc->byDepth : std::vector<geometry::DepthUncertainty>{}) {
    const long mm = std::lround(u.depthMm);
    double* depth = mm == 1000 ? &q.depthSigmaTotalMmAt1000
                    : mm == 1200 ? &q.depthSigmaTotalMmAt1200
                    : mm == 1400 ? &q.depthSigmaTotalMmAt1400
                    : mm == 1600 ? &q.depthSigmaTotalMmAt1600
                                 : nullptr;
    double* full = mm == 1000 ? &q.sigma3dTotalMmAt1000
                   : mm == 1200 ? &q.sigma3dTotalMmAt1200
                   : mm == 1400 ? &q.sigma3dTotalMmAt1400
                   : mm == 1600 ? &q.sigma3dTotalMmAt1600
                                : nullptr;
    if (depth != nullptr) *depth = u.depthSigmaTotalMm;
    if (full != nullptr) *full = u.sigma3dTotalMm;
  }
  q.fromTruth = false;
  return run;
}

}  // namespace alacs::calib
