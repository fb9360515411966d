// Which of a line's samples lie on a leaf, told by the laser-off frame's colour
// (ScanParams::leafGreenRatio; docs/geometry.md "Leaves told by their colour").
// Chlorophyll reflects 2-3 times more green than red, red skin the reverse: a sample whose
// own pixel in the laser-off frame is (G + 1) >= ratio * (R + 1) lies on a leaf. At a
// leaf's edge the pixel under a sample takes, through the lens's blur, the colour of what
// lies beside the leaf (a fruit's red, a dark gap) and passes for no leaf on its own; the
// samples of one segment (rows linked by continuity: mostly one surface) show it. Pure: a
// line and a frame in, one flag per row sample out.
#pragma once

#include <cstddef>
#include <vector>

#include "image/image_view.h"
#include "image/lle.h"

namespace alacs::localize {

// Along a segment (its valid samples in row order), a run of at most
// kLeafEdgeRunSamples samples that are not green, all within kLeafEdgeReachRows rows of
// the nearest sample of a run of at least kLeafGreenRunSamples green ones beside it, is
// the leaf's edge. A longer run is another surface's (a fruit the leaf touches, linked to
// it). The reach is about twice that of the lens's blur and the sensor's demosaicing; the
// case that prompted the rule (docs/geometry.md) had 4 such samples. The green run's
// length is how much of a leaf it takes to say so. Not varied on results.
inline constexpr size_t kLeafEdgeRunSamples = 4;
inline constexpr int kLeafEdgeReachRows = 4;
inline constexpr size_t kLeafGreenRunSamples = 3;

// Whether the laser-off frame's pixel under a sample (row, column) is leaf-green. A sample
// outside the frame is not.
bool leafGreen(const image::ImageView& laserOff, int row, float column, double ratio);

// One flag per line.rows entry: on a leaf (green, or a leaf's edge as above). Invalid rows
// are never. All false with ratio 0 (off) or without a laser-off frame (null). Rests on
// LaserLine::rows being in row order, as it is documented to be.
std::vector<bool> leafSamples(const image::LaserLine& line, const image::ImageView* laserOff, double ratio);

}  // namespace alacs::localize
