// Laser Line Extraction (LLE): from one frame to the sub-pixel column of the laser line
// in each row of a region of interest. docs/lle.md has the why and the measurements.
//
// Two methods share the first two stages:
//   1. bRCE: a pixel is a laser candidate when its red value exceeds BOTH neighbours
//      `step` columns away by more than `threshold`. (Algorithm 1 as printed subtracts
//      the centre from its neighbours; on 8-bit data that wraps. We implement its
//      meaning; `BrceForm::kLiteral` keeps the printed form for comparison.)
//   2. Noise removal: the paper's sliding-window count (window W/4 × H/2, stride γ,
//      threshold θ) clears windows with too few candidates.
// kPaper then does what the paper prints:
//   3. line focusing: the mean of the candidate columns of each row;
//   4. a least-squares 4th-order polynomial column = p(row).
// kRobust (the default) instead:
//   3. takes each run of candidates as a peak and computes the intensity-weighted centroid
//      of the red excess over the local background (sub-pixel);
//      (Candidates are taken at weakThresholdPct of the threshold; a segment must have rows
//      that pass the threshold itself: hysteresis, so weak lines in bright light are kept.)
//   4. links the peaks of successive rows into segments by continuity, grows a line from
//      each of the strongest segments (the segments that continue it across gaps), keeps
//      the one strongest after a weight on its distance from the ROI's centre, and fits the
//      polynomial robustly (rows beyond max(outlierPx, 3·1.4826·MAD) are rejected);
//   5. reports per row a confidence and a status, and the line's segments and coverage.
//
// Arithmetic: stages 1–4 are integer/fixed point (Q formats in lle_internal.h and
// docs/lle.md), bit-exact between the scalar path and the SIMD path (OpenCV universal
// intrinsics: NEON on Arm, SSE2/AVX2 on x86). `extractLineReference` is the same algorithm
// in double precision, the reference the fixed-point result is tested against.
//
// Buffers live in an `LleWorkspace`; with the `LaserLine&` overload, extraction allocates
// nothing once the workspace and the output have seen a ROI of that size.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "common/result.h"
#include "image/image_view.h"

namespace alacs::image {

enum class BrceForm : uint8_t {
  kMeaning,  // centre - neighbour > th, on both sides (default)
  kLiteral,  // the printed Algorithm 1 on uint8 (wrapping) arithmetic, for comparison
};

enum class LleMethod : uint8_t {
  kRobust,  // sub-pixel centroids, continuity, robust fit (default)
  kPaper,   // the paper's four steps as printed (with bRCE's meaning unless kLiteral)
};

enum class LleKernels : uint8_t {
  kAuto,    // the SIMD kernels when the build has them (bit-exact with kScalar)
  kScalar,  // the scalar reference kernels
};

// Largest frame side accepted; larger frames are refused (kBadInput) rather than risk
// overflowing the per-column counters.
constexpr int kLleMaxSidePx = 16384;

struct LleParams {
  LleMethod method = LleMethod::kRobust;
  int brceStep = 4;          // columns between a pixel and each neighbour it is compared with (1..64)
  int brceThreshold = 40;    // red-level margin over both neighbours (0..254)
  BrceForm brceForm = BrceForm::kMeaning;
  int noiseTheta = 8;        // θ: a window with at most this many candidates is cleared (0..1e8)
  int noiseGamma = 3;        // γ: horizontal stride of the sliding window, px (1..4096)
  int polyOrder = 4;         // order of the fitted curve column = p(row) (1..6)
  double outlierPx = 2.0;    // kRobust: residual beyond which a row is rejected from the fit (0.1..100)
  int minRows = 8;           // fewer line rows than this: no line (polyOrder+1..16384)
  // kRobust only:
  int robustThresholdPct = 100;  // kRobust's strong threshold: this share of brceThreshold
                             // (10..100). 60 (40 -> 24) finds the line in full sun behind a
                             // band-pass filter (docs/lle.md), at ~5 % more time per full frame
  int weakLineExcessDn = 64; // adaptive: when the line found is weak (median peak excess of its
                             // rows below this, DN, or no line), run again with the strong
                             // threshold at weakLineThresholdPct of brceThreshold (0: off, ..255)
  int weakLineThresholdPct = 60;  // (10..100)
  // ... and so is a short line, however strong: one with fewer kLine rows than this share
  // of the ROI's height (0: off, ..100). The ROI is planned round the target, so a short
  // line is a fruit mostly hidden, or a neighbour's line that crosses a few of its rows,
  // where the target's own fainter light beside it may lie under the strong bar; the
  // rerun reports it as another segment and the localizer tells them apart in 3D
  // (docs/lle.md, "A short line is run again too").
  int shortLinePct = 20;
  // The rerun's threshold instead, when a laser-off frame was subtracted (10..100): ambient
  // light is gone from the difference, so only its noise (1-3 DN in full sun) sets how low
  // it may go (docs/lle.md).
  int subtractedLineThresholdPct = 25;
  // ... and that rerun decides on the difference averaged over this many rows (1: the row
  // alone; 3: [1 2 1]/4 of the rows above, at and below, within the ROI), for its peaks'
  // sums as well: the difference's noise falls by 0.6 while a near-vertical line's signal
  // stays. The first pass, and every frame without a laser-off frame, use the row alone.
  // 3 with the threshold at 15 finds more of a sunlit line, but on the worlds it also lets
  // in other surfaces' weak segments: not the default (docs/lle.md).
  int subtractedRows = 1;
  // Either rerun lowers its bar to find a weak line: with this, its segments off the line
  // are reported only when two of their rows pass the first pass's strong threshold, as the
  // first pass would have required. With 3 rows at 15 % it gains on the tuning worlds and
  // loses on the second world: not the default (docs/lle.md, "The rerun's other segments").
  bool rerunOthersFirm = false;
  // After that rerun of a laser-off-subtracted frame, rows with no sample at all are filled
  // from a filter matched to the line's profile (a Gaussian of 1.5 px less its mean over
  // ±8 px), which sums the whole profile where bRCE compares a pixel with two: a row at
  // this many of its row's robust spread starts a run, one at matchedJoinSigmas joins a
  // run within 2 rows whose column it continues; their rows are kSegment samples of one
  // segment (docs/lle.md, "The sunlit line through a matched filter") (2..50).
  // With it on (the default), every subtracted rerun runs it, as alacs_lle with a laser-off
  // frame does; the localizer turns it on only where the metering also found the ambient
  // bright (direct sun: Localizer::observe's brightAmbient), since elsewhere a weak line's
  // frames hold leaves and neighbours at the filter's bar as well, and the tuning worlds'
  // fits lost as much as they gained there (docs/lle.md).
  bool matchedFilter = true;
  double matchedSeedSigmas = 5.0;
  double matchedJoinSigmas = 3.0;  // (1..matchedSeedSigmas)
  int weakThresholdPct = 75; // hysteresis: candidates at this share of the strong threshold; a
                             // segment needs two rows, and a quarter of its rows, whose margin
                             // exceeds the strong threshold itself (10..100; 100: no hysteresis)
  int maxPeaksPerRow = 4;    // strongest runs of a row considered by the continuity step (1..8)
  double maxJumpPx = 2.0;    // a peak continues a segment when within this of its prediction (0.25..64)
  int maxGapRows = 3;        // rows a segment may skip and still continue (0..64)
  int minSegmentRows = 6;    // shorter segments are noise (1..16384)
  double bridgePx = 3.0;     // two segments are one line when their ends, extrapolated to the
  double bridgePxPerRow = 0.08;  // middle of the gap between them, agree within bridgePx + this·gap
  bool keepOtherSegments = true;  // also report segments that are not the line (other surfaces)
  double centrePriorShare = 0.15;  // the line is the one, grown from one of the strongest segments, whose
                                   // rows' strengths, each times a Gaussian weight on the row's offset from the ROI's
                                   // centre (σ = this share of the ROI's width and height; the ROI is planned round the
                                   // target), sum largest; 0: grown from the strongest segment (0, 0.02..10)
  int smoothOrder = 1;       // of that local fit: 0 mean, 1 line, 2 quadratic
  int smoothRows = 8;        // a row's column: local fit through the centroids within ±this many rows (0: none) (0..32)
  int edgeRatio = 3;         // occluding edge: the background on one side of a run is darker than
                             // edgeRatio x the other's (less 8 DN): the profile may be cut by an
                             // occluder's edge; the row is kEdge (invalid) (0: off, 2..16)
  double edgeAgreePx = 0.5;  // ... unless its centroid agrees within this with the straight line
                             // through >= 4 other rows of its line or segment within ±smoothRows (0..8)
  LleKernels kernels = LleKernels::kAuto;

  Status validate() const;
  // kRobust: the strong threshold, robustThresholdPct of brceThreshold; kPaper: brceThreshold.
  int strongThreshold() const {
    return method == LleMethod::kRobust ? brceThreshold * robustThresholdPct / 100 : brceThreshold;
  }
  // The threshold bRCE runs with: brceThreshold, or the weak share of the strong one for kRobust.
  int detectionThreshold() const {
    return method == LleMethod::kRobust ? strongThreshold() * weakThresholdPct / 100 : brceThreshold;
  }
};

enum class RowStatus : uint8_t {
  kLine,     // on the line and accepted by its curve fit
  kOutlier,  // on the line's segments but rejected by the robust fit: INVALID, do not use
  kSegment,  // a laser segment that is not the line (another surface); valid, not fitted
  kEdge,     // at an occluding edge (the background steps across the peak: part of the profile
             // may be hidden, its centroid biased): INVALID, do not use
};

// One row of the extracted line, in full-frame pixels (pixel centres at integers).
struct RowSample {
  int row = 0;
  float column = 0.0F;      // sub-pixel column; exactly columnQ8 / 256
  float confidence = 0.0F;  // 0..1, see docs/lle.md; 0 for invalid rows
  bool inlier = false;      // status == kLine (accepted by the curve fit)
  RowStatus status = RowStatus::kLine;
  bool saturated = false;   // the peak's red core was clipped at 255
  int32_t segment = -1;     // index into LaserLine::segments, -1: none
  int32_t columnQ8 = 0;     // the fixed-point result, Q24.8 (1/256 px)
  int32_t centroidQ8 = 0;   // this row's own centroid before smoothing along the line, Q24.8

  bool valid() const { return status != RowStatus::kOutlier && status != RowStatus::kEdge; }
};

// A run of rows linked by continuity.
struct LineSegment {
  int firstRow = 0;
  int lastRow = 0;
  int rows = 0;          // rows with a sample of this segment
  bool onLine = false;   // part of the line (kLine/kOutlier rows) rather than another surface
};

struct LaserLine {
  // Ascending by row. A row has at most one sample of the line (kLine or kOutlier), which
  // comes first, then one per other segment crossing it (kSegment), stronger first: where
  // a leaf or a second fruit also carries the laser, both are reported and the caller
  // tells them apart in 3D.
  std::vector<RowSample> rows;
  std::vector<LineSegment> segments;  // in order of first row
  // column = Σ coeffs[k] * t^k with t = (row - rowCenter) / rowHalfSpan
  std::array<double, 8> coeffs{};
  int order = 0;
  double rowCenter = 0.0;
  double rowHalfSpan = 1.0;
  bool valid = false;            // a curve was fitted
  int inliers = 0;               // rows with status kLine
  double rmsResidualPx = 0.0;    // of the kLine rows about the curve
  // Coverage of the line: its first and last kLine rows, and the share of the rows in
  // between that have a kLine sample (1 = unbroken; 1 - coverage = occluded or rejected).
  int firstLineRow = 0;
  int lastLineRow = -1;
  double coverage = 0.0;

  double columnAt(double row) const;
  // The first sample of `row` (the line's when it has one), or nullptr when the row has
  // none (no line there: invalid).
  const RowSample* sampleAt(int row) const;
  void clear();
};

// Reusable buffers (internal layout). Not thread-safe: one per worker. Copyable.
struct LleWorkspace {
  std::vector<uint8_t> red;          // one padded red row
  std::vector<uint8_t> redRows;      // the last three rows of the difference (averaged rerun)
  std::vector<uint8_t> validLanes;   // 1 where bRCE may fire
  std::vector<uint16_t> counts;      // per column candidate counts of the current band
  std::vector<uint8_t> counts8;      // the same over the last < 256 rows
  std::vector<int32_t> prefix;       // prefix sums / clear coverage of a band
  std::vector<uint64_t> bits;        // candidate mask of the ROI, one bit per pixel
  std::vector<uint8_t> rowAny;       // per ROI row: any candidate left
  std::vector<uint64_t> clearBits;   // columns cleared by noise removal in a band
  std::vector<uint8_t> scratch;      // peaks, segments, fit buffers (typed views)
  LaserLine held;                    // a short line's first pass, while its rerun runs
  std::vector<RowSample> mergedRows;  // the first pass's rows and the rerun's segments beside them
  std::vector<int32_t> segmentMap;    // the rerun's segment -> its index among the first pass's (-1: dropped)
  int roiWidth = -1;
  int brceStep = -1;
};

// bRCE on one row of red values with pixel pitch `pitch` (3 for RGB888): writes
// mask[x] = 1 for candidates, 0 otherwise, for x in [0, width). Scalar reference.
void brceRow(const uint8_t* red, int pitch, int width, int step, int threshold, BrceForm form,
             uint8_t* mask);

// Runs LLE on `roi` of `frame` into `out` (cleared first). With `laserOff` (a frame of the
// same size and format taken with the laser off), its red is subtracted first, removing
// ambient light. Errors: kInvalidArgument for bad params; kBadInput for an empty or
// oversized frame, an unknown pixel format, a stride below width·3, a laser-off frame of
// another size or format, an empty ROI or one that leaves the frame. Allocates nothing
// once `ws` and `out` have seen a ROI this size. Thread-safe for distinct ws/out.
Status extractLine(const ImageView& frame, const Roi& roi, const LleParams& params, LleWorkspace& ws,
                   LaserLine& out, const ImageView* laserOff = nullptr);

// The same, returning a fresh LaserLine (allocates the result).
Result<LaserLine> extractLine(const ImageView& frame, const Roi& roi, const LleParams& params,
                              LleWorkspace& ws);

// The floating-point reference: the same algorithm with centroids, predictions and the
// curve fit in double precision (Eigen QR), scalar kernels. For tests and tools; slow,
// allocates. Same errors as extractLine.
Status extractLineReference(const ImageView& frame, const Roi& roi, const LleParams& params,
                            LaserLine& out, const ImageView* laserOff = nullptr);

// Which kernels `LleKernels::kAuto` runs in this process: "scalar", "sse2", "avx2", "neon".
const char* lleSimdName();

}  // namespace alacs::image
