// Shared helpers of the alacs-twin subcommands.
#pragma once

#include <Eigen/Core>
#include <atomic>
#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <string>
#include <thread>
#include <vector>

#include "common/result.h"
#include "localize/exposure.h"
#include "localize/localizer.h"
#include "sim/renderer.h"
#include "tool_common/json.h"

namespace alacs::twin {

// A subcommand's options as given (main.cpp declares them to CLI11, which checks that
// numbers are numbers, integers integral and lists numbers separated by commas); flags
// are "1". The subcommand reads them with its own defaults, which may depend on other
// options (generate's --set).
class Args {
 public:
  void set(const std::string& k, const std::string& v);
  void addPositional(const std::string& v);
  bool has(const std::string& k) const { return values_.count(k) != 0; }
  std::string str(const std::string& k, const std::string& fallback = "") const;
  double num(const std::string& k, double fallback) const;
  int64_t integer(const std::string& k, int64_t fallback) const;
  std::vector<double> list(const std::string& k, const std::vector<double>& fallback) const;
  const std::vector<std::string>& positional() const { return positional_; }

 private:
  std::map<std::string, std::string> values_;
  mutable std::map<std::string, bool> used_;
  std::vector<std::string> positional_;
};

// Runs work(i) for i in [0, n) on `jobs` threads; `done(i)` is called under a lock after
// each item (progress). Returns the first error.
Status parallelFor(int n, int jobs, const std::function<Status(int)>& work, const std::function<void(int)>& done);

// The ROI the pipeline will use for a target's rough position, and the region the twin
// renders around it: the plan of a localizer whose ROI margin is 10 mm wider, plus 8 px.
// Pixels outside are never read by the pipeline (its ROI is inside, and LLE reads
// nothing outside its ROI), so rendering only them is exact, and ~15× cheaper.
struct RenderPlan {
  localize::ScanPlan plan;
  cv::Rect region;
};
Result<RenderPlan> renderPlan(const geometry::Calibration& cal, const Eigen::Vector3d& roughMm, int stops = 5);

// The daemon's exposure metering (metering.* in its config, localize/exposure.h) as
// `generate` and `process` take it: --metering 0|1, --meter-target-dn,
// --meter-subtract-above-dn, its defaults unless given, and --max-exposure-us, the longest
// exposure it may choose (the daemon's camera.exposure_us, 3000). Errors: kInvalidArgument.
struct MeteringArgs {
  localize::MeteringParams params;
  int64_t maxExposureUs = 3000;
};
Result<MeteringArgs> meteringArgs(const Args& args);

// The scan worker's passes (app/scan_worker.cpp, doLocalize) without its devices: the
// plan's stops (pass 1), the estimate, and when `followUp` and the localizer asks for them
// (Localizer::followUpStops) its second pass's stops (pass 2), all the lines fused again.
// `observeAt` gives the line of a frame at a slide position (an error: no line). The twin's
// generator renders the second pass's frames because this asks for them; `process` then
// finds them in the scan and takes the same decision.
using ObserveAt = std::function<Result<localize::LineObservation>(double slideMm, int pass)>;
struct TwoPassScan {
  std::vector<localize::LineObservation> lines;  // both passes', in scan order
  Result<localize::AppleEstimate> firstPass{Error::kNotFound, "not scanned"};
  Result<localize::AppleEstimate> estimate{Error::kNotFound, "not scanned"};  // from all the lines
  std::vector<double> followUpMm;  // the second pass's stops (empty: none taken)
};
TwoPassScan twoPassScan(const localize::Localizer& loc, const localize::ScanPlan& plan, double strokeMm, bool followUp,
                        const ObserveAt& observeAt);

// A vector as a JSON array of three numbers ("%.6f" as printed before; null when not finite).
tools::Json jsonVec(const Eigen::Vector3d& v);

int generateMain(const Args& args);
int calibrationMain(const Args& args);
int processMain(const Args& args);
int examplesMain(const Args& args);
int renderMain(const Args& args);
int reachMain(const Args& args);

}  // namespace alacs::twin
