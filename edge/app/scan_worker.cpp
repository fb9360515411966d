#include "app/scan_worker.h"

#include <pthread.h>
#include <sys/eventfd.h>
#include <sys/prctl.h>
#include <unistd.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/log.h"

namespace alacs::app {

ScanWorker::ScanWorker(WorkerDeps deps, const localize::Localizer& localizer, int eventFd)
    : deps_(std::move(deps)), localizer_(localizer), eventFd_(eventFd) {
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

void ScanWorker::submit(const WorkerJob& job) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    jobs_.push_back(job);
    busy_.store(true);
  }
  cancel_.store(false);
  cv_.notify_all();
}

std::optional<WorkerEvent> ScanWorker::takeEvent() {
  std::lock_guard<std::mutex> lock(mu_);
  if (events_.empty()) return std::nullopt;
  WorkerEvent ev = std::move(events_.front());
  events_.pop_front();
  return ev;
}

void ScanWorker::setLocalizer(const localize::Localizer& l) {
  std::lock_guard<std::mutex> lock(mu_);
  localizer_ = l;
}

void ScanWorker::setExposureUs(int64_t us) {
  std::lock_guard<std::mutex> lock(mu_);
  deps_.capture.exposureUs = us;
}

void ScanWorker::run() {
  // Step pulses are timed by this thread (tools/jitter measures it): real-time priority
  // when the system allows it (on the board), else at least no timer slack, whose 50 us
  // default is otherwise the median lateness of every edge.
  sched_param sp{};
  sp.sched_priority = deps_.realtimePriority;
  if (deps_.realtimePriority <= 0 || pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) != 0) {
    prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL);
    ALACS_LOG_INFO("motion", "step timing: normal scheduling, timer slack 1 ns");
  } else {
    ALACS_LOG_INFO("motion", "step timing: SCHED_FIFO priority %d", deps_.realtimePriority);
  }
  while (true) {
    WorkerJob job;
    {
      std::unique_lock<std::mutex> lock(mu_);
      cv_.wait(lock, [&] { return quit_ || !jobs_.empty(); });
      if (quit_) return;
      job = jobs_.front();
      jobs_.pop_front();
    }
    WorkerEvent ev = job.kind == WorkerJob::Kind::kHome       ? doHome(job)
                     : job.kind == WorkerJob::Kind::kScanAll ? doScanAll(job)
                                                             : doLocalize(job);
    (void)deps_.laser->off();  // whatever happened, the laser ends the job off
    (void)deps_.enable->set(false);
    ev.doneNs = deps_.clock->now();
    {
      std::lock_guard<std::mutex> lock(mu_);
      events_.push_back(std::move(ev));
      busy_.store(!jobs_.empty());
    }
    const uint64_t one = 1;
    [[maybe_unused]] ssize_t w = ::write(eventFd_, &one, sizeof one);
  }
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
    homed_.store(true);
    ev.status = Status::ok();
    return ev;
  }
  ev.status = r.status.isOk() ? Status(Error::kFault, "homing failed") : r.status;
  if (r.outcome == motion::MoveOutcome::kCancelled) return ev;
  ev.faultBit = r.outcome == motion::MoveOutcome::kIoError ? protocol::kFaultInternal : protocol::kFaultHomingTimeout;
  return ev;
}

Status ScanWorker::moveTo(double mm, WorkerEvent& ev) {
  const int64_t from = positionSteps_.load();
  const int64_t to = deps_.limits.stepsFor(mm);
  Result<motion::TrapezoidMove> move = motion::planMove(deps_.limits, from, to);
  if (!move) return move.status();
  motion::StepRunner runner(deps_.limits, deps_.stepLines, *deps_.clock, *deps_.sleeper);
  const motion::MoveReport r = runner.run(*move, to > from, cancel_);
  ev.maxStepLatenessNs = std::max(ev.maxStepLatenessNs, r.maxLatenessNs);
  positionSteps_.store(from + (to > from ? r.stepsDone : -r.stepsDone));
  if (r.outcome == motion::MoveOutcome::kCompleted) return Status::ok();
  homed_.store(false);  // a move that did not complete leaves the position in doubt
  if (r.outcome == motion::MoveOutcome::kLimitHit) ev.faultBit = protocol::kFaultLimitHit;
  if (r.outcome == motion::MoveOutcome::kIoError) ev.faultBit = protocol::kFaultInternal;
  if (r.outcome == motion::MoveOutcome::kCancelled) ev.resultStatus = protocol::ResultStatus::kAborted;
  return r.status.isOk() ? Status(Error::kFault, "move failed") : r.status;
}

namespace {
void writeOverlay(const std::string& dir, const ports::CapturedFrame& frame, const localize::ScanPlan& plan,
                  const std::vector<localize::LineObservation>& lines) {
  cv::Mat img(frame.view.height, frame.view.width, CV_8UC3, const_cast<uint8_t*>(frame.view.data), frame.view.strideBytes);
  cv::Mat out = img.clone();
  static const cv::Scalar kColours[] = {{255, 255, 0}, {0, 255, 0}, {255, 0, 255}, {0, 255, 255}, {255, 128, 0}};
  size_t k = 0;
  for (const auto& l : lines) {
    const cv::Scalar c = kColours[k++ % 5];
    for (const auto& r : l.line.rows) {
      const cv::Point p(static_cast<int>(std::lround(r.column)), r.row);
      cv::circle(out, p, 1, r.inlier ? c : cv::Scalar(0, 0, 255), cv::FILLED);
    }
  }
  cv::rectangle(out, cv::Rect(plan.roi.x, plan.roi.y, plan.roi.width, plan.roi.height), {255, 255, 255}, 2);
  cv::Mat crop = out(cv::Rect(plan.roi.x, plan.roi.y, plan.roi.width, plan.roi.height));
  cv::imwrite(dir + "/overlay.png", crop);
}
}  // namespace

Result<ports::CapturedFrame> ScanWorker::exposeStop(size_t stop, const ports::CaptureRequest& capture,
                                                     WorkerEvent& ev) {
  // Timeouts and corrupted frames are retried (laser on only for each attempt's
  // exposure), then become a fault with the last reason.
  Result<ports::CapturedFrame> frame = Status(Error::kInternal, "no capture attempted");
  for (int attempt = 0; attempt <= deps_.captureRetries && !cancel_.load(); ++attempt) {
    if (Status s = deps_.laser->on(); !s) {
      ev.status = s;
      ev.faultBit = protocol::kFaultLaserOvertime;
      ev.resultStatus = protocol::ResultStatus::kFailed;
      return s;
    }
    frame = deps_.camera->capture(capture, [this] { (void)deps_.laser->off(); });
    (void)deps_.laser->off();
    if (frame) break;
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
  ev.lastExposureNs = frame->info.exposureStartNs + frame->info.exposureUs * kNsPerUs;
  ev.exposures.push_back({frame->info.exposureStartNs, ev.lastExposureNs});
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
      if (ev.resultStatus == protocol::ResultStatus::kValid) ev.resultStatus = protocol::ResultStatus::kFailed;
      return ev;
    }
    Result<ports::CapturedFrame> frame = exposeStop(i, capture, ev);
    if (!frame) return ev;
    if (Status s = survey.addFrame(frame->view, positionMm(), ws_); !s)
      ALACS_LOG_WARN("survey", "stop %zu: %s", i, s.toString().c_str());
    if (cancel_.load()) {
      ev.status = Status(Error::kFault, "scan stopped by command");
      ev.resultStatus = protocol::ResultStatus::kAborted;
      return ev;
    }
  }
  ev.estimates = survey.finish();
  ev.resultStatus = ev.estimates.empty() ? protocol::ResultStatus::kNoObject : protocol::ResultStatus::kValid;
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
  localize::Localizer localizer = [&] {
    std::lock_guard<std::mutex> lock(mu_);
    return localizer_;
  }();
  ports::CaptureRequest capture = [&] {
    std::lock_guard<std::mutex> lock(mu_);
    return deps_.capture;
  }();
  const localize::ScanPlan* plan = &job.plan;
  if (Status s = deps_.enable->set(true); !s) {
    ev.status = s;
    ev.faultBit = protocol::kFaultInternal;
    return ev;
  }
  std::vector<localize::LineObservation> lines;
  const bool wantOverlay = !deps_.debugDir.empty();
  for (size_t i = 0; i < plan->stopsMm.size(); ++i) {
    const double stop = plan->stopsMm[i];
    if (Status s = moveTo(stop, ev); !s) {
      ev.status = s;
      if (ev.resultStatus == protocol::ResultStatus::kValid) ev.resultStatus = protocol::ResultStatus::kFailed;
      return ev;
    }
    Result<ports::CapturedFrame> frame = exposeStop(i, capture, ev);
    if (!frame) return ev;
    Result<localize::LineObservation> obs = localizer.observe(frame->view, *plan, positionMm(), ws_);
    if (!obs) {
      ALACS_LOG_WARN("scan", "stop %zu: %s", i, obs.status().toString().c_str());
      continue;
    }
    ALACS_LOG_DEBUG("scan", "stop %zu at %.2f mm: %zu rows, %zu points", i, positionMm(), obs->line.rows.size(),
                    obs->pointsMm.size());
    lines.push_back(std::move(*obs));
    if (wantOverlay && i + 1 == plan->stopsMm.size()) writeOverlay(deps_.debugDir, *frame, *plan, lines);
    if (cancel_.load()) {
      ev.status = Status(Error::kFault, "scan stopped by command");
      ev.resultStatus = protocol::ResultStatus::kAborted;
      return ev;
    }
  }
  Result<localize::AppleEstimate> est = localizer.estimate(*plan, lines);
  if (!est) {
    ev.status = Status::ok();  // the scan worked; there was no apple where we were told
    ev.resultStatus = protocol::ResultStatus::kNoObject;
    return ev;
  }
  ev.estimates.push_back(*est);
  ev.resultStatus = est->sphereFit ? protocol::ResultStatus::kValid : protocol::ResultStatus::kPartial;
  ev.status = Status::ok();
  return ev;
}

}  // namespace alacs::app
