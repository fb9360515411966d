#include "geometry/camera_calibration.h"

#include <opencv2/calib3d.hpp>

#include <cmath>
#include <string>

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

}  // namespace

std::vector<Eigen::Vector3d> checkerboardCorners(int cols, int rows, double pitchMm) {
  std::vector<Eigen::Vector3d> out;
  out.reserve(static_cast<size_t>(std::max(0, cols * rows)));
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c) out.emplace_back(c * pitchMm, r * pitchMm, 0.0);
  return out;
}

Result<CameraFit> calibrateCamera(const std::vector<TargetView>& views, int widthPx, int heightPx,
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
  for (size_t v = 0; v < views.size(); ++v) {
    TargetPose pose = poseFrom(rvecs[v], tvecs[v]);
    pose.rmsPx = perView.at<double>(static_cast<int>(v));
    fit.poses.push_back(pose);
  }
  return fit;
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
