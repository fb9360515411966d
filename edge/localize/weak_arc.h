// The target's line where the per-row extraction cannot see it. On sunlit skin the laser
// adds a few DN to a red near full scale, and in one row its peak stands hardly above the
// shot noise of the pair (docs/lle.md, "What remains lost in sun"): bRCE finds a row here
// and there. Summed along the whole arc that the laser plane draws across a fruit, the
// same light stands far out of the noise. The search (docs/lle.md, "The sunlit line along
// its arc" and "Smoothed along the arc, and more than one arc a frame"): circles in the
// laser plane round the rough position, each scored by the summed contrast of the
// laser-off-subtracted red along its image curve, over the pixels not yet explained (the
// LLE's samples, earlier arcs). The best, when its score clears `minZ`, is followed row by
// row within a few px, each sample's column smoothed along the arc and samples off it
// dropped; it is a segment of its own (RowStatus::kSegment). Then the best of what it
// leaves, up to `maxArcs`: in sun a neighbour's or a leaf's arc may score above the
// target's. The localizer keeps the samples apart from the lines' and lets them join the
// fit only where the lines alone leave the target unseen (localize/localizer.h); the fit
// across the stops then tells which arc is the fruit. Pure: frames in, samples out.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "geometry/calibration.h"
#include "image/image_view.h"
#include "image/lle.h"

namespace alacs::localize {

struct WeakArcParams {
  double minZ = 0.0;                  // the arc's summed contrast over its noise; 0: off
  double searchMm = 45.0;             // the circle's centre within this of the rough position's, in the plane
  double stepMm = 5.0;                // the grid of centres
  double minRadiusMm = 10.0;          // the circle's radius (the fruit's cut): from ...
  double maxRadiusMm = 50.0;          // ... to ...
  double radiusStepMm = 5.0;          // ... in steps of
  int contrastPx = 4;                 // the curve's red against the pixels this far either side
  int minRows = 15;                   // an arc over fewer unexplained rows is not scored
  int followPx = 3;                   // each row's peak within this of the arc's column
  int maskPx = 4;                     // pixels this close to an LLE sample or a scored arc are explained
  double minRowContrastSigmas = 1.5;  // a followed row's peak contrast, in the contrast's σ
  int maxArcs = 3;                    // arcs over the bar followed, each over what the earlier leave (<= 1: one)
  // A followed sample's column: the local line through the arc's samples within ±this many
  // rows, weighted by contrast (0: the row's own centroid, and nothing dropped) ...
  int smoothRows = 8;
  double outlierPx = 1.5;  // ... and a sample this far off the line through the others is dropped
};

struct WeakArc {
  double z = 0.0;                         // the best arc's score (0: none scored)
  int rows = 0;                           // rows it was scored on
  int arcs = 0;                           // arcs over the bar followed (with minRows / 2 samples or more)
  // Followed rows, arc after arc (segment, segment + 1, ...; empty: none): column and
  // columnQ8 smoothed along the arc, centroidQ8 the row's own centroid.
  std::vector<image::RowSample> samples;
};

// Searches the ROI of `frame` (laser on) minus `laserOff` (same size and format) for the
// arc; `line` is the LLE's result on the same ROI (its samples are masked), `slideMm` the
// plane's position. The samples carry segment index `segment` (the next arcs' segment + 1,
// segment + 2, ...).
WeakArc findWeakArc(const image::ImageView& frame, const image::ImageView& laserOff, const image::Roi& roi,
                    const geometry::Calibration& cal, double slideMm, const Eigen::Vector3d& roughMm,
                    const image::LaserLine& line, int segment, const WeakArcParams& p);

}  // namespace alacs::localize
