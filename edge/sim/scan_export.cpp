#include "sim/scan_export.h"

#include <cstdio>
#include <fstream>
#include <sstream>

namespace alacs::sim {

std::string truthCsv(const SimScene& scene, double slideMm) {
  std::ostringstream o;
  o << "apple_id,row,column_px,x_mm,y_mm,z_mm,flags\n";
  char buf[160];
  auto emit = [&](const std::vector<RowTruth>& rows) {
    for (const auto& r : rows) {
      std::snprintf(buf, sizeof buf, "%d,%d,%.6f,%.5f,%.5f,%.5f,%u\n", r.appleId, r.row, r.column, r.pointMm.x(),
                    r.pointMm.y(), r.pointMm.z(), static_cast<unsigned>(r.flags));
      o << buf;
    }
  };
  for (const auto& a : scene.apples) emit(laserLineTruthAll(scene, a, slideMm));
  emit(boardLineTruth(scene, slideMm));
  return o.str();
}

namespace {
Status writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) return {Error::kIo, "cannot write '" + path + "'"};
  out << text;
  out.flush();
  if (!out) return {Error::kIo, "cannot write '" + path + "'"};
  return Status::ok();
}
}  // namespace

Status writeTruthCsv(const SimScene& scene, double slideMm, const std::string& path) {
  return writeText(path, truthCsv(scene, slideMm));
}

Status exportScan(const SimScene& scene, const std::shared_ptr<const RayTable>& rays, const std::string& dir,
                  replay::ScanInfo info, const std::vector<ExportFrame>& frames, const ExportOptions& options) {
  info.widthPx = scene.truth.camera.widthPx;
  info.heightPx = scene.truth.camera.heightPx;
  info.source = "twin";
  if (options.writeTruth) info.truthFile = "truth/scene.json";
  Result<replay::ScanWriter> w = replay::ScanWriter::create(dir, info, scene.truth);
  if (!w) return w.status();
  if (options.writeTruth) {
    if (Status s = replay::makeDirectories(dir + "/truth"); !s) return s;
    if (Status s = saveScene(scene, dir + "/truth/scene.json"); !s) return s;
    if (scene.board) {
      std::ostringstream o;
      o << "i,j,x_mm,y_mm,z_mm,column_px,row_px,visible\n";
      char buf[160];
      for (const auto& c : boardCorners(scene)) {
        std::snprintf(buf, sizeof buf, "%d,%d,%.5f,%.5f,%.5f,%.6f,%.6f,%d\n", c.i, c.j, c.pointMm.x(), c.pointMm.y(),
                      c.pointMm.z(), c.pixel.x(), c.pixel.y(), c.visible ? 1 : 0);
        o << buf;
      }
      if (Status s = writeText(dir + "/truth/corners.csv", o.str()); !s) return s;
    }
  }
  Renderer renderer(scene, rays);
  const cv::Rect full(0, 0, info.widthPx, info.heightPx);
  const cv::Rect region = options.renderRegion ? (*options.renderRegion & full) : full;
  if (region.empty()) return {Error::kInvalidArgument, "render region is outside the frame"};
  if ((!options.frameIndices.empty() && options.frameIndices.size() != frames.size()) ||
      (!options.rendered.empty() && options.rendered.size() != frames.size()))
    return {Error::kInvalidArgument, "frameIndices and rendered hold one entry per frame, or none"};
  cv::Mat crop;
  for (size_t i = 0; i < frames.size(); ++i) {
    const ExportFrame& f = frames[i];
    FrameRequest req;
    req.slideStartMm = f.slideStartMm;
    req.slideEndMm = f.slideEndMm;
    req.laserFraction = f.laserOn ? 1.0 : 0.0;
    req.exposureUs = f.exposureUs > 0 ? f.exposureUs : scene.sensor.exposureUs;
    req.analogueGain = f.analogueGain > 0.0 ? f.analogueGain : scene.sensor.analogueGain();
    req.frameIndex = options.frameIndices.empty() ? options.firstFrameIndex + i : options.frameIndices[i];
    const cv::Mat* rendered = options.rendered.empty() || options.rendered[i].empty() ? nullptr : &options.rendered[i];
    if (rendered == nullptr) {
      renderer.renderRegion(req, region, crop);
    } else if (rendered->size() == region.size() && rendered->type() == CV_8UC3) {
      crop = *rendered;
    } else {
      return {Error::kInvalidArgument, "a frame rendered beforehand is not of the render region"};
    }
    replay::FrameRecord rec;
    rec.slideMm = 0.5 * (f.slideStartMm + f.slideEndMm);
    if (f.slideStartMm != f.slideEndMm) {
      rec.slideStartMm = f.slideStartMm;
      rec.slideEndMm = f.slideEndMm;
    }
    rec.timestampS = f.timestampS;
    rec.exposureUs = req.exposureUs;
    rec.analogueGain = req.analogueGain;
    rec.laserOn = f.laserOn;
    rec.tag = f.tag;
    if (options.writeTruth && f.laserOn) {
      char name[64];
      std::snprintf(name, sizeof name, "truth/frame_%04d.csv", w->frameCount());
      rec.truthFile = name;
      if (Status s = writeTruthCsv(scene, rec.slideMm, dir + "/" + rec.truthFile); !s) return s;
    }
    if (Status s = w->addCrop(crop, image::Roi{region.x, region.y, region.width, region.height}, rec); !s) return s;
  }
  return w->finish();
}

}  // namespace alacs::sim
