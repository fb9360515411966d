// A recording fake of the scan worker for the sensor's unit tests: jobs are recorded
// and stay "running" until the test finishes them (finish(), finishCancelled()), which
// returns the WorkerEvent the real worker would post. No thread, no clock of its own.
#pragma once

#include <deque>
#include <vector>

#include "app/scan_jobs.h"

namespace alacs::app {

class FakeScanJobs final : public ScanJobs {
 public:
  // Jobs submitted, in order (refused ones excluded).
  const std::vector<WorkerJob>& submitted() const { return submitted_; }
  int cancels() const { return cancels_; }
  size_t queued() const { return jobs_.size(); }
  bool cancelPending() const { return cancelPending_; }
  const std::optional<localize::Localizer>& localizer() const { return localizer_; }
  int64_t exposureUs() const { return exposureUs_; }
  void setHomed(bool homed) { homed_ = homed; }
  void setDroppedFrames(uint32_t n) { dropped_ = n; }
  void setProgressNs(TimeNs t) { progressNs_ = t; }
  void setFrameReadSinceNs(TimeNs t) { frameReadSinceNs_ = t; }
  void setProgress(const ScanProgress& p) { progress_ = p; }

  // Ends the running job with `ev` (its job filled in). A home job that succeeds homes.
  WorkerEvent finish(WorkerEvent ev = {}) {
    ev.job = jobs_.front();
    jobs_.pop_front();
    if (jobs_.empty()) cancelPending_ = false;
    if (ev.job.kind == WorkerJob::Kind::kHome && ev.status.isOk()) homed_ = true;
    return ev;
  }
  // Ends the running job as the real worker does after cancel(): aborted.
  WorkerEvent finishCancelled() {
    WorkerEvent ev;
    ev.status = Status(Error::kFault, "scan stopped");
    ev.resultStatus = protocol::ResultStatus::kAborted;
    return finish(ev);
  }

  bool submit(const WorkerJob& job) override {
    if (jobs_.size() >= 2) return false;
    jobs_.push_back(job);
    submitted_.push_back(job);
    return true;
  }
  void cancel() override {
    ++cancels_;
    if (!jobs_.empty()) cancelPending_ = true;
  }
  bool busy() const override { return !jobs_.empty(); }
  bool homed() const override { return homed_; }
  void markUnhomed() override { homed_ = false; }
  double positionMm() const override { return positionMm_; }
  uint32_t droppedFrames() const override { return dropped_; }
  TimeNs progressNs() const override { return progressNs_; }
  TimeNs frameReadSinceNs() const override { return frameReadSinceNs_; }
  ScanProgress progress() const override { return progress_; }
  void setLocalizer(const localize::Localizer& l) override { localizer_ = l; }
  void setExposureUs(int64_t us) override { exposureUs_ = us; }

 private:
  std::deque<WorkerJob> jobs_;
  std::vector<WorkerJob> submitted_;
  std::optional<localize::Localizer> localizer_;
  int64_t exposureUs_ = 0;
  int cancels_ = 0;
  bool cancelPending_ = false;
  bool homed_ = false;
  double positionMm_ = 0.0;
  uint32_t dropped_ = 0;
  TimeNs progressNs_ = 0;
  TimeNs frameReadSinceNs_ = 0;
  ScanProgress progress_;
};

}  // namespace alacs::app
