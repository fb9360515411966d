#include "geometry/camera_calibration.h"

#include <algorithm>

#include <opencv2/calib3d.hpp>

#include <Eigen/Dense>
#include <cmath>
#include <string>

#include "geometry/triangulation.h"

namespace alacs::geometry {

namespace {

std::vector<cv::Point3d> toCv(const std::vector<Eigen::Vector3d>& pts) {
  std::vector<cv::Point3d> out;
  out.reserve(pts.size());
  for (const auto& p : pts) out.emplace_back(p.x(), p.y(), p.z());
  return out;
}

std::vector<cv::Point2d> toCv(const std::vector<Eigen::Vector2d>& pts) {
  std::vector<cv::Point2d> out;
  out.reserve(pts.size());
  for (const auto& p : pts) out.emplace_back(p.x(), p.y());
  return out;
}

TargetPose poseFrom(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat r;
  cv::Rodrigues(rvec, r);
  TargetPose pose;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) pose.rotation(i, j) = r.at<double>(i, j);
    pose.translationMm(i) = tvec.at<double>(i);
  }
  return pose;
}

double viewRms(const std::vector<cv::Point3d>& obj, const std::vector<cv::Point2d>& img, const cv::Mat& rvec,
               const cv::Mat& tvec, const cv::Matx33d& k, const cv::Mat& dist) {
  std::vector<cv::Point2d> proj;
  cv::projectPoints(obj, rvec, tvec, k, dist, proj);
  double sum = 0.0;
  for (size_t i = 0; i < proj.size(); ++i) {
    const cv::Point2d d = proj[i] - img[i];
    sum += d.dot(d);
  }
  return proj.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(proj.size()));
}

cv::Matx33d cameraMatrix(const CameraIntrinsics& cam) {
  return {cam.fxPx, 0.0, cam.cxPx, 0.0, cam.fyPx, cam.cyPx, 0.0, 0.0, 1.0};
}

// The intrinsics' covariance as calib3d forms its σ, σ²·(JᵀJ)⁻¹, but kept whole: the 6
// pose parameters of each view are eliminated per view (Schur complement), which leaves
// the 9×9 block of the inverse exactly. σ² = Σr²/(N − free parameters) with N the number
// of *corners*, as calib3d divides (not 2N residuals): that is √2 more conservative than
// the textbook per-coordinate variance, and keeps the diagonal equal to the fx_sigma_px
// etc. that calib3d reports and the gate checks (docs/calibration.md, "Total σ").
IntrinsicsCovariance intrinsicsCovariance(const std::vector<std::vector<cv::Point3f>>& obj,
                                          const std::vector<std::vector<cv::Point2f>>& img,
                                          const std::vector<cv::Mat>& rvecs, const std::vector<cv::Mat>& tvecs,
                                          const cv::Mat& k, const cv::Mat& dist, const std::array<bool, 9>& isFree) {
  using Mat96 = Eigen::Matrix<double, 9, 6>;
  using Mat66 = Eigen::Matrix<double, 6, 6>;
  Eigen::Matrix<double, 9, 9> a = Eigen::Matrix<double, 9, 9>::Zero();
  double sumSq = 0.0;
  size_t observations = 0;
  for (size_t v = 0; v < obj.size(); ++v) {
    std::vector<cv::Point3d> o(obj[v].begin(), obj[v].end());
    std::vector<cv::Point2d> proj;
    cv::Mat jac;  // 2N × (3 rvec, 3 tvec, fx, fy, cx, cy, 5 distortion)
    cv::projectPoints(o, rvecs[v], tvecs[v], k, dist, proj, jac);
    Mat96 b = Mat96::Zero();
    Mat66 c = Mat66::Zero();
    for (int r = 0; r < jac.rows; ++r) {
      Eigen::Matrix<double, 6, 1> je;
      Eigen::Matrix<double, 9, 1> ji;
      for (int j = 0; j < 6; ++j) je(j) = jac.at<double>(r, j);
      for (int j = 0; j < 9; ++j) ji(j) = isFree[static_cast<size_t>(j)] ? jac.at<double>(r, 6 + j) : 0.0;
      a += ji * ji.transpose();
      b += ji * je.transpose();
      c += je * je.transpose();
    }
    a -= b * c.ldlt().solve(b.transpose());
    for (size_t i = 0; i < proj.size(); ++i) {
      const cv::Point2d d = proj[i] - cv::Point2d(img[v][i]);
      sumSq += d.dot(d);
    }
    observations += 2 * proj.size();
  }
  int nFree = 0;
  for (bool f : isFree) nFree += f ? 1 : 0;
  const double dof =
      static_cast<double>(observations / 2) - static_cast<double>(nFree + 6 * static_cast<int>(obj.size()));
  IntrinsicsCovariance cov = IntrinsicsCovariance::Zero();
  if (!(dof > 0.0)) return cov;
  // Invert only the free block; a fixed parameter has no variance.
  std::vector<int> idx;
  for (int i = 0; i < 9; ++i)
    if (isFree[static_cast<size_t>(i)]) idx.push_back(i);
  Eigen::MatrixXd sub(idx.size(), idx.size());
  for (size_t i = 0; i < idx.size(); ++i)
    for (size_t j = 0; j < idx.size(); ++j) sub(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = a(idx[i], idx[j]);
  const Eigen::MatrixXd inv = sub.ldlt().solve(Eigen::MatrixXd::Identity(sub.rows(), sub.cols()));
  const double sigma2 = sumSq / dof;
  for (size_t i = 0; i < idx.size(); ++i)
    for (size_t j = 0; j < idx.size(); ++j)
      cov(idx[i], idx[j]) = sigma2 * inv(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j));
  return cov;
}

}  // namespace

CameraIntrinsics perturbIntrinsics(const CameraIntrinsics& camera, const IntrinsicsVector& delta) {
  CameraIntrinsics c = camera;
  c.fxPx += delta(0);
  c.fyPx += delta(1);
  c.cxPx += delta(2);
  c.cyPx += delta(3);
  for (size_t i = 0; i < 5; ++i) c.distortion[i] += delta(static_cast<Eigen::Index>(4 + i));
  return c;
}

std::vector<Eigen::Vector3d> checkerboardCorners(int cols, int rows, double pitchMm) {
  std::vector<Eigen::Vector3d> out;
  out.reserve(static_cast<size_t>(std::max(0, cols * rows)));
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) out.emplace_back(c * pitchMm, r * pitchMm, 0.0);
  return out;
}

namespace {

// One calib3d solve over every corner of every view.
Result<CameraFit> solveCamera(const std::vector<TargetView>& views, int widthPx, int heightPx,
                              const CameraFitOptions& options) {
  if (views.size() < options.minViews)
    return Status(Error::kBadInput, "camera calibration needs at least " + std::to_string(options.minViews) +
                                        " target views, got " + std::to_string(views.size()));
  if (widthPx < 16 || heightPx < 16) return Status(Error::kBadInput, "camera calibration: bad image size");
  std::vector<std::vector<cv::Point3f>> obj;
  std::vector<std::vector<cv::Point2f>> img;
  for (size_t v = 0; v < views.size(); ++v) {
    const TargetView& view = views[v];
    if (view.objectMm.size() != view.imagePx.size())
      return Status(Error::kBadInput, "target view " + std::to_string(v) + ": corner counts differ");
    if (view.objectMm.size() < options.minCornersPerView)
      return Status(Error::kBadInput, "target view " + std::to_string(v) + " has only " +
                                          std::to_string(view.objectMm.size()) + " corners");
    // calib3d's planar initialisation wants float points; the refinement runs in double.
    std::vector<cv::Point3f> o;
    std::vector<cv::Point2f> i;
    for (size_t k = 0; k < view.objectMm.size(); ++k) {
      const Eigen::Vector3d& p = view.objectMm[k];
      if (std::abs(p.z()) > 1e-9) return Status(Error::kBadInput, "target corners must lie on z = 0");
      o.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), 0.0F);
      i.emplace_back(static_cast<float>(view.imagePx[k].x()), static_cast<float>(view.imagePx[k].y()));
    }
    obj.push_back(std::move(o));
    img.push_back(std::move(i));
  }
  int flags = 0;
  if (options.fixK3) flags |= cv::CALIB_FIX_K3;
  if (options.fixTangential) flags |= cv::CALIB_ZERO_TANGENT_DIST;
  cv::Mat k = cv::Mat::eye(3, 3, CV_64F);
  cv::Mat dist = cv::Mat::zeros(5, 1, CV_64F);
  std::vector<cv::Mat> rvecs;
  std::vector<cv::Mat> tvecs;
  cv::Mat stdIntrinsics;
  cv::Mat stdExtrinsics;
  cv::Mat perView;
  double rms = 0.0;
  try {
    rms = cv::calibrateCamera(obj, img, cv::Size(widthPx, heightPx), k, dist, rvecs, tvecs, stdIntrinsics,
                              stdExtrinsics, perView, flags,
                              cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-12));
  } catch (const cv::Exception& e) {
    return Status(Error::kBadInput, std::string("calib3d failed: ") + e.what());
  }
  if (!std::isfinite(rms)) return Status(Error::kBadInput, "calib3d returned a non-finite error");
  CameraFit fit;
  fit.rmsPx = rms;
  fit.camera.widthPx = widthPx;
  fit.camera.heightPx = heightPx;
  fit.camera.fxPx = k.at<double>(0, 0);
  fit.camera.fyPx = k.at<double>(1, 1);
  fit.camera.cxPx = k.at<double>(0, 2);
  fit.camera.cyPx = k.at<double>(1, 2);
  for (int i = 0; i < 5; ++i) fit.camera.distortion[static_cast<size_t>(i)] = dist.at<double>(i);
  for (int i = 0; i < 4; ++i) fit.sigmaPx[static_cast<size_t>(i)] = stdIntrinsics.at<double>(i);
  for (int i = 0; i < 5; ++i) fit.sigmaDistortion[static_cast<size_t>(i)] = stdIntrinsics.at<double>(4 + i);
  std::array<bool, 9> isFree{};
  isFree.fill(true);
  if (options.fixK3) isFree[8] = false;
  if (options.fixTangential) isFree[6] = isFree[7] = false;
  fit.covariance = intrinsicsCovariance(obj, img, rvecs, tvecs, k, dist, isFree);
  for (size_t v = 0; v < views.size(); ++v) {
    TargetPose pose = poseFrom(rvecs[v], tvecs[v]);
    pose.rmsPx = perView.at<double>(static_cast<int>(v));
    fit.poses.push_back(pose);
  }
  return fit;
}

}  // namespace

size_t CornerOutliers::count() const {
  size_t n = 0;
  for (const auto& v : perView) n += v.size();
  return n;
}

std::vector<TargetView> withoutCorners(const std::vector<TargetView>& views, const CornerOutliers& outliers) {
  std::vector<TargetView> out;
  out.reserve(views.size());
  for (size_t v = 0; v < views.size(); ++v) {
    const std::vector<size_t>* drop = v < outliers.perView.size() ? &outliers.perView[v] : nullptr;
    if (drop == nullptr || drop->empty()) {
      out.push_back(views[v]);
      continue;
    }
    TargetView kept;
    for (size_t k = 0; k < views[v].objectMm.size(); ++k) {
      if (std::find(drop->begin(), drop->end(), k) != drop->end()) continue;
      kept.objectMm.push_back(views[v].objectMm[k]);
      kept.imagePx.push_back(views[v].imagePx[k]);
    }
    out.push_back(std::move(kept));
  }
  return out;
}

CornerOutliers findCornerOutliers(const std::vector<TargetView>& views, const CameraFit& fit,
                                  const CameraFitOptions& options) {
  CornerOutliers out;
  out.perView.resize(views.size());
  if (!(options.outlierSigmas > 0.0) || fit.poses.size() != views.size()) return out;
  std::vector<std::vector<double>> residuals(views.size());
  std::vector<double> all;
  for (size_t v = 0; v < views.size(); ++v) {
    std::vector<Eigen::Vector3d> camPts;
    camPts.reserve(views[v].objectMm.size());
    for (const auto& p : views[v].objectMm) camPts.push_back(fit.poses[v].rotation * p + fit.poses[v].translationMm);
    const std::vector<PixelPoint> proj = projectPoints(fit.camera, camPts);
    for (size_t k = 0; k < proj.size(); ++k) {
      const double r = std::hypot(proj[k].columnPx - views[v].imagePx[k].x(), proj[k].rowPx - views[v].imagePx[k].y());
      residuals[v].push_back(r);
      all.push_back(r);
    }
  }
  if (all.empty()) return out;
  auto mid = all.begin() + static_cast<std::ptrdiff_t>(all.size() / 2);
  std::nth_element(all.begin(), mid, all.end());
  // The norm of a 2D Gaussian residual (σ per axis) is Rayleigh: its median is 1.1774 σ.
  out.sigmaPx = *mid / 1.1774;
  out.boundPx = std::max(options.outlierMinPx, options.outlierSigmas * out.sigmaPx);
  for (size_t v = 0; v < views.size(); ++v) {
    std::vector<size_t> far;
    for (size_t k = 0; k < residuals[v].size(); ++k)
      if (residuals[v][k] > out.boundPx) far.push_back(k);
    // A view that would keep too few corners keeps them all (the solve needs them; its own
    // RMS then shows it).
    if (residuals[v].size() - far.size() >= options.minCornersPerView) out.perView[v] = std::move(far);
  }
  return out;
}

Result<CameraFit> calibrateCamera(const std::vector<TargetView>& views, int widthPx, int heightPx,
                                  const CameraFitOptions& options) {
  Result<CameraFit> first = solveCamera(views, widthPx, heightPx, options);
  if (!first || !(options.outlierSigmas > 0.0)) return first;
  CornerOutliers outliers = findCornerOutliers(views, *first, options);
  if (outliers.count() == 0) {
    first->outliers = std::move(outliers);
    return first;
  }
  Result<CameraFit> second = solveCamera(withoutCorners(views, outliers), widthPx, heightPx, options);
  if (!second) return second;
  second->outliers = std::move(outliers);
  return second;
}

Result<TargetPose> locateTarget(const CameraIntrinsics& camera, const TargetView& view) {
  if (view.objectMm.size() < 4 || view.objectMm.size() != view.imagePx.size())
    return Status(Error::kBadInput, "target pose needs at least 4 matched corners");
  const std::vector<cv::Point3d> obj = toCv(view.objectMm);
  const std::vector<cv::Point2d> img = toCv(view.imagePx);
  const cv::Matx33d k = cameraMatrix(camera);
  cv::Mat dist(5, 1, CV_64F);
  for (int i = 0; i < 5; ++i) dist.at<double>(i) = camera.distortion[static_cast<size_t>(i)];
  cv::Mat rvec;
  cv::Mat tvec;
  try {
    // IPPE is the closed form for planar targets; LM then minimises the reprojection error.
    if (!cv::solvePnP(obj, img, k, dist, rvec, tvec, false, cv::SOLVEPNP_IPPE))
      return Status(Error::kBadInput, "target pose: solvePnP failed");
    cv::solvePnPRefineLM(obj, img, k, dist, rvec, tvec,
                         cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
  } catch (const cv::Exception& e) {
    return Status(Error::kBadInput, std::string("target pose: ") + e.what());
  }
  TargetPose pose = poseFrom(rvec, tvec);
  if (!(pose.translationMm.z() > 0.0)) return Status(Error::kBadInput, "target pose: target behind the camera");
  pose.rmsPx = viewRms(obj, img, rvec, tvec, k, dist);
  return pose;
}

}  // namespace alacs::geometry
