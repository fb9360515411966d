// The worker thread that does everything that blocks: homing, moves, exposures and
// the per-frame image work of a scan. The event loop submits one job at a time and
// receives one WorkerEvent per job through a queue and an eventfd.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "app/frame_pipeline.h"
#include "app/laser_guard.h"
#include "app/scan_jobs.h"
#include "common/frame_clock.h"
#include "localize/exposure.h"
#include "localize/localizer.h"
#include "motion/step_runner.h"
#include "motion/sweep_speed.h"
#include "ports/frame_source.h"
#include "protocol/codec.h"
#include "survey/survey.h"

namespace alacs::app {

struct WorkerDeps {
  const Clock* clock = nullptr;
  Sleeper* sleeper = nullptr;
  motion::SlideLimits limits;
  motion::StepLines stepLines;
  ports::DigitalOut* enable = nullptr;
  LaserGuard* laser = nullptr;
  ports::FrameSource* camera = nullptr;
  ports::CaptureRequest capture;
  // Before a localize scan's stops, the exposure is metered from laser-off frames of the
  // ROI (localize/exposure.h); `metering.enabled` false: the configured exposure as is.
  localize::MeteringParams metering;
  int realtimePriority = 0;            // SCHED_FIFO priority of the worker (0: normal scheduling)
  int captureRetries = 2;              // further attempts after a failed frame, then a fault
  // A rolling-shutter sensor's line time: row v of a frame exposes v × this after row 0
  // (whose start is the frame's timestamp). In a sweep each row then has its own slide
  // position (Localizer::observe). 0: a global shutter (config camera.line_time_us).
  TimeNs lineTimeNs = 0;
  // The frame's timestamp marks the end of row 0's exposure (Raspberry Pi's pipelines), not
  // its start (config camera.timestamp_at_exposure_end).
  bool timestampAtExposureEnd = false;
  // How long before a free-running sensor's frame starts the camera must be asked for it
  // to take that frame: 2 × camera.laser_lead_us with the laser on the frame clock (the
  // libcamera source wakes a lead before the frame and switches the laser a lead before
  // it), 0 when it arms at the request. A sweep then asks for each stop's frame so that
  // the frame nearest the stop is taken. -1: not known (a camera that exposes on request),
  // each frame is asked for as the slide passes its stop.
  TimeNs slotLeadNs = -1;
  // How the worker learns the sensor's frame clock from the frames' timestamps (the sweep's
  // pace and the frame nearest each stop): camera.frame_clock_jitter_us, as the libcamera
  // source's own clock.
  FrameClockParams frameClock;
  // After homing, laser-off frames until the camera's pace is known, from a camera that runs
  // free (slotLeadNs >= 0; ScanWorker::learnCameraPace). false: the first scan learns it.
  bool learnPaceAtHome = true;
  std::string debugDir;                // overlay PNGs go here when not empty
  // alacsd --replay: the slide position the frame just captured was recorded at, used
  // instead of the worker's own (unset or NaN: the worker's). Called on the worker thread.
  std::function<double()> frameSlideMm;
};

// WorkerDeps::slotLeadNs for a free-running camera that switches the laser on its frame
// clock `laserLeadNs` before a frame (two leads: one to wake, one to switch), or at the
// request when `laserOnFrameClock` is false (0).
inline TimeNs slotLeadFor(bool laserOnFrameClock, TimeNs laserLeadNs) {
  return laserOnFrameClock ? 2 * laserLeadNs : 0;
}

class ScanWorker final : public ScanJobs {
 public:
  ScanWorker(WorkerDeps deps, const localize::Localizer& localizer, int eventFd);
  // Without a calibration: LOCALIZE jobs fail (kNotCalibrated) until setLocalizer().
  ScanWorker(WorkerDeps deps, int eventFd);
  ~ScanWorker() override;

  // Queues a job; false (refused) when one is already waiting: the queue holds one job
  // besides the running one. A job waits when the daemon sends it while a continuous
  // scan's result is out but its slide still brakes; it runs once the slide is at rest.
  bool submit(const WorkerJob& job) override;
  std::optional<WorkerEvent> takeEvent();
  // Stops the running job and the braking after a result, and cancels the jobs queued so
  // far (they end at once as aborted); jobs submitted afterwards run normally.
  void cancel() override;
  // A job is running or queued and its result is not out yet.
  bool busy() const override { return busy_.load(); }
  bool homed() const override { return homed_.load(); }
  double positionMm() const override { return deps_.limits.mmFor(positionSteps_.load()); }
  void setLocalizer(const localize::Localizer& l) override;
  void setExposureUs(int64_t us) override;
  void markUnhomed() override { homed_.store(false); }
  // Frames that failed (timeout, corrupt) and were retried or led to a fault.
  uint32_t droppedFrames() const override { return dropped_.load(); }
  TimeNs progressNs() const override { return progressNs_.load(); }
  TimeNs frameReadSinceNs() const override { return frameReadSinceNs_.load(); }
  ScanProgress progress() const override;

 private:
  void run();
  WorkerEvent doHome(const WorkerJob& job);
  // After homing, laser-off frames until the sweep's pace no longer rests on how few
  // captures the worker knows (paceSettled(), at most CaptureTimes::kFrames): the first
  // localize after a start then sweeps as fast as the later ones (docs/daemon.md, "The
  // camera's pace, learnt at homing"). Only from a camera that runs free
  // (WorkerDeps::slotLeadNs known); none when replaying a recording.
  void learnCameraPace();
  // The sensor's clock is learnt and the captures wait on it, or kFrames captures are known.
  bool paceSettled() const;
  WorkerEvent doLocalize(const WorkerJob& job);
  WorkerEvent doScanAll(const WorkerJob& job);
  // Laser on, expose (with retries), laser off. On failure `ev` holds the fault. When
  // `midSlideMm` is given it receives the slide's position at mid-exposure (the mean of
  // the counted positions at exposure start and end).
  // `second`: the stop's second exposure (WorkerEvent::secondExposureUs), not counted as
  // a stop done.
  Result<ports::CapturedFrame> exposeStop(size_t stop, const ports::CaptureRequest& capture, WorkerEvent& ev,
                                          double* midSlideMm = nullptr, bool second = false);
  // Laser off, meters the exposure for `plan`'s laser frames into `capture.exposureUs` and
  // hands the pipeline the laser-off frame to subtract, when the meter asks for one, and
  // the one at the stops' second exposure (ev.secondExposureUs) when it chose one. Never
  // fails the scan: a frame that cannot be had (a replayed scan without laser-off frames, a
  // camera error) ends metering with what is known, logged.
  void meterExposure(const localize::ScanPlan& plan, ports::CaptureRequest& capture, WorkerEvent& ev);
  // `meanwhile` (optional) runs on this thread while the slide moves (the metering).
  Status moveTo(double mm, WorkerEvent& ev, const std::function<void()>& meanwhile = {});
  Status moveOutcome(const motion::MoveReport& r, WorkerEvent& ev);
  // The two ways through a localize plan's stops; both hand frames to pipeline_.
  Status stopAndGo(const localize::ScanPlan& plan, const ports::CaptureRequest& capture, WorkerEvent& ev);
  // Takes the slide to where a sweep through `stops` (in passing order) at `paceMmPerS`
  // starts: back to the first stop when it waits inside their span, at full speed to a
  // slow sweep's run-up when that is sooner (motion::fastRunUpMm), else nowhere. `runUp`
  // (the metering) runs during such a move: true when it ran.
  Result<bool> toSweepStart(const std::vector<double>& stops, double paceMmPerS, const std::function<void()>& runUp,
                            WorkerEvent& ev);
  Status sweepStops(const localize::ScanPlan& plan, ports::CaptureRequest& capture, WorkerEvent& ev,
                    const std::function<void()>& runUp);
  // A sweep's stop as sweptFrame() takes it: the sweep, its start and direction, the
  // limits it runs at, the ROI, the stop's index and when the plan has the slide pass it.
  struct SweptStop;
  // Exposes a sweep's stop (its second exposure when `second`), places the frame where the
  // slide was at its mid-exposure (a replayed frame where it was recorded) and hands it to
  // the pipeline (a second exposure as a line of its own).
  Status sweptFrame(const SweptStop& at, const ports::CaptureRequest& capture, WorkerEvent& ev, bool second);
  // Posts `ev` to the loop (queue + eventfd).
  void post(WorkerEvent ev);
  // Waits for the braking after a continuous scan's last frame; a second event when it
  // did not complete.
  void finishBraking(const WorkerJob& job);
  // Waits for a continuous sweep still braking (before the slide moves again within the
  // same job); its outcome, as moveOutcome.
  Status settleBraking(WorkerEvent& ev);

  // The sweep's motion, on a thread of its own while the worker exposes the frames; it
  // outlives sweepStops() when the slide brakes after the last frame.
  struct Sweep {
    Sweep(const motion::SlideLimits& limits, motion::StepLines lines, const Clock& clock, Sleeper& sleeper,
          const motion::TrapezoidMove& m, bool fwd)
        : runner(limits, lines, clock, sleeper), move(m), forward(fwd), log(m.steps()) {
      runner.logSteps(&log);
    }
    motion::StepRunner runner;
    motion::TrapezoidMove move;
    bool forward;
    motion::StepLog log;  // when each step came: where the slide was at a frame's mid-exposure
    motion::MoveReport report;
    std::atomic<bool> moving{true};
    std::thread thread;
  };
  struct SweptStop {
    const Sweep& sweep;
    int64_t fromSteps;
    bool forward;
    const motion::SlideLimits& lim;
    const image::Roi& roi;
    size_t stop;
    TimeNs passNs;
  };
  struct Queued {
    WorkerJob job;
    uint64_t cancelEpoch;  // cancel() calls before its submission
  };

  WorkerDeps deps_;
  std::optional<localize::Localizer> localizer_;
  int eventFd_;
  std::thread thread_;
  std::mutex mu_;
  std::condition_variable cv_;
  static constexpr size_t kMaxWaitingJobs = 1;
  std::deque<Queued> jobs_;  // at most kMaxWaitingJobs
  std::deque<WorkerEvent> events_;
  bool quit_ = false;
  std::atomic<bool> cancel_{false};
  std::atomic<uint64_t> cancelEpoch_{0};
  // Runs `move` on a thread of its own, from `startNs` on (0: at once); joinSweep() waits for it.
  std::unique_ptr<Sweep> startMove(const motion::TrapezoidMove& move, bool forward, TimeNs startNs = 0);
  // Waits for the sweep's thread to end (detached from the sleeper meanwhile).
  void joinSweep(Sweep& sweep);
  std::unique_ptr<Sweep> braking_;  // a continuous scan's sweep still braking after its last frame
  std::atomic<bool> busy_{false};
  std::atomic<bool> homed_{false};
  std::atomic<int64_t> positionSteps_{0};
  std::atomic<uint32_t> dropped_{0};
  std::atomic<TimeNs> progressNs_{0};
  void markProgress() { progressNs_.store(deps_.clock->now()); }
  std::atomic<TimeNs> frameReadSinceNs_{0};  // the capture in flight began (0: none)
  // How long the last metering took, first request to last delivery (0: none yet): the
  // next one's expected length, to fit it into a sweep's run-up (sweepStops()).
  TimeNs meterNs_ = 0;
  // Whether the last metering chose a second exposure at each stop: the next sweep's pace
  // is planned for it when its metering overlaps its run-up (sweepStops()).
  bool lastSecondExposure_ = false;
  // The camera's recent captures, request to delivery (laser frames and metering frames):
  // how long a sweep must leave between two stops (motion/sweep_speed.h). Worker thread only.
  motion::CaptureTimes captures_;
  // The sensor's frame clock, from the delivered frames' timestamps: its period bounds the
  // worst capture when the recent ones did not show it (CaptureTimes::paceNs). Worker thread only.
  FrameClock sensorClock_{deps_.frameClock};  // after deps_
  // One capture with its bookkeeping: the watchdog told a frame is being read meanwhile
  // (frameReadSinceNs_), and a delivered frame's time, request to delivery, recorded for the
  // sweep's pace and its timestamp for the sensor's frame clock. `tookNs`, when given, gets
  // that time (untouched when the capture failed).
  Result<ports::CapturedFrame> captureRecorded(const ports::CaptureRequest& request, const ports::ExposureHooks& hooks,
                                               TimeNs* tookNs = nullptr);
  TimeNs capturePaceNs() const { return captures_.paceNs(sensorClock_.periodNs()); }
  // When to ask for the frame whose window is exposed nearest `exposureMidNs` (the sensor's
  // clock learnt and waited on, deps_.slotLeadNs known); nullopt: as the slide passes the stop.
  std::optional<TimeNs> nearestFrameAskNs(TimeNs exposureMidNs, const image::Roi& window, int64_t exposureUs) const;
  // In a sweep, waits until stop `stopMm`'s frame is to be asked for (the slide passing it,
  // or in time for the frame nearest it); the time the plan has the slide pass the stop.
  TimeNs awaitStop(const Sweep& sw, TimeNs moveStartNs, int64_t fromSteps, const motion::SlideLimits& lim,
                   double stopMm, const image::Roi& window, int64_t exposureUs);
  // ALACS_Progress: written by the worker, read by the loop.
  std::atomic<int> stopsDone_{0};
  std::atomic<int> stopsTotal_{0};
  std::atomic<int> objectsFound_{0};
  std::atomic<protocol::ProgressPhase> phase_{protocol::ProgressPhase::kMoving};
  std::atomic<bool> secondPass_{false};
  void setPhase(protocol::ProgressPhase p);
  void resetProgress(const WorkerJob& job);
  int overlays_ = 0;  // debug overlays written (worker thread only)
  image::LleWorkspace ws_;  // scan-all's full-frame LLE
  FramePipeline pipeline_;  // localize's per-frame image work, overlapped with motion
};

}  // namespace alacs::app
