// alacs-twin reach: what any scan strategy could see of each scan's target. The truth
// (sim::laserLineTruth: the target's rows that the camera sees and the laser lights) at
// every slide position over the stroke, `--step-mm` apart (or at `--slides`). A target
// that no position lights on `--min-rows` rows or more is beyond every placement of the
// stops: leaves hide it wherever the line crosses it, and only the rough position can
// stand in for it (docs/evaluation.md, "What any placement of the stops could see").
// Beside it, how surely the rough position names the target at all (identityPct).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include "replay/scan_dir.h"
#include "sim/orchard.h"
#include "sim/scene.h"
#include "sim/truth.h"
#include "twin.h"

namespace alacs::twin {

namespace {

// Positions closer than this (mm) belong to one run of the stroke: the sweep's step, with
// room for the rounding of a position given in `--slides`.
constexpr double kRunGapSlackMm = 1e-6;

// Fruit whose centres lie this close to the target's are as good as the target: a result
// there is within the end effector's tolerance.
constexpr double kSameFruitMm = 20.0;

struct Reach {
  std::vector<std::pair<double, int>> lit;  // each position that lights min-rows or more, and its rows
  int maxRows = 0;                          // the most visible lit rows at any position tried
  double widestRunMm = 0.0;                 // the widest run of consecutive lit positions, last − first
  std::optional<double> identityPct;        // identityPct() of the scan's rough position (none without one)
};

// How surely the rough position names the target: the chance (%) that an ideal observer,
// who knows every fruit's centre in the scene and the rough position's error as the twin
// draws it (sim::roughSigmaMm about the target's centre, the same on each axis), takes the
// target (or a fruit within kSameFruitMm of it) for the fruit the rough position was made
// for. What it leaves is the share of such scans that no sensor could tell from a
// neighbour's by the rough position, however well it saw every fruit.
double identityPct(const sim::SimScene& scene, const sim::SimApple& target, const Eigen::Vector3d& roughMm) {
  const double sigmaMm = sim::roughSigmaMm(target.centerMm.norm());
  const auto logLikelihood = [&](const sim::SimApple& a) {
    return -0.5 * (a.centerMm - roughMm).squaredNorm() / (sigmaMm * sigmaMm);
  };
  double most = logLikelihood(target);
  for (const sim::SimApple& a : scene.apples) most = std::max(most, logLikelihood(a));
  double same = 0.0;
  double all = 0.0;
  for (const sim::SimApple& a : scene.apples) {
    const double w = std::exp(logLikelihood(a) - most);  // relative, so that none underflows
    all += w;
    if ((a.centerMm - target.centerMm).norm() <= kSameFruitMm) same += w;
  }
  return all > 0.0 ? 100.0 * same / all : 100.0;
}

// Visible, lit rows of the target at one slide position, one per image row (the truth can
// list a row twice where the arc turns back near the limb; the evaluation counts it once,
// tools/eval metrics.visible_rows).
int visibleRows(const sim::SimScene& scene, const sim::SimApple& target, double slideMm) {
  std::set<int> rows;
  for (const sim::RowTruth& t : sim::laserLineTruth(scene, target, slideMm)) rows.insert(t.row);
  return static_cast<int>(rows.size());
}

Result<Reach> reachOf(const std::string& dir, const std::vector<double>& slidesMm, double stepMm, int minRows) {
  const Result<replay::ScanManifest> m = replay::readManifest(dir);
  if (!m) return Status(m.status().code(), dir + ": " + m.status().reason());
  if (m->scan.truthFile.empty()) return Status(Error::kBadInput, dir + ": the scan has no truth (scan.truth)");
  const Result<sim::SimScene> scene = sim::loadScene(dir + "/" + m->scan.truthFile);
  if (!scene) return Status(scene.status().code(), dir + ": " + scene.status().reason());
  const sim::SimApple* target = scene->apple(m->scan.targetId);
  if (target == nullptr)
    return Status(Error::kBadInput, dir + ": the scene has no apple " + std::to_string(m->scan.targetId));
  Reach r;
  if (m->scan.roughMm) r.identityPct = identityPct(*scene, *target, *m->scan.roughMm);
  double runFirstMm = 0.0;
  double previousMm = 0.0;
  bool inRun = false;
  for (const double slideMm : slidesMm) {
    const int rows = visibleRows(*scene, *target, slideMm);
    r.maxRows = std::max(r.maxRows, rows);
    if (rows < minRows) {
      inRun = false;
      continue;
    }
    r.lit.emplace_back(slideMm, rows);
    if (!inRun || slideMm - previousMm > stepMm + kRunGapSlackMm) runFirstMm = slideMm;
    inRun = true;
    previousMm = slideMm;
    r.widestRunMm = std::max(r.widestRunMm, slideMm - runFirstMm);
  }
  return r;
}

}  // namespace

int reachMain(const Args& args) {
  const std::vector<std::string>& dirs = args.positional();
  const double strokeMm = args.num("stroke-mm", 200.0);
  const double stepMm = args.num("step-mm", 1.0);
  const auto minRows = static_cast<int>(args.integer("min-rows", 8));
  if (!(strokeMm > 0.0) || !(stepMm > 0.0) || stepMm > strokeMm || minRows < 1) {
    std::fprintf(stderr, "alacs-twin reach: --stroke-mm and --step-mm must be > 0 (step ≤ stroke), --min-rows ≥ 1\n");
    return 2;
  }
  // The positions tried: those given (in order; a run is consecutive positions `--step-mm`
  // apart), else the whole stroke at the step.
  std::vector<double> slidesMm = args.list("slides", {});
  if (slidesMm.empty()) {
    const int steps = static_cast<int>(strokeMm / stepMm + 1e-9);
    for (int i = 0; i <= steps; ++i) slidesMm.push_back(i * stepMm);
  }
  const bool listing = args.has("list");
  std::mutex out;
  const Status st = parallelFor(
      static_cast<int>(dirs.size()), static_cast<int>(args.integer("jobs", 2)),
      [&](int i) -> Status {
        const std::string& dir = dirs[static_cast<size_t>(i)];
        tools::Json o;
        o["scan"] = dir;
        const Result<Reach> r = reachOf(dir, slidesMm, stepMm, minRows);
        if (!r) {
          o["error"] = r.status().reason();
        } else {
          o["positions"] = r->lit.size();
          o["lit_mm"] = tools::jsonNumber(static_cast<double>(r->lit.size()) * stepMm, "%.1f");
          o["widest_run_mm"] = tools::jsonNumber(r->widestRunMm, "%.1f");
          o["first_mm"] = r->lit.empty() ? tools::Json(nullptr) : tools::jsonNumber(r->lit.front().first, "%.3f");
          o["last_mm"] = r->lit.empty() ? tools::Json(nullptr) : tools::jsonNumber(r->lit.back().first, "%.3f");
          o["max_rows"] = r->maxRows;
          o["identity_pct"] = r->identityPct ? tools::jsonNumber(*r->identityPct, "%.3f") : tools::Json(nullptr);
          if (listing) {
            o["lit"] = tools::Json::array();
            for (const auto& [slideMm, rows] : r->lit) o["lit"].push_back({tools::jsonNumber(slideMm, "%.3f"), rows});
          }
        }
        // One line as each scan is done (the evaluation's progress bar counts them).
        const std::lock_guard<std::mutex> lock(out);
        std::fputs(tools::jsonText(o).c_str(), stdout);
        std::fflush(stdout);
        return Status::ok();
      },
      [](int) {});
  if (!st) {
    std::fprintf(stderr, "alacs-twin reach: %s\n", st.toString().c_str());
    return 1;
  }
  return 0;
}

}  // namespace alacs::twin
