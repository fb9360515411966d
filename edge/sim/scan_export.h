// Exports a simulated scan as a scan directory (docs/scan-format.md): the frames as the
// camera would have taken them, the manifest, the true calibration, and the truth (the
// scene, and per frame the laser line on every apple and on the board, with flags).
#pragma once

#include <memory>
#include <optional>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "replay/scan_dir.h"
#include "sim/renderer.h"

namespace alacs::sim {

struct ExportFrame {
  double slideStartMm = 0.0;  // commanded position at exposure start
  double slideEndMm = 0.0;    // and end (different: exposed while moving)
  bool laserOn = true;
  int64_t exposureUs = 0;     // 0: the scene's
  double timestampS = 0.0;
  std::string tag;            // the frame's role in the manifest ("stop", "aimed"), optional
  double analogueGain = 0.0;  // linear; 0: the scene's (sensor.gainDb)
};

struct ExportOptions {
  // Render (and store) only this region of each frame: pixels outside are zero in the
  // replayed frame. The pipeline never reads outside its ROI, so a region covering the
  // ROI with a margin gives it exactly the pixels of a full render.
  std::optional<cv::Rect> renderRegion;
  bool writeTruth = true;
  uint64_t firstFrameIndex = 0;  // noise seed of the first frame
  // Per frame, or empty: each frame's noise seed (firstFrameIndex + its position when empty).
  std::vector<uint64_t> frameIndices;
  // Per frame, or empty: frames already rendered (the render region, as
  // Renderer::renderRegion gives it for this frame's request), written as they are; an
  // empty Mat is rendered here.
  std::vector<cv::Mat> rendered;
};

// Renders and writes `frames` into `dir`. `info` gives kind, target, rough position,
// stops and ROI; its size and source are filled in. Errors: kIo, kInvalidArgument.
Status exportScan(const SimScene& scene, const std::shared_ptr<const RayTable>& rays, const std::string& dir,
                  replay::ScanInfo info, const std::vector<ExportFrame>& frames, const ExportOptions& options = {});

// Truth rows of one frame as CSV: apple_id,row,column_px,x_mm,y_mm,z_mm,flags (board: -1).
std::string truthCsv(const SimScene& scene, double slideMm);
// truthCsv written to `path`. Errors: kIo.
Status writeTruthCsv(const SimScene& scene, double slideMm, const std::string& path);

}  // namespace alacs::sim
