// Loading a scan directory's manifest is linear in its frame count (issue 15, finding
// 4.5: the old cv::FileStorage reader took 1.9 s for 10 k frames and 21 s for 40 k).
// A benchmark, hidden from the default run ([.bench]); it prints the median load time per
// size and the ratio to the size half as large (2.0 is linear, 4.0 quadratic), measured
// in the same run: build/release/tests/alacs_unit_tests "[bench][manifest]"
#include <algorithm>
#include <catch2/catch.hpp>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "common/json_file.h"
#include "replay/scan_dir.h"
#include "temp_dir.h"

using namespace alacs;
using alacs::Json;

namespace {

replay::ScanManifest manifestOf(int frames) {
  replay::ScanManifest m;
  m.scan.kind = "localize";
  m.scan.source = "bench";
  m.scan.widthPx = 2048;
  m.scan.heightPx = 1536;
  for (int i = 0; i < frames; ++i) {
    replay::FrameRecord f;
    f.index = i;
    f.file = "frames/frame_" + std::to_string(i) + ".png";
    f.slideMm = 0.005 * i;
    f.timestampS = 0.01 * i;
    f.exposureUs = 2000;
    m.frames.push_back(std::move(f));
  }
  return m;
}

template <typename F>
double medianMs(int runs, F&& f) {
  std::vector<double> ms;
  for (int r = 0; r < runs; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  return ms[ms.size() / 2];
}

}  // namespace

TEST_CASE("Manifest loading is linear in the frame count", "[.][bench][manifest]") {
  const test::TempDir tmp;
  // The whole load (file, JSON parse, checks), and the project's part alone (the checks
  // and the copy into ScanManifest, on a parsed document): the parse is nlohmann-json's.
  double previousLoad = 0.0;
  double previousCheck = 0.0;
  for (const int frames : {5000, 10000, 20000, 40000}) {
    const std::string dir = tmp.file("scan_" + std::to_string(frames));
    std::filesystem::create_directories(dir);
    REQUIRE(replay::writeManifest(dir, manifestOf(frames)).isOk());
    const double load = medianMs(5, [&] { REQUIRE(replay::readManifest(dir).isOk()); });
    const Json doc = Json::parse(replay::manifestJson(manifestOf(frames)));
    const double check = medianMs(5, [&] {
      replay::ScanManifest m;
      REQUIRE(replay::manifestFromJson(doc, m).isOk());
    });
    std::printf("manifest of %5d frames: load %7.1f ms", frames, load);
    if (previousLoad > 0.0) std::printf(" (x%.2f)", load / previousLoad);
    std::printf(", of which the checks %6.1f ms", check);
    if (previousCheck > 0.0) std::printf(" (x%.2f)", check / previousCheck);
    std::printf("; medians of 5, (xN) = the time of half as many frames times N\n");
    previousLoad = load;
    previousCheck = check;
  }
}
