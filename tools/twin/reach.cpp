// alacs-twin reach: what any scan strategy could see of each scan's target. The truth
// (sim::laserLineTruth: the target's rows that the camera sees and the laser lights) at
// every slide position over the stroke, `--step-mm` apart (or at `--slides`). A target that no position
// lights on `--min-rows` rows or more is beyond every placement of the stops: leaves hide
// it wherever the line crosses it, and only the rough position can stand in for it
// (docs/evaluation.md, "What no scan strategy can see").
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <utility>
#include <vector>

#include "sim/scene.h"
#include "sim/truth.h"
#include "twin.h"

namespace alacs::twin {

namespace {

struct Reach {
  int positions = 0;      // positions that light min-rows or more
  double firstMm = -1.0;  // the first and last of them (-1: none)
  double lastMm = -1.0;
  int maxRows = 0;                          // the most visible lit rows at any position
  std::vector<std::pair<double, int>> lit;  // each such position and its rows
};

Result<int> targetId(const std::string& dir) {
  std::ifstream in(dir + "/manifest.json");
  if (!in) return Status(Error::kNotFound, dir + ": no manifest.json");
  const tools::Json m = tools::Json::parse(in, nullptr, false);
  if (m.is_discarded() || !m.contains("scan") || !m["scan"].contains("target_id") ||
      !m["scan"]["target_id"].is_number_integer())
    return Status(Error::kBadInput, dir + ": manifest.json has no scan.target_id");
  return m["scan"]["target_id"].get<int>();
}

Result<Reach> reachOf(const std::string& dir, const std::vector<double>& slidesMm, int minRows) {
  const Result<int> id = targetId(dir);
  if (!id) return id.status();
  const Result<sim::SimScene> scene = sim::loadScene(dir + "/truth/scene.json");
  if (!scene) return Status(scene.status().code(), dir + ": " + scene.status().reason());
  const sim::SimApple* target = scene->apple(*id);
  if (target == nullptr) return Status(Error::kBadInput, dir + ": the scene has no apple " + std::to_string(*id));
  Reach r;
  for (const double slideMm : slidesMm) {
    const int rows = static_cast<int>(sim::laserLineTruth(*scene, *target, slideMm).size());
    r.maxRows = std::max(r.maxRows, rows);
    if (rows < minRows) continue;
    ++r.positions;
    r.lit.emplace_back(slideMm, rows);
    if (r.firstMm < 0.0) r.firstMm = slideMm;
    r.lastMm = slideMm;
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
  // The positions tried: those given, else the whole stroke at the step.
  std::vector<double> slidesMm = args.list("slides", {});
  if (slidesMm.empty()) {
    const int steps = static_cast<int>(strokeMm / stepMm + 1e-9);
    for (int i = 0; i <= steps; ++i) slidesMm.push_back(i * stepMm);
  }
  std::vector<std::string> lines(dirs.size());
  const Status st = parallelFor(
      static_cast<int>(dirs.size()), static_cast<int>(args.integer("jobs", 2)),
      [&](int i) -> Status {
        const std::string& dir = dirs[static_cast<size_t>(i)];
        tools::Json o;
        o["scan"] = dir;
        const Result<Reach> r = reachOf(dir, slidesMm, minRows);
        if (!r) {
          o["error"] = r.status().reason();
        } else {
          o["positions"] = r->positions;
          o["lit_span_mm"] = r->positions > 0 ? tools::jsonNumber(r->lastMm - r->firstMm, "%.1f") : tools::Json(0);
          o["max_rows"] = r->maxRows;
          if (args.has("list")) {
            o["lit"] = tools::Json::array();
            for (const auto& [slideMm, rows] : r->lit) o["lit"].push_back({tools::jsonNumber(slideMm, "%.3f"), rows});
          }
        }
        lines[static_cast<size_t>(i)] = tools::jsonText(o);
        return Status::ok();
      },
      [](int) {});
  for (const std::string& l : lines) std::fputs(l.c_str(), stdout);
  if (!st) {
    std::fprintf(stderr, "alacs-twin reach: %s\n", st.toString().c_str());
    return 1;
  }
  return 0;
}

}  // namespace alacs::twin
