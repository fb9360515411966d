// Localization of one target apple from the laser lines of a scan. Pure logic: frames
// and slide positions in, an estimate out; no device, thread or clock (docs/geometry.md).
//
//   plan:      rough position (from the arm's RGB-D camera) -> slide stops + image ROI
//   observe:   LLE on the ROI, triangulation of every row, gating around the target
//   estimate:  robust sphere fit to the points of every line (beyond the paper): centre,
//              diameter, approach point and normal, σ and confidence; when the lines
//              cannot fix a sphere, the paper's single-line candidate
//   estimateSingleLine: the paper's method alone (P = ω1·N − ω2·Δd), for comparison
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"
#include "geometry/sphere_fit.h"
#include "geometry/triangulation.h"
#include "image/lle.h"

namespace alacs::localize {

struct ScanParams {
  // The first pass: seven stops 13.3 mm apart over the paper's 80 mm span (the paper: five
  // stops 2 cm apart). More lines on the fruit leave fewer fits on two or three lines, whose
  // diameter is off by 4 mm at 1.6 m; in a continuous sweep the extra frames cost no motion
  // (docs/geometry.md "Accuracy on the twin", docs/daemon.md "Cycle time").
  int stops = 7;
  double stopSpacingMm = 13.3;
  double roiMarginMm = 35.0;     // added to the largest apple radius around the rough position
  double maxAppleRadiusMm = 50.0;
  double gateMm = 90.0;          // 3D points farther than this from the rough centre are not the target
  // The widened search: when the lines within the gate fit no sphere (nothing there, or one
  // line only), the points the scan saw up to searchMm from the rough position are fitted
  // to the fruit model with a weak prior on where it is. A rough position 100 mm short in
  // depth then still gives the fruit, flagged outsideGate and with its confidence capped
  // at outsideGateConfidencePct (it may be a neighbour of the fruit the arm meant).
  // 0: off (the gate alone). docs/geometry.md "The widened search".
  double searchMm = 250.0;
  double outsideGateConfidencePct = 50.0;
  // The paper's candidate score P = ω1·N − ω2·Δd (N: the line's pixels on the target,
  // Δd: px from the expected centre). Only ω2/ω1 matters; chosen by 5-fold
  // cross-validation on the twin (docs/geometry.md, tools/geometry_eval).
  double paperW1 = 1.0;
  double paperW2 = 2.0;
  // Sphere fit: a prior on the radius (dessert apples: 65–95 mm) that ranks RANSAC's
  // candidates and, weakly, steadies the fit when the lines fix little (a small cap).
  double priorRadiusMm = 40.0;
  double priorRadiusSigmaMm = 6.0;
  double minRadiusMm = 27.5;      // what counts as an apple: 55–105 mm across
  double maxRadiusMm = 52.5;
  // Apples are a little oblate about the stem: the sphere is refined into a spheroid with
  // these priors (aspect = height/width; the stem's tilt from "up" in the camera frame,
  // σ per axis of the tilt's two angles). The tilt's was 20°: fruit hang with the stem
  // leaning 50° and more, and a prior that held them near vertical put the centre
  // millimetres off with a σ that did not cover it. 30° chosen on the tuning worlds; from
  // 35° on, a round fruit in full view may take an oblate shape facing the camera
  // (docs/geometry.md, "The stem's tilt").
  bool spheroid = true;
  double priorAspect = 0.9;
  double priorAspectSigma = 0.1;
  double stemTiltSigmaDeg = 30.0;
  // The largest sphere the sphere fit may take for a fruit (its search, its refinement and
  // the one-line fit alike): the longest semi-axis of the largest fruit (equatorial radius
  // maxRadiusMm) at the aspect prior's 2σ, maxRadiusMm × max(1, priorAspect +
  // 2·priorAspectSigma) (57.75 mm by default). A prolate or lumpy fruit curves flatter than
  // its equatorial radius where the vertical lines cut it (c²/a at the equator), so its
  // sphere comes out larger than maxRadiusMm, and was refused as no fruit; the spheroid
  // refinement then sets the shape and size. A fit on a few central lines of the largest
  // such fruit comes out larger still and is refused (docs/geometry.md).
  double sphereMaxRadiusMm() const;
  // The rough position's error, 1σ per axis (the RealSense D435i's, paper Table 2:
  // 16–21.5 mm mean 3D error at 1.0–1.6 m). Among the spheres the lines support, the one
  // near the rough position is the target, not its neighbour; with one line only, it
  // helps place the centre.
  double roughSigmaMm = 15.0;
  // What one line (or the paper's candidate) says is not taken when it puts the centre
  // farther than this many roughSigmaMm from the rough position (a 3D distance of 4σ has a
  // chance of 1e-3 from the rough position's error alone): a short arc of a leaf's edge
  // or of a neighbour, not the target. The estimate is then the rough position's own, with
  // its σ. 0: off. Multi-line spheres are not gated (their centre is measured).
  double roughGateSigmas = 4.0;
  // Adaptive scan (docs/geometry.md "The second pass"): a second pass of stops when the
  // first pass leaves the fit in doubt:
  //   - fewer than `followUpMinLines` lines reached the fit (a leaf hides the others, or the
  //     rough position centred the stops beside the fruit): the priors set the centre;
  //   - the fruit is mostly hidden: at least `followUpHiddenPct` of its expected rows did
  //     not reach the fit (0: not a reason);
  //   - another object explains the same lines about as well (Doubt::kTwoSurfaces);
  //   - the fit is more likely another object, away from the rough position
  //     (Doubt::kFarFromRough): the new stops then go round the rough position instead;
  //   - its diameter's 1σ above `followUpDiameterSigmaMm` (0, the default: not a reason;
  //     three lines far away leave the diameter to ±4 mm and more).
  // The new stops are denser (a third of the spacing) and placed where the first pass saw
  // the fruit: round the stops whose line put points on it, one spacing either side; at
  // most `followUpMaxStops` of them, the nearest the middle of what was seen first. All the
  // lines are then fused. 0 stops: off (the paper's scan).
  // When the first pass saw nothing of the fruit (no line put points on it, or what the
  // lines saw is likely another object: far from the rough position), there is no span to
  // follow: the target may show through any gap in the leaves across its width round the
  // rough position, and the cap is `followUpUnseenMaxStops` instead (docs/geometry.md).
  // The rough position standing in with one line alone in the gate, the new stops span
  // from round the rough position to one spacing round that line (a lone line: the rough
  // position may be off along the slide), under the same cap.
  // Honest uncertainty (docs/geometry.md "Honest uncertainty"): a fitted fruit may be
  // another object than the target (a touching neighbour, a leaf and the fruit bent into
  // one sphere). The chance that it is the target weighs how far its centre lies from the
  // rough position (the RGB-D error above, against "anywhere in the gate"; this prior share
  // of other objects) and how well the best rival object explains the same lines. σ is
  // that mixture's (the other object's error is its distance from the rough position);
  // the confidence is multiplied by the chance. Set a priori, not tuned on a benchmark.
  // 0: off (σ and confidence from the fit alone).
  double otherObjectPrior = 0.1;
  // A fit within the gate that is more likely another object than the target (its centre
  // far from the rough position: Doubt::kFarFromRough) locates that other object, not the
  // target. The points off its surface are fitted again first (estimateBesideOther: a
  // sphere there on three lines or more, likelier the target, goes out as found); else the
  // best estimate of the target is the rough position's own (its σ, low confidence), and
  // the bus says ROUGH_ONLY with reason FAR_FROM_ROUGH. On the tuning
  // worlds not one such fit was within 20 mm of the target (docs/geometry.md). false: the
  // fit goes out, AMBIGUOUS (before issue 17's last change). A fit of the widened search
  // (OUTSIDE_GATE) is treated alike when the lines lit something within the gate (the
  // target may be there, hidden); when the gate saw nothing at all, the rough position is
  // what is off, and the fruit found beyond goes out as found (issue 16).
  bool roughWhenFarFromRough = true;
  // What no fit's covariance holds, because it does not average out over a line's points:
  // a bias of the whole laser line in the image (the LLE's mean error on the twin's tuning
  // worlds is 0.09-0.11 px, docs/lle.md), carried through the triangulation at the
  // approach point, and the calibration's own 3D error at that depth (the file's
  // quality.sigma_3d_total_mm_at_*; 0 when the file has none). Both are added to σ in
  // quadrature (docs/geometry.md "Honest uncertainty"). 0: no line bias.
  double lineBiasPx = 0.1;
  // Nor does a fruit's departure from the fitted spheroid: ridges, lobes and bumps put the
  // skin off the smooth shape by a few per cent of the radius, over areas as wide as a
  // line's cut, so the few lines of a fit do not average them out, and the fit's residual
  // hides most of them (the spheroid bends to them). This share of the fitted radius goes
  // into σ (the approach point's and the centre's) in quadrature (docs/geometry.md "Honest
  // uncertainty"). 2 %, a priori (the lumpy fruit of the twin's hard cases have bumps of 2-6 %
  // of the radius). 0: a spheroid is taken as exact.
  double shapeIrregularityPct = 2.0;
  // The sunlit line along its arc (localize/weak_arc.h, docs/lle.md): where the laser-off
  // frame was subtracted, the arc of a fruit's cut that the per-row extraction missed is
  // searched by its summed contrast and followed row by row when it clears this score
  // (the summed contrast over its noise; the best of some 3000 arcs of noise alone scores
  // about 4). Its points join the fit only when the lines alone leave the target unseen
  // (estimate()). 0: off.
  double weakArcMinZ = 8.0;
  // Leaves told from skin by their colour where the laser-off frame shows it: a line
  // sample whose own pixel in that frame is at least this many times greener than red,
  // (G + 1) ≥ ratio · (R + 1), lies on a leaf (chlorophyll reflects 2-3 times more green
  // than red) and not on a red or bicolour fruit (whose yellow-green ground colour is about
  // even): it joins no fit; so do up to 4 samples of the same segment at the leaf's edge
  // (within 4 rows of 3 or more green ones), whose pixels take the colour of what lies
  // beside it (localize/leaf_colour.h). Only where a laser-off frame is held (metering
  // chose to subtract). 0: off (green varieties), else 1.1..10. docs/geometry.md "Leaves
  // told by their colour".
  double leafGreenRatio = 1.4;
  int followUpMinLines = 3;
  double followUpHiddenPct = 60.0;
  double followUpDiameterSigmaMm = 0.0;
  int followUpMaxStops = 6;
  int followUpUnseenMaxStops = 6;
  // A fit whose centre lies farther from the rough position than this many roughSigmaMm
  // (3D distance) also has the second pass look round the rough position, as a fit more
  // likely another object does (Doubt::kFarFromRough), though the doubt model still takes
  // it for the target: a touching neighbour lies about that far, and where the lines missed
  // the target (sunlit skin), the neighbour is all they saw. The rough position's own error
  // puts a target beyond 2.5σ in 10 % of scans (Maxwell); on the twin's hard cases it asks
  // for 1.7 % more second passes (docs/geometry.md, "A fit far from the rough position
  // looks again"). 0: off.
  double followUpFarSigmas = 2.5;
  Status validate() const;
  // The paper's scan: these defaults with five stops 2 cm apart (the twin's benchmark
  // scans, and the tests built on them).
  static ScanParams paperScan() {
    ScanParams p;
    p.stops = 5;
    p.stopSpacingMm = 20.0;
    return p;
  }
};

struct ScanPlan {
  std::vector<double> stopsMm;   // commanded slide positions, in scan order
  image::Roi roi;                // where the target can appear
  Eigen::Vector3d roughMm = Eigen::Vector3d::Zero();
};

// Which limit refused a plan, for the NACK's detail on the bus: the value the target
// needed and the limit it broke (mm; px for kFrame).
struct PlanRefusal {
  enum class Limit { kNone, kDepth, kStroke, kFrame } limit = Limit::kNone;
  double value = 0.0;
  double bound = 0.0;
};

struct LineObservation {
  double slideMm = 0.0;
  image::LaserLine line;
  std::vector<Eigen::Vector3d> pointsMm;       // gated 3D points of this line
  std::vector<geometry::PixelPoint> pixels;    // their pixels (same order)
  std::vector<Eigen::Vector3d> outsidePointsMm;  // beyond the gate, within scan.searchMm (the widened search's)
  // Samples on leaves, told by their colour (ScanParams::leafGreenRatio): seen, so those in
  // the gate show it occupied, but no fruit's surface; those beyond it (within searchMm)
  // join no widened search and only say that the line lit something there.
  std::vector<Eigen::Vector3d> leafPointsMm;
  std::vector<Eigen::Vector3d> leafOutsidePointsMm;
  // The sunlit arcs the per-row extraction missed (ScanParams::weakArcMinZ), gated; used
  // only when the lines alone leave the target unseen (estimate()).
  std::vector<Eigen::Vector3d> arcPointsMm;
  std::vector<geometry::PixelPoint> arcPixels;
};

struct AppleEstimate {
  Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
  Eigen::Vector3d approachMm = Eigen::Vector3d::Zero();  // surface point nearest the sensor on the line to the centre
  Eigen::Vector3d approachNormal = Eigen::Vector3d::Zero();  // outward unit surface normal there
  double aspect = 1.0;           // height/width of the fitted spheroid (1: a sphere)
  // The sphere's weight in the estimate against the spheroid's (Akaike's weights: the
  // spheroid's aspect and tilt must lower the points' χ² by 2 each to break even). Near 1:
  // the lines cannot tell the fruit from a round one; near 0: they show it oblate or prolate.
  double sphereWeight = 1.0;
  double diameterMm = 0.0;  // equatorial (across the stem), at most 2·ScanParams::maxRadiusMm
  // How far the fitted sphere's diameter exceeded the largest fruit's before it was held
  // there (a prolate fruit seen along its meridians; 0 when not held). The fitted surface
  // lies at surfaceRadiusMm() about centerMm, which is what tells points on it from others.
  double diameterHeldMm = 0.0;
  double surfaceRadiusMm() const { return 0.5 * (diameterMm + diameterHeldMm); }
  // How far a point lies from that surface, either side: the test for "on this fruit".
  double offSurfaceMm(const Eigen::Vector3d& pointMm) const {
    return std::abs((pointMm - centerMm).norm() - surfaceRadiusMm());
  }
  double sigmaMm = 0.0;          // 1σ (3D) of the approach point
  double centerSigmaMm = 0.0;    // 1σ (3D) of the centre
  double diameterSigmaMm = 0.0;
  double confidencePct = 0.0;    // see docs/geometry.md: support × chance of the 20 mm tolerance
  double occlusionPct = 0.0;     // share of the expected line rows that did not reach the fit
  double rmsMm = 0.0;            // fit residual
  int linesUsed = 0;
  int pointsUsed = 0;
  bool sphereFit = false;        // false: the paper's single-line estimate
  bool outsideGate = false;      // found by the widened search, away from the rough position
  bool fromWeakArcs = false;     // the lines alone left the target unseen; the sunlit arcs found it
  // Why the estimate may be another object than the target, when the chance that it is
  // the target (targetPct) is below one half: its centre is far from the rough position,
  // or another object explains the lines about as well. The bus reports such a result
  // as AMBIGUOUS with the reason (docs/can-protocol.md).
  enum class Doubt { kNone, kFarFromRough, kTwoSurfaces };
  Doubt doubt = Doubt::kNone;
  double targetPct = 100.0;  // chance that the fitted object is the target
  double fitSigmaMm = 0.0;   // σ of the approach point: the fit's, systematic and shape terms (no mixture)
  double rivalShare = 0.0;   // rival score / (own + rival) from the sphere fit (0: no rival)
  // When the rival is a fruit of its own (its own sphere on two lines or more, apart from
  // this one): the chance, by the rough position alone, that this fit and not that fruit is
  // the target (Localizer::weighRivalFruit; 1: no such fruit).
  double rivalFruitIdentity = 1.0;
  Eigen::Vector3d rivalCenterMm = Eigen::Vector3d::Zero();
  // Every other object the sphere fit found in the same points (the rival among them),
  // each with its share: score / (own + its score). Empty: the rival alone, if any.
  struct Other {
    Eigen::Vector3d centerMm = Eigen::Vector3d::Zero();
    double share = 0.0;
  };
  std::vector<Other> others;
};

// The paper's candidates: one per line with points on the target.
struct PaperCandidate {
  size_t line = 0;              // index into the observations
  double pixelCount = 0.0;      // N
  double distancePx = 0.0;      // Δd: the line's middle from the expected centre, px
  Eigen::Vector3d middleMm = Eigen::Vector3d::Zero();  // the line's middle, triangulated
};

class Localizer {
 public:
  Localizer(const geometry::Calibration& cal, const image::LleParams& lle, const ScanParams& scan,
            const geometry::WorkingRange& range = {});

  // Plans the stops around a rough target position, clamped to [0, strokeMm].
  // Errors: kOutOfRange when no stop can reach the target; `why` (optional) then says
  // which limit and by how much.
  Result<ScanPlan> plan(const Eigen::Vector3d& roughMm, double strokeMm, PlanRefusal* why = nullptr) const;

  // Processes one frame taken at `slideMm`. With `laserOff` (a frame of the same size and
  // format, the laser off, at the same exposure; only the plan's ROI is read), its red is
  // subtracted first (the ambient light). Errors: those of LLE (bad frame or ROI).
  // A rolling shutter in a sweep: `slideMmPerRow` is how far the slide moved from one
  // sensor row's exposure to the next's; `slideMm` is then the position for the middle row
  // of the plan's ROI, and row v's is slideMm + (v − that row) × slideMmPerRow (0: every
  // row at slideMm, a global shutter or a frame at rest). `brightAmbient`: the metering
  // found the ambient bright (MeteringDecision::bright, direct sun); with `laserOff`, rows
  // the LLE leaves empty are then looked for with a matched filter
  // (LleParams::matchedFilter).
  Result<LineObservation> observe(const image::ImageView& frame, const ScanPlan& plan, double slideMm,
                                  image::LleWorkspace& ws, const image::ImageView* laserOff = nullptr,
                                  double slideMmPerRow = 0.0, bool brightAmbient = false) const;

  // A stop's second exposure (MeteringParams::secondExposureFactor) into its first frame's
  // observation: the second frame's gated samples of its line (the curve fit's inliers,
  // not its other segments) on rows where the first frame's LLE has no valid sample join
  // the first's, kept in row order; where the first has one, it stands. The second's sunlit
  // arcs are taken only when the first has none. Pure. Returns how many samples joined.
  static size_t mergeSecondExposure(LineObservation& first, const LineObservation& second);

  // The second pass of an adaptive scan (ScanParams "Adaptive scan"): the stops to add
  // after the first pass's `lines` gave `first`; empty when the first pass is enough, when
  // `first` is an error, when following up is off, or when every such stop is outside
  // [0, strokeMm]. Ordered as one sweep back from where the first pass ended.
  // Pure: the caller scans them (observe) and calls estimate() with all the lines.
  std::vector<double> followUpStops(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                    const Result<AppleEstimate>& first, double strokeMm) const;

  // Fuses the observations. A line at the slide position of an earlier one (within 0.05 mm)
  // is the same line again and is left out: a replayed scan serves the frame recorded
  // nearest each planned stop, so a plan denser than the recording repeats frames.
  // Errors: kNotFound when no line hit the target.
  Result<AppleEstimate> estimate(const ScanPlan& plan, const std::vector<LineObservation>& lines) const;

  // The paper's single-line estimate: the best candidate's middle is the approach point;
  // the centre lies one prior radius behind it. Errors: kNotFound.
  Result<AppleEstimate> estimateSingleLine(const ScanPlan& plan, const std::vector<LineObservation>& lines) const;

  // The candidates of the paper's selection, and the one P = w1·N − w2·Δd picks.
  std::vector<PaperCandidate> paperCandidates(const ScanPlan& plan, const std::vector<LineObservation>& lines) const;
  static size_t selectCandidate(const std::vector<PaperCandidate>& candidates, double w1, double w2);

 // The part of the plan's ROI where the laser plane at `slideMm` can light anything within
  // the gate around the rough position (empty when it cannot).
  image::Roi stopRoi(const ScanPlan& plan, double slideMm) const;

  // The chance (%) that another object the fit found in the same lines
  // (AppleEstimate::others, else its rival) is the target, reckoned as weighDoubt() reckons
  // the fit's (AppleEstimate::targetPct): its distance from the rough position, its share
  // of the support; of every such object, the likeliest (not always the strongest: a
  // weaker one may lie nearer the rough position). 0 without one. When it exceeds the
  // fit's, estimate() reports that object's own estimate instead (the fit with the rough
  // position's prior on it, weighed alike), if that holds up.
  double rivalTargetPct(const ScanPlan& plan, const AppleEstimate& est) const;
  // The same object's centre (meaningful when rivalTargetPct() > 0).
  Eigen::Vector3d likeliestOtherMm(const ScanPlan& plan, const AppleEstimate& est) const;

  // The systematic part of the approach point's σ at `approachMm` (ScanParams::lineBiasPx
  // and the calibration's error), 1σ 3D, mm: added to every fit's σ.
  double systematicSigmaMm(const Eigen::Vector3d& approachMm) const;

 private:
  // estimate() before the rough-position gate; the fit's prior on the centre is the rough
  // position with priorCenterSigmaMm.
  Result<AppleEstimate> estimateFused(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                      double priorCenterSigmaMm) const;
  // The widened search: every point the lines saw within searchMm, a weak centre prior; a
  // sphere on two lines or more, else kNotFound.
  Result<AppleEstimate> estimateWidened(const ScanPlan& plan, const std::vector<LineObservation>& lines) const;
  // The lines' points off `other`'s surface, fitted again round the rough position: a fit
  // on three lines or more (kFirmLines) that is likelier the target than not; else kNotFound.
  Result<AppleEstimate> estimateBesideOther(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                            const AppleEstimate& other) const;
  // The estimate from the rough position alone: centre there, a prior radius, σ its error.
  AppleEstimate roughEstimate(const ScanPlan& plan) const;
  // When rivalTargetPct() exceeds the fit's targetPct: the estimate of that other object
  // (likeliestOtherMm()), if it is found there and weighs more; else `est`.
  Result<AppleEstimate> likelierOfRival(const ScanPlan& plan, const std::vector<LineObservation>& lines,
                                        Result<AppleEstimate> est) const;
  // Triangulates `pixels` at the stop: those within the gate round the rough position go
  // to gatedMm and gatedPixels (when given), those beyond it within searchMm to outsideMm
  // (when given).
  void triangulateRows(const ScanPlan& plan, double slideMm, double slideMmPerRow,
                       const std::vector<geometry::PixelPoint>& pixels, std::vector<Eigen::Vector3d>* gatedMm,
                       std::vector<geometry::PixelPoint>* gatedPixels, std::vector<Eigen::Vector3d>* outsideMm) const;
  // estimate() on the lines as they are (one per stop).
  Result<AppleEstimate> estimateLines(const ScanPlan& plan, const std::vector<LineObservation>& lines) const;
  // The prior share of other objects for a fit on `linesUsed` lines (ScanParams::otherObjectPrior),
  // for weighDoubt() and rivalTargetPct() alike.
  double otherObjectPrior(int linesUsed) const;
  // Weighs a sphere-fit estimate against the chance that it is another object (see
  // ScanParams::otherObjectPrior): targetPct, doubt, the mixture σ and the confidence.
  void weighDoubt(const ScanPlan& plan, double ballMm, AppleEstimate& est) const;
  // The approach point's σ for a chance p that `est` is the target: its own (fitSigmaMm)
  // mixed with the other object's distance (weighDoubt()).
  double mixtureSigmaMm(const ScanPlan& plan, const AppleEstimate& est, double p) const;
  // On the estimate that goes out, after weighDoubt() and the choice: when its rival is a
  // fruit of its own, sets est.rivalFruitIdentity from the two centres' distances to the
  // rough position and, when that is the smaller rival term, lowers targetPct and the
  // confidence with it, widens σ, and marks a chance below one half TWO_SURFACES.
  void weighRivalFruit(const ScanPlan& plan, const std::vector<LineObservation>& lines, AppleEstimate& est) const;

  geometry::Calibration cal_;
  image::LleParams lle_;
  ScanParams scan_;
  geometry::WorkingRange range_;
};

}  // namespace alacs::localize
