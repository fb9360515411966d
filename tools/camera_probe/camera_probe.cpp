// alacs_camera_probe: opens the camera through the daemon's libcamera source
// (drivers/libcamera) and captures frames as the scan worker does, one request at a
// time, then prints what was negotiated and counted as one JSON object on stdout:
// format, size, stride, the exposure asked for and the one the pipeline applied (from
// the request metadata), timestamps' source and spacing, dropped frames, and the
// resident memory after the first frames and at the end.
//
// The laser: each capture switches a laser that is not there through the daemon's hooks
// (ports::ExposureHooks) and the probe times them. It reports how long the laser was on
// per frame and whether it covered the window of each frame delivered: with
// --laser-timing frame-clock (the daemon's default) it goes on just before the predicted
// frame; with request, from the request to the delivery.
//
// --interrupt-every N: every Nth capture is interrupted from another thread DELAY µs
// after it starts (as STOP does), and the probe checks that the capture ended with the
// interruption well before its timeout and that the next capture works.
//
// Exit status: 0 when every capture worked; 1 when the camera cannot be opened (the
// reason on stderr) or a capture failed; 2 for a refused command line.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/process_memory.h"
#include "common/frame_clock.h"
#include "drivers/libcamera/libcamera_source.h"
#include "tool_common/cli.h"

using namespace alacs;

namespace {

struct Options {
  drivers::LibcameraConfig camera;
  int frames = 100;
  int64_t exposureUs = 3000;
  int64_t timeoutMs = 1000;
  int windowRows = 0;  // 0: whole frames
  int interruptEvery = 0;
  int interruptDelayUs = 2000;
  int rssAfterFrames = 100;
  bool list = false;
  std::string laserTiming = "frame-clock";
  double laserLeadUs = 1000.0;
  double frameClockJitterUs = 300.0;
  double lineTimeUs = 0.0;
  bool globalShutter = false;
  int64_t frameDurationUs = 0;
};

TimeNs nowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// The laser as the probe's hooks saw it in one capture.
struct LaserLog {
  TimeNs onNs = 0;   // the last switch on
  TimeNs offNs = 0;  // the last switch off
  TimeNs totalOnNs = 0;
  int switchedOn = 0;
  bool on = false;
  void begin() {
    onNs = nowNs();
    on = true;
    ++switchedOn;
  }
  void end() {
    if (!on) return;
    offNs = nowNs();
    totalOnNs += offNs - onNs;
    on = false;
  }
};

double medianOf(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

nlohmann::json statsJson(const drivers::LibcameraStats& s) {
  return {{"camera_id", s.cameraId},
          {"pixel_format", s.pixelFormat},
          {"width_px", s.widthPx},
          {"height_px", s.heightPx},
          {"stride_bytes", s.strideBytes},
          {"buffers", s.buffers},
          {"exposure_control", s.exposureControl},
          {"gain_control", s.gainControl},
          {"frame_duration_control", s.frameDurationControl},
          {"frame_duration_asked_us", s.frameDurationAskedUs},
          {"frame_duration_reported_us",
           s.frameDurationReportedUs < 0 ? nlohmann::json(nullptr) : nlohmann::json(s.frameDurationReportedUs)},
          {"sensor_timestamp", s.sensorTimestamp},
          {"exposure_requested_us", s.lastExposureRequestedUs},
          {"exposure_applied_us",
           s.lastExposureAppliedUs < 0 ? nlohmann::json(nullptr) : nlohmann::json(s.lastExposureAppliedUs)},
          {"frames_delivered", s.framesDelivered},
          {"timeouts", s.timeouts},
          {"failed_frames", s.failedFrames},
          {"stale_frames_skipped", s.staleFramesSkipped},
          {"interrupted", s.interrupted},
          {"requests_cancelled", s.requestsCancelled},
          {"reopens", s.reopens},
          {"laser_on_frame_clock", s.laserOnFrameClock},
          {"laser_from_request", s.laserFromRequest},
          {"frame_clock_misses", s.frameClockMisses},
          {"frame_clock_finer_grids", s.frameClockFinerGrids},
          {"frame_period_us", static_cast<double>(s.framePeriodNs) / 1e3},
          {"frame_jitter_us", static_cast<double>(s.frameJitterNs) / 1e3}};
}

int run(const Options& o) {
  app::mapLargeBlocks();
  if (o.list) {
    Result<int> n = drivers::LibcameraSource::countCameras();
    if (!n) {
      std::cerr << "alacs_camera_probe: " << n.status().toString() << "\n";
      return 1;
    }
    std::cout << nlohmann::json{{"cameras", *n}}.dump() << "\n";
    return 0;
  }
  drivers::LibcameraConfig camera = o.camera;
  camera.laserOnFrameClock = o.laserTiming == "frame-clock";
  camera.laserLeadNs = std::llround(o.laserLeadUs * 1e3);
  camera.frameClockJitterNs = std::llround(o.frameClockJitterUs * 1e3);
  camera.lineTimeNs = std::llround(o.lineTimeUs * 1e3);
  camera.globalShutter = o.globalShutter;
  camera.frameDurationNs = o.frameDurationUs * kNsPerUs;
  Result<std::unique_ptr<drivers::LibcameraSource>> opened = drivers::LibcameraSource::open(camera);
  if (!opened) {
    std::cerr << "alacs_camera_probe: " << opened.status().toString() << "\n";
    return 1;
  }
  drivers::LibcameraSource& cam = **opened;
  ports::CaptureRequest req;
  req.exposureUs = o.exposureUs;
  req.timeoutMs = o.timeoutMs;
  if (o.windowRows > 0) req.window = {0, (o.camera.heightPx - o.windowRows) / 2, o.camera.widthPx, o.windowRows};

  nlohmann::json failures = nlohmann::json::array();
  std::vector<double> periodsMs;
  std::vector<double> interruptedAfterMs;
  int64_t lastStartNs = -1;
  bool monotonic = true;
  int captured = 0;
  int interruptsLanded = 0;  // captures that ended by the interruption (not a frame first)
  int nextAfterInterruptFailed = 0;
  double rssEarlyMb = 0.0;
  int exposureEnds = 0;
  int laserOns = 0;   // over the run: every switch on ...
  int laserOffs = 0;  // ... and every switch off of a laser that was on
  LaserLog laser;
  const ports::ExposureHooks hooks(
      [&laser, &laserOns]() -> Status {
        laser.begin();
        ++laserOns;
        return Status::ok();
      },
      [&laser, &exposureEnds, &laserOffs] {
        laserOffs += laser.on ? 1 : 0;
        laser.end();
        ++exposureEnds;
      });
  std::vector<double> laserOnPerFrameMs;
  int uncovered = 0;                       // frames delivered whose window the laser did not cover
  std::vector<double> laserOnClockedMs;    // laser-on time of those frames
  std::vector<double> predictionErrorsUs;  // |timestamp - predicted|, frames on the frame clock
  int onFrameClockCaptures = 0;            // frames delivered with the laser switched on the frame clock
  const int y0 = req.window.empty() ? 0 : req.window.y;
  for (int i = 0; i < o.frames; ++i) {
    laser = {};
    const bool interrupt = o.interruptEvery > 0 && i % o.interruptEvery == o.interruptEvery - 1;
    std::thread stopper;
    if (interrupt)
      stopper = std::thread([&cam, &o] {
        std::this_thread::sleep_for(std::chrono::microseconds(o.interruptDelayUs));
        cam.interrupt();
      });
    const auto t0 = std::chrono::steady_clock::now();
    Result<ports::CapturedFrame> f = cam.capture(req, hooks);
    const double tookMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (interrupt) {
      stopper.join();
      cam.resume();
      if (!f && f.status().code() == Error::kFault) {
        ++interruptsLanded;
        interruptedAfterMs.push_back(tookMs);
      }
      // The capture after an interruption must work.
      Result<ports::CapturedFrame> next = cam.capture(req, hooks);
      if (!next) {
        ++nextAfterInterruptFailed;
        failures.push_back({{"capture", i}, {"after_interrupt", true}, {"error", next.status().toString()}});
      }
      continue;
    }
    if (!f) {
      failures.push_back({{"capture", i}, {"error", f.status().toString()}});
      continue;
    }
    ++captured;
    const int64_t startNs = f->info.exposureStartNs;
    // The window's rows exposed from its first row's start (0 line times, unless told).
    // (For either meaning of the timestamp: the first row's exposure start or its end.)
    const TimeNs windowStartNs = startNs - f->info.exposureUs * kNsPerUs + std::llround(y0 * o.lineTimeUs * 1e3);
    // The laser must have been on when the window began exposing. Its end is the adapter's
    // own check (litBy): off after the modelled span, or at the frame's completion, which
    // the probe cannot see (vimc completes a frame long before a modelled readout ends).
    const drivers::LibcameraStats st = cam.stats();
    const bool onFrameClock = st.lastPredictedStartNs != 0;
    if (onFrameClock) {
      ++onFrameClockCaptures;
      predictionErrorsUs.push_back(static_cast<double>(std::llabs(startNs - st.lastPredictedStartNs)) / 1e3);
      laserOnClockedMs.push_back(static_cast<double>(laser.totalOnNs) / 1e6);
    }
    if (laser.switchedOn == 0 || laser.on || windowStartNs < laser.onNs) ++uncovered;
    laserOnPerFrameMs.push_back(static_cast<double>(laser.totalOnNs) / 1e6);
    if (lastStartNs >= 0) {
      if (startNs <= lastStartNs) monotonic = false;
      periodsMs.push_back(static_cast<double>(startNs - lastStartNs) / 1e6);
    }
    lastStartNs = startNs;
    if (captured == o.rssAfterFrames) rssEarlyMb = app::residentMb();
  }
  const double rssEndMb = app::residentMb();
  const drivers::LibcameraStats s = cam.stats();
  nlohmann::json out = statsJson(s);
  out["frames_asked"] = o.frames;
  out["frames_captured"] = captured;
  out["capture_failures"] = failures;
  out["timestamps_increasing"] = monotonic;
  out["frame_interval_median_ms"] = medianOf(periodsMs);
  out["exposure_end_callbacks"] = exposureEnds;
  out["frame_rate_note"] = s.framePeriodNs > 0
                               ? frameRateNote(o.frameDurationUs, s.frameDurationControl, s.framePeriodNs).text
                               : std::string("no frame clock learnt");
  out["laser_switched_on"] = laserOns;
  out["laser_switched_off"] = laserOffs;
  out["laser_timing"] = o.laserTiming;
  out["laser_on_per_frame_median_ms"] = medianOf(laserOnPerFrameMs);
  out["laser_on_per_frame_max_ms"] =
      laserOnPerFrameMs.empty() ? 0.0 : *std::max_element(laserOnPerFrameMs.begin(), laserOnPerFrameMs.end());
  out["frames_laser_did_not_cover"] = uncovered;
  out["frames_on_frame_clock"] = onFrameClockCaptures;
  out["laser_on_per_frame_on_clock_median_ms"] = medianOf(laserOnClockedMs);
  out["prediction_error_median_us"] = medianOf(predictionErrorsUs);
  out["prediction_error_max_us"] =
      predictionErrorsUs.empty() ? 0.0 : *std::max_element(predictionErrorsUs.begin(), predictionErrorsUs.end());
  out["rss_after_first_mb"] = rssEarlyMb;
  out["rss_end_mb"] = rssEndMb;
  out["rss_peak_mb"] = app::peakResidentMb();
  out["rss_after_frames"] = o.rssAfterFrames;
  if (o.interruptEvery > 0) {
    out["interrupts"] = {{"asked", o.frames / o.interruptEvery},
                         {"landed_in_flight", interruptsLanded},
                         {"median_return_ms", medianOf(interruptedAfterMs)},
                         {"next_capture_failed", nextAfterInterruptFailed}};
  }
  std::cout << out.dump(2) << "\n";
  return failures.empty() ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{"Captures frames through alacsd's libcamera source and reports what was negotiated and counted",
               "alacs_camera_probe"};
  app.add_flag("--list", o.list, "print how many cameras libcamera sees and exit");
  app.add_option("--camera", o.camera.cameraId, "camera id (default: the first)");
  app.add_option("--width", o.camera.widthPx, "frame width, px")->check(CLI::Range(1, 16384));
  app.add_option("--height", o.camera.heightPx, "frame height, px")->check(CLI::Range(1, 16384));
  app.add_option("--buffers", o.camera.bufferCount, "requests and buffers to allocate")->check(CLI::Range(1, 16));
  app.add_option("--frames", o.frames, "captures to make")->check(CLI::Range(1, 1000000));
  app.add_option("--exposure-us", o.exposureUs, "exposure to ask for, µs")->check(CLI::Range(1, 1000000));
  app.add_option("--timeout-ms", o.timeoutMs, "per-capture timeout, ms")->check(CLI::Range(1, 60000));
  app.add_option("--window-rows", o.windowRows, "copy only this many central rows (as a scan's ROI does)")
      ->check(CLI::Range(0, 16384));
  app.add_option("--interrupt-every", o.interruptEvery, "interrupt every Nth capture from another thread")
      ->check(CLI::Range(0, 1000000));
  app.add_option("--interrupt-delay-us", o.interruptDelayUs, "how long after the capture starts")
      ->check(CLI::Range(0, 10000000));
  app.add_option("--rss-after", o.rssAfterFrames, "read the early resident memory after this many frames")
      ->check(CLI::Range(1, 1000000));
  app.add_option("--laser-timing", o.laserTiming,
                 "frame-clock: the laser just around the predicted frame; request: "
                 "from the request to the delivery")
      ->check(CLI::IsMember({"frame-clock", "request"}))
      ->capture_default_str();
  app.add_option("--laser-lead-us", o.laserLeadUs, "the laser on this long before the frame, off this long after")
      ->check(CLI::Range(0.0, 100000.0))
      ->capture_default_str();
  app.add_option("--frame-clock-jitter-us", o.frameClockJitterUs, "a frame further from the learnt clock relearns it")
      ->check(CLI::Range(1.0, 100000.0))
      ->capture_default_str();
  app.add_option("--line-time-us", o.lineTimeUs, "the sensor's line time (0: not known)")
      ->check(CLI::Range(0.0, 1000.0))
      ->capture_default_str();
  app.add_option("--frame-duration-us", o.frameDurationUs,
                 "ask the sensor for this frame duration (FrameDurationLimits; 0: its own)")
      ->check(CLI::Validator(
          [](const std::string& s) {
            const long long us = std::atoll(s.c_str());
            return us == 0 || (us >= 1000 && us <= 1000000) ? std::string() : "0, or 1000 to 1000000";
          },
          "0|1000..1000000"))
      ->capture_default_str();
  app.add_flag("--global-shutter", o.globalShutter, "the sensor exposes all rows at once (camera.global_shutter)");
  if (const int exit = tools::parseCommandLine(app, argc, argv); exit >= 0) return exit;
  return run(o);
}
