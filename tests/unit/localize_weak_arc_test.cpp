// The sunlit line along its arc (localize/weak_arc.h): a laser line a few DN high on red
// skin near full scale, under the shot noise of a laser-on/laser-off pair, which a row
// alone cannot tell from the noise; summed along the arc of the fruit's cut it can.
#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "geometry/triangulation.h"
#include "localize/localizer.h"
#include "localize/weak_arc.h"
#include "sim/scene.h"

using namespace alacs;

namespace {

struct SunlitFrame {
  geometry::Calibration cal = sim::defaultScene().truth;
  Eigen::Vector3d centerMm{15.0, -10.0, 1300.0};
  double radiusMm = 38.0;
  double slideMm = 0.0;
  image::Roi roi;
  std::vector<uint8_t> on;
  std::vector<uint8_t> off;
  std::vector<std::pair<int, double>> truth;  // row, column of the line on the fruit

  image::ImageView view(const std::vector<uint8_t>& px) const {
    return {px.data(), cal.camera.widthPx, cal.camera.heightPx, static_cast<size_t>(cal.camera.widthPx) * 3,
            image::PixelFormat::kBgr888};
  }
};

// A fruit the plane cuts: its centre, radius and the laser's peak on it (DN).
struct Fruit {
  Eigen::Vector3d centerMm;
  double radiusMm;
  double peakDn;
};

// The camera-facing arc where the plane cuts `fruit`, one column per image row (-1: none).
std::vector<double> frontArc(const SunlitFrame& f, const Fruit& fruit) {
  const Eigen::Vector3d n = f.cal.laser.planeNormal;
  std::vector<double> lineCol(static_cast<size_t>(f.cal.camera.heightPx), -1.0);
  const double delta = n.dot(fruit.centerMm) - f.cal.laser.planeOffsetAt(f.slideMm);
  if (std::abs(delta) >= fruit.radiusMm) return lineCol;
  const Eigen::Vector3d c0 = fruit.centerMm - delta * n;
  const double rho = std::sqrt(fruit.radiusMm * fruit.radiusMm - delta * delta);
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  for (int i = 0; i < 20000; ++i) {
    const double phi = 2.0 * M_PI * i / 20000.0;
    const Eigen::Vector3d p = c0 + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
    if ((p - fruit.centerMm).dot(-p) <= 0.0) continue;
    const geometry::PixelPoint px = geometry::projectPoint(f.cal.camera, p);
    const int row = static_cast<int>(std::lround(px.rowPx));
    if (row >= 0 && row < f.cal.camera.heightPx && lineCol[static_cast<size_t>(row)] < 0.0)
      lineCol[static_cast<size_t>(row)] = px.columnPx;
  }
  return lineCol;
}

// A bright red ambient (200 DN) with shot noise of 3 DN in each frame; the laser frame adds
// a Gaussian line of `peakDn` (σ 1.2 px) where the plane 8 mm off the centre cuts the fruit,
// and the lines of any `others` the plane cuts too. The truth is the first fruit's line.
SunlitFrame render(double peakDn, unsigned seed, const std::vector<Fruit>& others = {}) {
  SunlitFrame f;
  const Eigen::Vector3d n = f.cal.laser.planeNormal;
  f.slideMm = f.cal.laser.slideForPoint(f.centerMm + 8.0 * n);
  const geometry::PixelPoint c = geometry::projectPoint(f.cal.camera, f.centerMm);
  const int halfPx = static_cast<int>(f.radiusMm * f.cal.camera.fyPx / f.centerMm.z()) + 40;
  f.roi = {static_cast<int>(c.columnPx) - halfPx, static_cast<int>(c.rowPx) - halfPx, 2 * halfPx, 2 * halfPx};
  const size_t size = static_cast<size_t>(f.cal.camera.widthPx) * f.cal.camera.heightPx * 3;
  f.on.assign(size, 0);
  f.off.assign(size, 0);
  std::vector<std::pair<std::vector<double>, double>> lines{{frontArc(f, {f.centerMm, f.radiusMm, peakDn}), peakDn}};
  for (const Fruit& o : others) lines.emplace_back(frontArc(f, o), o.peakDn);
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 3.0);
  for (int y = f.roi.y; y < f.roi.y + f.roi.height; ++y) {
    if (lines[0].first[static_cast<size_t>(y)] >= 0.0) f.truth.emplace_back(y, lines[0].first[static_cast<size_t>(y)]);
    for (int x = f.roi.x; x < f.roi.x + f.roi.width; ++x) {
      const size_t i = (static_cast<size_t>(y) * f.cal.camera.widthPx + x) * 3 + 2;  // red, BGR
      double line = 0.0;
      for (const auto& [col, peak] : lines) {
        const double cy = col[static_cast<size_t>(y)];
        if (cy >= 0.0) line += peak * std::exp(-0.5 * std::pow((x - cy) / 1.2, 2));
      }
      f.on[i] = static_cast<uint8_t>(std::clamp(std::lround(200.0 + line + noise(rng)), 0L, 255L));
      f.off[i] = static_cast<uint8_t>(std::clamp(std::lround(200.0 + noise(rng)), 0L, 255L));
    }
  }
  return f;
}

// The median |column − truth| of `samples` in segment `segment` on the rows of `truth`
// (row, column), and how many lie on them (within 3 px).
std::pair<double, int> medianError(const std::vector<std::pair<int, double>>& truth,
                                   const std::vector<image::RowSample>& samples, int segment) {
  std::vector<double> err;
  for (const auto& s : samples) {
    if (s.segment != segment) continue;
    const auto t = std::find_if(truth.begin(), truth.end(), [&](const auto& r) { return r.first == s.row; });
    if (t != truth.end() && std::abs(s.column - t->second) < 3.0) err.push_back(std::abs(s.column - t->second));
  }
  if (err.empty()) return {1e9, 0};
  std::sort(err.begin(), err.end());
  return {err[err.size() / 2], static_cast<int>(err.size())};
}

// The rough position 20 mm off the centre by default, as an RGB-D camera's may be.
localize::WeakArc search(const SunlitFrame& f, const image::LaserLine& line,
                         const Eigen::Vector3d& roughOffMm = Eigen::Vector3d(12.0, -9.0, 13.0)) {
  localize::WeakArcParams p;
  p.minZ = 8.0;
  const Eigen::Vector3d roughMm = f.centerMm + roughOffMm;
  return localize::findWeakArc(f.view(f.on), f.view(f.off), f.roi, f.cal, f.slideMm, roughMm, line, 7, p);
}

}  // namespace

TEST_CASE("A sunlit line below the per-row noise is found along its arc and followed row by row",
          "[localize][weak_arc]") {
  const SunlitFrame f = render(7.0, 3);
  REQUIRE(f.truth.size() > 60);
  const localize::WeakArc arc = search(f, image::LaserLine{});
  INFO("z " << arc.z << " over " << arc.rows << " rows, " << arc.samples.size() << " samples of " << f.truth.size());
  CHECK(arc.z >= 8.0);
  // Followed: most rows, each near the truth; a segment of its own, not the line.
  CHECK(arc.samples.size() >= f.truth.size() / 2);
  std::vector<double> err;
  int beyondTheFruit = 0;  // rows past its limb, where the arc of the search runs on
  for (const auto& s : arc.samples) {
    CHECK(s.status == image::RowStatus::kSegment);
    CHECK(s.segment == 7);
    const auto t = std::find_if(f.truth.begin(), f.truth.end(), [&](const auto& r) { return r.first == s.row; });
    if (t == f.truth.end()) {
      ++beyondTheFruit;
      continue;
    }
    err.push_back(std::abs(s.column - t->second));
  }
  CHECK(beyondTheFruit <= 3);
  std::sort(err.begin(), err.end());
  // Smoothed along the arc (±8 rows): one row alone is off by 0.66 px (median) under this
  // noise, 2-3 mm in depth at this fruit's 1.3 m.
  INFO("median |error| " << err[err.size() / 2] << " px");
  CHECK(err[err.size() / 2] < 0.35);
}

TEST_CASE("A row whose peak near the arc is another's, off the arc's line, gives no sample", "[localize][weak_arc]") {
  // Speckle or a leaf's edge beside the line: in a few rows a brighter, narrow peak 2.5 px
  // off the line, within the ±3 px a row is followed in. Measured against the line through
  // the arc's other samples it is off by more than 1.5 px: dropped.
  SunlitFrame f = render(7.0, 3);
  std::vector<std::pair<int, double>> planted;
  for (size_t k = 10; k < f.truth.size(); k += 17) planted.push_back({f.truth[k].first, f.truth[k].second + 2.5});
  for (const auto& [row, col] : planted) {
    const int x = static_cast<int>(std::lround(col));
    for (int dx = -1; dx <= 1; ++dx) {
      const size_t i = (static_cast<size_t>(row) * f.cal.camera.widthPx + x + dx) * 3 + 2;
      f.on[i] = static_cast<uint8_t>(std::min(255, f.on[i] + (dx == 0 ? 40 : 16)));
    }
  }
  const localize::WeakArc arc = search(f, image::LaserLine{});
  INFO(planted.size() << " rows planted; " << arc.samples.size() << " samples");
  REQUIRE(planted.size() >= 6);
  REQUIRE(arc.arcs == 1);
  // Each planted row's peak is the brighter within the followed ±3 px, so the row offers it
  // and nothing else: no sample there.
  for (const auto& s : arc.samples)
    for (const auto& [row, col] : planted) {
      INFO("row " << row << ": a sample at " << s.column << ", the planted peak at " << col);
      CHECK(s.row != row);
    }
  const auto [median, onLine] = medianError(f.truth, arc.samples, 7);
  INFO("median |error| " << median << " px over " << onLine << " rows");
  CHECK(median < 0.35);
}

TEST_CASE("A second arc is followed too, each a segment of its own", "[localize][weak_arc]") {
  // In sun a neighbour's or a leaf's line may outscore the target's; the fit across the
  // stops, not the search in one frame, tells which is the fruit. Here a touching neighbour
  // below the target, its line three times as strong, the target's at 7 DN, and the rough
  // position between the two.
  const Fruit neighbour{SunlitFrame{}.centerMm + Eigen::Vector3d(0.0, 72.0, 8.0), 34.0, 21.0};
  const SunlitFrame f = render(7.0, 6, {neighbour});
  const std::vector<double> neighbourCol = frontArc(f, neighbour);
  std::vector<std::pair<int, double>> neighbourTruth;
  for (int y = f.roi.y; y < f.roi.y + f.roi.height; ++y)
    if (neighbourCol[static_cast<size_t>(y)] >= 0.0)
      neighbourTruth.emplace_back(y, neighbourCol[static_cast<size_t>(y)]);
  const localize::WeakArc arc = search(f, image::LaserLine{}, Eigen::Vector3d(0.0, 30.0, 0.0));
  INFO("z " << arc.z << ", " << arc.arcs << " arcs, " << arc.samples.size() << " samples");
  REQUIRE(arc.arcs == 2);  // the two lines, and nothing a third search finds in what they leave
  // No sample twice: each later search runs over what the earlier arcs leave.
  for (size_t i = 0; i < arc.samples.size(); ++i)
    for (size_t j = i + 1; j < arc.samples.size(); ++j)
      CHECK_FALSE(
          (arc.samples[i].row == arc.samples[j].row && std::abs(arc.samples[i].column - arc.samples[j].column) < 1.0F));
  // Which segment is whose: the target's rows and the neighbour's, in the ROI.
  const auto [t7, onTarget7] = medianError(f.truth, arc.samples, 7);
  const auto [t8, onTarget8] = medianError(f.truth, arc.samples, 8);
  const auto [n7, onNeighbour7] = medianError(neighbourTruth, arc.samples, 7);
  const auto [n8, onNeighbour8] = medianError(neighbourTruth, arc.samples, 8);
  INFO("segment 7: target " << onTarget7 << " rows, neighbour " << onNeighbour7 << "; segment 8: target " << onTarget8
                            << ", neighbour " << onNeighbour8);
  const bool neighbourFirst = onNeighbour7 > onTarget7;
  CHECK(neighbourFirst);  // the stronger line's arc scores first
  CHECK((neighbourFirst ? onTarget8 : onTarget7) >= static_cast<int>(f.truth.size()) / 2);
  CHECK((neighbourFirst ? onNeighbour7 : onNeighbour8) >= 15);
  INFO("the target's median |error| " << (neighbourFirst ? t8 : t7) << " px, the neighbour's "
                                      << (neighbourFirst ? n7 : n8));
  CHECK((neighbourFirst ? t8 : t7) < 0.35);
}

TEST_CASE("No arc in the noise alone, and none over rows the LLE already explains", "[localize][weak_arc]") {
  SECTION("noise alone") {
    const SunlitFrame f = render(0.0, 4);
    const localize::WeakArc arc = search(f, image::LaserLine{});
    INFO("z " << arc.z);
    CHECK(arc.z < 8.0);
    CHECK(arc.arcs == 0);
    CHECK(arc.samples.empty());
  }
  SECTION("the LLE found the line: its rows are masked, nothing is left to find") {
    const SunlitFrame f = render(7.0, 5);
    image::LaserLine found;
    for (const auto& [row, col] : f.truth) {
      image::RowSample s;
      s.row = row;
      s.column = static_cast<float>(col);
      found.rows.push_back(s);
    }
    const localize::WeakArc arc = search(f, found);
    INFO("z " << arc.z);
    CHECK(arc.samples.empty());
  }
}

TEST_CASE("The localizer runs the matched filter only where the metering found direct sun", "[localize][matched]") {
  // A sunlit line of 9 DN under 3 DN of noise in each frame: the subtracted rerun finds about
  // half of its rows; the filter matched to the line's profile (LleParams::matchedFilter,
  // docs/lle.md) finds more of them, but only when Localizer::observe is told the ambient is
  // bright (MeteringDecision::bright): outside sun it cost fits on the tuning worlds.
  const SunlitFrame f = render(9.0, 5);
  REQUIRE(f.truth.size() > 60);
  localize::ScanParams scan;
  scan.weakArcMinZ = 0.0;  // the arcs apart: only the LLE's rows are compared here
  const localize::Localizer loc(f.cal, image::LleParams{}, scan);
  const Eigen::Vector3d roughMm = f.centerMm + Eigen::Vector3d(6.0, -4.0, 8.0);
  const Result<localize::ScanPlan> plan = loc.plan(roughMm, 200.0);
  REQUIRE(plan.isOk());
  const image::ImageView on = f.view(f.on);
  const image::ImageView off = f.view(f.off);
  image::LleWorkspace ws;
  const auto onFruit = [&](const localize::LineObservation& ob) {
    int n = 0;
    for (const Eigen::Vector3d& p : ob.pointsMm) n += std::abs((p - f.centerMm).norm() - f.radiusMm) < 3.0 ? 1 : 0;
    return n;
  };
  const Result<localize::LineObservation> dim = loc.observe(on, *plan, f.slideMm, ws, &off, 0.0, false);
  const Result<localize::LineObservation> sun = loc.observe(on, *plan, f.slideMm, ws, &off, 0.0, true);
  REQUIRE(dim.isOk());
  REQUIRE(sun.isOk());
  INFO("points on the fruit: " << onFruit(*dim) << " of " << dim->pointsMm.size() << " without the filter, "
                               << onFruit(*sun) << " of " << sun->pointsMm.size() << " with it; " << f.truth.size()
                               << " rows lit");
  CHECK(onFruit(*sun) >= onFruit(*dim) + 6);                              // (64 -> 73 of the 138 rows lit)
  CHECK(sun->pointsMm.size() - static_cast<size_t>(onFruit(*sun)) <= 3);  // what it adds is the fruit's
  // Without a laser-off frame there is nothing to filter, bright or not.
  const Result<localize::LineObservation> bare = loc.observe(on, *plan, f.slideMm, ws, nullptr, 0.0, true);
  const Result<localize::LineObservation> bareDim = loc.observe(on, *plan, f.slideMm, ws, nullptr, 0.0, false);
  REQUIRE(bare.isOk());
  REQUIRE(bareDim.isOk());
  CHECK(bare->pointsMm.size() == bareDim->pointsMm.size());
}

TEST_CASE("Samples on a leaf, told by the laser-off frame's colour, join no fit", "[localize][leaf]") {
  // A clear line across a fruit whose lower half a leaf covers: there both frames are green
  // (G 120 over R 60, as chlorophyll reflects; B 150, so that a frame read in the wrong
  // channel order shows no leaf), above it red skin (R 200, G 0). The line's
  // samples on the leaf go to leafPointsMm (seen, no fruit's surface), the skin's to the fit.
  SunlitFrame f = render(60.0, 7);
  REQUIRE(f.truth.size() > 60);
  const int leafFromRow = f.truth[f.truth.size() / 2].first;
  for (std::vector<uint8_t>* frame : {&f.on, &f.off})
    for (int y = leafFromRow; y < f.roi.y + f.roi.height; ++y)
      for (int x = f.roi.x; x < f.roi.x + f.roi.width; ++x) {
        uint8_t* px = frame->data() + (static_cast<size_t>(y) * f.cal.camera.widthPx + x) * 3;  // BGR
        px[2] = static_cast<uint8_t>(std::max(0, px[2] - 140));
        px[1] = 120;
        px[0] = 150;
      }
  const image::ImageView on = f.view(f.on);
  const image::ImageView off = f.view(f.off);
  const auto observe = [&](double ratio, const image::ImageView* laserOff, const image::ImageView& laserOn) {
    localize::ScanParams scan;
    scan.weakArcMinZ = 0.0;
    scan.leafGreenRatio = ratio;
    const localize::Localizer loc(f.cal, image::LleParams{}, scan);
    const Result<localize::ScanPlan> plan = loc.plan(f.centerMm + Eigen::Vector3d(6.0, -4.0, 8.0), 200.0);
    REQUIRE(plan.isOk());
    image::LleWorkspace ws;
    Result<localize::LineObservation> obs = loc.observe(laserOn, *plan, f.slideMm, ws, laserOff);
    REQUIRE(obs.isOk());
    return *obs;
  };
  const auto rowsOnLeaf = [&](const localize::LineObservation& obs) {
    return std::count_if(obs.pixels.begin(), obs.pixels.end(),
                         [&](const geometry::PixelPoint& p) { return p.rowPx >= leafFromRow; });
  };
  const localize::LineObservation told = observe(localize::ScanParams{}.leafGreenRatio, &off, on);
  const localize::LineObservation blind = observe(0.0, &off, on);
  INFO("fit points " << told.pointsMm.size() << " (on the leaf " << rowsOnLeaf(told) << "), leaf points "
                     << told.leafPointsMm.size() << "; off: " << blind.pointsMm.size() << " (on the leaf "
                     << rowsOnLeaf(blind) << ")");
  CHECK(rowsOnLeaf(blind) > 40);
  CHECK(rowsOnLeaf(told) == 0);
  CHECK(told.leafPointsMm.size() == static_cast<size_t>(rowsOnLeaf(blind)));
  CHECK(told.pointsMm.size() + told.leafPointsMm.size() == blind.pointsMm.size());
  CHECK(blind.leafPointsMm.empty());
  // Without a laser-off frame the colour is unknown: every sample may be the fruit's.
  const localize::LineObservation unseen = observe(localize::ScanParams{}.leafGreenRatio, nullptr, on);
  CHECK(unseen.leafPointsMm.empty());
  CHECK(rowsOnLeaf(unseen) > 40);
  // The same frames in memory order R, G, B (a camera that gives RGB888): the same samples
  // on the leaf (read as BGR, the leaf's red would be its blue, and it would not be green).
  std::vector<uint8_t> rgbOn = f.on;
  std::vector<uint8_t> rgbOff = f.off;
  for (std::vector<uint8_t>* frame : {&rgbOn, &rgbOff})
    for (size_t i = 0; i + 2 < frame->size(); i += 3) std::swap((*frame)[i], (*frame)[i + 2]);
  const auto asRgb = [&](const std::vector<uint8_t>& px) {
    image::ImageView v = f.view(px);
    v.format = image::PixelFormat::kRgb888;
    return v;
  };
  const image::ImageView offRgb = asRgb(rgbOff);
  const localize::LineObservation rgb = observe(localize::ScanParams{}.leafGreenRatio, &offRgb, asRgb(rgbOn));
  CHECK(rgb.leafPointsMm.size() == told.leafPointsMm.size());
  CHECK(rgb.pointsMm.size() == told.pointsMm.size());
}
