// Renders what the camera sees, physically: ambient light (diffuse sky or room light and
// a directional sun or lamp, with shadows) reflected by apples, leaves, branches, the
// board and the background (with gaps of sky); the laser sheet's irradiance where it
// meets those surfaces (range and incidence, sub-surface halo on skin, speckle, shadows
// of the laser, the slide's motion during the exposure); the lens (f-number,
// transmission, cos⁴ vignetting, blur); the sensor (electrons, shot noise, PRNU, full
// well, read noise, gain, 12-bit ADC, optional RGGB mosaic and demosaic) and 8-bit
// output with clipping. Every constant: docs/simulation.md.
//
// Deterministic for (scene.seed, frameIndex): the noise of a pixel depends on its
// coordinates, not on the order of rendering, so a region render is exactly the crop
// of the full render (tests/unit/sim_render_test.cpp). Not thread-safe per instance;
// one renderer per thread (they can share a RayTable).
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "sim/raycast.h"
#include "sim/scene.h"
#include "sim/truth.h"

namespace alacs::sim {

// The undistorted normalised ray (x/z, y/z) of every pixel, and per 16×16 tile the
// bounding box of those rays. Built once per camera and shared (read-only).
class RayTable {
 public:
  explicit RayTable(const geometry::CameraIntrinsics& cam);
  static constexpr int kTile = 16;
  struct Box {
    float x0, y0, x1, y1;
  };
  const geometry::CameraIntrinsics& camera() const { return cam_; }
  const cv::Point2f& ray(int u, int v) const {
    return rays_[static_cast<size_t>(v) * static_cast<size_t>(cam_.widthPx) + static_cast<size_t>(u)];
  }
  int tilesX() const { return tilesX_; }
  int tilesY() const { return tilesY_; }
  const Box& tile(int tu, int tv) const { return tiles_[static_cast<size_t>(tv * tilesX_ + tu)]; }

 private:
  geometry::CameraIntrinsics cam_;
  std::vector<cv::Point2f> rays_;
  int tilesX_ = 0;
  int tilesY_ = 0;
  std::vector<Box> tiles_;
};

struct FrameRequest {
  double slideStartMm = 0.0;   // slide position (commanded mm) when the exposure starts
  double slideEndMm = 0.0;     // and when it ends; equal for a frame taken at rest
  // A rolling shutter: row v exposes v line times after row 0, when the slide has moved
  // v × this further (the positions above are row 0's). 0: a global shutter.
  double slideMmPerRow = 0.0;
  double laserFraction = 1.0;  // share of the exposure the laser was on, 0..1
  int64_t exposureUs = 0;      // 0: the scene's sensor.exposureUs
  // The sensor's analogue gain, linear (1: 0 dB, the full well at the ADC's full scale;
  // 2: the twin's usual 6 dB). 0: the scene's sensor.gainDb.
  double analogueGain = 0.0;
  uint64_t frameIndex = 0;     // seeds noise and speckle, with the scene's seed
  // The speckle's seed instead of frameIndex (-1: frameIndex, a new speckle each frame, as
  // a moving slide sees). A laser at rest on a still scene keeps its speckle from frame to
  // frame, so frames of one stop averaged (alacs-twin render --average) share one.
  int64_t speckleFrameIndex = -1;
};

class Renderer {
 public:
  // `rays` must be for the scene's camera; null: built here.
  explicit Renderer(const SimScene& scene, std::shared_ptr<const RayTable> rays = nullptr);
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  // A frame at rest at `slideMm` with the scene's exposure, into `out` (BGR8, full frame,
  // reallocated only when the size changes). `laserFraction`: share of the exposure the
  // laser was on (0..1).
  void render(double slideMm, double laserFraction, uint64_t frameIndex, cv::Mat& out);
  // A full frame (BGR8).
  void render(const FrameRequest& request, cv::Mat& out);
  // Only `roi` (clipped to the frame) into `crop` (BGR8, roi-sized): the same pixels as
  // the full frame's crop, at a fraction of the cost.
  void renderRegion(const FrameRequest& request, const cv::Rect& roi, cv::Mat& crop);

  const SimScene& scene() const { return scene_; }
  const std::shared_ptr<const RayTable>& rays() const { return rays_; }

 private:
  void shadeRegion(const FrameRequest& request, const cv::Rect& region, cv::Mat& electrons) const;
  void sensorRegion(const FrameRequest& request, const cv::Rect& region, cv::Mat& electrons, cv::Mat& bgr) const;

  SimScene scene_;
  std::shared_ptr<const RayTable> rays_;
  SceneGeometry geometry_;
  std::vector<std::vector<int>> tileObjects_;  // per tile: objects whose projection may cover it
  double skyThreshold_ = 0.0;                  // value-noise level below which the foliage is sky
};

}  // namespace alacs::sim
