#include "replay/scan_dir.h"

#include <sys/stat.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "common/json_file.h"
#include "replay/png_io.h"

namespace alacs::replay {

namespace {

Status fieldError(const std::string& dir, const std::string& field, const std::string& what) {
  return {Error::kBadInput, "scan '" + dir + "': manifest field '" + field + "' " + what};
}

bool isNumber(const cv::FileNode& n) { return n.isReal() || n.isInt(); }

Result<std::optional<image::Roi>> readRoi(const std::string& dir, const cv::FileNode& n, const std::string& field) {
  if (n.empty() || n.isNone()) return std::optional<image::Roi>{};
  if (!n.isSeq() || n.size() != 4) return fieldError(dir, field, "must be [x, y, width, height]");
  int v[4];
  for (int i = 0; i < 4; ++i) {
    if (!n[i].isInt()) return fieldError(dir, field, "must hold integers");
    v[i] = static_cast<int>(n[i]);
  }
  if (v[2] <= 0 || v[3] <= 0 || v[0] < 0 || v[1] < 0) return fieldError(dir, field, "must be a non-empty rectangle");
  return std::optional<image::Roi>(image::Roi{v[0], v[1], v[2], v[3]});
}

std::string jsonString(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') {
      o += '\\';
      o += c;
    } else if (c == '\n') {
      o += "\\n";
    } else if (static_cast<unsigned char>(c) < 0x20) {
      o += ' ';
    } else {
      o += c;
    }
  }
  return o + "\"";
}

std::string roiJson(const image::Roi& r) {
  // snprintf, not string concatenation: GCC 12 at -O3 warns (-Wrestrict) on the latter.
  char buf[64];
  std::snprintf(buf, sizeof buf, "[%d, %d, %d, %d]", r.x, r.y, r.width, r.height);
  return buf;
}

std::string num(double v, const char* fmt = "%.10g") {
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  return buf;
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

Result<ScanManifest> readManifest(const std::string& dir) {
  Result<cv::FileStorage> file = openJsonFile(dir + "/manifest.json", "scan manifest");
  if (!file) return file.status();
  const cv::FileNode root = file->root();
  const cv::FileNode fmt = root["format"];
  if (!fmt.isString() || static_cast<std::string>(fmt) != kScanFormat)
    return fieldError(dir, "format", std::string("must be \"") + kScanFormat + "\"");
  ScanManifest m;
  const cv::FileNode scan = root["scan"];
  if (!scan.isMap()) return fieldError(dir, "scan", "is missing");
  ScanInfo& s = m.scan;
  if (scan["kind"].isString()) s.kind = static_cast<std::string>(scan["kind"]);
  if (scan["source"].isString()) s.source = static_cast<std::string>(scan["source"]);
  if (!scan["width_px"].isInt() || !scan["height_px"].isInt()) return fieldError(dir, "scan.width_px", "and height_px must be integers");
  s.widthPx = static_cast<int>(scan["width_px"]);
  s.heightPx = static_cast<int>(scan["height_px"]);
  if (s.widthPx < 16 || s.heightPx < 16 || s.widthPx > 16384 || s.heightPx > 16384)
    return fieldError(dir, "scan.width_px", "must be in 16..16384");
  if (scan["pixel_format"].isString()) s.pixelFormat = static_cast<std::string>(scan["pixel_format"]);
  if (s.pixelFormat != "bgr8") return fieldError(dir, "scan.pixel_format", "must be \"bgr8\"");
  if (scan["target_id"].isInt()) s.targetId = static_cast<int>(scan["target_id"]);
  const cv::FileNode rough = scan["rough_mm"];
  if (!rough.empty() && !rough.isNone()) {
    if (!rough.isSeq() || rough.size() != 3 || !isNumber(rough[0]) || !isNumber(rough[1]) || !isNumber(rough[2]))
      return fieldError(dir, "scan.rough_mm", "must be an array of 3 numbers");
    s.roughMm = Eigen::Vector3d(rough[0].real(), rough[1].real(), rough[2].real());
  }
  const cv::FileNode stops = scan["stops_mm"];
  if (stops.isSeq())
    for (int i = 0; i < static_cast<int>(stops.size()); ++i) s.stopsMm.push_back(stops[i].real());
  Result<std::optional<image::Roi>> roi = readRoi(dir, scan["roi_px"], "scan.roi_px");
  if (!roi) return roi.status();
  s.roiPx = *roi;
  if (scan["calibration"].isString()) s.calibrationFile = static_cast<std::string>(scan["calibration"]);
  if (scan["truth"].isString()) s.truthFile = static_cast<std::string>(scan["truth"]);
  if (scan["note"].isString()) s.note = static_cast<std::string>(scan["note"]);

  const cv::FileNode frames = root["frames"];
  if (!frames.isSeq()) return fieldError(dir, "frames", "must be an array");
  for (int i = 0; i < static_cast<int>(frames.size()); ++i) {
    const cv::FileNode f = frames[i];
    const std::string w = "frames[" + std::to_string(i) + "]";
    FrameRecord r;
    r.index = f["index"].isInt() ? static_cast<int>(f["index"]) : i;
    if (!f["file"].isString()) return fieldError(dir, w + ".file", "is missing");
    r.file = static_cast<std::string>(f["file"]);
    if (r.file.empty() || r.file[0] == '/' || r.file.find("..") != std::string::npos)
      return fieldError(dir, w + ".file", "must be a path inside the scan directory");
    if (!isNumber(f["slide_mm"])) return fieldError(dir, w + ".slide_mm", "must be a number");
    r.slideMm = f["slide_mm"].real();
    if (!std::isfinite(r.slideMm)) return fieldError(dir, w + ".slide_mm", "must be finite");
    if (isNumber(f["slide_start_mm"])) r.slideStartMm = f["slide_start_mm"].real();
    if (isNumber(f["slide_end_mm"])) r.slideEndMm = f["slide_end_mm"].real();
    if (!isNumber(f["timestamp_s"])) return fieldError(dir, w + ".timestamp_s", "must be a number");
    r.timestampS = f["timestamp_s"].real();
    if (!f["exposure_us"].isInt() || static_cast<int>(f["exposure_us"]) <= 0)
      return fieldError(dir, w + ".exposure_us", "must be a positive integer");
    r.exposureUs = static_cast<int>(f["exposure_us"]);
    if (!f["laser_on"].isInt()) return fieldError(dir, w + ".laser_on", "must be true or false");
    r.laserOn = static_cast<int>(f["laser_on"]) != 0;
    Result<std::optional<image::Roi>> crop = readRoi(dir, f["crop_px"], w + ".crop_px");
    if (!crop) return crop.status();
    r.cropPx = *crop;
    if (r.cropPx && (r.cropPx->x + r.cropPx->width > s.widthPx || r.cropPx->y + r.cropPx->height > s.heightPx))
      return fieldError(dir, w + ".crop_px", "leaves the frame");
    if (f["truth"].isString()) r.truthFile = static_cast<std::string>(f["truth"]);
    if (f["tag"].isString()) r.tag = static_cast<std::string>(f["tag"]);
    m.frames.push_back(r);
  }
  return m;
}

std::string manifestJson(const ScanManifest& m) {
  const ScanInfo& s = m.scan;
  std::ostringstream o;
  o << "{\n  \"format\": \"" << kScanFormat << "\",\n  \"scan\": {\n";
  o << "    \"kind\": " << jsonString(s.kind) << ",\n    \"source\": " << jsonString(s.source) << ",\n";
  o << "    \"width_px\": " << s.widthPx << ", \"height_px\": " << s.heightPx
    << ", \"pixel_format\": " << jsonString(s.pixelFormat) << ",\n";
  o << "    \"target_id\": " << s.targetId << ",\n";
  if (s.roughMm)
    o << "    \"rough_mm\": [" << num(s.roughMm->x()) << ", " << num(s.roughMm->y()) << ", " << num(s.roughMm->z())
      << "],\n";
  o << "    \"stops_mm\": [";
  for (size_t i = 0; i < s.stopsMm.size(); ++i) o << (i ? ", " : "") << num(s.stopsMm[i]);
  o << "],\n";
  if (s.roiPx) o << "    \"roi_px\": " << roiJson(*s.roiPx) << ",\n";
  if (!s.truthFile.empty()) o << "    \"truth\": " << jsonString(s.truthFile) << ",\n";
  if (!s.note.empty()) o << "    \"note\": " << jsonString(s.note) << ",\n";
  o << "    \"calibration\": " << jsonString(s.calibrationFile) << "\n  },\n  \"frames\": [";
  for (size_t i = 0; i < m.frames.size(); ++i) {
    const FrameRecord& f = m.frames[i];
    o << (i ? ",\n" : "\n") << "    {\"index\": " << f.index << ", \"file\": " << jsonString(f.file)
      << ", \"slide_mm\": " << num(f.slideMm, "%.6f");
    if (std::isfinite(f.slideStartMm)) o << ", \"slide_start_mm\": " << num(f.slideStartMm, "%.6f");
    if (std::isfinite(f.slideEndMm)) o << ", \"slide_end_mm\": " << num(f.slideEndMm, "%.6f");
    o << ", \"timestamp_s\": " << num(f.timestampS, "%.9f") << ", \"exposure_us\": " << f.exposureUs
      << ", \"laser_on\": " << (f.laserOn ? "true" : "false");
    if (f.cropPx) o << ", \"crop_px\": " << roiJson(*f.cropPx);
    if (!f.truthFile.empty()) o << ", \"truth\": " << jsonString(f.truthFile);
    if (!f.tag.empty()) o << ", \"tag\": " << jsonString(f.tag);
    o << "}";
  }
  o << (m.frames.empty() ? "]\n}\n" : "\n  ]\n}\n");
  return o.str();
}

Status writeManifest(const std::string& dir, const ScanManifest& m) {
  const std::string path = dir + "/manifest.json";
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    if (!out) return {Error::kIo, "cannot write '" + tmp + "'"};
    out << manifestJson(m);
    out.flush();
    if (!out) return {Error::kIo, "cannot write '" + tmp + "'"};
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return {Error::kIo, "cannot rename to '" + path + "'"};
  return Status::ok();
}

Status loadFrameInto(const std::string& dir, const ScanManifest& m, const FrameRecord& f, cv::Mat& out) {
  const std::string path = dir + "/" + f.file;
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return {Error::kNotFound, "frame '" + path + "' does not exist"};
  // One buffer of the frame's size, reused from frame to frame; a crop decodes in place.
  out.create(m.scan.heightPx, m.scan.widthPx, CV_8UC3);
  cv::Mat dst = out;
  if (f.cropPx) {
    const cv::Rect crop(f.cropPx->x, f.cropPx->y, f.cropPx->width, f.cropPx->height);
    if ((crop & cv::Rect(0, 0, m.scan.widthPx, m.scan.heightPx)) != crop)
      return {Error::kBadInput, "frame '" + path + "': crop_px leaves the frame"};
    out.setTo(cv::Scalar::all(0));
    dst = out(crop);
  }
  if (Status s = readPngInto(path, dst); !s) return {s.code(), "frame " + s.reason()};
  return Status::ok();
}

Result<cv::Mat> loadFrame(const std::string& dir, const ScanManifest& m, const FrameRecord& f) {
  cv::Mat img;
  if (Status s = loadFrameInto(dir, m, f, img); !s) return s;
  return img;
}

Result<geometry::Calibration> loadScanCalibration(const std::string& dir, const ScanManifest& m) {
  return geometry::loadCalibration(dir + "/" + m.scan.calibrationFile);
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
