// libFuzzer target for the PNG reader (edge/replay/png_io.h): any bytes as a file. The
// reader must return an image or an error, never crash, leak, read out of bounds or
// allocate past its limits (ASan/UBSan and -rss_limit_mb/-malloc_limit_mb watch), and an
// image it returns is 8-bit BGR within kMaxPngSidePx. readPngInto gets the same bytes
// with a destination of a fixed size.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "replay/png_io.h"

using namespace alacs;

namespace {

// The reader takes a path: the input goes to one file of this process, rewritten per run.
const std::string& scratchPath() {
  static const std::string path = "/tmp/alacs_fuzz_png_" + std::to_string(getpid()) + ".png";
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = scratchPath();
  FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);

  cv::Mat out;
  const Status s = replay::readPng(path, out);
  if (s.isOk()) {
    if (out.type() != CV_8UC3 || out.cols < 1 || out.rows < 1 || out.cols > static_cast<int>(replay::kMaxPngSidePx) ||
        out.rows > static_cast<int>(replay::kMaxPngSidePx))
      std::abort();
  } else if (s.reason().find(path) == std::string::npos) {
    std::abort();  // every error names the file
  }
  cv::Mat frame(32, 48, CV_8UC3);
  cv::Mat view = frame(cv::Rect(4, 4, 40, 24));
  const Status into = replay::readPngInto(path, view);
  if (into.isOk() && (view.cols != 40 || view.rows != 24)) std::abort();
  return 0;
}
