// PNG files of 8-bit frames, through libpng directly. The daemon's PNG work (replay,
// recording, the debug overlay) does without OpenCV's imgcodecs, whose dependencies
// (GDAL, Poppler, HDF5, X11, ... 120 shared libraries on Debian 12) cost about 40 MB of
// resident memory from the start, most of a 64 MB budget (docs/daemon.md).
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "common/result.h"

namespace alacs::replay {

// Decodes the PNG at `path` into `out` as 8-bit BGR, as OpenCV's imread(IMREAD_COLOR)
// does (grey and palette expanded, alpha dropped, 16-bit to its high byte). `out` is
// reused when it is already CV_8UC3 of the image's size, so a reader of many frames
// allocates nothing per frame. Errors: kNotFound, kBadInput (not a PNG, corrupt).
Status readPng(const std::string& path, cv::Mat& out);
// The same into `dst`, which must already be CV_8UC3 of the image's size: a view into a
// larger image receives a crop in place. Errors: those of readPng, kBadInput naming both
// sizes when they differ.
Status readPngInto(const std::string& path, cv::Mat& dst);
// Writes an 8-bit BGR (CV_8UC3) or grey (CV_8UC1) image, zlib `level` 0..9 (1: a 5 MP
// frame in tens of ms). Errors: kInvalidArgument, kIo.
Status writePng(const std::string& path, const cv::Mat& image, int level = 1);

}  // namespace alacs::replay
