// Renders what the camera sees: shaded apples and foliage, the laser line where the
// laser sheet meets the surfaces (with halo and speckle), noise, 8-bit clipping.
// Deterministic for (scene.seed, frameIndex). Not thread-safe per instance.
#pragma once

#include <opencv2/core.hpp>

#include "sim/scene.h"

namespace alacs::sim {

class Renderer {
 public:
  explicit Renderer(const SimScene& scene);

  // Renders one BGR frame into `out` (reallocated only when the size changes).
  // `laserFraction` is the share of the exposure during which the laser was on (0..1).
  void render(double slideMm, double laserFraction, uint64_t frameIndex, cv::Mat& out);

  const SimScene& scene() const { return scene_; }

 private:
  SimScene scene_;
  std::vector<cv::Point2f> rays_;  // undistorted normalized coordinates per pixel
};

}  // namespace alacs::sim
