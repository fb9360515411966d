// Leaves told by the laser-off frame's colour (localize/leaf_colour.h): a sample on a green
// pixel, and the few samples of the same segment at a leaf's edge whose pixels take the
// colour of what lies beside the leaf.
#include <algorithm>
#include <catch2/catch.hpp>
#include <cstdint>
#include <vector>

#include "image/image_view.h"
#include "image/lle.h"
#include "localize/leaf_colour.h"

using namespace alacs;

namespace {

// Pixel colours of the laser-off frame (B, G, R).
struct Bgr {
  uint8_t b, g, r;
};
constexpr Bgr kSkin{20, 10, 150};    // red skin
constexpr Bgr kLeaf{6, 30, 10};      // a leaf in shade: G/R 2.8
constexpr Bgr kLeafEdge{6, 14, 15};  // a leaf's pixel blurred with the fruit beside it: G/R 0.94
constexpr Bgr kDark{3, 4, 4};        // a dark vein or gap: G/R 1
constexpr double kRatio = 1.4;       // ScanParams::leafGreenRatio's default

// A laser-off frame and a line whose samples are placed one by one, each on a pixel of a
// chosen colour, in a chosen segment.
struct Scene {
  static constexpr int kWidth = 64;
  static constexpr int kHeight = 64;
  std::vector<uint8_t> bgr = std::vector<uint8_t>(static_cast<size_t>(kWidth) * kHeight * 3, 0);
  image::LaserLine line;

  // Rows [from, to) of `segment` at `column`, their pixels `colour`.
  void add(int segment, int column, int from, int to, Bgr colour,
           image::RowStatus status = image::RowStatus::kSegment) {
    while (segment >= 0 && line.segments.size() <= static_cast<size_t>(segment)) line.segments.push_back({});
    for (int row = from; row < to; ++row) {
      uint8_t* px = bgr.data() + (static_cast<size_t>(row) * kWidth + column) * 3;
      px[0] = colour.b;
      px[1] = colour.g;
      px[2] = colour.r;
      image::RowSample s;
      s.row = row;
      s.column = static_cast<float>(column);
      s.status = status;
      s.segment = segment;
      line.rows.push_back(s);
    }
  }
  image::ImageView view() const {
    return {bgr.data(), kWidth, kHeight, static_cast<size_t>(kWidth) * 3, image::PixelFormat::kBgr888};
  }
  // In row order, as the LLE lays a line out (several segments' samples in one row).
  void sortByRow() {
    std::stable_sort(line.rows.begin(), line.rows.end(),
                     [](const image::RowSample& a, const image::RowSample& b) { return a.row < b.row; });
  }
  // The flags of the samples at `column`, in the order they were added.
  std::vector<bool> at(const std::vector<bool>& leaf, int column) const {
    std::vector<bool> out;
    for (size_t i = 0; i < line.rows.size(); ++i)
      if (static_cast<int>(line.rows[i].column) == column) out.push_back(leaf[i]);
    return out;
  }
};

}  // namespace

TEST_CASE("A leaf's edge: the few samples beside its green run that take the fruit's red are the leaf's",
          "[localize][leaf]") {
  Scene s;
  // The fruit's segment: twenty rows of red skin.
  s.add(0, 10, 0, 20, kSkin);
  // A leaf in front, its own segment (a step in depth): four rows at its edge whose pixels
  // the fruit beside it makes red (not green on their own), then twelve green rows.
  s.add(1, 30, 5, 9, kLeafEdge);
  s.add(1, 30, 9, 21, kLeaf);
  // Another leaf whose edge is at its far end: exactly kLeafGreenRunSamples green rows, then
  // four red.
  const int green = static_cast<int>(localize::kLeafGreenRunSamples);
  s.add(2, 45, 30, 30 + green, kLeaf);
  s.add(2, 45, 30 + green, 34 + green, kLeafEdge);
  s.sortByRow();
  const image::ImageView off = s.view();
  REQUIRE_FALSE(localize::leafGreen(off, 5, 30.0F, kRatio));  // on its own, no leaf
  REQUIRE(localize::leafGreen(off, 12, 30.0F, kRatio));
  const std::vector<bool> leaf = localize::leafSamples(s.line, &off, kRatio);
  REQUIRE(leaf.size() == s.line.rows.size());
  CHECK(s.at(leaf, 10) == std::vector<bool>(20, false));
  CHECK(s.at(leaf, 30) == std::vector<bool>(16, true));
  CHECK(s.at(leaf, 45) == std::vector<bool>(static_cast<size_t>(green) + 4, true));
  // Off: no sample is a leaf's.
  CHECK(localize::leafSamples(s.line, &off, 0.0) == std::vector<bool>(s.line.rows.size(), false));
  // Without a laser-off frame: none either.
  CHECK(localize::leafSamples(s.line, nullptr, kRatio) == std::vector<bool>(s.line.rows.size(), false));
}

TEST_CASE("A leaf's edge is short and beside a green run: longer runs and lone samples are left as they are",
          "[localize][leaf]") {
  Scene s;
  // One more than the edge's rows of red, then a green run: a fruit and a leaf that
  // continuity linked (no step): the fruit's samples stay.
  const int red = static_cast<int>(localize::kLeafEdgeRunSamples) + 1;
  s.add(0, 10, 0, red, kSkin);
  s.add(0, 10, red, red + 6, kLeaf);
  // Red rows beside a green run shorter than kLeafGreenRunSamples: too little of a leaf to
  // say its edge; they stay, the green ones are a leaf's on their own.
  const int green = static_cast<int>(localize::kLeafGreenRunSamples) - 1;
  s.add(1, 20, 0, 3, kLeafEdge);
  s.add(1, 20, 3, 3 + green, kLeaf);
  // Between two green runs: a dark vein, two rows, is the leaf's.
  s.add(2, 30, 0, 4, kLeaf);
  s.add(2, 30, 4, 6, kDark);
  s.add(2, 30, 6, 10, kLeaf);
  // Two red samples beyond the reach of the leaf's last green row (rows missing between):
  // not its edge.
  s.add(4, 60, 0, 5, kLeaf);
  s.add(4, 60, 5 + localize::kLeafEdgeReachRows, 7 + localize::kLeafEdgeReachRows, kLeafEdge);
  // Samples of no segment: their own pixel alone decides.
  s.add(-1, 40, 0, 2, kLeafEdge);
  s.add(-1, 40, 2, 6, kLeaf);
  // Invalid samples (an occluding edge) are never a leaf's and do not part a run: the edge
  // run below still has the green run beside it.
  s.add(3, 50, 0, 2, kLeafEdge);
  s.add(3, 50, 2, 4, kLeaf, image::RowStatus::kEdge);
  s.add(3, 50, 4, 8, kLeaf);
  // A segment index the line does not hold: its samples' own pixels decide.
  s.add(5, 55, 0, 2, kLeafEdge);
  s.add(5, 55, 2, 6, kLeaf);
  for (image::RowSample& r : s.line.rows)
    if (r.segment == 5) r.segment = 99;
  s.sortByRow();
  const image::ImageView off = s.view();
  const std::vector<bool> leaf = localize::leafSamples(s.line, &off, kRatio);
  std::vector<bool> fruitThenLeaf(static_cast<size_t>(red), false);
  fruitThenLeaf.resize(static_cast<size_t>(red) + 6, true);
  CHECK(s.at(leaf, 10) == fruitThenLeaf);
  CHECK(s.at(leaf, 20) == std::vector<bool>{false, false, false, true, true});
  CHECK(s.at(leaf, 30) == std::vector<bool>(10, true));
  CHECK(s.at(leaf, 40) == std::vector<bool>{false, false, true, true, true, true});
  CHECK(s.at(leaf, 50) == std::vector<bool>{true, true, false, false, true, true, true, true});
  CHECK(s.at(leaf, 55) == std::vector<bool>{false, false, true, true, true, true});
  CHECK(s.at(leaf, 60) == std::vector<bool>{true, true, true, true, true, false, false});
}
