// Metering the laser frames' exposure from laser-off frames of the ROI (issue 17, sunlit
// skin). Pure logic, frames in and a decision out, like the localizer: no device, no
// clock. The caller (the scan worker, the twin's generator, alacs-twin process) takes each
// metering frame with the laser off at the exposure `ExposureMeter::nextMeteringUs()`
// asks for, feeds it back with `add()`, and when no more is asked for exposes the stops
// at `decision().exposureUs`, subtracting a laser-off frame at that exposure when
// `decision().subtract` says so (docs/lle.md "Metering and laser-off subtraction").
//
// Why: at a fixed exposure, sunlit red skin nears full scale and the laser line on it
// clips or vanishes (the red of the line is ambient + laser, and the LLE sees only the
// excess over the neighbours). A shorter exposure keeps the skin's red at a level that
// leaves headroom for the laser's peak; the laser then carries less signal too, but a
// line that is there beats one that is clipped away.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "common/result.h"
#include "image/image_view.h"

namespace alacs::localize {

struct MeteringParams {
  bool enabled = true;
  // The ambient level metered: this percentile of the red values in the ROI (the brightest
  // skin, not a specular pixel or two), in % (50..100).
  double percentile = 99.0;
  // The exposure is chosen so that the metered red is at most this (DN of 255): the rest
  // of the scale is the laser's headroom (1..254).
  int targetDn = 220;
  // ... and, when the ambient is bright (its metered red grows faster than this with the
  // exposure, DN per ms: direct sun), lengthened up to it too: the laser is then weak next
  // to the skin, and the scale is best spent on the exposure. Below (lab, overcast, the
  // benchmark's direct light) the laser can be as strong as the skin, and a longer
  // exposure would clip the line: the exposure is only ever shortened (1..1e6).
  double brightDnPerMs = 250.0;
  // A metering frame whose metered red reaches this is saturated: its true level is
  // unknown, so the meter asks again at exposure / stepDown (2..255).
  int saturatedDn = 250;
  double stepDown = 4.0;  // (1.5..64)
  int maxFrames = 3;      // metering frames at most (1..8)
  // Laser-off subtraction when the metered red at the chosen exposure is above this (DN):
  // the ambient then carries edges and texture that bRCE could take for the line. Below,
  // no ambient edge reaches the lowest candidate threshold (18 DN: the weak-line rerun's
  // 24 at 75 %) and a subtraction would only add its noise (0..255; 255: never).
  int subtractAboveDn = 16;
  int64_t minExposureUs = 20;  // the shortest exposure chosen or metered at (1..1e6)
  // When the ambient is bright, the laser frames (and the frame subtracted) are taken at
  // this analogue gain (linear, as libcamera's AnalogueGain: 1 is the sensor's least) and
  // the exposure lengthened by the metered gain over it, so that the skin reaches the same
  // level with more light collected: the shot noise of line and ambient falls by the
  // square root of the ratio (docs/lle.md, "A lower gain in sun"). Where the longest
  // exposure would be passed, the gain is lowered only as far as the longest allows. Only
  // ever lowers: a metering frame at or below it keeps its gain, and one whose gain the
  // source does not report (0) keeps it too. 0: never changed (0, or 1..64).
  double brightAnalogueGain = 1.0;
  // When the ambient is bright and a laser-off frame is subtracted, each stop takes a
  // second laser frame at this factor times the chosen exposure (at most the longest), with
  // a laser-off frame of its own at that exposure, and the rows the first frame's LLE
  // leaves without a sample are taken from the second (Localizer::mergeSecondExposure).
  // In a sunlit cluster the metered percentile is often another fruit's skin or a leaf in
  // full sun; the target's own skin, in part shade, then gets less exposure than it could
  // bear (docs/lle.md, "A second exposure in sun"). 0: never (0, or 1.25..8).
  double secondExposureFactor = 0.0;
  Status validate() const;
};

// What the meter decided. `exposureUs` lies between the shortest exposure and the first
// metering frame's, or, when the ambient is bright, the longest one the meter was given
// (the daemon: its configured exposure).
struct MeteringDecision {
  int64_t exposureUs = 0;  // for the laser frames
  // Their analogue gain (linear); 0: the metering frames' (the source's own, not asked for).
  double analogueGain = 0.0;
  bool subtract = false;   // take a laser-off frame at exposureUs and subtract it
  // The second laser frame's exposure at each stop (MeteringParams::secondExposureFactor),
  // with a laser-off frame at it to subtract; 0: none (not bright, no subtraction, factor
  // 0, or the longest exposure leaves less than the factor's 1.25).
  int64_t secondExposureUs = 0;
  int ambientDn = 0;       // metered red (the percentile) at exposureUs, DN (estimated)
  int meteredDn = 0;       // metered red of the last metering frame, DN
  int64_t meteredUs = 0;   // that frame's exposure
  double meteredGain = 0;  // and its analogue gain as the source reported it (0: not known)
  int frames = 0;          // metering frames used
  bool saturated = false;  // every metering frame was saturated (the level is a bound)
  // The ambient's red grows by MeteringParams::brightDnPerMs or more (direct sun on the
  // twin): the laser line is weak against it. Clipped, the rate is a lower bound.
  bool bright = false;
};

// The `percentile` (%) of the red values of `roi` in `frame` (its pixel format says which
// byte is red), DN. Errors: kBadInput for an empty ROI or one outside the frame.
Result<int> redPercentileDn(const image::ImageView& frame, const image::Roi& roi, double percentile);

class ExposureMeter {
 public:
  // Metering starts at `startExposureUs` (> 0) and chooses at most `maxExposureUs` (0: the
  // start). The daemon starts at its configured exposure, which is also the longest; the
  // twin starts at its scene's fixed exposure, with the daemon's configured one as the longest.
  ExposureMeter(const MeteringParams& params, int64_t startExposureUs, int64_t maxExposureUs = 0);

  // The exposure to take the next laser-off metering frame at (us); 0 when metering is
  // over (or off): decision() is then final.
  int64_t nextMeteringUs() const { return nextUs_; }

  // Adds the laser-off frame taken for nextMeteringUs(), of which only `roi` is read,
  // exposed for `exposureUs` at `analogueGain` (both as applied: a replayed or real camera
  // may report another exposure than the one asked for; the level is scaled by the one
  // reported. A gain of 0: not known, and not changed). Errors: kBadInput (ROI outside the
  // frame, exposure not positive, gain negative), kInvalidArgument when metering is over.
  Status add(const image::ImageView& frame, const image::Roi& roi, int64_t exposureUs, double analogueGain = 0.0);

  // Without any add(): the start exposure, no subtraction.
  const MeteringDecision& decision() const { return decision_; }

  // Whether the last metering frame was taken at decision().exposureUs and gain, so that
  // it can serve as the subtracted laser-off frame without another exposure.
  bool lastFrameAtDecision() const {
    return decision_.frames > 0 && decision_.meteredUs == decision_.exposureUs && decision_.analogueGain == 0.0;
  }

 private:
  // Sets decision_'s exposure (and gain) for an ambient that reaches the target at
  // `wantedUs` at the metered gain, clamped to [shortestUs, longestUs].
  void choose(double wantedUs, int64_t shortestUs, int64_t longestUs);
  // Sets decision_.secondExposureUs from the rest of the decision.
  void chooseSecond();

  MeteringParams p_;
  int64_t startUs_;
  int64_t maxUs_;
  int64_t firstUs_ = 0;
  int64_t nextUs_;
  MeteringDecision decision_;
};

// Which laser-off frame a metering run asks for: one the meter reads, or the one more at
// the chosen exposure that is subtracted (when no metering frame was taken at it).
enum class LaserOffUse { kMetering, kSubtraction };

// A laser-off frame as the caller's camera, replay or renderer took it: its pixels (valid
// until the caller's next frame), the exposure it reports, us, and the analogue gain it
// reports (linear; 0: not known).
struct LaserOffFrame {
  image::ImageView view;
  int64_t exposureUs = 0;
  double analogueGain = 0.0;
};

// Takes a laser-off frame at `exposureUs` and `analogueGain` (linear; 0: the source's
// own, as the metering frames are taken), the laser off. An error ends the run.
using TakeLaserOffFrame =
    std::function<Result<LaserOffFrame>(int64_t exposureUs, double analogueGain, LaserOffUse use)>;

struct MeteringRun {
  // ok, or the first failed frame or add(): a failed metering frame leaves the start's
  // decision; a failed frame to subtract, the one chosen without subtraction.
  Status status;
  MeteringDecision decision;  // what to expose the stops at, and whether to subtract
  int frames = 0;             // laser-off frames taken (metering and subtraction)
  // The frame to subtract: decision.subtract and it was taken. It is the last frame taken,
  // so it stays valid until the caller's next frame.
  bool hasLaserOff = false;
  LaserOffFrame laserOff;
};

// The whole metering of one scan, the same for the scan worker, the twin's generator and
// alacs-twin process: laser-off frames of `roi` from `startExposureUs` on, read by an
// ExposureMeter, then, when it asks for subtraction and its last frame was not taken at
// the exposure and gain chosen, one more at them. Metering off: no frame, the start's
// exposure, no subtraction.
MeteringRun runMetering(const MeteringParams& params, int64_t startExposureUs, int64_t maxExposureUs,
                        const image::Roi& roi, const TakeLaserOffFrame& take);

}  // namespace alacs::localize
