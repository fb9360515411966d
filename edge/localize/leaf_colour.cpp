#include "localize/leaf_colour.h"

#include <cmath>
#include <cstdint>

namespace alacs::localize {

bool leafGreen(const image::ImageView& laserOff, int row, float column, double ratio) {
  const int x = static_cast<int>(std::lround(column));
  if (row < 0 || row >= laserOff.height || x < 0 || x >= laserOff.width) return false;
  const uint8_t* px = laserOff.row(row) + 3 * static_cast<size_t>(x);
  const int red = px[image::redOffset(laserOff.format)];
  const int green = px[1];
  // (The +1 keeps a black pixel from counting as either.)
  return green + 1.0 >= ratio * (red + 1.0);
}

namespace {

// A run of one colour along a segment: [from, to) into its samples.
struct Run {
  size_t from = 0;
  size_t to = 0;
  bool green = false;
  size_t size() const { return to - from; }
};

// A leaf's edge along one segment (`seg`: indices into the rows, in row order): the short
// runs of samples that are not green, beside a green run long enough and near enough in
// rows, become the leaf's.
void markLeafEdges(const image::LaserLine& line, const std::vector<size_t>& seg, std::vector<bool>& leaf) {
  std::vector<Run> runs;
  for (size_t j = 0; j < seg.size(); ++j)
    if (j == 0 || leaf[seg[j]] != runs.back().green)
      runs.push_back({j, j + 1, leaf[seg[j]]});
    else
      runs.back().to = j + 1;
  const auto rowOf = [&](size_t j) { return line.rows[seg[j]].row; };
  for (size_t k = 0; k < runs.size(); ++k) {
    const Run& r = runs[k];
    if (r.green || r.size() > kLeafEdgeRunSamples) continue;
    // The green run before it ends at r.from - 1, the one after starts at r.to; the edge
    // run's far sample must lie within reach of it.
    const bool before = k > 0 && runs[k - 1].size() >= kLeafGreenRunSamples &&
                        rowOf(r.to - 1) - rowOf(r.from - 1) <= kLeafEdgeReachRows;
    const bool after = k + 1 < runs.size() && runs[k + 1].size() >= kLeafGreenRunSamples &&
                       rowOf(r.to) - rowOf(r.from) <= kLeafEdgeReachRows;
    if (before || after)
      for (size_t j = r.from; j < r.to; ++j) leaf[seg[j]] = true;
  }
}

}  // namespace

std::vector<bool> leafSamples(const image::LaserLine& line, const image::ImageView* laserOff, double ratio) {
  std::vector<bool> leaf(line.rows.size(), false);
  if (laserOff == nullptr || !(ratio > 0.0)) return leaf;
  std::vector<std::vector<size_t>> bySegment(line.segments.size());
  for (size_t i = 0; i < line.rows.size(); ++i) {
    const image::RowSample& r = line.rows[i];
    if (!r.valid()) continue;
    leaf[i] = leafGreen(*laserOff, r.row, r.column, ratio);
    if (r.segment >= 0 && static_cast<size_t>(r.segment) < bySegment.size())
      bySegment[static_cast<size_t>(r.segment)].push_back(i);
  }
  // Taken in index order, each segment's samples are in row order (LaserLine::rows is).
  for (const std::vector<size_t>& seg : bySegment) markLeafEdges(line, seg, leaf);
  return leaf;
}

}  // namespace alacs::localize
