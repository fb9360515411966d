#include "app/scan_worker.h"
#include "app/result_status.h"

#include <pthread.h>
#include <sys/eventfd.h>
#include <sys/prctl.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <string>

#include "common/log.h"
#include "replay/png_io.h"

namespace alacs::app {

ScanWorker::ScanWorker(WorkerDeps deps, const localize::Localizer& localizer, int eventFd)
    : deps_(std::move(deps)), localizer_(localizer), eventFd_(eventFd) {
  thread_ = std::thread([this] { run(); });
}

ScanWorker::ScanWorker(WorkerDeps deps, int eventFd) : deps_(std::move(deps)), eventFd_(eventFd) {
  thread_ = std::thread([this] { run(); });
}

ScanWorker::~ScanWorker() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    quit_ = true;
  }
  cancel_.store(true);
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

bool ScanWorker::submit(const WorkerJob& job) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (jobs_.size() >= kMaxWaitingJobs) return false;
    jobs_.push_back({job, cancelEpoch_.load()});
    busy_.store(true);
    // The progress the sensor reports from now on is this job's (not the last one's, nor
    // 0/0 until this thread picks the job up).
    resetProgress(job);
  }
  cv_.notify_all();
  return true;
}

void ScanWorker::resetProgress(const WorkerJob& job) {
  stopsDone_.store(0);
  stopsTotal_.store(job.kind == WorkerJob::Kind::kScanAll ? static_cast<int>(job.surveyStopsMm.size())
                                                         : static_cast<int>(job.plan.stopsMm.size()));
  objectsFound_.store(0);
  secondPass_.store(false);
  phase_.store(protocol::ProgressPhase::kMoving);
}

void ScanWorker::cancel() {
  // The epoch first: a job that starts after this sees it changed and stays cancelled.
  cancelEpoch_.fetch_add(1);
  cancel_.store(true);
  // A camera waiting for a frame lets go of it now, not at its timeout.
  deps_.camera->interrupt();
}

std::optional<WorkerEvent> ScanWorker::takeEvent() {
  std::lock_guard<std::mutex> lock(mu_);
  if (events_.empty()) return std::nullopt;
  WorkerEvent ev = std::move(events_.front());
  events_.pop_front();
  return ev;
}

void ScanWorker::setPhase(protocol::ProgressPhase p) {
  // The second pass's moves and exposures show as SECOND_PASS.
  const bool motion = p == protocol::ProgressPhase::kMoving || p == protocol::ProgressPhase::kExposing;
  phase_.store(secondPass_.load() && motion ? protocol::ProgressPhase::kSecondPass : p);
}

ScanProgress ScanWorker::progress() const {
  return {stopsDone_.load(), stopsTotal_.load(), objectsFound_.load(), phase_.load()};
}

void ScanWorker::setLocalizer(const localize::Localizer& l) {
  std::lock_guard<std::mutex> lock(mu_);
  localizer_ = l;
}

void ScanWorker::setExposureUs(int64_t us) {
  std::lock_guard<std::mutex> lock(mu_);
  deps_.capture.exposureUs = us;
}

namespace {
// Step pulses are timed by the worker thread (tools/jitter measures it). Real-time
// scheduling comes from the service (CPUSchedulingPolicy=fifo: systemd sets it before it
// applies the unit's system-call filter, and every thread inherits it) or from this
// thread asking for `priority`, which the shipped unit refuses (SystemCallFilter=~@resources
// holds sched_setscheduler; RestrictRealtime=yes): then the log says so and what works.
// Otherwise at least no timer slack, whose 50 us default is the median lateness of every edge.
void setUpStepTiming(int priority) {
  sched_param sp{};
  int policy = SCHED_OTHER;
  if (pthread_getschedparam(pthread_self(), &policy, &sp) == 0 && (policy == SCHED_FIFO || policy == SCHED_RR)) {
    ALACS_LOG_INFO("motion", "step timing: %s priority %d, inherited from the service (CPUSchedulingPolicy)",
                   policy == SCHED_FIFO ? "SCHED_FIFO" : "SCHED_RR", sp.sched_priority);
    return;
  }
  if (priority > 0) {
    sp.sched_priority = priority;
    const int err = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    if (err == 0) {
      ALACS_LOG_INFO("motion", "step timing: SCHED_FIFO priority %d (motion.realtime_priority)", priority);
      return;
    }
    ALACS_LOG_WARN("motion",
                   "step timing: motion.realtime_priority %d refused (%s): a process cannot take SCHED_FIFO under "
                   "the shipped unit (SystemCallFilter=~@resources, RestrictRealtime=yes); give the service "
                   "CPUSchedulingPolicy=fifo in a drop-in instead (docs/daemon.md, \"Step timing\")",
                   priority, std::strerror(err));
  }
  prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
  ALACS_LOG_INFO("motion", "step timing: normal scheduling, timer slack 1 ns");
}
}  // namespace

void ScanWorker::run() {
  setUpStepTiming(deps_.realtimePriority);
  while (true) {
    WorkerJob job;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [&] { return quit_ || !jobs_.empty(); });
      if (quit_) return;
      job = jobs_.front().job;
      const uint64_t epoch = jobs_.front().cancelEpoch;
      jobs_.pop_front();
      // A cancel() after the job's submission cancels it; none: it runs.
      cancel_.store(false);
      if (cancelEpoch_.load() != epoch) cancel_.store(true);
      // Before this job, the camera takes captures again. A cancel() from here on sets
      // cancel_ (checked before every capture) and interrupts the camera anew.
      deps_.camera->resume();
    }
    // The job's sleeps take turns with the sweep's on a virtual sleeper (tests).
    deps_.sleeper->attach();
    markProgress();
    resetProgress(job);
    WorkerEvent ev;
    switch (job.kind) {
      case WorkerJob::Kind::kHome: ev = doHome(job); break;
      case WorkerJob::Kind::kScanAll: ev = doScanAll(job); break;
      case WorkerJob::Kind::kLocalize: ev = doLocalize(job); break;
      case WorkerJob::Kind::kMoveTo:
        ev.job = job;
        if (!homed_.load()) {
          ev.status = Status(Error::kNotHomed, "slide not homed");
        } else if ((ev.status = deps_.enable->set(true)); ev.status.isOk()) {
          ev.status = moveTo(job.moveToMm, ev);
        }
        break;
    }
    (void)deps_.laser->off();  // whatever happened, the laser ends the job off
    markProgress();
    if (braking_) {
      // A continuous scan: the result goes out now; the slide still brakes past the last stop.
      post(std::move(ev));
      finishBraking(job);
      (void)deps_.enable->set(false);
    } else {
      (void)deps_.enable->set(false);
      post(std::move(ev));
    }
    deps_.sleeper->detach();
  }
}

void ScanWorker::post(WorkerEvent ev) {
  ev.doneNs = deps_.clock->now();
  {
    std::lock_guard<std::mutex> lock(mu_);
    events_.push_back(std::move(ev));
    busy_.store(!jobs_.empty());
  }
  const uint64_t one = 1;
  [[maybe_unused]] ssize_t w = ::write(eventFd_, &one, sizeof one);
}

Status ScanWorker::settleBraking(WorkerEvent& ev) {
  if (!braking_) return Status::ok();
  joinSweep(*braking_);
  const motion::MoveReport report = braking_->report;
  braking_.reset();
  return moveOutcome(report, ev);
}

void ScanWorker::joinSweep(Sweep& sweep) {
  // Not attached while it waits: the sweep's steps go on in (virtual) time meanwhile.
  deps_.sleeper->detach();
  sweep.thread.join();
  deps_.sleeper->attach();
}

void ScanWorker::finishBraking(const WorkerJob& job) {
  WorkerEvent late;
  late.job = job;
  late.afterResult = true;
  late.status = settleBraking(late);
  if (late.status.isOk()) return;
  ALACS_LOG_WARN("motion", "braking after the scan's last frame: %s", late.status.toString().c_str());
  post(std::move(late));
}

WorkerEvent ScanWorker::doHome(const WorkerJob& job) {
  WorkerEvent ev;
  ev.job = job;
  homed_.store(false);
  if (Status s = deps_.enable->set(true); !s) {
    ev.status = s;
    ev.faultBit = protocol::kFaultInternal;
    return ev;
  }
  motion::StepRunner runner(deps_.limits, deps_.stepLines, *deps_.clock, *deps_.sleeper);
  const motion::MoveReport r = runner.home(cancel_);
  ev.maxStepLatenessNs = r.maxLatenessNs;
  if (r.outcome == motion::MoveOutcome::kSwitchReached) {
    positionSteps_.store(0);
    // Homed (the status bit) once the job is done: a LOCALIZE sent on seeing it is not
    // refused as busy while the camera's frames are still being taken.
    learnCameraPace();
    homed_.store(true);
    ev.status = Status::ok();
    return ev;
  }
  ev.status = r.status.isOk() ? Status(Error::kFault, "homing failed") : r.status;
  if (r.outcome == motion::MoveOutcome::kCancelled) return ev;
  ev.faultBit = r.outcome == motion::MoveOutcome::kIoError ? protocol::kFaultInternal : protocol::kFaultHomingTimeout;
  return ev;
}

void ScanWorker::learnCameraPace() {
  // Only a camera that runs free (the board's: deps_.slotLeadNs known) has a pace to learn
  // that a first sweep would miss; a simulated one renders each frame on request, which
  // costs its start seconds on a slow machine. A replayed scan's frames are its
  // recording's, each for one stop: none to spare.
  if (!deps_.learnPaceAtHome || deps_.slotLeadNs < 0 || deps_.frameSlideMm) return;
  // The laser is off here (every job ends with it off, and these captures never switch it on).
  int taken = 0;
  TimeNs firstNs = 0;
  while (!paceSettled() && taken < motion::CaptureTimes::kFrames && !cancel_.load()) {
    TimeNs tookNs = 0;
    Result<ports::CapturedFrame> f = captureRecorded(deps_.capture, {}, &tookNs);
    markProgress();
    if (!f) {
      // The slide is homed all the same; the first scan finds the camera's fault and names it.
      ALACS_LOG_WARN("camera", "learning the camera's pace after homing: %s", f.status().toString().c_str());
      return;
    }
    if (taken++ == 0) firstNs = tookNs;
  }
  // Until a scan has metered, its metering is expected to take one laser-off frame (as it
  // does in every light but the sun's): a sweep then meters in its run-up from the first scan on.
  if (taken == 0) return;
  if (meterNs_ == 0) meterNs_ = firstNs;
  ALACS_LOG_INFO(
      "camera", "after homing: %d laser-off frames, %.1f ms a capture, the sensor's period %.1f ms (0: none)", taken,
      static_cast<double>(capturePaceNs()) / 1e6, static_cast<double>(sensorClock_.periodNs().value_or(0)) / 1e6);
}

bool ScanWorker::paceSettled() const {
  return captures_.waitsOnClock(sensorClock_.periodNs()) || captures_.count() >= motion::CaptureTimes::kFrames;
}

Status ScanWorker::moveTo(double mm, WorkerEvent& ev, const std::function<void()>& meanwhile) {
  const int64_t from = positionSteps_.load();
  const int64_t to = deps_.limits.stepsFor(mm);
  Result<motion::TrapezoidMove> move = motion::planMove(deps_.limits, from, to);
  if (!move) return move.status();
  setPhase(protocol::ProgressPhase::kMoving);
  if (meanwhile) {
    const std::unique_ptr<Sweep> m = startMove(*move, to > from);
    meanwhile();
    joinSweep(*m);
    markProgress();
    return moveOutcome(m->report, ev);
  }
  motion::StepRunner runner(deps_.limits, deps_.stepLines, *deps_.clock, *deps_.sleeper);
  runner.trackPosition(&positionSteps_);
  const motion::MoveReport report = runner.run(*move, to > from, cancel_);
  markProgress();
  return moveOutcome(report, ev);
}

std::unique_ptr<ScanWorker::Sweep> ScanWorker::startMove(const motion::TrapezoidMove& move, bool forward,
                                                         TimeNs startNs) {
  auto sweep = std::make_unique<Sweep>(deps_.limits, deps_.stepLines, *deps_.clock, *deps_.sleeper, move, forward);
  sweep->runner.trackPosition(&positionSteps_);
  Sweep* sw = sweep.get();
  deps_.sleeper->attach();  // for the move's thread, which detaches at its end
  sweep->thread = std::thread([this, sw, startNs] {
    if (startNs > 0) deps_.sleeper->sleepUntil(startNs);
    sw->report = sw->runner.run(sw->move, sw->forward, cancel_);
    sw->moving.store(false);
    deps_.sleeper->detach();
  });
  return sweep;
}

namespace {
// A move that did not complete leaves the position in doubt; one cancelled before its first
// step does not.
bool positionKnownAfter(const motion::MoveReport& r) {
  return r.outcome == motion::MoveOutcome::kCompleted ||
         (r.outcome == motion::MoveOutcome::kCancelled && r.stepsDone == 0);
}
}  // namespace

Status ScanWorker::moveOutcome(const motion::MoveReport& r, WorkerEvent& ev) {
  ev.maxStepLatenessNs = std::max(ev.maxStepLatenessNs, r.maxLatenessNs);
  if (r.outcome == motion::MoveOutcome::kCompleted) return Status::ok();
  if (!positionKnownAfter(r)) homed_.store(false);
  if (r.outcome == motion::MoveOutcome::kLimitHit) ev.faultBit = protocol::kFaultLimitHit;
  if (r.outcome == motion::MoveOutcome::kIoError) ev.faultBit = protocol::kFaultInternal;
  if (r.outcome == motion::MoveOutcome::kCancelled) ev.resultStatus = protocol::ResultStatus::kAborted;
  return r.status.isOk() ? Status(Error::kFault, "move failed") : r.status;
}

namespace {
// The slide position a frame belongs to: the replay source's recorded one when there is
// one (alacsd --replay), else the position the worker knows.
double recordedOr(const WorkerDeps& deps, double knownMm) {
  if (!deps.frameSlideMm) return knownMm;
  const double mm = deps.frameSlideMm();
  return std::isfinite(mm) ? mm : knownMm;
}
}  // namespace

namespace {
// Writes DIR/overlay_NNNN.png (one per scan, `scanIndex`) and points DIR/overlay.png at
// the newest, which the demo shows.
void writeOverlay(const std::string& dir, int scanIndex, const image::ImageView& frame, const localize::ScanPlan& plan,
                  const std::vector<localize::LineObservation>& lines) {
  if (frame.data == nullptr) return;
  // Only the target's window of the frame is valid (windowed capture): draw on a copy of it.
  const cv::Rect window(plan.roi.x, plan.roi.y, plan.roi.width, plan.roi.height);
  const cv::Mat img(frame.height, frame.width, CV_8UC3, const_cast<uint8_t*>(frame.data), frame.strideBytes);
  cv::Mat out = img(window).clone();
  // One colour a stop (BGR), each line labelled with its slide position where it begins;
  // samples the fit did not use in red. The picture is the last stop's frame, so its own
  // laser line shows too, wherever it fell.
  static const cv::Scalar kColours[] = {{255, 255, 0}, {0, 255, 0},     {255, 0, 255},  {0, 255, 255},
                                        {255, 128, 0}, {128, 128, 255}, {255, 255, 255}};
  constexpr size_t kNumColours = sizeof kColours / sizeof kColours[0];
  const auto label = [&out](const std::string& text, cv::Point at, const cv::Scalar& colour) {
    cv::putText(out, text, at, cv::FONT_HERSHEY_PLAIN, 0.9, colour, 1, cv::LINE_AA);
  };
  size_t k = 0;
  for (const auto& l : lines) {
    const cv::Scalar c = kColours[k++ % kNumColours];
    for (const auto& r : l.line.rows) {
      const cv::Point p(static_cast<int>(std::lround(r.column)) - window.x, r.row - window.y);
      cv::circle(out, p, 1, r.inlier ? c : cv::Scalar(0, 0, 255), cv::FILLED);
    }
    if (!l.line.rows.empty()) {
      const auto& first = l.line.rows.front();
      const cv::Point at(static_cast<int>(std::lround(first.column)) - window.x - 12, first.row - window.y - 4);
      label(std::to_string(static_cast<int>(std::lround(l.slideMm))), at, c);
    }
  }
  label("laser lines by stop (slide mm)", {6, 14}, {255, 255, 255});
  label("red: not fitted; image: last stop", {6, 28}, {255, 255, 255});
  cv::rectangle(out, cv::Rect(0, 0, window.width, window.height), {255, 255, 255}, 2);
  char name[32];
  std::snprintf(name, sizeof name, "overlay_%04d.png", scanIndex);
  if (Status s = replay::writePng(dir + "/" + name, out); !s) {
    ALACS_LOG_WARN("debug", "%s", s.toString().c_str());
    return;
  }
  const std::string latest = dir + "/overlay.png";
  const std::string tmp = latest + ".tmp";
  (void)::unlink(tmp.c_str());
  if (::symlink(name, tmp.c_str()) != 0 || ::rename(tmp.c_str(), latest.c_str()) != 0)
    ALACS_LOG_WARN("debug", "cannot point %s at %s", latest.c_str(), name);
}
}  // namespace

Result<ports::CapturedFrame> ScanWorker::captureRecorded(const ports::CaptureRequest& request,
                                                         const ports::ExposureHooks& hooks, TimeNs* tookNs) {
  const TimeNs askedNs = deps_.clock->now();
  frameReadSinceNs_.store(askedNs);
  Result<ports::CapturedFrame> f = deps_.camera->capture(request, hooks);
  frameReadSinceNs_.store(0);
  if (!f) return f;
  const TimeNs capturedNs = deps_.clock->now() - askedNs;
  captures_.record(capturedNs);
  if (tookNs != nullptr) *tookNs = capturedNs;
  // The frames' timestamps as the camera gives them (a start, or an exposure's end), as the
  // libcamera source learns its clock: it picks the frame a request gets from those.
  if (f->info.exposureStartNs > 0) sensorClock_.observe(f->info.sequence, f->info.exposureStartNs);
  return f;
}

std::optional<TimeNs> ScanWorker::nearestFrameAskNs(TimeNs exposureMidNs, const image::Roi& window,
                                                    int64_t exposureUs) const {
  if (deps_.slotLeadNs < 0 || !captures_.waitsOnClock(sensorClock_.periodNs())) return std::nullopt;
  const TimeNs exposureNs = exposureUs * kNsPerUs;
  // From a frame's timestamp to the middle of the window's exposure (a rolling shutter's
  // rows start a line time apart)...
  const TimeNs toMidNs = (deps_.timestampAtExposureEnd ? -exposureNs : 0) + exposureNs / 2 +
                         deps_.lineTimeNs * (window.y + window.height / 2);
  const std::optional<TimeNs> stampNs = motion::nearestFrameStartNs(sensorClock_, exposureMidNs - toMidNs);
  if (!stampNs) return std::nullopt;
  // ... and the camera takes the first frame whose window starts exposing, on its reckoning
  // (exposureSpan: the earliest either meaning of the timestamp allows), the lead after
  // the request: asked a little before that, as the frame before starts a period earlier.
  constexpr TimeNs kAskMarginNs = 500 * kNsPerUs;
  const ExposureSpan span =
      exposureSpan(*stampNs, exposureNs, window.y, window.y + window.height, deps_.lineTimeNs, 0, 0);
  return span.startNs - deps_.slotLeadNs - kAskMarginNs;
}

Result<ports::CapturedFrame> ScanWorker::exposeStop(size_t stop, const ports::CaptureRequest& capture, WorkerEvent& ev,
                                                    double* midSlideMm, bool second) {
  // Timeouts and corrupted frames are retried (the camera switches the laser around each
  // attempt's frame), then become a fault with the last reason.
  Result<ports::CapturedFrame> frame = Status(Error::kInternal, "no capture attempted");
  TimeNs endToldNs = 0;
  setPhase(protocol::ProgressPhase::kExposing);
  for (int attempt = 0; attempt <= deps_.captureRetries && !cancel_.load(); ++attempt) {
    // The camera switches the laser on just before the frame it will deliver starts (at
    // once when it does not know its sensor's frame clock), and off when it is exposed.
    Status laserRefused = Status::ok();
    double startMm = positionMm();
    double endMm = startMm;
    const ports::ExposureHooks laser(
        [this, &laserRefused, &startMm]() -> Status {
          laserRefused = deps_.laser->on();
          startMm = positionMm();
          return laserRefused;
        },
        [this, &endMm, &endToldNs] {
          endToldNs = deps_.clock->now();
          (void)deps_.laser->off();
          endMm = positionMm();
        });
    frame = captureRecorded(capture, laser);
    (void)deps_.laser->off();
    if (!laserRefused) {
      ev.status = laserRefused;
      ev.faultBit = protocol::kFaultLaserOvertime;
      ev.resultStatus = protocol::ResultStatus::kFailed;
      return laserRefused;
    }
    if (midSlideMm != nullptr) *midSlideMm = 0.5 * (startMm + endMm);
    markProgress();
    if (frame) {
      if (!second) stopsDone_.fetch_add(1);
      break;
    }
    if (cancel_.load()) break;  // interrupted by STOP: not a dropped frame
    dropped_.fetch_add(1);
    ALACS_LOG_WARN("camera", "stop %zu attempt %d: %s", stop, attempt + 1, frame.status().toString().c_str());
  }
  if (!frame && cancel_.load()) {
    ev.status = Status(Error::kFault, "scan stopped by command");
    ev.resultStatus = protocol::ResultStatus::kAborted;
    return ev.status;
  }
  if (!frame) {
    ev.status = frame.status();
    ev.faultBit = frame.status().code() == Error::kTimeout ? protocol::kFaultCameraTimeout : protocol::kFaultCameraCorrupt;
    ev.resultStatus = protocol::ResultStatus::kFailed;
    return frame;
  }
  // The exposure as it was (a timestamp at its end, camera.timestamp_at_exposure_end, moved
  // back to its start).
  const TimeNs exposureNs = frame->info.exposureUs * kNsPerUs;
  const TimeNs startNs = frame->info.exposureStartNs - (deps_.timestampAtExposureEnd ? exposureNs : 0);
  ev.lastExposureNs = startNs + exposureNs;
  ev.exposures.push_back({startNs, ev.lastExposureNs, endToldNs});
  return frame;
}

WorkerEvent ScanWorker::doScanAll(const WorkerJob& job) {
  WorkerEvent ev;
  ev.job = job;
  if (!homed_.load() || !job.survey) {
    ev.status = Status(Error::kNotHomed, "slide not homed");
    ev.resultStatus = protocol::ResultStatus::kFailed;
    return ev;
  }
  const ports::CaptureRequest capture = [&] {
    std::lock_guard<std::mutex> lock(mu_);
    return deps_.capture;
  }();
  if (Status s = deps_.enable->set(true); !s) {
    ev.status = s;
    ev.faultBit = protocol::kFaultInternal;
    return ev;
  }
  survey::Survey survey = *job.survey;
  for (size_t i = 0; i < job.surveyStopsMm.size(); ++i) {
    if (Status s = moveTo(job.surveyStopsMm[i], ev); !s) {
      ev.status = s;
      if (ev.resultStatus == protocol::ResultStatus::kMeasured) ev.resultStatus = protocol::ResultStatus::kFailed;
      return ev;
    }
    Result<ports::CapturedFrame> frame = exposeStop(i, capture, ev);
    if (!frame) return ev;
    if (Status s = survey.addFrame(frame->view, recordedOr(deps_, positionMm()), ws_); !s)
      ALACS_LOG_WARN("survey", "stop %zu: %s", i, s.toString().c_str());
    if (cancel_.load()) {
      ev.status = Status(Error::kFault, "scan stopped by command");
      ev.resultStatus = protocol::ResultStatus::kAborted;
      return ev;
    }
  }
  phase_.store(protocol::ProgressPhase::kFitting);
  ev.estimates = survey.finish();
  objectsFound_.store(static_cast<int>(ev.estimates.size()));
  ev.resultStatus = ev.estimates.empty() ? protocol::ResultStatus::kNotFound : protocol::ResultStatus::kMeasured;
  ev.status = Status::ok();
  return ev;
}

WorkerEvent ScanWorker::doLocalize(const WorkerJob& job) {
  WorkerEvent ev;
  ev.job = job;
  if (!homed_.load()) {
    ev.status = Status(Error::kNotHomed, "slide not homed");
    ev.resultStatus = protocol::ResultStatus::kFailed;
    return ev;
  }
  const std::optional<localize::Localizer> localizerOrNone = [&] {
    std::lock_guard<std::mutex> lock(mu_);
    return localizer_;
  }();
  if (!localizerOrNone) {
    // The sensor refuses LOCALIZE without a calibration; this is the worker's own guard.
    ev.status = Status(Error::kNotCalibrated, "no calibration: nothing to localize with");
    ev.resultStatus = protocol::ResultStatus::kFailed;
    return ev;
  }
  const localize::Localizer& localizer = *localizerOrNone;
  ports::CaptureRequest capture = [&] {
    std::lock_guard<std::mutex> lock(mu_);
    return deps_.capture;
  }();
  const localize::ScanPlan& plan = job.plan;
  capture.window = plan.roi;  // only the target's region is read: let the camera deliver just that
  if (Status s = deps_.enable->set(true); !s) {
    ev.status = s;
    ev.faultBit = protocol::kFaultInternal;
    return ev;
  }
  const bool continuous = job.localize.mode == protocol::ScanMode::kContinuous;
  // The exposure is metered on laser-off frames before the first laser frame: in a sweep
  // while the slide runs up to the first stop (sweepStops()), otherwise before the first move.
  const std::function<void()> meter = [&] { meterExposure(plan, capture, ev); };
  if (!continuous) {
    meter();
    if (cancel_.load()) {
      // STOP while metering: nothing moved, the slide stays homed.
      ev.resultStatus = protocol::ResultStatus::kAborted;
      ev.status = Status(Error::kFault, "scan stopped by command");
      return ev;
    }
  }
  // One pass over some stops; the frames' image work overlaps the motion.
  TimeNs motionDone = 0;
  const auto pass = [&](const localize::ScanPlan& p, std::vector<localize::LineObservation>& lines,
                        const std::function<void()>& runUp) {
    pipeline_.begin(localizer, p);
    const Status scanned = continuous ? sweepStops(p, capture, ev, runUp) : stopAndGo(p, capture, ev);
    motionDone = deps_.clock->now();
    // Whatever happened, let the frames already handed over finish before reporting.
    std::vector<localize::LineObservation> got = pipeline_.finish();
    lines.insert(lines.end(), std::make_move_iterator(got.begin()), std::make_move_iterator(got.end()));
    return scanned;
  };
  std::vector<localize::LineObservation> lines;
  Status scanned = pass(plan, lines, meter);
  phase_.store(protocol::ProgressPhase::kFitting);
  Result<localize::AppleEstimate> est = scanned ? localizer.estimate(plan, lines) : Result<localize::AppleEstimate>(scanned);
  // Adaptive scan: a first pass that leaves the fit in doubt (too few lines, the fruit mostly
  // hidden, two surfaces); a second pass, denser, where the fruit was seen.
  if (std::vector<double> more = localizer.followUpStops(plan, lines, est, deps_.limits.strokeMm);
      scanned && !more.empty() && !cancel_.load()) {
    ev.firstPassLines = est ? est->linesUsed : 0;
    ALACS_LOG_INFO("scan", "second pass: %zu stops (%d lines reached the fit)", more.size(), ev.firstPassLines);
    localize::ScanPlan second = plan;
    second.stopsMm = std::move(more);
    stopsTotal_.fetch_add(static_cast<int>(second.stopsMm.size()));
    secondPass_.store(true);
    setPhase(protocol::ProgressPhase::kSecondPass);
    scanned = settleBraking(ev);
    // (A replayed scan holds no frame at these stops: the replay serves the nearest recorded
    // one, already seen; estimate() leaves the repeats out.)
    if (scanned) scanned = pass(second, lines, {});
    ev.followUpStops = static_cast<int>(second.stopsMm.size());
    if (scanned) est = localizer.estimate(plan, lines);
  }
  if (!scanned) {
    ev.status = scanned;
    if (ev.resultStatus == protocol::ResultStatus::kMeasured) ev.resultStatus = protocol::ResultStatus::kFailed;
    return ev;
  }
  if (!deps_.debugDir.empty()) writeOverlay(deps_.debugDir, ++overlays_, pipeline_.lastFrame(), plan, lines);
  ev.processingTailNs = deps_.clock->now() - motionDone;
  if (!est) {
    ev.status = Status::ok();  // the scan worked; there was no apple where we were told
    ev.resultStatus = protocol::ResultStatus::kNotFound;
    // No stop put a point in the gate (a stop's frame may hold no line at all, or one
    // only outside the gate). None anywhere, under direct sun: most likely the sun's doing
    // (the line too weak against sunlit skin); a line seen only beyond the gate was not.
    const auto any = [&](auto member) {
      return std::any_of(lines.begin(), lines.end(),
                         [&](const localize::LineObservation& l) { return !(l.*member).empty(); });
    };
    const bool inGate = any(&localize::LineObservation::pointsMm) || any(&localize::LineObservation::arcPointsMm);
    // A line on leaves beyond the gate (told by their colour) was a line found too.
    const bool beyond =
        any(&localize::LineObservation::outsidePointsMm) || any(&localize::LineObservation::leafOutsidePointsMm);
    ev.resultReason = inGate                        ? protocol::ResultReason::kFitFailed
                      : ev.brightAmbient && !beyond ? protocol::ResultReason::kBrightAmbient
                                                    : protocol::ResultReason::kNoLinesInGate;
    return ev;
  }
  ev.estimates.push_back(*est);
  // Without a sphere fit the estimate is the rough position with the default size: never
  // a measurement (docs/can-protocol.md, ROUGH_ONLY).
  // A fit that is more likely another object than the target goes out as AMBIGUOUS with its
  // reason: the best guess, its σ and a low confidence (app/result_status.h).
  const ResultClass rc = classifyEstimate(*est);
  ev.resultStatus = rc.status;
  ev.resultReason = rc.reason;
  ev.status = Status::ok();
  return ev;
}

namespace {
// A gain as the log shows it: "?" where the camera does not report one.
std::string gainText(double gain) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", gain);
  return gain > 0.0 ? std::string(buf) : std::string("?");
}
}  // namespace

void ScanWorker::meterExposure(const localize::ScanPlan& plan, ports::CaptureRequest& capture, WorkerEvent& ev) {
  pipeline_.clearLaserOff();
  if (!deps_.metering.enabled) return;
  // The camera is fixed and only the laser moves: the ambient of the ROI is the same at
  // every stop, so it is metered once, before the first laser frame (a sweep's while the
  // slide gets to its first stop: sweepStops()). The laser is off (every job ends with it
  // off, and these captures never switch it on).
  setPhase(protocol::ProgressPhase::kExposing);
  const TimeNs startNs = deps_.clock->now();
  const localize::TakeLaserOffFrame take = [&](int64_t exposureUs, double analogueGain,
                                               localize::LaserOffUse) -> Result<localize::LaserOffFrame> {
    if (cancel_.load()) return Status(Error::kFault, "scan stopped by command");
    ports::CaptureRequest req = capture;
    req.exposureUs = exposureUs;
    if (analogueGain > 0.0) req.analogueGain = analogueGain;
    Result<ports::CapturedFrame> f = captureRecorded(req, {});
    markProgress();
    if (!f) return f.status();
    ++ev.laserOffFrames;
    return localize::LaserOffFrame{f->view, f->info.exposureUs, f->info.analogueGain};
  };
  const localize::MeteringRun run = localize::runMetering(deps_.metering, capture.exposureUs, 0, plan.roi, take);
  if (cancel_.load()) return;
  meterNs_ = deps_.clock->now() - startNs;
  // A frame that failed: the configured exposure (or, when only the one to subtract
  // failed, the one chosen), without subtraction.
  if (!run.status)
    ALACS_LOG_WARN("scan", "metering: %s: exposure %lld us, no subtraction", run.status.toString().c_str(),
                   static_cast<long long>(run.decision.exposureUs));
  const localize::MeteringDecision& d = run.decision;
  capture.exposureUs = d.exposureUs;
  if (d.analogueGain > 0.0) capture.analogueGain = d.analogueGain;
  ev.exposureUs = d.exposureUs;
  ev.analogueGain = d.analogueGain;
  ev.brightAmbient = d.bright;
  if (run.hasLaserOff) {
    pipeline_.setLaserOff(run.laserOff.view, plan.roi, d.bright);
    ev.laserOffSubtracted = true;
  }
  // Each stop's second exposure in sun (metering.second_exposure_factor) needs a laser-off
  // frame of its own; without it, one exposure per stop.
  if (run.hasLaserOff && d.secondExposureUs > 0 && !cancel_.load()) {
    Result<localize::LaserOffFrame> off = take(d.secondExposureUs, d.analogueGain, localize::LaserOffUse::kSubtraction);
    if (off && off->exposureUs == d.secondExposureUs) {
      pipeline_.setSecondLaserOff(off->view, plan.roi);
      ev.secondExposureUs = d.secondExposureUs;
    } else {
      ALACS_LOG_WARN("scan", "metering: no laser-off frame at the second exposure (%s): one exposure per stop",
                     off ? "the camera gave another exposure" : off.status().toString().c_str());
    }
  }
  const std::string second = ev.secondExposureUs > 0
                                 ? ", a second exposure of " + std::to_string(ev.secondExposureUs) + " us at each stop"
                                 : std::string();
  lastSecondExposure_ = ev.secondExposureUs > 0;
  ALACS_LOG_INFO("scan",
                 "metering: red p%.0f %d DN at %lld us gain %s%s -> exposure %lld us gain %s (red ~%d DN), %s, "
                 "%d laser-off frames%s",
                 deps_.metering.percentile, d.meteredDn, static_cast<long long>(d.meteredUs),
                 gainText(d.meteredGain).c_str(), d.saturated ? " (saturated)" : "",
                 static_cast<long long>(d.exposureUs),
                 gainText(d.analogueGain > 0.0 ? d.analogueGain : d.meteredGain).c_str(), d.ambientDn,
                 ev.laserOffSubtracted ? "laser-off subtracted" : "no subtraction", ev.laserOffFrames, second.c_str());
}

namespace {
// A scan ended by STOP.
Status aborted(WorkerEvent& ev) {
  ev.resultStatus = protocol::ResultStatus::kAborted;
  return {Error::kFault, "scan stopped by command"};
}
}  // namespace

Status ScanWorker::stopAndGo(const localize::ScanPlan& plan, const ports::CaptureRequest& capture, WorkerEvent& ev) {
  for (size_t i = 0; i < plan.stopsMm.size(); ++i) {
    if (Status s = moveTo(plan.stopsMm[i], ev); !s) return s;
    Result<ports::CapturedFrame> frame = exposeStop(i, capture, ev);
    if (!frame) return frame.status();
    // The image work of this stop runs while the slide moves to the next one.
    const double slideMm = recordedOr(deps_, positionMm());
    ev.exposures.back().slideMm = slideMm;
    pipeline_.push(frame->view, slideMm);
    if (ev.secondExposureUs > 0 && !cancel_.load()) {
      // In sun, the same stop again at the second exposure (metering.second_exposure_factor).
      ports::CaptureRequest longer = capture;
      longer.exposureUs = ev.secondExposureUs;
      frame = exposeStop(i, longer, ev, nullptr, true);
      if (!frame) return frame.status();
      const double secondMm = recordedOr(deps_, positionMm());
      ev.exposures.back().slideMm = secondMm;
      pipeline_.push(frame->view, secondMm, 0.0, FramePipeline::Exposure::kSecondMerged);
    }
    if (cancel_.load()) return aborted(ev);
  }
  return Status::ok();
}

namespace {
// Where the slide was while a sweep's frame was exposed.
struct FramePlace {
  double slideMm = 0.0;        // at the mid-exposure of the ROI's middle row
  double slideMmPerRow = 0.0;  // a rolling shutter's: the travel from one row's exposure to the next's
};

// The slide's position at a frame's mid-exposure in a sweep, from the frame's timestamp and
// the times of the sweep's STEP edges. A sensor exposes in its next frame slot after the
// request and delivers the frame after its readout, so the positions at the request and at
// the delivery are each up to a frame time off (10 mm at 300 mm/s and 30 fps). The
// timestamp is row 0's exposure start (libcamera's definition) or, on pipelines that stamp
// the start of readout (deps.timestampAtExposureEnd), its end. With a rolling shutter
// (deps.lineTimeNs > 0) row v exposes v line times after row 0: the ROI's first and last
// rows give the travel per row. A timestamp that cannot be this frame's (none, before the
// request, or the ROI's exposure not over at the delivery: another clock, or a line time
// too long) leaves `sampledMm`, the mean of the positions where the laser last went on
// and off (the hooks' begin and end).
FramePlace sweptFramePlace(const motion::StepLog& log, int64_t fromSteps, bool forward, const motion::SlideLimits& lim,
                           const ports::FrameInfo& info, const image::Roi& roi, const WorkerDeps& deps, TimeNs askedNs,
                           TimeNs deliveredNs, double sampledMm) {
  const TimeNs exposureNs = info.exposureUs * kNsPerUs;
  const TimeNs lineTimeNs = deps.lineTimeNs;
  const TimeNs startNs = info.exposureStartNs - (deps.timestampAtExposureEnd ? exposureNs : 0);
  // The ROI's last row's exposure must be over at the delivery (else the timestamp, or the
  // line time, is not this frame's).
  const TimeNs lastRowEndNs =
      startNs + exposureNs + std::llround((roi.y + roi.height) * static_cast<double>(lineTimeNs));
  if (startNs < askedNs || lastRowEndNs > deliveredNs) return {sampledMm, 0.0};
  const auto slideAtRow = [&](double row) {
    const TimeNs t = startNs + exposureNs / 2 + std::llround(row * static_cast<double>(lineTimeNs));
    const int64_t steps = log.stepsAt(t);
    return lim.mmFor(fromSteps + (forward ? steps : -steps));
  };
  FramePlace place;
  place.slideMm = slideAtRow(roi.y + 0.5 * roi.height);
  if (lineTimeNs > 0 && roi.height > 1)
    place.slideMmPerRow = (slideAtRow(roi.y + roi.height - 1.0) - slideAtRow(roi.y)) / (roi.height - 1.0);
  return place;
}
}  // namespace

Result<bool> ScanWorker::toSweepStart(const std::vector<double>& stops, double paceMmPerS,
                                      const std::function<void()>& runUp, WorkerEvent& ev) {
  const double here = positionMm();
  const bool forward = stops.back() >= stops.front();
  // Start from outside the span so that no stop lies behind the slide.
  const bool inside = (forward && here > stops.front()) || (!forward && here < stops.front());
  // A sweep slower than the motor that starts far before its first stop would crawl the
  // whole way there: the slide first goes at full speed to where the sweep's pace can be
  // reached from rest, when that is sooner (the second pass, which starts where the
  // first one braked, 40-50 mm from its own first stop).
  const std::optional<double> toMm = inside ? std::optional<double>(stops.front())
                                            : motion::fastRunUpMm(deps_.limits, paceMmPerS, here, stops.front());
  if (!toMm) return false;
  if (Status st = moveTo(*toMm, ev, runUp); !st) return st;
  if (cancel_.load()) return aborted(ev);
  ALACS_LOG_DEBUG("scan", "sweep: %s at full speed, metering meanwhile",
                  inside ? "back to the first stop" : "to the run-up of a slower sweep");
  return true;
}

TimeNs ScanWorker::awaitStop(const Sweep& sw, TimeNs moveStartNs, int64_t fromSteps, const motion::SlideLimits& lim,
                             double stopMm, const image::Roi& window, int64_t exposureUs) {
  const TimeNs halfExposure = exposureUs * kNsPerUs / 2;
  // Half an exposure's travel at cruise speed, in steps: the exposure is centred on the stop.
  const auto halfTravel =
      static_cast<int64_t>(lim.maxSpeedMmPerS * lim.stepsPerMm * static_cast<double>(halfExposure) * 1e-9);
  const int64_t k = std::llabs(lim.stepsFor(stopMm) - fromSteps);
  // Sleep to the planned passing time, then follow the steps actually emitted: a motor
  // running late (a loaded machine) must not make the frame early.
  const TimeNs passNs = moveStartNs + (k > 0 ? sw.move.stepTimeNs(k) : 0);
  TimeNs askNs = passNs - halfExposure;
  int64_t target = lim.stepsFor(stopMm) + (sw.forward ? -halfTravel : halfTravel);
  // A free-running sensor: ask in time for the frame nearest the stop, before or after
  // it (motion::nearestFrameStartNs), once the slide is where the plan has it then.
  if (const std::optional<TimeNs> nearest = nearestFrameAskNs(passNs, window, exposureUs);
      nearest && *nearest > deps_.clock->now()) {
    askNs = *nearest;
    const auto planned = static_cast<int64_t>(std::floor(sw.move.positionAt(askNs - moveStartNs)));
    target = fromSteps + (sw.forward ? planned : -planned);
  }
  deps_.sleeper->sleepUntil(askNs);
  while (sw.moving.load() && !cancel_.load() &&
         (sw.forward ? positionSteps_.load() < target : positionSteps_.load() > target))
    deps_.sleeper->sleepUntil(deps_.clock->now() + 100 * kNsPerUs);
  return passNs;
}

Status ScanWorker::sweptFrame(const SweptStop& at, const ports::CaptureRequest& capture, WorkerEvent& ev, bool second) {
  double sampledMm = 0.0;
  const TimeNs askedNs = deps_.clock->now();
  Result<ports::CapturedFrame> frame = exposeStop(at.stop, capture, ev, &sampledMm, second);
  if (!frame) return frame.status();
  if (!second)
    ALACS_LOG_DEBUG(
        "scan", "stop %zu: the slide passes at %.1f ms; asked at %.1f ms, stamped %.1f ms, delivered %.1f ms", at.stop,
        static_cast<double>(at.passNs) / 1e6, static_cast<double>(askedNs) / 1e6,
        static_cast<double>(frame->info.exposureStartNs) / 1e6, static_cast<double>(deps_.clock->now()) / 1e6);
  FramePlace place = sweptFramePlace(at.sweep.log, at.fromSteps, at.forward, at.lim, frame->info, at.roi, deps_,
                                     askedNs, deps_.clock->now(), sampledMm);
  // A replayed frame has its recorded position, for the frame as a whole.
  if (const double recordedMm = recordedOr(deps_, std::numeric_limits<double>::quiet_NaN()); std::isfinite(recordedMm))
    place = {recordedMm, 0.0};
  ev.exposures.back().slideMm = place.slideMm;
  pipeline_.push(frame->view, place.slideMm, place.slideMmPerRow,
                 second ? FramePipeline::Exposure::kSecondLine : FramePipeline::Exposure::kFirst);
  return Status::ok();
}

Status ScanWorker::sweepStops(const localize::ScanPlan& plan, ports::CaptureRequest& capture, WorkerEvent& ev,
                              const std::function<void()>& runUp) {
  // One move through every stop; each frame is exposed as the slide passes its stop, and
  // its position is the slide's (counted steps) at mid-exposure. `runUp` (the metering: its
  // frames are laser-off, and the camera is fixed) runs while the slide moves back to the
  // first stop, or during the sweep's own run-up to it (see below), or before the sweep
  // when the slide is on the first stop. It may shorten capture.exposureUs; the overrun,
  // planned before it, then keeps a little to spare.
  std::vector<double> stops = plan.stopsMm;
  const double here = positionMm();
  const double nearStart = std::abs(here - stops.front()) <= std::abs(here - stops.back()) ? stops.front() : stops.back();
  if (nearStart == stops.back()) std::reverse(stops.begin(), stops.end());
  const bool forward = stops.back() >= stops.front();
  // No faster than the camera gives frames: each stop's frame is asked for as the slide
  // passes it, and a stop passed before the last frame was delivered would be taken late,
  // and every stop after it later (motion/sweep_speed.h). The camera's time is its recent
  // captures' (a first scan's own metering frames are among them: asked again below).
  // In sun each stop takes a second exposure (ev.secondExposureUs) at the camera's next
  // frame, a line of its own: two captures a stop. With the metering in the run-up the
  // pace is planned before it is known, as the last scan's metering found; a sweep not
  // paced for them takes none.
  motion::SlideLimits lim = deps_.limits;
  bool pacedForTwo = false;
  const auto pace = [&] {
    pacedForTwo = ev.laserOffFrames > 0 ? ev.secondExposureUs > 0 : lastSecondExposure_;
    lim.maxSpeedMmPerS = motion::sweepSpeedMmPerS(deps_.limits, stops, capturePaceNs() * (pacedForTwo ? 2 : 1));
  };
  pace();
  Result<bool> started = toSweepStart(stops, lim.maxSpeedMmPerS, runUp, ev);
  if (!started) return started.status();
  const bool meteredAlready = *started;
  const int64_t from = positionSteps_.load();
  // The metering overlaps the sweep's own run-up to the first stop, expected to last as
  // long as the last one. It may make the first laser frame late by up to half a stop's
  // travel; when it would make it later, the slide starts that much later. With no
  // metering before (the first scan) it runs before the sweep.
  const int64_t firstStopSteps = std::llabs(deps_.limits.stepsFor(stops.front()) - from);
  const bool overlap = runUp && !meteredAlready && firstStopSteps > 0 && meterNs_ > 0;
  if (runUp && !meteredAlready && !overlap) {
    runUp();
    if (cancel_.load()) return aborted(ev);
  }
  pace();
  ev.sweepSpeedMmPerS =
      ev.sweepSpeedMmPerS > 0.0 ? std::min(ev.sweepSpeedMmPerS, lim.maxSpeedMmPerS) : lim.maxSpeedMmPerS;
  ALACS_LOG_DEBUG("scan",
                  "sweep: %zu stops at %.0f mm/s (%.1f ms a capture, from the camera's last %d; its period %.1f ms, 0 "
                  "until learnt)",
                  stops.size(), lim.maxSpeedMmPerS, static_cast<double>(capturePaceNs()) / 1e6, captures_.count(),
                  static_cast<double>(sensorClock_.periodNs().value_or(0)) / 1e6);
  // Run on past the last stop by an exposure's travel (it is centred on the stop), with a
  // rolling shutter's the travel until the ROI's last row has exposed, and by the braking
  // distance, so that the slide passes every stop at cruise speed (each row's position is
  // then linear in its row) and brakes only after the last frame, while the result is
  // already out.
  const double brakingMm = lim.maxSpeedMmPerS * lim.maxSpeedMmPerS / (2.0 * lim.accelMmPerS2);
  const double rowsS = static_cast<double>(deps_.lineTimeNs) * 1e-9 * (plan.roi.y + plan.roi.height);
  // (A second exposure after the last stop's frame: a capture and that exposure more.)
  const double secondUs = ev.secondExposureUs > 0 ? static_cast<double>(ev.secondExposureUs)
                                                  : static_cast<double>(capture.exposureUs) *
                                                        std::max(1.0, deps_.metering.secondExposureFactor);
  const double secondS = pacedForTwo ? static_cast<double>(capturePaceNs()) * 1e-9 + secondUs * 1e-6 : 0.0;
  const double overrunMm =
      lim.maxSpeedMmPerS * (static_cast<double>(capture.exposureUs) * 1e-6 + rowsS + secondS) + 0.5 + brakingMm;
  const double endMm = std::clamp(stops.back() + (forward ? overrunMm : -overrunMm), 0.0, lim.strokeMm);
  Result<motion::TrapezoidMove> move = motion::planMove(lim, from, lim.stepsFor(endMm));
  if (!move) return move.status();
  TimeNs startNs = deps_.clock->now();
  if (overlap) {
    const auto halfStopNs =
        static_cast<TimeNs>(stops.size() > 1 ? std::abs(stops[1] - stops[0]) / lim.maxSpeedMmPerS * 0.5e9 : 0.0);
    const TimeNs firstExposureNs = move->stepTimeNs(firstStopSteps) - capture.exposureUs * kNsPerUs / 2;
    const TimeNs lateNs = std::max<TimeNs>(0, meterNs_ - firstExposureNs - halfStopNs);
    startNs += lateNs;
    ALACS_LOG_DEBUG("scan", "sweep: metering (%.0f ms expected) in a %.0f ms run-up, the slide starts %.0f ms later",
                    static_cast<double>(meterNs_) / 1e6, static_cast<double>(firstExposureNs) / 1e6,
                    static_cast<double>(lateNs) / 1e6);
  }
  const TimeNs moveStart = startNs + lim.dirSetupNs;
  std::unique_ptr<Sweep> sweep = startMove(*move, forward, startNs);
  Sweep* sw = sweep.get();
  Status status = Status::ok();
  if (overlap) {
    runUp();
    if (cancel_.load()) status = aborted(ev);
  }
  if (ev.secondExposureUs > 0 && !pacedForTwo) {
    // Metered in the run-up of a sweep paced for one capture a stop: none this scan (the
    // next one is paced for two).
    ALACS_LOG_INFO("scan", "sweep paced for one exposure a stop: no second exposure in this scan");
    ev.secondExposureUs = 0;
  }
  for (size_t i = 0; i < stops.size() && status.isOk(); ++i) {
    const TimeNs passNs = awaitStop(*sw, moveStart, from, lim, stops[i], plan.roi, capture.exposureUs);
    const SweptStop at{*sw, from, forward, lim, plan.roi, i, passNs};
    status = sweptFrame(at, capture, ev, false);
    // In sun the stop again at the second exposure, at the camera's next frame.
    if (status.isOk() && pacedForTwo && ev.secondExposureUs > 0 && !cancel_.load()) {
      ports::CaptureRequest longer = capture;
      longer.exposureUs = ev.secondExposureUs;
      status = sweptFrame(at, longer, ev, true);
    }
    if (!status) cancel_.store(true);  // stop the sweep: the scan has failed
    if (status.isOk() && cancel_.load()) status = aborted(ev);
  }
  if (status.isOk() && sw->moving.load()) {
    // Every frame taken: the slide brakes while the result is made and posted (run()).
    braking_ = std::move(sweep);
    return status;
  }
  joinSweep(*sweep);
  if (!status) {
    // The sweep was cut short on purpose: the failure above is the reason, not the stop.
    ev.maxStepLatenessNs = std::max(ev.maxStepLatenessNs, sweep->report.maxLatenessNs);
    homed_.store(homed_.load() && positionKnownAfter(sweep->report));
    return status;
  }
  return moveOutcome(sweep->report, ev);
}

}  // namespace alacs::app
