#include "survey/survey.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <unordered_map>

#include "geometry/triangulation.h"

namespace alacs::survey {

Status SurveyParams::validate() const {
  if (!(stopSpacingMm >= 1.0 && stopSpacingMm <= 50.0)) return {Error::kInvalidArgument, "survey stop spacing must be in 1..50 mm"};
  if (!(clusterCellMm >= 2.0 && clusterCellMm <= 100.0)) return {Error::kInvalidArgument, "survey cluster cell must be in 2..100 mm"};
  if (maxObjects < 1 || maxObjects > 15) return {Error::kInvalidArgument, "survey max objects must be in 1..15"};
  return Status::ok();
}

std::vector<double> surveyStops(double strokeMm, const SurveyParams& p) {
  std::vector<double> stops;
  for (double s = 0.0; s <= strokeMm + 1e-9; s += p.stopSpacingMm) stops.push_back(s);
  return stops;
}

Survey::Survey(const geometry::Calibration& cal, const image::LleParams& lle, const localize::ScanParams& scan,
               const SurveyParams& params)
    : cal_(cal), lle_(lle), scan_(scan), params_(params) {}

Status Survey::addFrame(const image::ImageView& frame, double slideMm, image::LleWorkspace& ws) {
  if (frame.width != cal_.camera.widthPx || frame.height != cal_.camera.heightPx)
    return {Error::kBadInput, "frame size does not match the calibration"};
  Result<image::LaserLine> line = image::extractLine(frame, {0, 0, frame.width, frame.height}, lle_, ws);
  if (!line) return line.status();
  std::vector<geometry::PixelPoint> pixels;
  pixels.reserve(line->rows.size());
  for (const auto& r : line->rows) pixels.push_back({r.column, static_cast<double>(r.row)});
  const int stop = static_cast<int>(stopsMm_.size());
  stopsMm_.push_back(slideMm);
  for (const auto& xn : geometry::undistortPixels(cal_.camera, pixels)) {
    const geometry::TriangulatedPoint p = geometry::triangulate(cal_.laser, slideMm, xn);
    if (p.valid) points_.push_back({p.pointMm, stop});
  }
  return Status::ok();
}

namespace {

struct UnionFind {
  std::vector<size_t> parent;
  explicit UnionFind(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), size_t{0}); }
  size_t find(size_t i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
  }
  void unite(size_t a, size_t b) { parent[find(a)] = find(b); }
};

}  // namespace

std::vector<localize::AppleEstimate> Survey::finish() const {
  // Grid clustering: points in the same or neighbouring cells are one object.
  const double cell = params_.clusterCellMm;
  auto key = [&](int64_t x, int64_t y, int64_t z) { return (x * 73856093) ^ (y * 19349663) ^ (z * 83492791); };
  std::unordered_map<int64_t, std::vector<size_t>> grid;
  std::vector<std::array<int64_t, 3>> cells(points_.size());
  for (size_t i = 0; i < points_.size(); ++i) {
    const Eigen::Vector3d& p = points_[i].mm;
    cells[i] = {static_cast<int64_t>(std::floor(p.x() / cell)), static_cast<int64_t>(std::floor(p.y() / cell)),
                static_cast<int64_t>(std::floor(p.z() / cell))};
    grid[key(cells[i][0], cells[i][1], cells[i][2])].push_back(i);
  }
  // Only dense cells link: the few mixed pixels at a fruit's silhouette (half fruit, half
  // what is behind) triangulate between surfaces and would chain neighbours together.
  auto dense = [&](const std::vector<size_t>& members) { return members.size() >= params_.minCellPoints; };
  UnionFind uf(points_.size());
  for (const auto& [k, members] : grid) {
    if (!dense(members)) continue;
    for (size_t j = 1; j < members.size(); ++j) uf.unite(members[0], members[j]);
  }
  for (size_t i = 0; i < points_.size(); ++i) {
    const auto own = grid.find(key(cells[i][0], cells[i][1], cells[i][2]));
    if (!dense(own->second)) continue;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const auto it = grid.find(key(cells[i][0] + dx, cells[i][1] + dy, cells[i][2] + dz));
          if (it != grid.end() && dense(it->second)) uf.unite(i, it->second.front());
        }
  }
  std::unordered_map<size_t, std::vector<size_t>> clusters;
  for (size_t i = 0; i < points_.size(); ++i) {
    if (dense(grid.find(key(cells[i][0], cells[i][1], cells[i][2]))->second)) clusters[uf.find(i)].push_back(i);
  }

  const localize::Localizer fusion(cal_, lle_, scan_);
  std::vector<localize::AppleEstimate> found;
  for (const auto& [root, members] : clusters) {
    if (members.size() < params_.minPoints) continue;
    Eigen::Vector3d lo = points_[members[0]].mm, hi = lo, sum = Eigen::Vector3d::Zero();
    for (size_t i : members) {
      lo = lo.cwiseMin(points_[i].mm);
      hi = hi.cwiseMax(points_[i].mm);
      sum += points_[i].mm;
    }
    if ((hi - lo).maxCoeff() > params_.maxExtentMm) continue;
    // Fuse with the localizer: one observation per stop, the cluster's points of it.
    localize::ScanPlan plan;
    plan.roughMm = sum / static_cast<double>(members.size());
    std::vector<localize::LineObservation> lines(stopsMm_.size());
    for (size_t s = 0; s < stopsMm_.size(); ++s) lines[s].slideMm = stopsMm_[s];
    for (size_t i : members) lines[static_cast<size_t>(points_[i].stop)].pointsMm.push_back(points_[i].mm);
    lines.erase(std::remove_if(lines.begin(), lines.end(), [](const auto& l) { return l.pointsMm.empty(); }),
                lines.end());
    Result<localize::AppleEstimate> est = fusion.estimate(plan, lines);
    if (!est || !est->sphereFit) continue;
    // A sphere that explains the points badly is not a fruit (a leaf, a branch).
    if (est->sigmaMm > params_.maxCenterSigmaMm || est->confidencePct < 30.0) continue;
    found.push_back(*est);
  }
  std::sort(found.begin(), found.end(),
            [](const auto& a, const auto& b) { return a.approachMm.norm() < b.approachMm.norm(); });
  if (found.size() > static_cast<size_t>(params_.maxObjects)) found.resize(static_cast<size_t>(params_.maxObjects));
  return found;
}

}  // namespace alacs::survey
