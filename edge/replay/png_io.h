// PNG files of 8-bit frames, through libpng directly. The daemon's PNG work (replay,
// recording, the debug overlay) does without OpenCV's imgcodecs, whose dependencies
// (GDAL, Poppler, HDF5, X11, ... 120 shared libraries on Debian 12) cost about 40 MB of
// resident memory from the start, most of a 64 MB budget (docs/daemon.md).
#pragma once

#include <cstddef>
#include <opencv2/core.hpp>
#include <string>

#include "common/result.h"

namespace alacs::replay {

// What a PNG's header may declare before anything is allocated for it. A file is a
// frame of a camera (5 MP, 2592 x 1944, at most) or a crop of one; a header beyond these
// is refused, so that a corrupt or hostile file (60000 x 60000 declares 10 GB of BGR)
// never reaches an allocation, and neither does a large ancillary chunk.
inline constexpr unsigned kMaxPngSidePx = 8192;                       // width and height each
inline constexpr std::size_t kMaxPngDecodedBytes = 96U << 20;         // the 8-bit BGR result: 32 MP
inline constexpr std::size_t kMaxPngChunkBytes = 1U << 20;            // one ancillary chunk (iCCP, zTXt, ...)

// Decodes the PNG at `path` into `out` as 8-bit BGR, as OpenCV's imread(IMREAD_COLOR)
// does (grey and palette expanded, alpha dropped, 16-bit to its high byte). `out` is
// reused when it is already CV_8UC3 of the image's size, so a reader of many frames
// allocates nothing per frame. The header (size, bit depth, colour type) is checked
// against the limits above before libpng allocates anything. Errors: kNotFound,
// kBadInput (not a PNG, truncated, corrupt, or beyond the limits: the reason names the
// file and the declared size).
Status readPng(const std::string& path, cv::Mat& out);
// The same into `dst`, which must already be CV_8UC3 of the image's size: a view into a
// larger image receives a crop in place. Errors: those of readPng, kBadInput naming both
// sizes when they differ.
Status readPngInto(const std::string& path, cv::Mat& dst);
// The same from an open file (common/file_beneath.h's openBeneath); `name` names it in
// errors. `fd` stays open (the reader takes a duplicate).
Status readPngInto(int fd, const std::string& name, cv::Mat& dst);
// Writes an 8-bit BGR (CV_8UC3) or grey (CV_8UC1) image, zlib `level` 0..9 (1: a 5 MP
// frame in tens of ms). Errors: kInvalidArgument, kIo.
Status writePng(const std::string& path, const cv::Mat& image, int level = 1);

}  // namespace alacs::replay
