#include "localize/weak_arc.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "geometry/triangulation.h"

namespace alacs::localize {

namespace {

// The subtracted red and its contrast over the ROI (row-major, ROI coordinates).
struct ContrastMap {
  int width = 0;
  int height = 0;
  std::vector<int16_t> diff;    // red(on) − red(off)
  std::vector<float> contrast;  // diff − mean of diff contrastPx either side, in its local σ
  std::vector<float> pooled;    // the contrast's maximum within ±2 px, less its mean in noise
  std::vector<uint8_t> masked;  // 1: explained, near a sample the LLE found or an arc already followed

  float at(int x, int y) const { return contrast[static_cast<size_t>(y) * width + x]; }
  float pooledAt(int x, int y) const { return pooled[static_cast<size_t>(y) * width + x]; }
  bool isMasked(int x, int y) const { return masked[static_cast<size_t>(y) * width + x] != 0; }
  int16_t diffAt(int x, int y) const { return diff[static_cast<size_t>(y) * width + x]; }
  // Marks ±px round (x, y) as explained (clipped to the map).
  void mask(int x, int y, int px) {
    if (y < 0 || y >= height) return;
    for (int i = std::max(0, x - px); i <= std::min(width - 1, x + px); ++i)
      masked[static_cast<size_t>(y) * width + i] = 1;
  }
};

ContrastMap contrastMap(const image::ImageView& on, const image::ImageView& off, const image::Roi& roi,
                        const image::LaserLine& line, const WeakArcParams& p) {
  ContrastMap m;
  m.width = roi.width;
  m.height = roi.height;
  const size_t n = static_cast<size_t>(roi.width) * static_cast<size_t>(roi.height);
  m.diff.assign(n, 0);
  m.contrast.assign(n, 0.0F);
  m.masked.assign(n, 0);
  const int ro = image::redOffset(on.format);
  const int rf = image::redOffset(off.format);
  for (int y = 0; y < roi.height; ++y) {
    const uint8_t* a = on.row(roi.y + y) + 3 * roi.x + ro;
    const uint8_t* b = off.row(roi.y + y) + 3 * roi.x + rf;
    for (int x = 0; x < roi.width; ++x)
      m.diff[static_cast<size_t>(y) * roi.width + x] = static_cast<int16_t>(a[3 * x] - b[3 * x]);
  }
  const int w = p.contrastPx;
  for (int y = 0; y < roi.height; ++y)
    for (int x = w; x < roi.width - w; ++x) {
      const size_t i = static_cast<size_t>(y) * roi.width + x;
      m.contrast[i] = static_cast<float>(m.diff[i]) - 0.5F * static_cast<float>(m.diff[i - w] + m.diff[i + w]);
    }
  // The noise is the shot noise of the pair: bright skin's is several times a leaf's. Each
  // block's robust σ normalises its contrast, so that a bright region does not pass for an arc.
  constexpr int kBlock = 16;
  std::vector<float> sample;
  for (int by = 0; by < roi.height; by += kBlock)
    for (int bx = 0; bx < roi.width; bx += kBlock) {
      sample.clear();
      const int y1 = std::min(roi.height, by + kBlock);
      const int x1 = std::min(roi.width, bx + kBlock);
      for (int y = by; y < y1; ++y)
        for (int x = bx; x < x1; ++x) sample.push_back(std::abs(m.contrast[static_cast<size_t>(y) * roi.width + x]));
      std::nth_element(sample.begin(), sample.begin() + static_cast<long>(sample.size() / 2), sample.end());
      const float sigma = std::max(0.5F, 1.4826F * sample[sample.size() / 2]);
      for (int y = by; y < y1; ++y)
        for (int x = bx; x < x1; ++x) m.contrast[static_cast<size_t>(y) * roi.width + x] /= sigma;
    }
  // The coarse search's arcs fall up to a few px off the line: it scores each with the
  // best contrast within ±2 px (the mean of the largest of five normal draws is 1.16).
  m.pooled.assign(n, 0.0F);
  for (int y = 0; y < roi.height; ++y)
    for (int x = 2; x < roi.width - 2; ++x) {
      const float* c = &m.contrast[static_cast<size_t>(y) * roi.width + x];
      m.pooled[static_cast<size_t>(y) * roi.width + x] = std::max({c[-2], c[-1], c[0], c[1], c[2]}) - 1.16F;
    }
  for (const auto& r : line.rows)
    if (r.valid()) m.mask(static_cast<int>(std::lround(r.column)) - roi.x, r.row - roi.y, p.maskPx);
  return m;
}

// OpenCV's pinhole and Brown–Conrady model, as geometry::projectPoint (which goes through
// cv::projectPoints, too slow for the thousands of arcs a frame's search projects).
geometry::PixelPoint project(const geometry::CameraIntrinsics& cam, const Eigen::Vector3d& p) {
  const double x = p.x() / p.z();
  const double y = p.y() / p.z();
  const auto& d = cam.distortion;
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
  const double xd = x * radial + 2.0 * d[2] * x * y + d[3] * (r2 + 2.0 * x * x);
  const double yd = y * radial + d[2] * (r2 + 2.0 * y * y) + 2.0 * d[3] * x * y;
  return {cam.fxPx * xd + cam.cxPx, cam.fyPx * yd + cam.cyPx};
}

// A sample's reported column: columnQ8 rounded from `columnPx`, and column exactly that
// Q24.8 value, as the LLE reports its rows.
void setColumn(image::RowSample& s, double columnPx) {
  s.columnQ8 = static_cast<int32_t>(std::lround(columnPx * 256.0));
  s.column = static_cast<float>(s.columnQ8) / 256.0F;
}

// The camera-facing arc of the circle (centre centreMm, radius radiusMm, in the plane
// spanned by e1, e2) as ROI pixels, one per row, from one end of the arc to the other.
struct ArcPixel {
  int x;
  int y;
};

void arcPixels(const geometry::CameraIntrinsics& cam, const image::Roi& roi, const Eigen::Vector3d& centreMm,
               double radiusMm, const Eigen::Vector3d& e1, const Eigen::Vector3d& e2, double rowStride,
               std::vector<ArcPixel>& out) {
  out.clear();
  const double pxPerMm = cam.fyPx / std::max(100.0, centreMm.z());
  const double dTheta = 0.6 * rowStride / std::max(1.0, radiusMm * pxPerMm);
  // The camera-facing half is the one round the direction from the centre to the camera:
  // stepping round it from the far side keeps the half in one run, in order along the arc.
  const double towardCamera = std::atan2(-centreMm.dot(e2), -centreMm.dot(e1));
  int lastRow = -1 << 30;
  for (double t = towardCamera - M_PI; t < towardCamera + M_PI; t += dTheta) {
    const Eigen::Vector3d radial = std::cos(t) * e1 + std::sin(t) * e2;
    const Eigen::Vector3d pt = centreMm + radiusMm * radial;
    if (radial.dot(pt) >= 0.0) continue;  // faces away from the camera
    const geometry::PixelPoint px = project(cam, pt);
    const int row = static_cast<int>(std::lround(px.rowPx));
    if (row == lastRow) continue;
    lastRow = row;
    const int x = static_cast<int>(std::lround(px.columnPx)) - roi.x;
    const int y = row - roi.y;
    if (x < 0 || y < 0 || x >= roi.width || y >= roi.height) continue;
    out.push_back({x, y});
  }
}

// Each row's peak near the arc: sub-pixel centroid of the subtracted red.
std::vector<image::RowSample> follow(const ContrastMap& m, const image::Roi& roi, const std::vector<ArcPixel>& arc,
                                     int segment, const WeakArcParams& p) {
  std::vector<image::RowSample> out;
  const int w = p.contrastPx;
  for (const ArcPixel& a : arc) {
    if (m.isMasked(a.x, a.y)) continue;
    int best = -1;
    float bestC = 0.0F;
    for (int x = std::max(w + 2, a.x - p.followPx); x <= std::min(m.width - w - 3, a.x + p.followPx); ++x)
      if (!m.isMasked(x, a.y) && m.at(x, a.y) > bestC) {
        bestC = m.at(x, a.y);
        best = x;
      }
    if (best < 0 || bestC < p.minRowContrastSigmas) continue;
    const double base = 0.5 * (m.diffAt(best - w, a.y) + m.diffAt(best + w, a.y));
    double sw = 0.0;
    double sx = 0.0;
    for (int x = best - 2; x <= best + 2; ++x) {
      const double v = std::max(0.0, m.diffAt(x, a.y) - base);
      sw += v;
      sx += v * x;
    }
    if (!(sw > 0.0)) continue;
    image::RowSample s;
    s.row = roi.y + a.y;
    setColumn(s, roi.x + sx / sw);
    s.centroidQ8 = s.columnQ8;
    s.confidence = std::min(1.0F, bestC / 4.0F);
    s.inlier = false;
    s.status = image::RowStatus::kSegment;
    s.segment = segment;
    out.push_back(s);
  }
  return out;
}

struct ArcCandidate {
  double z = 0.0;
  int rows = 0;
  Eigen::Vector3d centreMm = Eigen::Vector3d::Zero();  // the circle's, in the laser plane
  double radiusMm = 0.0;
};

// The plane's frame: e1 along the camera's y (down the image) in the plane, e2 across it
// (towards depth), and the rough position's foot in it.
struct PlaneFrame {
  Eigen::Vector3d e1, e2, q0;
};

// The best arc over the pixels not yet explained (m's mask): coarse to fine, centres 1.5
// steps apart, radii 2 steps, every other row, each row's best within ±2 px; then round the
// five best, half a step in the plane and in the radius, every row. `arc` is scratch.
ArcCandidate bestArc(const ContrastMap& m, const image::Roi& roi, const geometry::CameraIntrinsics& cam,
                     const PlaneFrame& f, const WeakArcParams& p, std::vector<ArcPixel>& arc) {
  // The arc's score: its contrast summed over the rows left unexplained, over the noise of
  // that sum (each pixel's contrast is in its own σ).
  auto score = [&](const Eigen::Vector3d& centreMm, double radiusMm, bool coarse, int* rows) {
    arcPixels(cam, roi, centreMm, radiusMm, f.e1, f.e2, coarse ? 2.0 : 1.0, arc);
    double sum = 0.0;
    int count = 0;
    for (const ArcPixel& a : arc) {
      if (a.x < p.contrastPx || a.x >= m.width - p.contrastPx || m.isMasked(a.x, a.y)) continue;
      sum += coarse ? m.pooledAt(a.x, a.y) : m.at(a.x, a.y);
      ++count;
    }
    *rows = count;
    return count < (coarse ? p.minRows / 2 : p.minRows) ? 0.0 : sum / std::sqrt(static_cast<double>(count));
  };
  std::vector<ArcCandidate> coarse;
  const double coarseMm = 1.5 * p.stepMm;
  const int steps = static_cast<int>(std::floor(p.searchMm / coarseMm));
  int rows = 0;
  for (int i = -steps; i <= steps; ++i)
    for (int j = -steps; j <= steps; ++j)
      for (double radiusMm = p.minRadiusMm; radiusMm <= p.maxRadiusMm + 1e-9; radiusMm += 2.0 * p.radiusStepMm) {
        const Eigen::Vector3d centreMm = f.q0 + i * coarseMm * f.e1 + j * coarseMm * f.e2;
        coarse.push_back({score(centreMm, radiusMm, true, &rows), 0, centreMm, radiusMm});
      }
  constexpr size_t kKept = 5;
  std::partial_sort(coarse.begin(), coarse.begin() + static_cast<long>(std::min(kKept, coarse.size())), coarse.end(),
                    [](const ArcCandidate& a, const ArcCandidate& b) { return a.z > b.z; });
  coarse.resize(std::min(kKept, coarse.size()));
  ArcCandidate best{0.0, 0, f.q0, 0.0};
  for (const ArcCandidate& c : coarse)
    for (int i = -1; i <= 1; ++i)
      for (int j = -1; j <= 1; ++j)
        for (int k = -2; k <= 2; ++k) {
          const Eigen::Vector3d centreMm = c.centreMm + 0.5 * p.stepMm * (i * f.e1 + j * f.e2);
          const double radiusMm = c.radiusMm + 0.5 * p.radiusStepMm * k;
          if (radiusMm < p.minRadiusMm * 0.5) continue;
          const double z = score(centreMm, radiusMm, false, &rows);
          if (z > best.z) best = {z, rows, centreMm, radiusMm};
        }
  return best;
}

// The followed samples' columns, each replaced by the local straight line through the
// arc's other samples within ±halfRows rows and itself, weighted by their contrast: one
// sample's error is 0.5-1 px under the shot noise of sunlit skin, 3-5 mm in depth at
// 1.6 m, more than the sphere fit's bands. A sample more than outlierPx off the line
// through the others alone is another peak the row offered, and one with fewer than
// kMinNeighbours others in its window has nothing to be told from: both are dropped and
// the lines drawn again without them. Samples are in order along the arc (arcPixels).
void smoothAlong(std::vector<image::RowSample>& s, int halfRows, double outlierPx) {
  if (halfRows <= 0) return;
  constexpr int kMinNeighbours = 3;
  std::vector<uint8_t> use(s.size(), 1);
  struct Sums {
    double w = 0.0, r = 0.0, c = 0.0, rr = 0.0, rc = 0.0;
    int n = 0;
    void add(double weight, double row, double col, int sign) {
      w += sign * weight;
      r += sign * weight * row;
      c += sign * weight * col;
      rr += sign * weight * row * row;
      rc += sign * weight * row * col;
      n += sign;
    }
    // The weighted least-squares line's value at row offset 0 (the weighted mean where
    // every row is the same).
    double at0() const {
      const double d = w * rr - r * r;
      return std::abs(d) < 1e-9 ? c / w : (c * rr - r * rc) / d;
    }
  };
  // Sums over the window round sample i (i included), in offsets from its row.
  const auto window = [&](size_t i) {
    Sums sums;
    const auto near = [&](size_t j) { return std::abs(s[j].row - s[i].row) <= halfRows; };
    for (size_t j = i; near(j); --j) {  // i itself, then back along the arc
      if (use[j]) sums.add(s[j].confidence, s[j].row - s[i].row, s[j].column, 1);
      if (j == 0) break;
    }
    for (size_t j = i + 1; j < s.size() && near(j); ++j)
      if (use[j]) sums.add(s[j].confidence, s[j].row - s[i].row, s[j].column, 1);
    return sums;
  };
  for (size_t i = 0; i < s.size(); ++i) {
    Sums others = window(i);
    others.add(s[i].confidence, 0.0, s[i].column, -1);
    if (others.n < kMinNeighbours || std::abs(s[i].column - others.at0()) > outlierPx) use[i] = 0;
  }
  std::vector<image::RowSample> out;
  out.reserve(s.size());
  for (size_t i = 0; i < s.size(); ++i) {
    if (!use[i]) continue;
    const Sums all = window(i);
    image::RowSample r = s[i];  // centroidQ8 stays the row's own centroid, as the LLE's
    setColumn(r, all.at0());
    out.push_back(r);
  }
  s = std::move(out);
}

}  // namespace

WeakArc findWeakArc(const image::ImageView& frame, const image::ImageView& laserOff, const image::Roi& roi,
                    const geometry::Calibration& cal, double slideMm, const Eigen::Vector3d& roughMm,
                    const image::LaserLine& line, int segment, const WeakArcParams& p) {
  WeakArc result;
  if (!(p.minZ > 0.0) || roi.empty() || roi.width <= 2 * p.contrastPx + 8) return result;
  ContrastMap m = contrastMap(frame, laserOff, roi, line, p);
  PlaneFrame f;
  const Eigen::Vector3d n = cal.laser.planeNormal.normalized();
  f.e1 = (Eigen::Vector3d::UnitY() - n.dot(Eigen::Vector3d::UnitY()) * n).normalized();
  f.e2 = n.cross(f.e1);
  f.q0 = roughMm - (n.dot(roughMm) - cal.laser.planeOffsetAt(slideMm)) * n;
  std::vector<ArcPixel> arc;
  // The best arc over the bar, then the best over what it leaves, and so on: in sun a
  // neighbour's or a leaf's arc may outscore the target's, and the fit across the stops,
  // not this search, tells which one is the fruit. Each arc's whole path is masked once
  // scored, so that no later search scores its unfollowed rows again.
  for (int k = 0; k < std::max(1, p.maxArcs); ++k) {
    const ArcCandidate best = bestArc(m, roi, cal.camera, f, p, arc);
    if (k == 0) {
      result.z = best.z;
      result.rows = best.rows;
    }
    if (best.z < p.minZ) break;
    arcPixels(cal.camera, roi, best.centreMm, best.radiusMm, f.e1, f.e2, 1.0, arc);
    std::vector<image::RowSample> found = follow(m, roi, arc, segment + result.arcs, p);
    smoothAlong(found, p.smoothRows, p.outlierPx);
    for (const ArcPixel& a : arc) m.mask(a.x, a.y, p.maskPx);
    for (const image::RowSample& s : found)
      m.mask(static_cast<int>(std::lround(s.column)) - roi.x, s.row - roi.y, p.maskPx);
    if (static_cast<int>(found.size()) < p.minRows / 2) continue;  // too little of it to follow
    result.samples.insert(result.samples.end(), found.begin(), found.end());
    ++result.arcs;
  }
  return result;
}

}  // namespace alacs::localize
