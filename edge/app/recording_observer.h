// alacsd --record: each LOCALIZE's frames and manifest as a scan directory
// (docs/scan-format.md), begun when the sensor accepts the command and ended with its
// result; the platform's own observer (the simulator's laser timeline) is told too.
#pragma once

#include "app/sensor.h"
#include "common/log.h"
#include "replay/scan_recorder.h"

namespace alacs::app {

class RecordingObserver final : public ScanObserver {
 public:
  RecordingObserver(replay::ScanRecorder* recorder, ScanObserver* next) : recorder_(recorder), next_(next) {}
  void scanStarted(const protocol::LocalizeCommand& c, const localize::ScanPlan& plan) override {
    if (recorder_ != nullptr) {
      if (Status s = recorder_->begin(c.targetId, c.roughMm, plan.stopsMm, plan.roi); !s)
        ALACS_LOG_WARN("record", "%s", s.toString().c_str());
    }
    if (next_ != nullptr) next_->scanStarted(c, plan);
  }
  void scanFinished(const WorkerEvent& ev) override {
    if (recorder_ != nullptr && ev.job.kind == WorkerJob::Kind::kLocalize) {
      if (Result<std::string> dir = recorder_->end(); dir) ALACS_LOG_INFO("record", "scan written to %s", dir->c_str());
    }
    if (next_ != nullptr) next_->scanFinished(ev);
  }

 private:
  replay::ScanRecorder* recorder_;
  ScanObserver* next_;
};

}  // namespace alacs::app
