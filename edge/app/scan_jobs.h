// What the sensor asks of the thread that does everything that blocks (homing, moves,
// exposures, the image work of a scan): one job at a time, one WorkerEvent back per job.
// ScanWorker is the real one; FakeScanJobs (scan_jobs_fake.h) records jobs for the
// sensor's unit tests, which finish them by hand in virtual time.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "common/clock.h"
#include "common/result.h"
#include "localize/localizer.h"
#include "protocol/codec.h"
#include "survey/survey.h"

namespace alacs::app {

struct WorkerJob {
  enum class Kind { kHome, kLocalize, kScanAll, kMoveTo } kind = Kind::kHome;
  protocol::LocalizeCommand localize;
  localize::ScanPlan plan;  // made by the daemon when it accepted the command
  std::optional<survey::Survey> survey;  // scan-all: the survey to fill, and its stops
  std::vector<double> surveyStopsMm;
  double moveToMm = 0.0;  // kMoveTo: park the slide here (tools, diagnostics)
  TimeNs commandTimeNs = 0;
};

// One exposure as the camera reported it, for the laser timeline (docs/daemon.md), and
// when the camera told its end (the laser's `end` hook called, the last time in the
// capture): the laser goes off then, so the daemon's own share of the laser's time past
// the exposure is the line's off edge minus endToldNs.
struct ExposureWindow {
  TimeNs startNs = 0;
  TimeNs endNs = 0;
  TimeNs endToldNs = 0;
  double slideMm = 0.0;  // where the frame was placed (a sweep's: at its mid-exposure)
};

struct WorkerEvent {
  WorkerJob job;
  Status status;
  uint16_t faultBit = 0;               // set when the failure is a device fault
  protocol::ResultStatus resultStatus = protocol::ResultStatus::kMeasured;
  // Why resultStatus is not kMeasured, when the worker knows (nothing in the gate, too
  // few lines); the sensor names faults, STOP and shutdown itself.
  protocol::ResultReason resultReason = protocol::ResultReason::kNone;
  std::vector<localize::AppleEstimate> estimates;  // localize: at most one; scan-all: all found
  TimeNs lastExposureNs = 0;
  TimeNs doneNs = 0;
  TimeNs maxStepLatenessNs = 0;
  std::vector<ExposureWindow> exposures;  // of this job, in order
  TimeNs processingTailNs = 0;  // image work left after the last frame (not overlapped with motion)
  int followUpStops = 0;         // localize: stops of the adaptive second pass (0: none taken)
  int firstPassLines = 0;        // localize, second pass taken: lines in the first pass's fit
  // localize, continuous: the slowest cruise speed of its sweeps (the camera's pace,
  // motion/sweep_speed.h), mm/s; 0: no sweep
  double sweepSpeedMmPerS = 0.0;
  // localize: the exposure metered from laser-off frames of the ROI (localize/exposure.h)
  // and used for the laser frames (0: not metered), the laser-off frames it took (the
  // metering frames and the subtracted one), and whether the LLE subtracted a laser-off frame.
  int64_t exposureUs = 0;
  double analogueGain = 0.0;  // the laser frames' analogue gain when metering changed it (linear); 0: unchanged
  int laserOffFrames = 0;
  bool laserOffSubtracted = false;
  bool brightAmbient = false;  // the metering found the ambient bright (MeteringDecision::bright)
  // Each stop's second exposure (MeteringDecision::secondExposureUs, its laser-off frame
  // taken), us; 0: one exposure per stop (also when a sweep was paced for one: metered in
  // its run-up after a scan without).
  int64_t secondExposureUs = 0;
  // A continuous scan's result is posted as soon as it is known, while the slide still
  // brakes past the last stop; if that braking then ends badly (limit switch, I/O error,
  // STOP), a second event of the same job follows with this set: the result stands, only
  // the fault (faultBit, status) counts.
  bool afterResult = false;
};

// Where a scan job stands, for ALACS_Progress.
struct ScanProgress {
  int stopsDone = 0;
  int stopsTotal = 0;  // planned so far, a second pass included once it is planned
  int objectsFound = 0;
  protocol::ProgressPhase phase = protocol::ProgressPhase::kMoving;
  bool operator==(const ScanProgress&) const = default;
};

class ScanJobs {
 public:
  virtual ~ScanJobs() = default;
  // Queues a job; false (refused) when one is already waiting besides the running one.
  virtual bool submit(const WorkerJob& job) = 0;
  // Stops the running job (it ends as aborted) and the jobs queued so far.
  virtual void cancel() = 0;
  // A job is running or queued and its event is not out yet.
  virtual bool busy() const = 0;
  virtual bool homed() const = 0;
  virtual void markUnhomed() = 0;
  virtual double positionMm() const = 0;
  // Frames that failed (timeout, corrupt) and were retried or led to a fault.
  virtual uint32_t droppedFrames() const = 0;
  // When the worker last showed progress: a job began or ended, a frame came back, a
  // move ended (its clock; 0 before any). The sensor's stall check reads it.
  virtual TimeNs progressNs() const = 0;
  // When the frame read in flight began (FrameSource::capture, its clock); 0 when none
  // is. The sensor's frame-source deadline reads it.
  virtual TimeNs frameReadSinceNs() const = 0;
  // The running scan's progress (any thread).
  virtual ScanProgress progress() const = 0;
  // Settings for the next job (never the running one).
  virtual void setLocalizer(const localize::Localizer& l) = 0;
  virtual void setExposureUs(int64_t us) = 0;
};

}  // namespace alacs::app
