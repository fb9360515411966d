// libcamera adapter: a FrameSource on the first (or the named) camera, 24-bit RGB frames
// with manual exposure. Kept thin because libcamera's API is not stable before 1.0: the
// differences between 0.0.x (Debian 12) and 0.2-0.7 (Yocto, Raspberry Pi OS, Debian 13+)
// are confined to libcamera_source.cpp (LIBCAMERA_VERSION_*), and tests/aarch64's
// libcamera API check compiles it against the newer headers.
//
// What it guarantees (tested against the kernel's vimc camera in the UML bench,
// tests/system/test_camera_vimc.py):
// - the format is one the LLE reads (libcamera's RGB888 or BGR888) at exactly the size
//   asked for, or open() refuses and names what the camera offers;
// - the exposure is set only through controls the camera advertises, and the value the
//   pipeline applied is read back from the request's metadata (FrameInfo::exposureUs);
// - the stream is kept fed (every request queued: V4L2 drivers such as vimc start
//   streaming only with 2 buffers queued); frame timestamps are the sensor's
//   (SensorTimestamp, else the buffer's), never the wall clock;
// - the laser lit the whole window of the frame delivered: the sensor's frame clock is
//   learnt from the timestamps (common/frame_clock.h), the laser goes on just before the
//   predicted frame and off just after its exposure; a frame the laser did not cover
//   (it began before, or ended after), or whose applied exposure is not the one asked
//   for, is queued again unseen;
// - buffers and requests are allocated once, at open; a capture allocates nothing of
//   its own;
// - interrupt() (STOP) ends a capture at once and cancels the requests in flight (the
//   camera is stopped and started again);
// - a camera that stops answering or is unplugged (unbound) times out, and the next
//   capture opens it again by its id once libcamera sees it back.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "ports/frame_source.h"

namespace alacs::drivers {

struct LibcameraConfig {
  std::string cameraId;  // empty: the first camera
  int widthPx = 2048;
  int heightPx = 1536;
  int bufferCount = 4;  // requests (and buffers) allocated at open
  // The laser around the exposure (ports::ExposureHooks). True: once the sensor's frame
  // clock is learnt from its timestamps (FrameClock), the laser goes on `laserLeadNs`
  // before the first row of the window starts exposing and off `laserLeadNs` after its
  // last row ends; false, or while the clock is not learnt: on from the request to the
  // delivery.
  bool laserOnFrameClock = true;
  TimeNs laserLeadNs = 1 * kNsPerMs;
  // A frame further than this from the learnt clock makes it learn again.
  TimeNs frameClockJitterNs = 300 * kNsPerUs;
  // The sensor's rolling shutter (config camera.line_time_us; 0: not known, and the laser
  // covers the window's rows as if the readout took anything up to the whole frame
  // period). The laser covers either meaning of the timestamp (start or end of the first
  // row's exposure: common/frame_clock.h, exposureSpan).
  TimeNs lineTimeNs = 0;
  bool globalShutter = false;  // config camera.global_shutter: no readout to cover
  // The sensor's frame duration, asked as FrameDurationLimits (min = max) when the camera
  // starts; 0: the camera's own. Cameras without the control run at their own rate
  // (LibcameraStats::frameDurationControl says which).
  TimeNs frameDurationNs = 0;
};

// What the adapter negotiated and counted; for diagnostics and the bench's tests.
struct LibcameraStats {
  std::string cameraId;
  std::string pixelFormat;  // "RGB888" (memory B, G, R) or "BGR888" (memory R, G, B)
  int widthPx = 0;
  int heightPx = 0;
  int strideBytes = 0;
  int buffers = 0;
  bool exposureControl = false;  // the camera advertises ExposureTime
  bool gainControl = false;      // ... and AnalogueGain
  bool frameDurationControl = false;     // ... and FrameDurationLimits
  int64_t frameDurationAskedUs = 0;      // LibcameraConfig::frameDurationNs, when the camera took it
  int64_t frameDurationReportedUs = -1;  // the last frame's FrameDuration metadata; -1: not reported
  bool sensorTimestamp = false;  // the last frame carried SensorTimestamp metadata
  int64_t lastExposureRequestedUs = 0;
  int64_t lastExposureAppliedUs = -1;  // from the metadata; -1: the pipeline did not report it
  uint64_t framesDelivered = 0;
  uint64_t timeouts = 0;
  uint64_t failedFrames = 0;        // completed by the pipeline with an error or short
  uint64_t staleFramesSkipped = 0;  // began exposing before the capture was asked for, or
                                    // with another exposure: queued again, not delivered
  uint64_t interrupted = 0;         // captures ended by interrupt()
  uint64_t requestsCancelled = 0;   // requests libcamera completed as cancelled (stop)
  uint64_t reopens = 0;             // the camera opened again after it stopped answering
  // The laser and the frame clock: captures whose laser was switched around the predicted
  // frame, captures that had it on from the request (the clock not learnt), and frames
  // the laser missed in part (the prediction was wrong, or the thread woke late): the
  // laser went on again for the frame after.
  uint64_t laserOnFrameClock = 0;
  uint64_t laserFromRequest = 0;
  uint64_t frameClockMisses = 0;
  uint64_t frameClockFinerGrids = 0;  // models dropped as a grid finer than the frames
  int64_t framePeriodNs = 0;  // as learnt; 0: not learnt
  int64_t frameJitterNs = 0;
  // The timestamp predicted for the last capture's frame, switched on the frame clock;
  // 0: the laser was on from the request.
  int64_t lastPredictedStartNs = 0;
  // Its device went away (unplugged, driver unbound). libcamera 0.0.3 cannot take it back
  // in this process (it aborts on the camera's return, its removal never seen): the
  // daemon ends and its unit starts it afresh (docs/daemon.md, "The camera").
  bool lost = false;
};

class LibcameraSource : public ports::FrameSource {
 public:
  // Errors: kNotFound when no camera is present, kUnsupported when it cannot give a
  // 24-bit RGB format at the configured size (the message names what it offers), kBusy
  // when another process holds it, kIo when it cannot be configured or started.
  static Result<std::unique_ptr<LibcameraSource>> open(const LibcameraConfig& config);
  // The number of cameras libcamera sees (diagnostics; 0 on a PC without one).
  static Result<int> countCameras();

  // Thread-safe snapshot.
  virtual LibcameraStats stats() const = 0;
  // Thread-safe: stats().lost, without the copy.
  virtual bool lost() const = 0;
};

}  // namespace alacs::drivers
