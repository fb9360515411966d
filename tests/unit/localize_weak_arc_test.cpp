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

// A bright red ambient (200 DN) with shot noise of 3 DN in each frame; the laser frame adds
// a Gaussian line of `peakDn` (σ 1.2 px) where the plane 8 mm off the centre cuts the fruit.
SunlitFrame render(double peakDn, unsigned seed) {
  SunlitFrame f;
  const Eigen::Vector3d n = f.cal.laser.planeNormal;
  f.slideMm = f.cal.laser.slideForPoint(f.centerMm + 8.0 * n);
  const geometry::PixelPoint c = geometry::projectPoint(f.cal.camera, f.centerMm);
  const int halfPx = static_cast<int>(f.radiusMm * f.cal.camera.fyPx / f.centerMm.z()) + 40;
  f.roi = {static_cast<int>(c.columnPx) - halfPx, static_cast<int>(c.rowPx) - halfPx, 2 * halfPx, 2 * halfPx};
  const size_t size = static_cast<size_t>(f.cal.camera.widthPx) * f.cal.camera.heightPx * 3;
  f.on.assign(size, 0);
  f.off.assign(size, 0);
  // The front arc: the plane's circle on the sphere, one point per row.
  const double delta = n.dot(f.centerMm) - f.cal.laser.planeOffsetAt(f.slideMm);
  const Eigen::Vector3d c0 = f.centerMm - delta * n;
  const double rho = std::sqrt(f.radiusMm * f.radiusMm - delta * delta);
  const Eigen::Vector3d e1 = n.unitOrthogonal();
  const Eigen::Vector3d e2 = n.cross(e1);
  std::vector<double> lineCol(static_cast<size_t>(f.cal.camera.heightPx), -1.0);
  for (int i = 0; i < 20000; ++i) {
    const double phi = 2.0 * M_PI * i / 20000.0;
    const Eigen::Vector3d p = c0 + rho * (std::cos(phi) * e1 + std::sin(phi) * e2);
    if ((p - f.centerMm).dot(-p) <= 0.0) continue;
    const geometry::PixelPoint px = geometry::projectPoint(f.cal.camera, p);
    const int row = static_cast<int>(std::lround(px.rowPx));
    if (row >= 0 && row < f.cal.camera.heightPx && lineCol[static_cast<size_t>(row)] < 0.0)
      lineCol[static_cast<size_t>(row)] = px.columnPx;
  }
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 3.0);
  for (int y = f.roi.y; y < f.roi.y + f.roi.height; ++y) {
    const double col = lineCol[static_cast<size_t>(y)];
    if (col >= 0.0) f.truth.emplace_back(y, col);
    for (int x = f.roi.x; x < f.roi.x + f.roi.width; ++x) {
      const size_t i = (static_cast<size_t>(y) * f.cal.camera.widthPx + x) * 3 + 2;  // red, BGR
      const double line = col >= 0.0 ? peakDn * std::exp(-0.5 * std::pow((x - col) / 1.2, 2)) : 0.0;
      f.on[i] = static_cast<uint8_t>(std::clamp(std::lround(200.0 + line + noise(rng)), 0L, 255L));
      f.off[i] = static_cast<uint8_t>(std::clamp(std::lround(200.0 + noise(rng)), 0L, 255L));
    }
  }
  return f;
}

localize::WeakArc search(const SunlitFrame& f, const image::LaserLine& line) {
  localize::WeakArcParams p;
  p.minZ = 8.0;
  // The rough position 20 mm off the centre, as an RGB-D camera's may be.
  const Eigen::Vector3d roughMm = f.centerMm + Eigen::Vector3d(12.0, -9.0, 13.0);
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
  INFO("median |error| " << err[err.size() / 2] << " px");
  CHECK(err[err.size() / 2] < 1.0);
}

TEST_CASE("No arc in the noise alone, and none over rows the LLE already explains", "[localize][weak_arc]") {
  SECTION("noise alone") {
    const SunlitFrame f = render(0.0, 4);
    const localize::WeakArc arc = search(f, image::LaserLine{});
    INFO("z " << arc.z);
    CHECK(arc.z < 8.0);
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
