// LLE stages 3-5 of kRobust (line focusing, continuity, curve fit, output) and the paper's
// stages 3-4, over either arithmetic (lle_focus.h), instantiated for both at the end.
#include "image/lle_focus.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <type_traits>

namespace alacs::image::detail {

namespace {

// Scale of the MAD to a 3σ rejection limit: 3 · 1.4826 ≈ 18218 / 4096, in both arithmetics.
constexpr int64_t kMadToLimitQ12 = 18218;

// Carves typed arrays out of one byte buffer that only ever grows.
class Arena {
 public:
  explicit Arena(std::vector<uint8_t>& buf) : buf_(buf) {}
  template <class T>
  void reserve(size_t n) {
    need_ += n * sizeof(T) + 16;
  }
  void commit() {
    if (buf_.size() < need_) buf_.resize(need_);
    at_ = 0;
  }
  template <class T>
  T* take(size_t n) {
    static_assert(std::is_trivially_copyable_v<T>);
    at_ = (at_ + 15) & ~size_t{15};
    T* p = reinterpret_cast<T*>(buf_.data() + at_);  // NOLINT: storage for trivially copyable T
    at_ += n * sizeof(T);
    return p;
  }

 private:
  std::vector<uint8_t>& buf_;
  size_t need_ = 0;
  size_t at_ = 0;
};

// Sums of one run's red excess over the local background: the background is the straight
// line between the red values `step` columns beyond each end of the run (the pixels bRCE
// compared against). Every term is an integer: excess·span = R(x)·span − (rl·(xr−x) + rr·(x−xl)).
// `area` and `excess` are of the excess itself; the centroid's weights are the excess
// less 1/8 of the largest.
struct RunSums {
  int64_t sumW = 0;   // Σ excess·span over pixels with positive excess
  int64_t sumXW = 0;  // Σ x · excess·span
  int32_t area = 0;   // Σ excess (DN·px), the peak's strength
  int32_t excess = 0; // largest excess (DN)
  int32_t margin = 0; // largest bRCE margin min(c - l, c - r) over the run (the red bRCE saw)
  bool saturated = false;
  bool clipped = false;  // laser-off subtracted, and the ambient alone is at full scale within the peak's
                         // window: the difference there is what clipping left of the line, not the line
  bool edge = false;   // the background steps across the run (an occluder's edge)
};

// The rows a peak's sums read: the row alone, or with a laser-off frame and the averaged
// rerun, the rows above and below as well (clamped to the ROI), as candidateMask read them.
struct PeakRows {
  const uint8_t* on[3] = {};   // above, at, below
  const uint8_t* off[3] = {};  // the laser-off frame's, or nullptr
  int redOffset = 0;
  bool averaged = false;

  int red(const uint8_t* px, int x) const { return px[3U * static_cast<size_t>(x) + static_cast<size_t>(redOffset)]; }
  int difference(int k, int x) const { return off[k] == nullptr ? red(on[k], x) : red(on[k], x) - red(off[k], x); }
  // The red value bRCE compared: the difference saturated at 0, averaged as averageRowsScalar.
  int brce(int x) const {
    const int mid = std::max(0, difference(1, x));
    if (!averaged) return mid;
    const int outer = (std::max(0, difference(0, x)) + std::max(0, difference(2, x)) + 1) >> 1;
    return (outer + mid + 1) >> 1;
  }
  // The signed red the sums weigh, `scale` times over: [1 2 1] when averaged.
  int value(int x) const {
    return averaged ? difference(0, x) + 2 * difference(1, x) + difference(2, x) : difference(1, x);
  }
  int scale() const { return averaged ? 4 : 1; }
  // The ambient alone at full scale at x, in any row the sums read.
  bool clipped(int x) const {
    if (off[1] == nullptr) return false;
    if (red(off[1], x) == 255) return true;
    return averaged && (red(off[0], x) == 255 || red(off[2], x) == 255);
  }
};

inline RunSums runSums(const PeakRows& px, int w, int a, int b, int step, int edgeRatio) {
  RunSums s;
  for (int x = std::max(a, step); x <= std::min(b, w - 1 - step); ++x) {
    const int c = px.brce(x);
    s.margin = std::max(s.margin, std::min(c - px.brce(x - step), c - px.brce(x + step)));
  }
  const int xl = std::max(0, a - step);
  const int xr = std::min(w - 1, b + step);
  const int span = xr - xl;
  if (span <= 1) return s;
  const int64_t rl = px.value(xl);
  const int64_t rr = px.value(xr);
  // An occluding edge next to the line: one side's background (a leaf, a gap) is several
  // times darker than the other's (the skin the line is on). Integer test, 8 DN of slack.
  if (edgeRatio > 0) s.edge = std::max(rl, rr) > edgeRatio * std::max<int64_t>(0, std::min(rl, rr)) + 8 * px.scale();
  int64_t maxW = 0;
  for (int x = xl + 1; x < xr; ++x)
    maxW = std::max(maxW, px.value(x) * static_cast<int64_t>(span) - (rl * (xr - x) + rr * (x - xl)));
  // Weights: the excess above 1/8 of the peak's, so the tails, where speckle and the
  // background estimate dominate, weigh less (measured on the twin: see docs/lle.md).
  const int64_t floorW = maxW >> 3;
  for (int x = xl + 1; x < xr; ++x) {
    const int64_t wq = px.value(x) * static_cast<int64_t>(span) - (rl * (xr - x) + rr * (x - xl)) - floorW;
    if (wq <= 0) continue;
    s.sumW += wq;
    s.sumXW += wq * x;
  }
  for (int x = a; x <= b; ++x) s.saturated = s.saturated || px.red(px.on[1], x) == 255;
  // A clipped core is compared with the pixels `step` beyond the run's ends, as
  // clippedRunsRow marked it (its own pixels `step` away lie on the plateau).
  if (s.saturated && a - step >= 0 && b + step < w) {
    const int l = px.brce(a - step);
    const int r = px.brce(b + step);
    for (int x = a; x <= b; ++x)
      if (px.red(px.on[1], x) == 255) s.margin = std::max(s.margin, std::min(px.brce(x) - l, px.brce(x) - r));
  }
  for (int x = xl; x <= xr; ++x) s.clipped = s.clipped || px.clipped(x);
  s.area = static_cast<int32_t>(s.sumW / (static_cast<int64_t>(span) * px.scale()));
  s.excess = static_cast<int32_t>(maxW / (static_cast<int64_t>(span) * px.scale()));
  return s;
}

// Decisions: columns as Q24.8 keys, computed the same way from the same integer sums in
// both arithmetics, so both decide alike.
struct KeyArith {
  using Col = int32_t;  // Q24.8
  static Col fromPx(double px) { return static_cast<Col>(std::lround(px * 256.0)); }
  static Col fromInt(int px) { return static_cast<Col>(px * 256); }
  static Col ratio(int64_t num, int64_t den) { return static_cast<Col>(roundDiv(num * 256, den)); }
  static Col absDiff(Col a, Col b) { return a > b ? a - b : b - a; }
  // lastCol + (lastCol - prevCol) · gap / dr
  static Col extrapolate(Col last, Col prev, int gap, int dr) {
    return static_cast<Col>(last + roundDiv(static_cast<int64_t>(last - prev) * gap, dr));
  }
  static Col madLimit(Col mad) { return static_cast<Col>((static_cast<int64_t>(mad) * kMadToLimitQ12 + 2048) >> 12); }
  // 256 at zero residual down to 128 at the limit and beyond.
  static int fitTerm(Col res, Col limit) {
    return 256 - static_cast<int>(std::min<int64_t>(128, static_cast<int64_t>(res) * 128 / std::max<Col>(1, limit)));
  }
  // Least-squares line through (r[i], c[i]), evaluated at m: the closed form over integers.
  static Col lineAt(const int* r, const Col* c, int n, int m) {
    Int128 sr = 0, sc = 0, srr = 0, src = 0;
    for (int i = 0; i < n; ++i) {
      sr += r[i];
      sc += c[i];
      srr += static_cast<Int128>(r[i]) * r[i];
      src += static_cast<Int128>(r[i]) * c[i];
    }
    const Int128 d = n * srr - sr * sr;
    if (d == 0) return static_cast<Col>(roundDiv(static_cast<int64_t>(sc), n));
    const Int128 num = sc * d + (n * src - sr * sc) * (static_cast<Int128>(n) * m - sr);
    const Int128 den = static_cast<Int128>(n) * d;
    return static_cast<Col>(divRound(num, den));  // den > 0: n > 0 and d > 0 (Cauchy-Schwarz)
  }
  // The robust fit's decisions: the fixed-point fit through the keys.
  struct Fit {
    FitQ q;
    int64_t* scratch = nullptr;  // 3n
    int32_t* data = nullptr;     // n
    bool fit(const int32_t* rows, const Col* keys, const uint8_t* use, int n, int order, int first, int last) {
      for (int i = 0; i < n; ++i) data[i] = keys[i] * 256;  // Q8 -> Q16, exact
      return fitPolyQ(rows, data, use, n, order, first, last, scratch, q);
    }
    Col eval(int row) const { return static_cast<Col>(roundDiv(q.evalQ16(row), 256)); }
  };
};

namespace focus {

// The next set bit at or after `from` in a row of `nbits` bits, or nbits.
inline int nextSet(const uint64_t* words, int nbits, int from) {
  if (from >= nbits) return nbits;
  int k = from / 64;
  uint64_t word = words[k] & (~uint64_t{0} << (from % 64));
  const int nwords = (nbits + 63) / 64;
  while (word == 0) {
    if (++k >= nwords) return nbits;
    word = words[k];
  }
  return std::min(nbits, k * 64 + __builtin_ctzll(word));
}

// The next clear bit at or after `from`, or nbits.
inline int nextClear(const uint64_t* words, int nbits, int from) {
  if (from >= nbits) return nbits;
  int k = from / 64;
  uint64_t word = ~words[k] & (~uint64_t{0} << (from % 64));
  const int nwords = (nbits + 63) / 64;
  while (word == 0) {
    if (++k >= nwords) return nbits;
    word = ~words[k];
  }
  return std::min(nbits, k * 64 + __builtin_ctzll(word));
}

template <class Col>
struct Peak {
  Col col;          // ROI columns, the value
  int32_t key;      // the same in Q8, on which decisions are taken
  int32_t area;
  int32_t excess;
  int32_t chain;
  int32_t next;     // next peak of the same chain (row order), -1
  uint8_t saturated;
  uint8_t strong;   // its bRCE margin passes the strong threshold (not only the weak share)
  uint8_t edge;     // at an occluding edge (RunSums::edge): reported kEdge, not smoothed over
  uint8_t firm;     // its margin passes the first pass's strong threshold (a rerun's other segments need it)
};

struct Chain {
  int32_t first;
  int32_t last;
  int32_t prevRow;
  int32_t count;
  int64_t area;
  int32_t lastKey;
  int32_t prevKey;
  int32_t head;     // first peak
  int32_t tail;     // last peak
  int32_t segment;  // index in LaserLine::segments, -1: too short
  int32_t strong;   // rows whose peak is strong
  int32_t firm;     // rows whose peak is firm (Peak::firm)
  uint8_t onLine;
};

}  // namespace focus

}  // namespace

FixedArith::Col FixedArith::quadAtZero(const int* u, const Col* c, const int32_t* wt, int n, int order) {
  int64_t s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, t0 = 0, t1 = 0, t2 = 0;
  if (order >= 2) {
    for (int i = 0; i < n; ++i) {
      const int64_t x = u[i];
      const int64_t x2 = x * x;
      const int64_t w = wt[i];
      const int64_t wc = w * c[i];
      s0 += w;
      s1 += w * x;
      s2 += w * x2;
      s3 += w * x2 * x;
      s4 += w * x2 * x2;
      t0 += wc;
      t1 += x * wc;
      t2 += x2 * wc;
    }
  } else {  // the linear fit (the default) needs no third or fourth moments
    for (int i = 0; i < n; ++i) {
      const int64_t x = u[i];
      const int64_t w = wt[i];
      const int64_t wx = w * x;
      s0 += w;
      s1 += wx;
      s2 += wx * x;
      t0 += w * c[i];
      t1 += wx * c[i];
    }
  }
  auto div = [](Int128 a, Int128 b) {
    if (b < 0) {
      a = -a;
      b = -b;
    }
    return static_cast<Col>(divRound(a, b));
  };
  if (order >= 2 && n >= 3) {
    const Int128 S2 = s2, S3 = s3, S4 = s4, S1 = s1, T1 = t1, T2 = t2;
    const Int128 det = s0 * (S2 * S4 - S3 * S3) - S1 * (S1 * S4 - S3 * S2) + S2 * (S1 * S3 - S2 * S2);
    if (det != 0) {
      const Int128 det0 = t0 * (S2 * S4 - S3 * S3) - S1 * (T1 * S4 - S3 * T2) + S2 * (T1 * S3 - S2 * T2);
      return div(det0, det);
    }
  }
  const int64_t d2 = s0 * s2 - s1 * s1;
  if (order >= 1 && n >= 2 && d2 != 0) return div(static_cast<Int128>(t0) * s2 - static_cast<Int128>(s1) * t1, d2);
  return div(t0, s0);
}

FloatArith::Col FloatArith::quadAtZero(const int* u, const Col* c, const int32_t* wt, int n, int order) {
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, t0 = 0, t1 = 0, t2 = 0;
  for (int i = 0; i < n; ++i) {
    const double x = u[i];
    const double w = wt[i];
    s0 += w;
    s1 += w * x;
    s2 += w * x * x;
    s3 += w * x * x * x;
    s4 += w * x * x * x * x;
    t0 += w * c[i];
    t1 += w * x * c[i];
    t2 += w * x * x * c[i];
  }
  const double det = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2);
  if (order >= 2 && n >= 3 && det != 0.0)
    return (t0 * (s2 * s4 - s3 * s3) - s1 * (t1 * s4 - s3 * t2) + s2 * (t1 * s3 - s2 * t2)) / det;
  const double d2 = s0 * s2 - s1 * s1;
  if (order >= 1 && n >= 2 && d2 != 0.0) return (t0 * s2 - s1 * t1) / d2;
  return t0 / s0;
}

namespace {

using focus::Chain;
using focus::Peak;
using Q = KeyArith;  // decisions, on the exact Q8 keys shared by both arithmetics

// The arrays of one focusRobust call, carved out of ws.scratch (no allocation once warm).
// Rows of the ROI: h; peak slots: h · maxPeaksPerRow, row y's at [y·kMax, y·kMax + nPeaks[y]).
template <class Col>
struct RobustArrays {
  Peak<Col>* peaks;
  int32_t* nPeaks;      // peaks per row
  Chain* chains;
  int32_t* active;      // active chains
  int32_t* owner;       // the line's peak of each row, -1
  int32_t* order;       // segments by strength
  int32_t* fitRows;     // the robust fit's rows (full frame)
  int32_t* fitKeys;     // ... their keys (Q8)
  Col* fitCols;         // ... their values
  uint8_t* use;         // ... kept
  uint8_t* usePrev;     // ... kept in the previous iteration
  int32_t* residual;    // ... residuals (Q8)
  int32_t* sorted;      // residuals for the median; later the line's excess
  int64_t* fitScratch;  // fixed-point fit scratch (3h)
  int32_t* fitData;     // fixed-point fit data
  int* endRows;         // 64: rows of a local line fit (4b, 5a, 5b)
  int32_t* endKeys;     // 64: their keys
  Col* smoothCols;      // 64: their values (5b)
  Col* outCol;          // per output sample: centroid
  int32_t* outKey;      // ... smoothing key: -2 line, -3 outlier, -4 edge, else segment
  int32_t* outWt;       // ... smoothing weight
  int32_t* outPeakKey;  // ... peak key (Q8)
  uint8_t* outEdge;     // ... at an occluding edge
  int32_t* smoothWt;    // 64: weights of a local fit (5b)
};

template <class Col>
RobustArrays<Col> carveArrays(LleWorkspace& ws, int h, int kMax) {
  const auto uh = static_cast<size_t>(h);
  const size_t slots = uh * static_cast<size_t>(kMax);
  Arena arena(ws.scratch);
  arena.reserve<Peak<Col>>(slots);
  arena.reserve<int32_t>(uh);
  arena.reserve<Chain>(slots);
  arena.reserve<int32_t>(slots);
  arena.reserve<int32_t>(uh);
  arena.reserve<int32_t>(slots);
  arena.reserve<int32_t>(uh);
  arena.reserve<int32_t>(uh);
  arena.reserve<Col>(uh);
  arena.reserve<uint8_t>(uh);
  arena.reserve<uint8_t>(uh);
  arena.reserve<int32_t>(uh);
  arena.reserve<int32_t>(uh);
  arena.reserve<int64_t>(3 * uh);
  arena.reserve<int32_t>(uh);
  arena.reserve<int>(64);
  arena.reserve<int32_t>(64);
  arena.reserve<Col>(64);
  arena.reserve<Col>(slots);
  arena.reserve<int32_t>(slots);
  arena.reserve<int32_t>(slots);
  arena.reserve<int32_t>(slots);
  arena.reserve<uint8_t>(slots);
  arena.reserve<int32_t>(64);
  arena.commit();
  RobustArrays<Col> r{};
  r.peaks = arena.take<Peak<Col>>(slots);
  r.nPeaks = arena.take<int32_t>(uh);
  r.chains = arena.take<Chain>(slots);
  r.active = arena.take<int32_t>(slots);
  r.owner = arena.take<int32_t>(uh);
  r.order = arena.take<int32_t>(slots);
  r.fitRows = arena.take<int32_t>(uh);
  r.fitKeys = arena.take<int32_t>(uh);
  r.fitCols = arena.take<Col>(uh);
  r.use = arena.take<uint8_t>(uh);
  r.usePrev = arena.take<uint8_t>(uh);
  r.residual = arena.take<int32_t>(uh);
  r.sorted = arena.take<int32_t>(uh);
  r.fitScratch = arena.take<int64_t>(3 * uh);
  r.fitData = arena.take<int32_t>(uh);
  r.endRows = arena.take<int>(64);
  r.endKeys = arena.take<int32_t>(64);
  r.smoothCols = arena.take<Col>(64);
  r.outCol = arena.take<Col>(slots);
  r.outKey = arena.take<int32_t>(slots);
  r.outWt = arena.take<int32_t>(slots);
  r.outPeakKey = arena.take<int32_t>(slots);
  r.outEdge = arena.take<uint8_t>(slots);
  r.smoothWt = arena.take<int32_t>(64);
  return r;
}

// Stage 3: per row, every run of candidates is a peak (holes of up to mergeGap pixels,
// speckle, are bridged); its centre is the centroid of the red excess. The strongest
// kMax peaks of the row go on, ordered by area (ties: leftmost first).
template <class A>
void findPeaks(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const LleParams& p, int rows,
               int firmTh, const LleWorkspace& ws, Peak<typename A::Col>* peaks, int32_t* nPeaks) {
  const int w = roi.width;
  const int h = roi.height;
  const int words = paddedWidth(w) / 64;
  const int kMax = p.maxPeaksPerRow;
  const int redOff = redOffset(frame.format);
  const int step = p.brceStep;
  const int mergeGap = std::max(1, step / 2);
  const int strongTh = p.strongThreshold();
  for (int y = 0; y < h; ++y) {
    const uint64_t* bits = ws.bits.data() + static_cast<size_t>(y) * static_cast<size_t>(words);
    PeakRows px;
    px.redOffset = redOff;
    px.averaged = laserOff != nullptr && rows == 3;
    for (int k = 0; k < 3; ++k) {
      const int yk = px.averaged ? std::clamp(y + k - 1, 0, h - 1) : y;
      px.on[k] = roiRow(&frame, roi, yk);
      px.off[k] = roiRow(laserOff, roi, yk);
    }
    Peak<typename A::Col>* row = peaks + static_cast<size_t>(y) * static_cast<size_t>(kMax);
    int n = 0;
    int x = ws.rowAny[static_cast<size_t>(y)] != 0 ? focus::nextSet(bits, w, 0) : w;
    while (x < w) {
      const int a = x;
      int b = focus::nextClear(bits, w, a) - 1;
      for (;;) {
        const int nx = focus::nextSet(bits, w, b + 1);
        if (nx >= w || nx - b - 1 > mergeGap) {
          x = nx;
          break;
        }
        b = focus::nextClear(bits, w, nx) - 1;
      }
      const RunSums s = runSums(px, w, a, b, step, p.edgeRatio);
      if (s.area <= 0 || s.clipped) continue;
      if (n == kMax && s.area <= row[n - 1].area) continue;
      int i = n < kMax ? n++ : n - 1;
      while (i > 0 && row[i - 1].area < s.area) {
        row[i] = row[i - 1];
        --i;
      }
      row[i] = Peak<typename A::Col>{A::ratio(s.sumXW, s.sumW),
                                     Q::ratio(s.sumXW, s.sumW),
                                     s.area,
                                     s.excess,
                                     -1,
                                     -1,
                                     static_cast<uint8_t>(s.saturated ? 1 : 0),
                                     static_cast<uint8_t>(s.margin > strongTh ? 1 : 0),
                                     static_cast<uint8_t>(s.edge ? 1 : 0),
                                     static_cast<uint8_t>(s.margin > firmTh ? 1 : 0)};
    }
    nPeaks[y] = n;
  }
}

// Stage 4a: link peaks of successive rows into chains. A peak continues the active chain
// whose prediction (its last two rows extrapolated) is nearest, when within maxJump
// (growing by half of it per skipped row); stronger peaks choose first. Returns the
// number of chains.
template <class Col>
int linkChains(const LleParams& p, int h, Peak<Col>* peaks, const int32_t* nPeaks, Chain* chains, int32_t* active) {
  const int kMax = p.maxPeaksPerRow;
  const int32_t jump = Q::fromPx(p.maxJumpPx);
  int nChains = 0;
  int nActive = 0;
  for (int y = 0; y < h; ++y) {
    int keep = 0;
    for (int i = 0; i < nActive; ++i)
      if (y - chains[active[i]].last <= p.maxGapRows + 1) active[keep++] = active[i];
    nActive = keep;
    const int activeBefore = nActive;
    for (int j = 0; j < nPeaks[y]; ++j) {
      const int pi = y * kMax + j;
      Peak<Col>& pk = peaks[pi];
      int best = -1;
      int32_t bestD = 0;
      for (int i = 0; i < activeBefore; ++i) {
        const Chain& c = chains[active[i]];
        if (c.last >= y) continue;  // already continued in this row
        const int gap = y - c.last;
        const int32_t pred = c.count >= 2 ? Q::extrapolate(c.lastKey, c.prevKey, gap, c.last - c.prevRow) : c.lastKey;
        const int32_t d = Q::absDiff(pk.key, pred);
        const int32_t tol = jump + jump * (gap - 1) / 2;
        if (d <= tol && (best < 0 || d < bestD)) {
          best = active[i];
          bestD = d;
        }
      }
      if (best < 0) {
        best = nChains++;
        chains[best] = Chain{y, y, -1, 0, 0, pk.key, pk.key, pi, pi, -1, 0, 0, 0};
        active[nActive++] = best;
      } else {
        Chain& c = chains[best];
        peaks[c.tail].next = pi;
        c.tail = pi;
        c.prevRow = c.last;
        c.prevKey = c.lastKey;
        c.last = y;
        c.lastKey = pk.key;
      }
      Chain& c = chains[best];
      c.count += 1;
      c.area += pk.area;
      c.strong += pk.strong;
      c.firm += pk.firm;
      pk.chain = best;
    }
  }
  return nChains;
}

// Segments: chains of at least minSegmentRows rows of which at least two, and a quarter,
// pass the strong threshold itself (hysteresis: a weak line needs strong parts; a faint laser
// line on a far background, never strong, stays out).
bool isSegment(const Chain& c, const LleParams& p) {
  return c.count >= p.minSegmentRows && c.strong >= std::min(2, c.count) && 4 * c.strong >= c.count;
}

// The segments' chain indices into `order`, strongest first; returns how many.
int segmentsByStrength(const LleParams& p, const Chain* chains, int nChains, int32_t* order) {
  int nSeg = 0;
  for (int c = 0; c < nChains; ++c)
    if (isSegment(chains[c], p)) order[nSeg++] = c;
  std::sort(order, order + nSeg, [&](int32_t a, int32_t b) {
    return chains[a].area != chains[b].area ? chains[a].area > chains[b].area : a < b;
  });
  return nSeg;
}

// The straight line through the first (fromTop) or the last 8 peaks of the chain that
// starts at peak `head`, at row m (Q8). endRows/endKeys: 8 each, scratch.
template <class Col>
int32_t chainEndAt(const Peak<Col>* peaks, int kMax, int head, bool fromTop, int m, int* endRows, int32_t* endKeys) {
  int n = 0;
  if (fromTop) {
    for (int pi = head; pi >= 0 && n < 8; pi = peaks[pi].next) {
      endRows[n] = pi / kMax;
      endKeys[n++] = peaks[pi].key;
    }
  } else {
    // The last 8 peaks (chains are singly linked: keep a ring of them).
    int cnt = 0;
    for (int pi = head; pi >= 0; pi = peaks[pi].next) {
      endRows[cnt % 8] = pi / kMax;
      endKeys[cnt % 8] = peaks[pi].key;
      ++cnt;
    }
    n = std::min(cnt, 8);
  }
  return Q::lineAt(endRows, endKeys, n, m);
}

// The straight line through up to 8 line rows from `from` going in `dir`, within 64 rows,
// at row m (Q8).
template <class Col>
int32_t lineEndAt(const Peak<Col>* peaks, const int32_t* owner, int h, int from, int dir, int m, int* endRows,
                  int32_t* endKeys) {
  int n = 0;
  for (int y = from; y >= 0 && y < h && n < 8 && std::abs(y - from) <= 64; y += dir) {
    if (owner[y] < 0) continue;
    endRows[n] = y;
    endKeys[n++] = peaks[owner[y]].key;
  }
  return Q::lineAt(endRows, endKeys, n, m);
}

// Whether segment c continues the line (the rows owned so far): no more than a few rows
// shared with it, and across each gap to it both ends, extrapolated as straight lines to
// the middle of the gap, agree within bridgePx + bridgePxPerRow·gap.
template <class Col>
bool continuesLine(const Chain& c, const LleParams& p, int h, const Peak<Col>* peaks, const int32_t* owner,
                   int lineFirst, int lineLast, int* endRows, int32_t* endKeys) {
  const int kMax = p.maxPeaksPerRow;
  const int32_t bridge = Q::fromPx(p.bridgePx);
  const int32_t bridgePerRow = Q::fromPx(p.bridgePxPerRow);
  int shared = 0;
  for (int pi = c.head; pi >= 0; pi = peaks[pi].next) shared += owner[pi / kMax] >= 0 ? 1 : 0;
  if (shared > std::max(2, c.count / 10)) return false;
  // The line's nearest rows above and below the segment; every line row lies within
  // [lineFirst, lineLast] (-1: no line yet), so the search starts there.
  int above = -1;
  for (int y = std::min(c.first - 1, lineLast); lineFirst >= 0 && y >= lineFirst; --y)
    if (owner[y] >= 0) {
      above = y;
      break;
    }
  int below = -1;
  for (int y = std::max(c.last + 1, lineFirst); lineFirst >= 0 && y <= lineLast && y < h; ++y)
    if (owner[y] >= 0) {
      below = y;
      break;
    }
  bool agrees = above >= 0 || below >= 0;
  if (above >= 0) {
    const int gap = c.first - above;
    const int m = (above + c.first) / 2;
    const int32_t d = Q::absDiff(lineEndAt(peaks, owner, h, above, -1, m, endRows, endKeys),
                                 chainEndAt(peaks, kMax, c.head, true, m, endRows, endKeys));
    agrees = agrees && d <= bridge + bridgePerRow * gap;
  }
  if (below >= 0) {
    const int gap = below - c.last;
    const int m = (below + c.last) / 2;
    const int32_t d = Q::absDiff(lineEndAt(peaks, owner, h, below, +1, m, endRows, endKeys),
                                 chainEndAt(peaks, kMax, c.head, false, m, endRows, endKeys));
    agrees = agrees && d <= bridge + bridgePerRow * gap;
  }
  return agrees;
}

// The line grown from segment order[seed]: it, then every other segment that continues
// it (continuesLine), in order of strength. Sets Chain::onLine and owner[y], the line's
// peak of each row (-1: none).
template <class Col>
void growLine(const LleParams& p, int h, const Peak<Col>* peaks, Chain* chains, const int32_t* order, int nSeg,
              int seed, int32_t* owner, int* endRows, int32_t* endKeys) {
  const int kMax = p.maxPeaksPerRow;
  std::fill(owner, owner + h, -1);
  for (int s = 0; s < nSeg; ++s) chains[order[s]].onLine = 0;
  if (seed >= nSeg) return;  // no segment: no line
  int lineFirst = -1;        // the line's first and last row so far
  int lineLast = -1;
  for (int k = -1; k < nSeg; ++k) {
    const int s = k < 0 ? seed : k;
    if (k == seed) continue;
    Chain& c = chains[order[s]];
    if (k >= 0 && !continuesLine(c, p, h, peaks, owner, lineFirst, lineLast, endRows, endKeys)) continue;
    c.onLine = 1;
    for (int pi = c.head; pi >= 0; pi = peaks[pi].next)
      if (owner[pi / kMax] < 0) owner[pi / kMax] = pi;
    lineFirst = lineFirst < 0 ? c.first : std::min(lineFirst, c.first);
    lineLast = std::max(lineLast, c.last);
  }
}

// The grown line's rank: the sum over its rows of the row's peak area times the centre
// prior's weight at that peak (Q16), exp(-½·((dx/σ)² + (dy/σ)²)), dx and dy the peak's
// offset from the ROI's centre in shares of the ROI's width and height, σ =
// centrePriorShare. Weighed row by row, a neighbour's long line counts only the rows it has
// near the middle, where the target is; weighed as a whole (its mean column and middle
// row), its rows far above or below outweighed the target's (docs/lle.md, "Which line is
// the fruit's"). Each weight is rounded to an integer, so both arithmetics rank alike.
template <class Col>
int64_t lineRank(const LleParams& p, int w, int h, const Peak<Col>* peaks, const int32_t* owner) {
  const double inv = 1.0 / (p.centrePriorShare * p.centrePriorShare);
  int64_t rank = 0;
  for (int y = 0; y < h; ++y) {
    if (owner[y] < 0) continue;
    const Peak<Col>& pk = peaks[owner[y]];
    const double dx = pk.key / (256.0 * w) - 0.5;  // keys: Q8 columns
    const double dy = (y + 0.5) / h - 0.5;
    rank += static_cast<int64_t>(pk.area) * std::lround(65536.0 * std::exp(-0.5 * (dx * dx + dy * dy) * inv));
  }
  return rank;
}

// Stage 4b: the line. Without the centre prior (or on the whole frame, which is not a
// window round a target), the one grown from the strongest segment;
// with it, of the lines grown from each of the kSeeds strongest (those with at least an
// eighth of the strongest's area), the highest-ranked (lineRank: strength, continuity
// across gaps and the line's place in the ROI, which is planned round the target). A frame
// of more than kMaxSegments segments is noise, not a choice of surfaces: the strongest.
template <class Col>
void assembleLine(const LleParams& p, bool window, int w, int h, const Peak<Col>* peaks, Chain* chains,
                  const int32_t* order, int nSeg, int32_t* owner, int* endRows, int32_t* endKeys) {
  constexpr int kSeeds = 6;
  constexpr int kMaxSegments = 48;
  int best = 0;
  int grown = -1;  // the seed whose line owner[] and Chain::onLine hold
  if (window && p.centrePriorShare > 0.0 && nSeg > 1 && nSeg <= kMaxSegments) {
    int64_t bestRank = -1;
    const int seeds = std::min(nSeg, kSeeds);
    bool covered[kSeeds] = {};  // on a line already grown: it would grow that line again
    for (int seed = 0; seed < seeds && 8 * chains[order[seed]].area >= chains[order[0]].area; ++seed) {
      if (covered[seed]) continue;
      growLine(p, h, peaks, chains, order, nSeg, seed, owner, endRows, endKeys);
      grown = seed;
      for (int k = seed + 1; k < seeds; ++k) covered[k] = covered[k] || chains[order[k]].onLine != 0;
      const int64_t rank = lineRank(p, w, h, peaks, owner);
      if (rank > bestRank) {
        bestRank = rank;
        best = seed;
      }
    }
  }
  if (grown != best) growLine(p, h, peaks, chains, order, nSeg, best, owner, endRows, endKeys);
}

// The robust fit's outcome: n rows (the line's), `fitted`, and the rejection limit (Q8).
struct RobustFit {
  int n = 0;
  bool fitted = false;
  int32_t limit = 0;
};

// Stage 4c: robust curve fit over the line's rows (full-frame coordinates): rows beyond
// max(outlierPx, 3·1.4826·MAD) are dropped and the fit repeated until stable. The
// decisions are taken on the keys with the fixed-point fit; the curve reported is then
// fitted (in A) through the values of the rows kept. Fills a.fitRows/fitKeys/fitCols,
// a.use (kept) and a.residual.
template <class A>
RobustFit robustFit(const Roi& roi, const LleParams& p, const RobustArrays<typename A::Col>& a,
                    typename A::Fit& curve) {
  const int h = roi.height;
  int32_t* fitRows = a.fitRows;
  int32_t* fitKeys = a.fitKeys;
  typename A::Col* fitCols = a.fitCols;
  uint8_t* use = a.use;
  int32_t* residual = a.residual;
  int32_t* sorted = a.sorted;
  int n = 0;
  for (int y = 0; y < h; ++y) {
    if (a.owner[y] < 0) continue;
    fitRows[n] = roi.y + y;
    fitKeys[n] = a.peaks[a.owner[y]].key + Q::fromInt(roi.x);
    fitCols[n] = a.peaks[a.owner[y]].col + A::fromInt(roi.x);
    use[n] = 1;
    ++n;
  }
  Q::Fit decide;
  decide.scratch = a.fitScratch;
  decide.data = a.fitData;
  const int32_t outlier = Q::fromPx(p.outlierPx);
  int32_t limit = outlier;
  bool fitted = false;
  const int fitOrder = std::max(0, std::min(p.polyOrder, n / 2 - 1));
  if (n >= p.minRows) {
    for (int iteration = 0; iteration < 8; ++iteration) {
      int inl = 0;
      for (int i = 0; i < n; ++i) inl += use[i];
      if (inl < p.minRows || !decide.fit(fitRows, fitKeys, use, n, fitOrder, fitRows[0], fitRows[n - 1])) {
        fitted = false;
        break;
      }
      fitted = true;
      for (int i = 0; i < n; ++i) {
        residual[i] = Q::absDiff(fitKeys[i], decide.eval(fitRows[i]));
        sorted[i] = residual[i];
      }
      std::nth_element(sorted, sorted + n / 2, sorted + n);
      limit = std::max(outlier, Q::madLimit(sorted[n / 2]));
      bool changed = false;
      for (int i = 0; i < n; ++i) {
        a.usePrev[i] = use[i];
        use[i] = residual[i] <= limit ? 1 : 0;
        changed = changed || use[i] != a.usePrev[i];
      }
      if (!changed) break;
    }
  }
  if constexpr (A::kFixed) curve.scratch = a.fitScratch;
  if (fitted) fitted = curve.fit(fitRows, fitCols, use, n, fitOrder, fitRows[0], fitRows[n - 1]);
  return RobustFit{n, fitted, limit};
}

// Numbers the segments (Chain::segment, in chain order) and lists them in out.segments.
// `firmOnly` (a rerun at a lower bar): a segment off the line needs two firm rows, as the
// first pass would have found it; the bar came down to find a weak line, not to let in
// other surfaces' weak ones (docs/lle.md, "The rerun's other segments").
void listSegments(const Roi& roi, const LleParams& p, Chain* chains, int nChains, bool firmOnly, LaserLine& out) {
  int nOut = 0;
  for (int c = 0; c < nChains; ++c)
    if (isSegment(chains[c], p) && (!firmOnly || chains[c].onLine != 0 || chains[c].firm >= 2))
      chains[c].segment = nOut++;
  for (int c = 0; c < nChains; ++c)
    if (chains[c].segment >= 0)
      out.segments.push_back(LineSegment{roi.y + chains[c].first, roi.y + chains[c].last, 0, chains[c].onLine != 0});
}

// Appends the sample of peak pk in ROI row y to out.rows, and its smoothing inputs to the
// a.out* arrays at the same index.
template <class A>
void emitSample(const Roi& roi, int y, const Peak<typename A::Col>& pk, const Chain* chains, RowStatus status,
                int fitTerm, const RobustArrays<typename A::Col>& a, LaserLine& out) {
  using Col = typename A::Col;
  // Built in place (out.rows is reserved: no allocation), not copied from the stack.
  const size_t idx = out.rows.size();
  RowSample& sm = out.rows.emplace_back();
  sm.row = roi.y + y;
  const Col col = pk.col + A::fromInt(roi.x);
  sm.centroidQ8 = A::toQ8(col);
  sm.columnQ8 = sm.centroidQ8;
  sm.column = A::toFloat(col);
  sm.status = status;
  sm.inlier = status == RowStatus::kLine;
  sm.saturated = pk.saturated != 0;
  sm.segment = chains[pk.chain].segment;
  if (status != RowStatus::kOutlier) {
    int conf = std::min(256, pk.excess * 256 / 96) * fitTerm / 256;
    if (sm.saturated) conf = conf * 3 / 4;
    sm.confidence = static_cast<float>(conf) / 256.0F;
  }
  if (sm.segment >= 0) out.segments[static_cast<size_t>(sm.segment)].rows += 1;
  a.outCol[idx] = col;
  // The smoothing weight: the peak's area cubed, area³ / 2^18 in 1..4096 (an integer: the
  // sums of the weighted fit stay within int64). Rows where part of the profile is hidden
  // (a leaf's edge crossing the line, a grazing limb) are weaker and count far less.
  {
    const int64_t ar = std::max(1, pk.area);
    a.outWt[idx] = static_cast<int32_t>(std::clamp<int64_t>(ar * ar * ar >> 18, 1, kMaxSmoothWeight));
  }
  a.outKey[idx] = status == RowStatus::kLine ? -2 : status == RowStatus::kOutlier ? -3 : sm.segment;
  a.outPeakKey[idx] = pk.key;
  a.outEdge[idx] = static_cast<uint8_t>(pk.edge != 0 && status != RowStatus::kOutlier ? 1 : 0);
}

// Stage 5: the samples of each row: the line's first, then those of the other segments
// (keepOtherSegments), stronger segments first. Returns the sum of the squared residuals
// (px²) of the line's kLine rows to the curve.
template <class A>
double emitRows(const Roi& roi, const LleParams& p, const RobustArrays<typename A::Col>& a, const Chain* chains,
                const RobustFit& f, const typename A::Fit& curve, LaserLine& out) {
  const int h = roi.height;
  const int kMax = p.maxPeaksPerRow;
  const auto* peaks = a.peaks;
  const int32_t* owner = a.owner;
  double sumSq = 0.0;
  int fi = 0;
  int others[8];
  for (int y = 0; y < h; ++y) {
    if (owner[y] >= 0) {
      RowStatus status = RowStatus::kSegment;
      int fitTerm = 128;
      if (f.fitted && a.use[fi] != 0) {
        status = RowStatus::kLine;
        fitTerm = Q::fitTerm(a.residual[fi], f.limit);
        const double d = A::toPx(A::absDiff(a.fitCols[fi], curve.eval(a.fitRows[fi])));
        sumSq += d * d;
      } else if (f.fitted) {
        status = RowStatus::kOutlier;
      }
      ++fi;
      emitSample<A>(roi, y, peaks[owner[y]], chains, status, fitTerm, a, out);
    }
    if (!p.keepOtherSegments) continue;
    int n2 = 0;
    for (int j = 0; j < a.nPeaks[y]; ++j) {
      const int pi = y * kMax + j;
      if (pi == owner[y] || chains[peaks[pi].chain].segment < 0) continue;
      int i = n2++;
      while (i > 0 && chains[peaks[others[i - 1]].chain].area < chains[peaks[pi].chain].area) {
        others[i] = others[i - 1];
        --i;
      }
      others[i] = pi;
    }
    for (int i = 0; i < n2; ++i) emitSample<A>(roi, y, peaks[others[i]], chains, RowStatus::kSegment, 128, a, out);
  }
  return sumSq;
}

// Stage 5a: a sample at an occluding edge (RunSums::edge) is kept only when its centroid
// agrees with the straight line through the keys of the same line or segment within
// ±smoothRows rows that are not at an edge themselves (at least 4 of them), within
// edgeAgreePx; otherwise it is kEdge: invalid, not smoothed, not used for smoothing.
// Then counts the line's rows (inliers, first and last).
template <class Col>
void markEdges(const LleParams& p, const RobustArrays<Col>& a, LaserLine& out) {
  const int nRows = static_cast<int>(out.rows.size());
  const int32_t edgeTolQ8 = Q::fromPx(p.edgeAgreePx);
  int* endRows = a.endRows;
  int32_t* endKeys = a.endKeys;
  const uint8_t* outEdge = a.outEdge;
  int32_t* outKey = a.outKey;
  const int32_t* outPeakKey = a.outPeakKey;
  int lo = 0;  // the first sample within smoothRows above row k's (the rows come in order)
  for (int k = 0; k < nRows; ++k) {
    if (outEdge[k] == 0) continue;
    const int r0 = out.rows[static_cast<size_t>(k)].row;
    while (r0 - out.rows[static_cast<size_t>(lo)].row > p.smoothRows) ++lo;
    int m = 0;
    for (int j = lo; j < nRows && out.rows[static_cast<size_t>(j)].row - r0 <= p.smoothRows && m < 64; ++j) {
      if (j == k || outEdge[j] != 0 || outKey[j] != outKey[k]) continue;
      endRows[m] = out.rows[static_cast<size_t>(j)].row - r0;
      endKeys[m++] = outPeakKey[j];
    }
    if (m >= 4 && Q::absDiff(Q::lineAt(endRows, endKeys, m, 0), outPeakKey[k]) <= edgeTolQ8) continue;
    RowSample& sm = out.rows[static_cast<size_t>(k)];
    sm.status = RowStatus::kEdge;
    sm.inlier = false;
    sm.confidence = 0.0F;
    outKey[k] = -4;
  }
  for (const RowSample& sm : out.rows) {
    if (sm.status != RowStatus::kLine) continue;
    if (out.inliers == 0) out.firstLineRow = sm.row;
    out.lastLineRow = sm.row;
    out.inliers += 1;
  }
}

// Stage 5b: along the line, each row's column is the local fit (smoothOrder: mean, line,
// quadratic) through the centroids within ±smoothRows rows of the same line or segment,
// each weighted by its peak's area cubed (speckle averages out over rows; rows whose
// profile is partly hidden are weak and barely count). Rows at an occluding edge (kEdge)
// and rejected rows are neither smoothed nor used.
template <class A>
void smoothAlongLine(const LleParams& p, const RobustArrays<typename A::Col>& a, LaserLine& out) {
  using Col = typename A::Col;
  const int nRows = static_cast<int>(out.rows.size());
  int* endRows = a.endRows;
  Col* smoothCols = a.smoothCols;
  int32_t* smoothWt = a.smoothWt;
  const int32_t* outKey = a.outKey;
  const Col* outCol = a.outCol;
  const int32_t* outWt = a.outWt;
  int lo = 0;  // the first sample within smoothRows above row k's (the rows come in order)
  for (int k = 0; k < nRows; ++k) {
    if (outKey[k] == -3 || outKey[k] == -4) continue;
    const int r0 = out.rows[static_cast<size_t>(k)].row;
    while (r0 - out.rows[static_cast<size_t>(lo)].row > p.smoothRows) ++lo;
    int m = 0;
    for (int j = lo; j < nRows && out.rows[static_cast<size_t>(j)].row - r0 <= p.smoothRows; ++j) {
      if (outKey[j] != outKey[k]) continue;
      endRows[m] = out.rows[static_cast<size_t>(j)].row - r0;
      smoothCols[m] = outCol[j];
      smoothWt[m] = outWt[j];
      if (++m == 64) break;
    }
    const Col smooth = A::quadAtZero(endRows, smoothCols, smoothWt, m, p.smoothOrder);
    RowSample& sm = out.rows[static_cast<size_t>(k)];
    sm.columnQ8 = A::toQ8(smooth);
    sm.column = A::toFloat(smooth);
  }
}

// The line's strength: the median excess of its kLine rows' peaks (an integer, the same
// in both arithmetics); 0 without a line.
template <class Col>
int lineStrength(int h, const RobustArrays<Col>& a, bool fitted) {
  int32_t* sorted = a.sorted;
  int nLine = 0;
  int fi = 0;
  for (int y = 0; y < h; ++y) {
    if (a.owner[y] < 0) continue;
    if (fitted && a.use[fi] != 0) sorted[nLine++] = a.peaks[a.owner[y]].excess;
    ++fi;
  }
  if (nLine == 0) return 0;
  std::nth_element(sorted, sorted + nLine / 2, sorted + nLine);
  return sorted[nLine / 2];
}

// Stages 3-5 of kRobust over the candidate mask in ws.bits. Returns the median peak excess
// (DN) of the line's kLine rows, 0 without a line: how strong the line is.
template <class A>
int focusRobust(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const LleParams& p, int rows,
                int firmTh, LleWorkspace& ws, LaserLine& out) {
  const int h = roi.height;
  const RobustArrays<typename A::Col> a = carveArrays<typename A::Col>(ws, h, p.maxPeaksPerRow);
  findPeaks<A>(frame, laserOff, roi, p, rows, firmTh, ws, a.peaks, a.nPeaks);
  const int nChains = linkChains(p, h, a.peaks, a.nPeaks, a.chains, a.active);
  const int nSeg = segmentsByStrength(p, a.chains, nChains, a.order);
  // The centre prior only where the ROI is a window planned round the target, not the whole frame.
  const bool window = roi.width < frame.width || roi.height < frame.height;
  assembleLine(p, window, roi.width, h, a.peaks, a.chains, a.order, nSeg, a.owner, a.endRows, a.endKeys);
  typename A::Fit curve;
  const RobustFit f = robustFit<A>(roi, p, a, curve);
  listSegments(roi, p, a.chains, nChains, firmTh > p.strongThreshold(), out);
  const double sumSq = emitRows<A>(roi, p, a, a.chains, f, curve, out);
  markEdges(p, a, out);
  if (p.smoothRows > 0) smoothAlongLine<A>(p, a, out);
  if (f.fitted) {
    curve.describe(out);
    out.valid = true;
    out.rmsResidualPx = out.inliers > 0 ? std::sqrt(sumSq / out.inliers) : 0.0;
  }
  if (out.inliers > 0) out.coverage = static_cast<double>(out.inliers) / (out.lastLineRow - out.firstLineRow + 1);
  return lineStrength(h, a, f.fitted);
}

// The matched filter's kernel: a Gaussian of the line's width (σ kMatchedSigmaPx) less its
// mean over ±kMatchedHalfPx, in Q8 and summing to exactly zero, so that the ambient's
// remainder after the subtraction (a slope, an offset) gives no response.
constexpr int kMatchedHalfPx = 8;
constexpr double kMatchedSigmaPx = 1.5;
struct MatchedKernel {
  std::array<int32_t, 2 * kMatchedHalfPx + 1> q8{};
  MatchedKernel() {
    std::array<double, 2 * kMatchedHalfPx + 1> g{};
    double mean = 0.0;
    for (size_t i = 0; i < g.size(); ++i) {
      const double k = static_cast<double>(i) - kMatchedHalfPx;
      g[i] = std::exp(-0.5 * k * k / (kMatchedSigmaPx * kMatchedSigmaPx));
      mean += g[i] / static_cast<double>(g.size());
    }
    int32_t sum = 0;
    for (size_t i = 0; i < g.size(); ++i) {
      q8[i] = static_cast<int32_t>(std::lround(256.0 * (g[i] - mean)));
      sum += q8[i];
    }
    q8[kMatchedHalfPx] -= sum;
    for (size_t i = 0; i < q8.size(); ++i) q16[i] = static_cast<int16_t>(q8[i]);
  }
  std::array<int16_t, 2 * kMatchedHalfPx + 1> q16{};  // the same in 16 bits (-57..199)
};

// A response's noise relative to a mid-scale level's, from the level under its window
// (Σ q² · red, `level` below): √((floor + 128) / (floor + level / Σq²)) in Q12, tabled at a
// quarter DN of mean level (0..255), so that each response costs a multiply and a shift,
// not a square root and a division. A floor far above every level (noise that does not grow
// with the light) gives exactly 4096: the responses unchanged.
class NoiseShares {
 public:
  NoiseShares(double floorDn, const MatchedKernel& k) {
    int64_t q2sum = 0;
    for (const int16_t q : k.q16) q2sum += static_cast<int64_t>(q) * q;
    // level · 4 / Σq² as (level · perLevel) >> 32: the quarter-DN bin.
    perLevelQ32_ = (int64_t{4} << 32) / std::max<int64_t>(1, q2sum);
    const double f = std::max(0.5, floorDn);
    for (size_t i = 0; i < q12_.size(); ++i)
      q12_[i] =
          static_cast<int32_t>(std::lround(4096.0 * std::sqrt((f + 128.0) / (f + 0.25 * static_cast<double>(i)))));
  }
  // (response · share) >> 12, rounded towards minus infinity (exact at 4096).
  int32_t scale(int32_t response, int32_t level) const {
    const int64_t bin = std::clamp<int64_t>((static_cast<int64_t>(level) * perLevelQ32_) >> 32, 0,
                                            static_cast<int64_t>(q12_.size()) - 1);
    return static_cast<int32_t>((static_cast<int64_t>(response) * q12_[static_cast<size_t>(bin)]) >> 12);
  }

 private:
  std::array<int32_t, 1024> q12_{};
  int64_t perLevelQ32_ = 0;
};

// out[j] = Σ_i weight(i) · src[j + i] for j < n, one tap at a time over the whole row (the
// compiler vectorises the inner loop): the matched filter's responses and its levels.
template <class Src, class Weight>
void sumTaps(const Src* src, int n, size_t taps, Weight weight, int32_t* __restrict__ out) {
  std::fill(out, out + n, 0);
  for (size_t i = 0; i < taps; ++i) {
    const int32_t q = weight(i);
    const Src* __restrict__ s = src + i;
    for (int j = 0; j < n; ++j) out[j] += q * static_cast<int32_t>(s[j]);
  }
}

// One ROI row through the matched filter: its best column (-1: none), the response there
// over its noise, in hundredths, and the responses beside it. Shot noise's variance follows
// the light, so each response is first divided by its own noise's share: √(floor + level),
// the level being the laser-off red under its window weighed as the response weighs it (by
// the kernel's squares) and the floor the read noise in DN of light (matchedNoiseFloorDn);
// the row's robust spread (1.4826 · MAD) is then taken of those, and the best column is the
// largest of them. (Until 2026-12-05 the raw responses: where most of a row lay in shade,
// noise on a band of sunlit skin stood at 5 of the shade's spread; docs/lle.md.) A column
// whose window holds a laser-off pixel at full scale gives no response (the difference
// there is no measure of the line). `resp`, `sorted` and `level` hold w each.
struct MatchedRow {
  int x = -1;
  int zCenti = 0;
  int32_t left = 0, mid = 0, right = 0;  // the responses at x - 1, x, x + 1
};
MatchedRow matchedRow(const uint8_t* on, const uint8_t* off, int redOffset, int w, const MatchedKernel& k,
                      const NoiseShares& shares, int32_t* resp, int32_t* sorted, int16_t* diff, int32_t* level) {
  constexpr int32_t kNone = std::numeric_limits<int32_t>::min();
  const auto ro = static_cast<size_t>(redOffset);
  const auto red = [&](const uint8_t* f, int x) { return static_cast<int32_t>(f[static_cast<size_t>(x) * 3U + ro]); };
  const int n = std::max(0, w - 2 * kMatchedHalfPx);
  MatchedRow out;
  if (n < 4) return out;
  // The level under each window: the laser-off red into `level`, its sums weighed by the
  // kernel's squares into sorted[x - half], one tap at a time (Σ q² · red ≤ 17 · 199² · 255
  // fits 32 bits), then back into level[x].
  for (int x = 0; x < w; ++x) level[x] = red(off, x);
  sumTaps(
      level, n, k.q16.size(), [&](size_t i) { return static_cast<int32_t>(k.q16[i]) * k.q16[i]; }, sorted);
  for (int j = 0; j < n; ++j) level[j + kMatchedHalfPx] = sorted[j];
  // The difference (16 bits: -255..255), then the filter over it into sorted[x - half], one
  // tap at a time over the whole row (16 × 16 → 32-bit products, which the compiler
  // vectorises), then each response into resp[x] where no clipped laser-off pixel is in its
  // window.
  for (int x = 0; x < w; ++x) diff[x] = static_cast<int16_t>(red(on, x) - red(off, x));
  sumTaps(
      diff, n, k.q16.size(), [&](size_t i) { return static_cast<int32_t>(k.q16[i]); }, sorted);
  int clipAt = -1000000;  // the last laser-off pixel at full scale up to x + half
  for (int x = 0; x < std::min(kMatchedHalfPx, w); ++x)
    if (red(off, x) == 255) clipAt = x;
  for (int x = 0; x < w; ++x) {
    resp[x] = kNone;
    if (x + kMatchedHalfPx < w && red(off, x + kMatchedHalfPx) == 255) clipAt = x + kMatchedHalfPx;
    if (x < kMatchedHalfPx || x + kMatchedHalfPx >= w) continue;
    if (clipAt < x - kMatchedHalfPx) resp[x] = sorted[x - kMatchedHalfPx];
  }
  // Each response over its noise's share (NoiseShares: integers, a table per frame).
  int best = -1;
  for (int j = 0; j < n; ++j) {
    const int x = j + kMatchedHalfPx;
    sorted[j] = shares.scale(sorted[j], level[x]);
    if (x > kMatchedHalfPx && x + kMatchedHalfPx + 1 < w && resp[x] != kNone &&
        (best < 0 || sorted[j] > sorted[best - kMatchedHalfPx]))
      best = x;
  }
  if (best < 0 || resp[best - 1] == kNone || resp[best + 1] == kNone) return out;
  const int32_t bestScaled = sorted[best - kMatchedHalfPx];
  const int32_t median = kthSmallest(sorted, n, n / 2);
  for (int i = 0; i < n; ++i) sorted[i] = std::abs(sorted[i] - median);
  const double spread = 1.4826 * std::max<int32_t>(1, kthSmallest(sorted, n, n / 2));
  out.x = best;
  out.zCenti = static_cast<int>(std::lround(100.0 * (bestScaled - median) / spread));
  out.left = resp[best - 1];
  out.mid = resp[best];
  out.right = resp[best + 1];
  return out;
}

// The noise floor of a laser-off-subtracted ROI, in DN of light: the difference's variance
// grows with the ambient's level as read² + level/gain does (shot noise), and the floor is
// read²·gain, the level at which the two are equal. From the pixels themselves: their
// |difference| binned by the laser-off red (16 DN bins, clipped pixels left out; every other
// row and column), each bin's robust spread (1.4826 · median |difference|; the line's few
// pixels barely move a median), and a straight line through (level, spread²) weighed by the
// bins' counts.
// Where the spread does not grow with the level (fewer than two bins, or a flat or falling
// line), a floor so high that every window's noise is the row's (as before 2026-12-05).
double matchedNoiseFloorDn(const ImageView& frame, const ImageView& laserOff, const Roi& roi, int ro) {
  constexpr double kFlat = 1e9;
  constexpr int kBins = 16;
  constexpr int32_t kMinCount = 64;
  std::array<std::array<int32_t, 256>, kBins> hist{};
  std::array<int64_t, kBins> sum{};
  std::array<int32_t, kBins> count{};
  // Every other row and column: a quarter of the ROI is ample for 16 medians, at a quarter of the cost.
  for (int y = 0; y < roi.height; y += 2) {
    const uint8_t* on = roiRow(&frame, roi, y);
    const uint8_t* off = roiRow(&laserOff, roi, y);
    for (int x = 0; x < roi.width; x += 2) {
      const int o = off[static_cast<size_t>(x) * 3U + static_cast<size_t>(ro)];
      if (o >= 250) continue;
      const int d = std::abs(static_cast<int>(on[static_cast<size_t>(x) * 3U + static_cast<size_t>(ro)]) - o);
      const auto b = static_cast<size_t>(o >> 4);
      ++hist[b][static_cast<size_t>(d)];
      sum[b] += o;
      ++count[b];
    }
  }
  double sw = 0.0, sx = 0.0, sy = 0.0, sxx = 0.0, sxy = 0.0;
  int bins = 0;
  for (size_t b = 0; b < static_cast<size_t>(kBins); ++b) {
    if (count[b] < kMinCount) continue;
    // The median |difference|, interpolated within its integer value.
    const double half = 0.5 * count[b];
    int32_t below = 0;
    size_t v = 0;
    while (below + hist[b][v] < half) below += hist[b][v++];
    const double mad = static_cast<double>(v) - 0.5 + (half - below) / std::max(1, hist[b][v]);
    const double var = std::pow(1.4826 * std::max(mad, 0.0), 2.0);
    const double level = static_cast<double>(sum[b]) / count[b];
    const double wgt = count[b];
    sw += wgt;
    sx += wgt * level;
    sy += wgt * var;
    sxx += wgt * level * level;
    sxy += wgt * level * var;
    ++bins;
  }
  const double det = sw * sxx - sx * sx;
  if (bins < 2 || !(det > 0.0)) return kFlat;
  const double slope = (sw * sxy - sx * sy) / det;
  const double intercept = (sy - slope * sx) / sw;
  if (!(slope > 1e-6)) return kFlat;
  return std::clamp(intercept / slope, 0.5, kFlat);
}

// Buffers of matchedFilterRows, per ROI row (h) or column (w).
struct MatchedArrays {
  int32_t* resp;    // w: a row's responses
  int32_t* sorted;  // w: the same, for the median
  int16_t* diff;    // w: the row's red difference
  int32_t* level;   // w: the laser-off red under each response's window (Σ q² · red)
  int32_t* colQ8;   // h: the column (Q8, in the ROI) of the row's line sample or filter peak (unsmoothed)
  int32_t* z;       // h: the peak's response over its noise (hundredths; matchedRow)
  uint8_t* state;   // h: 0 free, 1 the line's, 2 another sample (left alone), 3 taken here
  int32_t* run;     // h: the run the row belongs to (-1: none)
  int32_t* stack;   // h: the walk's stack, then the kept rows' smoothed columns (Q8, in the ROI)
  int32_t* segOf;   // h: a kept run's new segment (0.., in order of first row), -1: none
};

// Grows runs from the seeds (the line's rows, and free rows at `seed` or more) through free
// rows at `join` or more: a walk over rows within 2 of each other whose columns agree within
// `jumpQ8` (LleParams::maxJumpPx, as the LLE links its own segments). Returns the number of runs.
int growMatchedRuns(int h, int seed, int join, int32_t jumpQ8, const MatchedArrays& a) {
  std::fill(a.run, a.run + h, -1);
  int runs = 0;
  for (int y0 = 0; y0 < h; ++y0) {
    const bool isSeed = a.state[y0] == 1 || (a.state[y0] == 0 && a.z[y0] >= seed);
    if (!isSeed || a.run[y0] >= 0) continue;
    int top = 0;
    a.stack[top++] = y0;
    a.run[y0] = runs;
    while (top > 0) {
      const int y = a.stack[--top];
      for (int dy = -2; dy <= 2; ++dy) {
        const int v = y + dy;
        if (dy == 0 || v < 0 || v >= h || a.run[v] >= 0) continue;
        const bool open = a.state[v] == 1 || (a.state[v] == 0 && a.z[v] >= join);
        if (!open || std::abs(a.colQ8[v] - a.colQ8[y]) > jumpQ8) continue;
        a.run[v] = runs;
        a.stack[top++] = v;
      }
    }
    ++runs;
  }
  return runs;
}

// Keeps the runs that hold a line row, or minRows free rows of their own (state 3 for their
// free rows; tallied in one pass over the rows); then each kept row's column (into `stack`)
// from the straight line through its run's rows within ±smoothRows (at least 4, some on
// either side: no extrapolation; unweighted, where the LLE weighs its own rows by their
// strength). Returns the rows kept.
int keepMatchedRuns(int h, int runs, int minRows, int smoothRows, const MatchedArrays& a) {
  // Per run, in one pass over the rows: its free rows (into segOf, free until
  // addMatchedSegments) and whether it holds a line row (into stack, free until the
  // smoothing below).
  int32_t* own = a.segOf;
  int32_t* line = a.stack;
  std::fill(own, own + runs, 0);
  std::fill(line, line + runs, 0);
  for (int y = 0; y < h; ++y) {
    const int r = a.run[y];
    if (r < 0) continue;
    line[r] |= a.state[y] == 1 ? 1 : 0;
    own[r] += a.state[y] == 0 ? 1 : 0;
  }
  int kept = 0;
  for (int y = 0; y < h; ++y) {
    const int r = a.run[y];
    if (r < 0 || a.state[y] != 0 || own[r] == 0 || (line[r] == 0 && own[r] < minRows)) continue;
    a.state[y] = 3;
    ++kept;
  }
  for (int y = 0; y < h; ++y) {
    if (a.state[y] != 3) continue;
    double n = 0.0, sv = 0.0, sc = 0.0, svv = 0.0, svc = 0.0;
    bool above = false, below = false;
    for (int v = std::max(0, y - smoothRows); v <= std::min(h - 1, y + smoothRows); ++v) {
      if (a.run[v] != a.run[y] || (a.state[v] != 1 && a.state[v] != 3)) continue;
      above = above || v < y;
      below = below || v > y;
      const double dv = v - y;
      const double c = a.colQ8[v];
      n += 1.0;
      sv += dv;
      sc += c;
      svv += dv * dv;
      svc += dv * c;
    }
    const double det = n * svv - sv * sv;
    a.stack[y] = n >= 4.0 && above && below && det > 0.0
                     ? static_cast<int32_t>(std::lround((sc * svv - sv * svc) / det))
                     : a.colQ8[y];
  }
  return kept;
}

// New segments appended to out.segments after its first nOld, in order of first row, take
// their places by first row, an older segment first on a tie (placeMatchedSegments() then
// moves them there). renumberOlderRows: the rows of the older segments (out.rows holds no
// other yet) move down by the new ones that start before theirs. newSegmentIndex: the final
// index of the k-th new one, its order among the new ones after every older one starting no
// later.
void renumberOlderRows(LaserLine& out, size_t nOld) {
  const auto newBefore = [&](int firstRow) {
    int32_t n = 0;
    for (size_t j = nOld; j < out.segments.size(); ++j) n += out.segments[j].firstRow < firstRow ? 1 : 0;
    return n;
  };
  for (RowSample& r : out.rows)
    if (r.segment >= 0) r.segment += newBefore(out.segments[static_cast<size_t>(r.segment)].firstRow);
}

int32_t newSegmentIndex(const LaserLine& out, size_t nOld, int32_t k) {
  const int first = out.segments[nOld + static_cast<size_t>(k)].firstRow;
  int32_t older = 0;
  for (size_t i = 0; i < nOld; ++i) older += out.segments[i].firstRow <= first ? 1 : 0;
  return k + older;
}

// One new segment per kept run (appended to out.segments, in order of first row; runs beyond
// the segments' reserved capacity join the last new one, so that no frame allocates), the
// line's rows renumbered for their place among them, and each kept run's final segment
// index into segOf (run -> index). placeMatchedSegments() then moves the new segments there.
// Ties keep an older segment before a new one with the same first row.
void addMatchedSegments(int h, int roiY, const MatchedArrays& a, LaserLine& out) {
  const size_t nOld = out.segments.size();
  const size_t room = out.segments.capacity() - nOld;
  std::fill(a.segOf, a.segOf + h, -1);
  int32_t k = 0;
  for (int y = 0; y < h; ++y) {
    if (a.state[y] != 3) continue;
    int32_t& j = a.segOf[a.run[y]];
    if (j < 0) {
      if (k == 0 || static_cast<size_t>(k) < room) {
        j = k++;
        LineSegment seg;
        seg.firstRow = roiY + y;
        out.segments.push_back(seg);
      } else {
        j = k - 1;
      }
    }
    LineSegment& seg = out.segments[nOld + static_cast<size_t>(j)];
    seg.lastRow = roiY + y;
    ++seg.rows;
  }
  renumberOlderRows(out, nOld);
  for (int run = 0; run < h; ++run)
    if (a.segOf[run] >= 0) a.segOf[run] = newSegmentIndex(out, nOld, a.segOf[run]);
}

// The new segments (appended by addMatchedSegments or addRerunSegments, in order of first
// row) moved into their places by first row, after the older segments that start no later:
// the indices newSegmentIndex gave. A stable insertion sort (in place: std::stable_sort may
// allocate); both parts were in order.
void placeMatchedSegments(LaserLine& out) {
  auto& segs = out.segments;
  for (size_t j = 1; j < segs.size(); ++j) {
    size_t i = j;
    while (i > 0 && segs[i - 1].firstRow > segs[j].firstRow) --i;
    if (i < j)
      std::rotate(segs.begin() + static_cast<std::ptrdiff_t>(i), segs.begin() + static_cast<std::ptrdiff_t>(j),
                  segs.begin() + static_cast<std::ptrdiff_t>(j) + 1);
  }
}

// Rows of a laser-off-subtracted ROI with no sample at all, filled from a filter matched to
// the line's profile (docs/lle.md, "The sunlit line through a matched filter"): where bRCE
// decides each pixel against two others, the filter sums the whole profile. Rows at
// LleParams::matchedSeedSigmas of their row's spread start a run, rows at matchedJoinSigmas
// join one (growMatchedRuns); runs that touch the line's rows are kept whatever their
// length, others with minSegmentRows rows (keepMatchedRuns). The rows kept are kSegment
// samples of a new segment per run (addMatchedSegments): the 3D gate and the localizer's
// fit sort them, as they do other segments. The responses are integers; the spread, the
// parabola's vertex and the smoothing are computed in double, outside the arithmetics'
// templates (the same code for both).
void matchedFilterRows(const ImageView& frame, const ImageView& laserOff, const Roi& roi, const LleParams& p,
                       LleWorkspace& ws, LaserLine& out) {
  static const MatchedKernel kKernel;
  const int w = roi.width;
  const int h = roi.height;
  const auto uw = static_cast<size_t>(w);
  const auto uh = static_cast<size_t>(h);
  Arena arena(ws.scratch);  // one reserve per take (each take may pad to 16 bytes)
  for (int i = 0; i < 2; ++i) arena.reserve<int32_t>(uw);
  arena.reserve<int16_t>(uw);
  arena.reserve<int32_t>(uw);
  for (int i = 0; i < 5; ++i) arena.reserve<int32_t>(uh);
  arena.reserve<uint8_t>(uh);
  arena.commit();
  MatchedArrays a{arena.take<int32_t>(uw), arena.take<int32_t>(uw), arena.take<int16_t>(uw), arena.take<int32_t>(uw),
                  arena.take<int32_t>(uh), arena.take<int32_t>(uh), arena.take<uint8_t>(uh), arena.take<int32_t>(uh),
                  arena.take<int32_t>(uh), arena.take<int32_t>(uh)};
  std::fill(a.state, a.state + h, uint8_t{0});
  for (const RowSample& r : out.rows) {
    const int y = r.row - roi.y;
    if (y < 0 || y >= h) continue;
    if (r.status == RowStatus::kLine && a.state[y] != 1) {
      a.state[y] = 1;
      a.colQ8[y] = r.columnQ8 - roi.x * 256;
    } else if (a.state[y] == 0) {
      a.state[y] = 2;
    }
  }
  const int ro = redOffset(frame.format);
  const NoiseShares shares(matchedNoiseFloorDn(frame, laserOff, roi, ro), kKernel);
  for (int y = 0; y < h; ++y) {
    a.z[y] = 0;
    if (a.state[y] != 0) continue;
    const MatchedRow m = matchedRow(roiRow(&frame, roi, y), roiRow(&laserOff, roi, y), ro, w, kKernel, shares, a.resp,
                                    a.sorted, a.diff, a.level);
    if (m.x < 0) continue;
    a.z[y] = m.zCenti;
    // Sub-pixel: the vertex of the parabola through the three responses (within ±0.5 px).
    const int64_t den = 2 * (static_cast<int64_t>(m.left) - 2 * static_cast<int64_t>(m.mid) + m.right);
    const int64_t offQ8 = den != 0 ? (256 * (static_cast<int64_t>(m.left) - m.right)) / den : 0;
    a.colQ8[y] = m.x * 256 + static_cast<int32_t>(std::clamp<int64_t>(offQ8, -128, 128));
  }
  const int runs = growMatchedRuns(h, static_cast<int>(std::lround(100.0 * p.matchedSeedSigmas)),
                                   static_cast<int>(std::lround(100.0 * p.matchedJoinSigmas)),
                                   static_cast<int32_t>(std::lround(256.0 * p.maxJumpPx)), a);
  const int added = keepMatchedRuns(h, runs, p.minSegmentRows, p.smoothRows, a);
  if (added == 0) return;
  addMatchedSegments(h, roi.y, a, out);
  // The new samples merged into the rows (ascending by row), from the end.
  size_t src = out.rows.size();
  out.rows.resize(src + static_cast<size_t>(added));
  size_t dst = out.rows.size();
  for (int y = h - 1; y >= 0; --y) {
    const int row = roi.y + y;
    while (src > 0 && out.rows[src - 1].row > row) out.rows[--dst] = out.rows[--src];
    if (a.state[y] == 3) {
      RowSample sm;
      sm.row = row;
      sm.columnQ8 = a.stack[y] + roi.x * 256;
      sm.centroidQ8 = a.colQ8[y] + roi.x * 256;  // the row's own, before smoothing
      sm.column = static_cast<float>(sm.columnQ8) / 256.0F;
      sm.confidence = std::clamp(static_cast<float>(a.z[y]) / 1000.0F, 0.1F, 1.0F);
      sm.status = RowStatus::kSegment;
      sm.segment = a.segOf[a.run[y]];
      out.rows[--dst] = sm;
    }
  }
  placeMatchedSegments(out);
}

}  // namespace

int32_t kthSmallest(int32_t* v, int n, int k) {
  int32_t lo = v[0];
  int32_t hi = v[0];
  for (int i = 1; i < n; ++i) {
    lo = std::min(lo, v[i]);
    hi = std::max(hi, v[i]);
  }
  const auto span = static_cast<uint64_t>(static_cast<int64_t>(hi) - lo);
  int shift = 0;
  while ((span >> shift) >= 256U) ++shift;
  const auto bin = [&](int32_t x) {
    return static_cast<size_t>(static_cast<uint64_t>(static_cast<int64_t>(x) - lo) >> shift);
  };
  std::array<int, 256> count{};
  for (int i = 0; i < n; ++i) ++count[bin(v[i])];
  size_t b = 0;
  int below = 0;
  while (below + count[b] <= k) below += count[b++];
  int m = 0;
  for (int i = 0; i < n; ++i)
    if (bin(v[i]) == b) std::swap(v[m++], v[i]);
  std::nth_element(v, v + (k - below), v + m);
  return v[k - below];
}

// A short strong line's rerun (LleParams::shortLinePct) adds to its first pass and replaces
// nothing: the first pass's line, its fit and segments stay as they were, and each of the
// rerun's segments that crosses none of the first pass's samples (no sample of it within
// kCrossPx of one in the same row) joins them as another segment (kSegment; kEdge rows stay
// invalid). A rerun's lower bar lets other pieces into a line and its fit then drops rows
// of the target's own (docs/lle.md, "A short line is run again too"). A row keeps at most
// maxPeaksPerRow samples and the segments their reserved capacity: no frame allocates once
// the workspace has seen the ROI.
constexpr float kCrossPx = 3.0F;

void markCrossingSegments(const LaserLine& first, const LaserLine& rerun, std::vector<int32_t>& map) {
  map.reserve(rerun.segments.capacity());
  map.assign(rerun.segments.size(), 0);
  size_t i = 0;
  for (const RowSample& r : rerun.rows) {
    if (r.segment < 0) continue;
    while (i < first.rows.size() && first.rows[i].row < r.row) ++i;
    for (size_t j = i; j < first.rows.size() && first.rows[j].row == r.row; ++j)
      if (std::abs(first.rows[j].column - r.column) < kCrossPx) map[static_cast<size_t>(r.segment)] = -1;
  }
}

// `out` holds the first pass, `rerun` the rerun's result; ws.mergedRows and ws.segmentMap are
// the workspace's.
void addRerunSegments(const LaserLine& rerun, const LleParams& p, LleWorkspace& ws, LaserLine& out) {
  std::vector<int32_t>& map = ws.segmentMap;
  markCrossingSegments(out, rerun, map);
  const size_t nOld = out.segments.size();
  size_t added = 0;
  for (size_t k = 0; k < rerun.segments.size(); ++k) {
    if (map[k] < 0 || rerun.segments[k].rows == 0 || nOld + added >= out.segments.capacity()) {
      map[k] = -1;
      continue;
    }
    LineSegment seg = rerun.segments[k];
    seg.onLine = false;
    out.segments.push_back(seg);
    map[k] = static_cast<int32_t>(added++);
  }
  if (added == 0) return;
  renumberOlderRows(out, nOld);
  for (int32_t& m : map)
    if (m >= 0) m = newSegmentIndex(out, nOld, m);
  // Rows merged by row: the first pass's samples of a row first, then the rerun's.
  std::vector<RowSample>& merged = ws.mergedRows;
  merged.clear();
  merged.reserve(out.rows.capacity());
  size_t i = 0;
  for (size_t j = 0; j <= rerun.rows.size(); ++j) {
    const int row = j < rerun.rows.size() ? rerun.rows[j].row : INT32_MAX;
    while (i < out.rows.size() && out.rows[i].row <= row) merged.push_back(out.rows[i++]);
    if (j == rerun.rows.size()) break;
    const RowSample& r = rerun.rows[j];
    if (r.segment < 0 || map[static_cast<size_t>(r.segment)] < 0) continue;
    if (!merged.empty() && merged.back().row == row) {
      int n = 0;
      for (size_t b = merged.size(); b > 0 && merged[b - 1].row == row; --b) ++n;
      if (n >= p.maxPeaksPerRow) continue;
    }
    RowSample sm = r;
    sm.segment = map[static_cast<size_t>(r.segment)];
    sm.inlier = false;
    if (sm.status != RowStatus::kEdge) sm.status = RowStatus::kSegment;
    merged.push_back(sm);
  }
  out.rows.swap(merged);
  placeMatchedSegments(out);
}

template <class A>
void extractRobust(const ImageView& frame, const ImageView* laserOff, const Roi& roi, const LleParams& p,
                   const SimdKernels* kernels, LleWorkspace& ws, LaserLine& out) {
  candidateMask(frame, laserOff, roi, p, kernels, ws, 1);
  const int strength = focusRobust<A>(frame, laserOff, roi, p, 1, p.strongThreshold(), ws, out);
  // With the laser-off frame subtracted, what is left besides the line is noise, not
  // ambient texture: the rerun may go lower there (docs/lle.md "weak line").
  const int lowPct = laserOff != nullptr ? p.subtractedLineThresholdPct : p.weakLineThresholdPct;
  const bool weak = strength < p.weakLineExcessDn;
  const bool shortLine = out.inliers * 100 < p.shortLinePct * roi.height;
  if (p.weakLineExcessDn <= 0 || (!weak && !shortLine) || lowPct >= p.robustThresholdPct) return;
  // A strong short line is kept; the rerun only adds the segments beside it (addRerunSegments).
  if (!weak) std::swap(out, ws.held);
  LleParams low = p;
  low.robustThresholdPct = lowPct;
  reserveOutput(roi, low, out);
  // There, too, the difference is averaged over rows where asked: more signal per decision.
  const int rows = laserOff != nullptr ? p.subtractedRows : 1;
  candidateMask(frame, laserOff, roi, low, kernels, ws, rows);
  // rerunOthersFirm: its segments off the line still need the first pass's strong bar (listSegments).
  focusRobust<A>(frame, laserOff, roi, low, rows, p.rerunOthersFirm ? p.strongThreshold() : low.strongThreshold(), ws,
                 out);
  if (laserOff != nullptr && p.matchedFilter) matchedFilterRows(frame, *laserOff, roi, p, ws, out);
  if (weak) return;
  std::swap(out, ws.held);
  addRerunSegments(ws.held, p, ws, out);
}

template <class A>
void focusPaper(const Roi& roi, const LleParams& p, LleWorkspace& ws, LaserLine& out) {
  using Col = typename A::Col;
  const int w = roi.width;
  const int h = roi.height;
  const int words = paddedWidth(w) / 64;
  const auto uh = static_cast<size_t>(h);
  Arena arena(ws.scratch);
  arena.reserve<int32_t>(uh);
  arena.reserve<Col>(uh);
  arena.reserve<uint8_t>(uh);
  arena.reserve<int32_t>(uh);
  arena.reserve<int64_t>(3 * uh);
  arena.commit();
  int32_t* fitRows = arena.take<int32_t>(uh);
  Col* fitCols = arena.take<Col>(uh);
  uint8_t* use = arena.take<uint8_t>(uh);
  int32_t* counts = arena.take<int32_t>(uh);
  int64_t* fitScratch = arena.take<int64_t>(3 * uh);
  // Line focusing as printed: the mean of the candidate columns of each row.
  int n = 0;
  for (int y = 0; y < h; ++y) {
    if (ws.rowAny[static_cast<size_t>(y)] == 0) continue;
    const uint64_t* bits = ws.bits.data() + static_cast<size_t>(y) * static_cast<size_t>(words);
    int64_t sumX = 0;
    int count = 0;
    for (int x = focus::nextSet(bits, w, 0); x < w; x = focus::nextSet(bits, w, x + 1)) {
      sumX += x;
      ++count;
    }
    if (count == 0) continue;
    fitRows[n] = roi.y + y;
    fitCols[n] = A::ratio(sumX, count) + A::fromInt(roi.x);
    use[n] = 1;
    counts[n] = count;
    ++n;
  }
  // Curve fitting as printed: least squares, every focused row counts.
  typename A::Fit fit;
  if constexpr (A::kFixed) fit.scratch = fitScratch;
  const bool fitted = n >= p.minRows && fit.fit(fitRows, fitCols, use, n, std::min(p.polyOrder, n - 1),
                                               fitRows[0], fitRows[n - 1]);
  double sumSq = 0.0;
  for (int i = 0; i < n; ++i) {
    RowSample sm;
    sm.row = fitRows[i];
    sm.columnQ8 = A::toQ8(fitCols[i]);
    sm.centroidQ8 = sm.columnQ8;
    sm.column = A::toFloat(fitCols[i]);
    sm.status = RowStatus::kLine;
    sm.inlier = true;
    sm.confidence = static_cast<float>(std::min(counts[i], 4)) / 4.0F;
    out.rows.push_back(sm);
    if (fitted) {
      const double d = A::toPx(A::absDiff(fitCols[i], fit.eval(fitRows[i])));
      sumSq += d * d;
    }
  }
  out.inliers = n;
  if (n > 0) {
    out.firstLineRow = fitRows[0];
    out.lastLineRow = fitRows[n - 1];
    out.coverage = static_cast<double>(n) / (out.lastLineRow - out.firstLineRow + 1);
  }
  if (fitted) {
    fit.describe(out);
    out.valid = true;
    out.rmsResidualPx = std::sqrt(sumSq / n);
  }
}

template void extractRobust<FixedArith>(const ImageView&, const ImageView*, const Roi&, const LleParams&,
                                        const SimdKernels*, LleWorkspace&, LaserLine&);
template void extractRobust<FloatArith>(const ImageView&, const ImageView*, const Roi&, const LleParams&,
                                        const SimdKernels*, LleWorkspace&, LaserLine&);
template void focusPaper<FixedArith>(const Roi&, const LleParams&, LleWorkspace&, LaserLine&);
template void focusPaper<FloatArith>(const Roi&, const LleParams&, LleWorkspace&, LaserLine&);

}  // namespace alacs::image::detail
