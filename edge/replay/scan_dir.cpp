#include "replay/scan_dir.h"

#include <sys/stat.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "common/file_beneath.h"
#include "common/json_file.h"
#include "replay/png_io.h"

namespace alacs::replay {

namespace {

constexpr size_t kMaxFrames = 100000;
constexpr size_t kMaxStops = 1000;

// A rectangle [x, y, width, height] of non-negative integers with a non-empty area.
std::optional<image::Roi> readRoi(JsonObjectReader& r, std::string_view key) {
  std::array<int64_t, 4> v{};
  if (!r.integers(key, v, 0, std::numeric_limits<int>::max())) return std::nullopt;
  if (v[2] <= 0 || v[3] <= 0) {
    r.fail(key, "must be a non-empty rectangle [x, y, width, height]");
    return std::nullopt;
  }
  return image::Roi{static_cast<int>(v[0]), static_cast<int>(v[1]), static_cast<int>(v[2]), static_cast<int>(v[3])};
}

// Whether `roi` lies inside a width × height frame, in 64-bit so that x + width cannot
// overflow.
bool insideFrame(const image::Roi& roi, int widthPx, int heightPx) {
  return int64_t{roi.x} + roi.width <= widthPx && int64_t{roi.y} + roi.height <= heightPx;
}

OrderedJson roiJson(const image::Roi& r) { return OrderedJson::array({r.x, r.y, r.width, r.height}); }

void readFrame(JsonObjectReader& f, const ScanInfo& s, size_t i, FrameRecord& r) {
  r.index = static_cast<int>(i);
  f.integer("index", r.index, Need::kOptional, 0, std::numeric_limits<int>::max());
  if (f.text("file", r.file, Need::kRequired, 1024) &&
      (r.file.empty() || r.file[0] == '/' || r.file.find("..") != std::string::npos))
    f.fail("file", "must be a path inside the scan directory");
  f.number("slide_mm", r.slideMm, Need::kRequired);
  f.number("slide_start_mm", r.slideStartMm);
  f.number("slide_end_mm", r.slideEndMm);
  f.number("timestamp_s", r.timestampS, Need::kRequired);
  f.integer("exposure_us", r.exposureUs, Need::kRequired, 1, 100000000);
  f.number("analogue_gain", r.analogueGain, Need::kOptional, 0.01, 1000.0);
  f.flag("laser_on", r.laserOn, Need::kRequired);
  if (f.has("crop_px")) {
    r.cropPx = readRoi(f, "crop_px");
    if (r.cropPx && !insideFrame(*r.cropPx, s.widthPx, s.heightPx)) f.fail("crop_px", "leaves the frame");
  }
  f.text("truth", r.truthFile, Need::kOptional, 1024);
  f.text("tag", r.tag, Need::kOptional, 256);
  f.finish();
}

}  // namespace

Status makeDirectories(const std::string& path) {
  std::string cur;
  std::stringstream ss(path);
  std::string part;
  if (!path.empty() && path[0] == '/') cur = "/";
  while (std::getline(ss, part, '/')) {
    if (part.empty()) continue;
    cur += part;
    if (::mkdir(cur.c_str(), 0755) != 0 && errno != EEXIST)
      return {Error::kIo, "cannot create directory '" + cur + "': " + std::strerror(errno)};
    cur += "/";
  }
  return Status::ok();
}

Status manifestFromJson(const Json& json, ScanManifest& m) {
  JsonErrors errors("manifest");
  JsonObjectReader root(errors, &json, "");
  std::string format;
  if (root.text("format", format, Need::kRequired) && format != kScanFormat)
    root.fail("format", std::string("must be \"") + kScanFormat + "\"");
  ScanInfo& s = m.scan;
  if (auto scan = root.object("scan", Need::kRequired)) {
    scan->text("kind", s.kind, Need::kOptional, 64);
    scan->text("source", s.source, Need::kOptional, 256);
    // What one frame buffer may take (replay/png_io.h's limits), checked before it is made.
    constexpr int kMaxSidePx = static_cast<int>(kMaxPngSidePx);
    if (scan->integer("width_px", s.widthPx, Need::kRequired, 16, kMaxSidePx) &&
        scan->integer("height_px", s.heightPx, Need::kRequired, 16, kMaxSidePx) &&
        static_cast<size_t>(s.widthPx) * static_cast<size_t>(s.heightPx) * 3U > kMaxPngDecodedBytes)
      scan->fail("height_px", "makes a frame larger than " + std::to_string(kMaxPngDecodedBytes >> 20) + " MB");
    if (scan->text("pixel_format", s.pixelFormat, Need::kOptional, 64) && s.pixelFormat != "bgr8")
      scan->fail("pixel_format", "must be \"bgr8\"");
    scan->integer("target_id", s.targetId);
    if (scan->has("rough_mm")) {
      std::array<double, 3> v{};
      if (scan->numbers("rough_mm", v)) s.roughMm = Eigen::Vector3d(v[0], v[1], v[2]);
    }
    scan->numberList("stops_mm", s.stopsMm, kMaxStops);
    if (scan->has("roi_px")) s.roiPx = readRoi(*scan, "roi_px");
    scan->text("calibration", s.calibrationFile, Need::kOptional, 1024);
    scan->text("truth", s.truthFile, Need::kOptional, 1024);
    scan->text("note", s.note, Need::kOptional, 65536);
    scan->finish();
  }
  if (const Json* frames = root.array("frames", kMaxFrames, Need::kRequired); frames != nullptr && errors.ok()) {
    m.frames.reserve(frames->size());
    for (size_t i = 0; i < frames->size() && errors.ok(); ++i) {
      JsonObjectReader f = root.element("frames", *frames, i);
      FrameRecord r;
      if (f.ok()) readFrame(f, s, i, r);
      m.frames.push_back(std::move(r));
    }
  }
  root.finish();
  return errors.status();
}

Result<ScanManifest> readManifest(const std::string& dir) {
  Result<Json> file = readJsonFileBeneath(dir, "manifest.json", "scan manifest", kManifestMaxBytes);
  if (!file) return file.status();
  ScanManifest m;
  if (Status s = manifestFromJson(*file, m); !s) return Status(s.code(), "scan '" + dir + "': " + s.reason());
  return m;
}

OrderedJson manifestToJson(const ScanManifest& m) {
  const ScanInfo& s = m.scan;
  OrderedJson scan;
  scan["kind"] = s.kind;
  scan["source"] = s.source;
  scan["width_px"] = s.widthPx;
  scan["height_px"] = s.heightPx;
  scan["pixel_format"] = s.pixelFormat;
  scan["target_id"] = s.targetId;
  if (s.roughMm) scan["rough_mm"] = {s.roughMm->x(), s.roughMm->y(), s.roughMm->z()};
  scan["stops_mm"] = s.stopsMm;
  if (s.roiPx) scan["roi_px"] = roiJson(*s.roiPx);
  if (!s.truthFile.empty()) scan["truth"] = s.truthFile;
  if (!s.note.empty()) scan["note"] = s.note;
  scan["calibration"] = s.calibrationFile;
  OrderedJson frames = OrderedJson::array();
  for (const FrameRecord& f : m.frames) {
    OrderedJson o;
    o["index"] = f.index;
    o["file"] = f.file;
    o["slide_mm"] = f.slideMm;
    if (std::isfinite(f.slideStartMm)) o["slide_start_mm"] = f.slideStartMm;
    if (std::isfinite(f.slideEndMm)) o["slide_end_mm"] = f.slideEndMm;
    o["timestamp_s"] = f.timestampS;
    o["exposure_us"] = f.exposureUs;
    if (f.analogueGain > 0.0) o["analogue_gain"] = f.analogueGain;
    o["laser_on"] = f.laserOn;
    if (f.cropPx) o["crop_px"] = roiJson(*f.cropPx);
    if (!f.truthFile.empty()) o["truth"] = f.truthFile;
    if (!f.tag.empty()) o["tag"] = f.tag;
    frames.push_back(std::move(o));
  }
  return {{"format", kScanFormat}, {"scan", std::move(scan)}, {"frames", std::move(frames)}};
}

std::string manifestJson(const ScanManifest& m) { return jsonText(manifestToJson(m)); }

Status writeManifest(const std::string& dir, const ScanManifest& m) {
  return geometry::writeFileAtomically(dir + "/manifest.json", manifestJson(m));
}

Status loadFrameInto(const std::string& dir, const ScanManifest& m, const FrameRecord& f, cv::Mat& out) {
  const std::string path = dir + "/" + f.file;
  // Inside the scan directory only: no symlink, no FIFO, no device (a scan directory
  // comes from a user, a field technician or the bus's --record).
  Result<UniqueFd> fd = openBeneath(dir, f.file, "frame");
  if (!fd) return fd.status();
  // One buffer of the frame's size, reused from frame to frame; a crop decodes in place.
  out.create(m.scan.heightPx, m.scan.widthPx, CV_8UC3);
  cv::Mat dst = out;
  if (f.cropPx) {
    const cv::Rect crop(f.cropPx->x, f.cropPx->y, f.cropPx->width, f.cropPx->height);
    if (crop.x < 0 || crop.y < 0 || crop.width <= 0 || crop.height <= 0 ||
        !insideFrame(*f.cropPx, m.scan.widthPx, m.scan.heightPx))
      return {Error::kBadInput, "frame '" + path + "': crop_px leaves the frame"};
    out.setTo(cv::Scalar::all(0));
    dst = out(crop);
  }
  if (Status s = readPngInto(fd->get(), path, dst); !s) return {s.code(), "frame " + s.reason()};
  return Status::ok();
}

Result<cv::Mat> loadFrame(const std::string& dir, const ScanManifest& m, const FrameRecord& f) {
  cv::Mat img;
  if (Status s = loadFrameInto(dir, m, f, img); !s) return s;
  return img;
}

int nearestFrame(const ScanManifest& m, double slideMm, bool laserOn, int64_t exposureUs, double analogueGain) {
  int best = -1;
  double bestExposureErr = std::numeric_limits<double>::infinity();
  double bestErr = std::numeric_limits<double>::infinity();
  const auto logRatioOf = [&](const FrameRecord& f) {
    return exposureUs > 0 && f.exposureUs > 0
               ? std::abs(std::log(static_cast<double>(f.exposureUs) / static_cast<double>(exposureUs)))
               : 0.0;
  };
  // Laser frames: the recorded exposure nearest the one asked for, those within 20 % of it
  // counting as one (a stop's second exposure is 1.25 times the first or more), then the
  // position.
  double nearestLaserRatio = std::numeric_limits<double>::infinity();
  if (laserOn)
    for (const FrameRecord& f : m.frames)
      if (f.laserOn) nearestLaserRatio = std::min(nearestLaserRatio, logRatioOf(f));
  for (size_t i = 0; i < m.frames.size(); ++i) {
    const FrameRecord& f = m.frames[i];
    if (f.laserOn != laserOn) continue;
    const double gainErr = !laserOn && analogueGain > 0.0 && f.analogueGain > 0.0
                               ? std::abs(std::log(f.analogueGain / analogueGain))
                               : 0.0;
    const double logRatio = logRatioOf(f);
    const double exposureErr = gainErr + (!laserOn                                        ? logRatio
                                          : logRatio <= nearestLaserRatio + std::log(1.2) ? 0.0
                                                                                          : logRatio);
    const double err = std::abs(f.slideMm - slideMm);
    if (exposureErr < bestExposureErr - 1e-9 || (exposureErr <= bestExposureErr + 1e-9 && err < bestErr)) {
      bestExposureErr = exposureErr;
      bestErr = err;
      best = static_cast<int>(i);
    }
  }
  return best;
}

Result<geometry::Calibration> loadScanCalibration(const std::string& dir, const ScanManifest& m) {
  return geometry::loadCalibrationBeneath(dir, m.scan.calibrationFile);
}

Result<ScanWriter> ScanWriter::create(const std::string& dir, const ScanInfo& info, const geometry::Calibration& cal) {
  if (Status s = makeDirectories(dir + "/frames"); !s) return s;
  if (info.widthPx != cal.camera.widthPx || info.heightPx != cal.camera.heightPx)
    return Status(Error::kInvalidArgument, "scan size differs from the calibration's camera");
  if (Status s = geometry::saveCalibration(cal, dir + "/" + info.calibrationFile); !s) return s;
  ScanManifest m;
  m.scan = info;
  return ScanWriter(dir, m);
}

Status ScanWriter::writePng(const cv::Mat& bgr, FrameRecord& record) {
  record.index = frameCount();
  char name[64];
  std::snprintf(name, sizeof name, "frames/frame_%04d.png", record.index);
  record.file = name;
  const std::string path = dir_ + "/" + record.file;
  // Level 1: a full frame encodes in tens of ms instead of hundreds; PNG stays lossless.
  if (Status s = replay::writePng(path, bgr, 1); !s) return s;
  manifest_.frames.push_back(record);
  return Status::ok();
}

Status ScanWriter::addFrame(const image::ImageView& frame, FrameRecord record, std::optional<image::Roi> crop) {
  if (frame.data == nullptr || frame.width != manifest_.scan.widthPx || frame.height != manifest_.scan.heightPx)
    return {Error::kBadInput, "frame size differs from the scan's"};
  cv::Mat view(frame.height, frame.width, CV_8UC3, const_cast<uint8_t*>(frame.data), frame.strideBytes);
  cv::Mat bgr;
  if (frame.format == image::PixelFormat::kRgb888) {
    cv::cvtColor(view, bgr, cv::COLOR_RGB2BGR);
  } else {
    bgr = view;
  }
  if (crop) {
    const cv::Rect r = cv::Rect(crop->x, crop->y, crop->width, crop->height) & cv::Rect(0, 0, frame.width, frame.height);
    if (r.empty()) return {Error::kInvalidArgument, "crop leaves the frame"};
    record.cropPx = image::Roi{r.x, r.y, r.width, r.height};
    return writePng(bgr(r), record);
  }
  record.cropPx.reset();
  return writePng(bgr, record);
}

Status ScanWriter::addCrop(const cv::Mat& cropBgr, const image::Roi& crop, FrameRecord record) {
  if (cropBgr.type() != CV_8UC3 || cropBgr.cols != crop.width || cropBgr.rows != crop.height)
    return {Error::kInvalidArgument, "crop image does not match its rectangle"};
  if (crop.x < 0 || crop.y < 0 || crop.x + crop.width > manifest_.scan.widthPx || crop.y + crop.height > manifest_.scan.heightPx)
    return {Error::kInvalidArgument, "crop leaves the frame"};
  const bool full = crop.x == 0 && crop.y == 0 && crop.width == manifest_.scan.widthPx && crop.height == manifest_.scan.heightPx;
  record.cropPx = full ? std::nullopt : std::optional<image::Roi>(crop);
  return writePng(cropBgr, record);
}

Status ScanWriter::finish() { return writeManifest(dir_, manifest_); }

}  // namespace alacs::replay
