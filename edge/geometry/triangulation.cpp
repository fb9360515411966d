#include "geometry/triangulation.h"

#include <opencv2/calib3d.hpp>
#include <Eigen/Geometry>
#include <cmath>

namespace alacs::geometry {

namespace {
cv::Matx33d cameraMatrix(const CameraIntrinsics& cam) {
  return {cam.fxPx, 0.0, cam.cxPx, 0.0, cam.fyPx, cam.cyPx, 0.0, 0.0, 1.0};
}
cv::Vec<double, 5> distCoeffs(const CameraIntrinsics& cam) {
  return {cam.distortion[0], cam.distortion[1], cam.distortion[2], cam.distortion[3], cam.distortion[4]};
}
}  // namespace

std::vector<Eigen::Vector2d> undistortPixels(const CameraIntrinsics& cam,
                                             const std::vector<PixelPoint>& pixels) {
  std::vector<Eigen::Vector2d> out;
  if (pixels.empty()) return out;
  std::vector<cv::Point2d> in;
  in.reserve(pixels.size());
  for (const auto& p : pixels) in.emplace_back(p.columnPx, p.rowPx);
  std::vector<cv::Point2d> und;
  // More iterations than OpenCV's default 5: at the frame corners the default leaves
  // tenths of a pixel, which is millimetres of depth.
  cv::undistortPoints(in, und, cameraMatrix(cam), distCoeffs(cam), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-12));
  out.reserve(und.size());
  for (const auto& p : und) out.emplace_back(p.x, p.y);
  return out;
}

TriangulatedPoint triangulate(const LaserGeometry& laser, double slideMm, const Eigen::Vector2d& xn,
                              const WorkingRange& range) {
  TriangulatedPoint result;
  const Eigen::Vector3d ray(xn.x(), xn.y(), 1.0);
  const double denom = laser.planeNormal.dot(ray);
  if (!std::isfinite(denom) || std::abs(denom) < range.minCosIncidence * ray.norm()) return result;
  const double t = laser.planeOffsetAt(slideMm) / denom;  // = depth z, since ray.z == 1
  if (!std::isfinite(t) || t <= 0.0) return result;
  if (t < range.minDepthMm || t > range.maxDepthMm) return result;
  result.pointMm = t * ray;
  result.valid = true;
  return result;
}

std::vector<PixelPoint> projectPoints(const CameraIntrinsics& cam, const std::vector<Eigen::Vector3d>& pointsMm) {
  std::vector<PixelPoint> out;
  if (pointsMm.empty()) return out;
  std::vector<cv::Point3d> obj;
  obj.reserve(pointsMm.size());
  for (const auto& p : pointsMm) obj.emplace_back(p.x(), p.y(), p.z());
  std::vector<cv::Point2d> img;
  cv::projectPoints(obj, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cameraMatrix(cam), distCoeffs(cam), img);
  out.reserve(img.size());
  for (const auto& q : img) out.push_back({q.x, q.y});
  return out;
}

PixelPoint projectPoint(const CameraIntrinsics& cam, const Eigen::Vector3d& pointMm) {
  return projectPoints(cam, {pointMm})[0];
}

}  // namespace alacs::geometry
