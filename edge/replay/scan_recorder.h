// Records live scans as scan directories (alacsd --record DIR): one directory per scan,
// DIR/scan_0001, DIR/scan_0002, ..., each with its frames, the calibration in use and a
// manifest, so that any scan can be replayed (alacsd --replay) or evaluated later.
// Thread-safe: begin() and end() come from the event loop, frames from the worker.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "common/clock.h"
#include "ports/frame_source.h"
#include "replay/scan_dir.h"

namespace alacs::replay {

// How much --record may keep on disk. Before each scan, and when a frame would pass the
// byte limit, the oldest scan directories (lowest number) are removed; a scan that alone
// exceeds the byte limit stops being recorded (its further frames are refused, kIo "record
// quota", and logged; the scan itself goes on). Scans already in the directory count, and
// numbering continues after the highest found.
struct RecordQuota {
  int maxScans = 500;
  uint64_t maxBytes = uint64_t{2} << 30;  // 2 GiB
};

class ScanRecorder {
 public:
  ScanRecorder(std::string rootDir, geometry::Calibration calibration, std::string source = "alacsd",
               RecordQuota quota = {});

  // Opens the next scan directory; an unfinished one is finished first. Errors: kIo.
  Status begin(int targetId, const Eigen::Vector3d& roughMm, const std::vector<double>& stopsMm,
               const image::Roi& roi);
  // Writes one frame into the open scan: the full frame, or only `window` when the camera
  // delivered only that (a windowed readout). Errors: kInvalidArgument when no scan is
  // open; kIo.
  // `analogueGain`: as the camera reports it (0: not known, not recorded).
  Status frame(const image::ImageView& view, double slideMm, TimeNs exposureStartNs, int64_t exposureUs, bool laserOn,
               const image::Roi& window = {}, double analogueGain = 0.0);
  // Writes the manifest and closes the scan; returns its directory. Errors: kInvalidArgument
  // when no scan is open; kIo.
  Result<std::string> end();
  int scansStarted() const;
  // The scan directories kept (oldest first) and their bytes, the open one included.
  std::vector<std::string> scansKept() const;
  uint64_t bytesKept() const;
  // Whether a scan is open (frames outside scans are not recorded).
  bool recording() const;

 private:
  struct Kept {
    int number = 0;
    std::string dir;
    uint64_t bytes = 0;
  };
  // Drops the oldest scans (never the open one) until `more` bytes and one more scan fit.
  void makeRoom(uint64_t more, bool newScan);
  // The newest kept scan's bytes counted again from the disk (after a frame or its manifest).
  void recountNewest();
  void scanExisting();

  std::string root_;
  geometry::Calibration calibration_;
  std::string source_;
  RecordQuota quota_;
  mutable std::mutex mu_;
  std::optional<ScanWriter> writer_;
  std::vector<Kept> kept_;  // oldest first; the open scan is the last while writer_ is set
  uint64_t bytes_ = 0;
  bool openScanOverQuota_ = false;
  int count_ = 0;
  int started_ = 0;
};

// A camera decorator: every frame captured through it is also written to the recorder.
class RecordingSource final : public ports::FrameSource {
 public:
  // `slideMm` and `laserOn` are read at the start of each capture.
  // `inner` is lent: it must outlive this source.
  RecordingSource(ports::FrameSource& inner, ScanRecorder& recorder, std::function<double()> slideMm,
                  std::function<bool()> laserOn);
  const char* name() const override { return inner_.name(); }
  ports::FrameSource& inner() { return inner_; }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& request,
                                         const ports::ExposureHooks& hooks) override;
  void doInterrupt() override { inner_.interrupt(); }
  void doResume() override { inner_.resume(); }
  ports::FrameSource& inner_;
  ScanRecorder& recorder_;
  std::function<double()> slideMm_;
  std::function<bool()> laserOn_;
};

}  // namespace alacs::replay
