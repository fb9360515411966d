// The scan directory: frames as PNG, a manifest (per frame: slide position, timestamp,
// exposure, laser on/off), the calibration, and optionally the truth. Written by the
// digital twin (tools/twin), by `alacsd --record`, or by anyone else; read by
// `alacsd --replay`, the evaluation (tools/eval) and the calibration tools.
// The format: docs/scan-format.md. Thread-safe (pure functions; ScanWriter is not).
#pragma once

#include <Eigen/Core>
#include <limits>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"
#include "image/image_view.h"

namespace alacs::replay {

inline constexpr const char* kScanFormat = "alacs-scan/1";

struct FrameRecord {
  int index = 0;
  std::string file;                 // PNG, relative to the scan directory
  double slideMm = 0.0;             // commanded slide position the frame belongs to (mean over the exposure)
  double slideStartMm = std::numeric_limits<double>::quiet_NaN();  // optional: at exposure start
  double slideEndMm = std::numeric_limits<double>::quiet_NaN();    // optional: at exposure end
  double timestampS = 0.0;          // exposure start, s (the recorder's monotonic clock, or scene time)
  int64_t exposureUs = 0;
  double analogueGain = 0.0;  // optional: the sensor's analogue gain, linear; 0: not recorded
  bool laserOn = true;
  std::optional<image::Roi> cropPx; // the PNG holds only this part of the frame; the rest is zero
  std::string truthFile;            // optional: truth rows of this frame (CSV), relative
  std::string tag;                  // optional role: "stop" (planned), "aimed" (laser on a known point), ...
};

struct ScanInfo {
  std::string kind = "localize";    // localize | lle | checkerboard | laser_plane | other
  std::string source = "twin";      // twin | alacsd | ...
  int widthPx = 0;
  int heightPx = 0;
  std::string pixelFormat = "bgr8"; // frames decode to 8-bit BGR
  int targetId = 0;
  std::optional<Eigen::Vector3d> roughMm;  // the rough target position the scan was made for
  std::vector<double> stopsMm;             // the planned stops
  std::optional<image::Roi> roiPx;         // the planned image ROI
  std::string calibrationFile = "calibration.json";
  std::string truthFile;                   // optional: truth/scene.json
  std::string note;                        // free text (the twin's case description)
};

struct ScanManifest {
  ScanInfo scan;
  std::vector<FrameRecord> frames;
};

inline constexpr size_t kManifestMaxBytes = size_t{64} << 20;
// Reads and checks DIR/manifest.json (a regular file of at most kManifestMaxBytes).
// Errors: kNotFound, kBadInput naming the field.
Result<ScanManifest> readManifest(const std::string& dir);
// Reads the manifest's fields; unknown keys are refused. Errors: kBadInput naming the field.
Status manifestFromJson(const Json& json, ScanManifest& manifest);
OrderedJson manifestToJson(const ScanManifest& manifest);
std::string manifestJson(const ScanManifest& manifest);
// Writes DIR/manifest.json atomically.
Status writeManifest(const std::string& dir, const ScanManifest& manifest);

// Decodes one frame to a full-size 8-bit BGR image; pixels outside its crop are zero.
// Errors: kNotFound, kBadInput (not a PNG, wrong size).
Result<cv::Mat> loadFrame(const std::string& dir, const ScanManifest& manifest, const FrameRecord& frame);
// The same into `out`, for a reader of many frames: a cropped frame reuses `out` when it
// has the frame's size (only the crop is decoded apart); a full frame replaces it, `out`
// released before the decode. On error `out` may be released.
Status loadFrameInto(const std::string& dir, const ScanManifest& manifest, const FrameRecord& frame, cv::Mat& out);
// The index of the frame a capture at `slideMm` with the laser `laserOn` is served in
// replay; -1: none. Laser-off frames (the ambient, the same at every slide position) are
// matched by exposure and gain first (the recorded one nearest `exposureUs` and
// `analogueGain` in ratio, the two ratios' logarithms added; 0: any, or a gain not
// recorded), then by position; laser-on frames by the recorded exposure nearest
// `exposureUs` first, frames within 20 % of it counting as one (so that a stop's second
// exposure, 1.25 times the first or more: MeteringParams::secondExposureFactor, is told
// apart), then by position.
int nearestFrame(const ScanManifest& manifest, double slideMm, bool laserOn, int64_t exposureUs = 0,
                 double analogueGain = 0.0);
// The calibration stored with the scan.
Result<geometry::Calibration> loadScanCalibration(const std::string& dir, const ScanManifest& manifest);

// Builds a scan directory frame by frame: create() makes the folders and writes the
// calibration; addFrame() writes each PNG at once; finish() writes the manifest.
class ScanWriter {
 public:
  // Errors: kIo when the directory cannot be made.
  static Result<ScanWriter> create(const std::string& dir, const ScanInfo& info, const geometry::Calibration& cal);
  // Writes `frame` (BGR8 or RGB8 view, full frame) or only `crop` of it. Fills in
  // record.index and record.file. Errors: kIo, kBadInput.
  Status addFrame(const image::ImageView& frame, FrameRecord record, std::optional<image::Roi> crop = std::nullopt);
  // The same for a frame that is already only the crop (e.g. a region render).
  Status addCrop(const cv::Mat& cropBgr, const image::Roi& crop, FrameRecord record);
  Status finish();

  const std::string& dir() const { return dir_; }
  ScanManifest& manifest() { return manifest_; }
  int frameCount() const { return static_cast<int>(manifest_.frames.size()); }

 private:
  ScanWriter(std::string dir, ScanManifest m) : dir_(std::move(dir)), manifest_(std::move(m)) {}
  Status writePng(const cv::Mat& bgr, FrameRecord& record);
  std::string dir_;
  ScanManifest manifest_;
};

// mkdir -p. Errors: kIo.
Status makeDirectories(const std::string& path);

}  // namespace alacs::replay
