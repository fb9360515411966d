// PNG frames through libpng (replay/png_io.h): what OpenCV's imread would give, in a
// reused buffer, and crops decoded in place.

#include <catch2/catch.hpp>
#include <cstdio>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "replay/png_io.h"
#include "replay/scan_dir.h"
#include "temp_dir.h"

using namespace alacs;

namespace {

bool same(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0.0;
}

}  // namespace

TEST_CASE("PNG frames read back exactly, as OpenCV reads them, into one reused buffer", "[replay][png]") {
  const test::TempDir tmp("alacs_png");
  const std::string path = tmp.file("bgr.png");
  cv::Mat bgr(37, 53, CV_8UC3);
  cv::randu(bgr, 0, 256);
  REQUIRE(replay::writePng(path, bgr, 1).isOk());
  CHECK(same(cv::imread(path, cv::IMREAD_COLOR), bgr));  // OpenCV reads our files
  cv::Mat out;
  REQUIRE(replay::readPng(path, out).isOk());
  CHECK(same(out, bgr));
  const uint8_t* buffer = out.data;
  out.setTo(0);
  REQUIRE(replay::readPng(path, out).isOk());
  CHECK(out.data == buffer);  // same size: decoded into the same buffer
  CHECK(same(out, bgr));

  // Other layouts decode as imread(IMREAD_COLOR) does: grey, 16-bit, alpha.
  cv::Mat grey(20, 30, CV_8UC1), grey16(20, 30, CV_16UC1), bgra(20, 30, CV_8UC4), bgr16(20, 30, CV_16UC3);
  cv::randu(grey, 0, 256);
  cv::randu(grey16, 0, 65536);
  cv::randu(bgra, 0, 256);
  cv::randu(bgr16, 0, 65536);
  for (const cv::Mat* m : {&grey, &grey16, &bgra, &bgr16}) {
    const std::string p = tmp.file("other.png");
    REQUIRE(cv::imwrite(p, *m));
    cv::Mat o;
    REQUIRE(replay::readPng(p, o).isOk());
    CHECK(same(o, cv::imread(p, cv::IMREAD_COLOR)));
  }
  const std::string greyPath = tmp.file("grey.png");
  REQUIRE(replay::writePng(greyPath, grey, 9).isOk());
  CHECK(same(cv::imread(greyPath, cv::IMREAD_GRAYSCALE), grey));
}

TEST_CASE("A PNG crop decodes in place into a view of the whole frame", "[replay][png]") {
  const test::TempDir tmp("alacs_png");
  const std::string path = tmp.file("crop.png");
  cv::Mat crop(10, 16, CV_8UC3, cv::Scalar(1, 2, 3));
  REQUIRE(replay::writePng(path, crop).isOk());
  cv::Mat frame(48, 64, CV_8UC3, cv::Scalar::all(7));
  cv::Mat view = frame(cv::Rect(5, 6, 16, 10));
  REQUIRE(replay::readPngInto(path, view).isOk());
  CHECK(same(view, crop));
  CHECK(frame.at<cv::Vec3b>(5, 5) == cv::Vec3b(7, 7, 7));
  CHECK(frame.at<cv::Vec3b>(16, 20) == cv::Vec3b(7, 7, 7));
  cv::Mat wrong(10, 10, CV_8UC3);
  const Status s = replay::readPngInto(path, wrong);
  CHECK(s.code() == Error::kBadInput);
  CHECK(s.reason().find("16x10") != std::string::npos);
}

TEST_CASE("Bad PNG files are refused with a reason", "[replay][png]") {
  const test::TempDir tmp("alacs_png");
  cv::Mat out;
  CHECK(replay::readPng(tmp.file("none.png"), out).code() == Error::kNotFound);
  const std::string text = tmp.file("text.png");
  std::ofstream(text) << "not a picture at all";
  CHECK(replay::readPng(text, out).code() == Error::kBadInput);
  // Cut short: libpng's own error comes back as kBadInput, not as a crash.
  const std::string whole = tmp.file("whole.png");
  cv::Mat img(64, 64, CV_8UC3);
  cv::randu(img, 0, 256);
  REQUIRE(replay::writePng(whole, img).isOk());
  std::ifstream in(whole, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string cut = tmp.file("cut.png");
  std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  const Status s = replay::readPng(cut, out);
  CHECK(s.code() == Error::kBadInput);
  CHECK(!s.reason().empty());
  CHECK(replay::writePng("/nonexistent/dir/x.png", img).code() == Error::kIo);
  CHECK(replay::writePng(tmp.file("f.png"), cv::Mat(4, 4, CV_32FC1)).code() == Error::kInvalidArgument);
}

TEST_CASE("Frames of a scan load into one buffer, crops zeroed around", "[replay][png]") {
  const test::TempDir tmp("alacs_pngscan");
  const std::string dir = tmp.path();
  replay::ScanManifest m;
  m.scan.widthPx = 64;
  m.scan.heightPx = 48;
  cv::Mat full(48, 64, CV_8UC3, cv::Scalar::all(9));
  cv::Mat crop(10, 16, CV_8UC3, cv::Scalar(1, 2, 3));
  REQUIRE(replay::writePng(dir + "/full.png", full).isOk());
  REQUIRE(replay::writePng(dir + "/crop.png", crop).isOk());
  replay::FrameRecord f;
  f.file = "full.png";
  replay::FrameRecord c;
  c.file = "crop.png";
  c.cropPx = image::Roi{5, 6, 16, 10};
  cv::Mat out;
  REQUIRE(replay::loadFrameInto(dir, m, f, out).isOk());
  CHECK(same(out, full));
  const uint8_t* buffer = out.data;
  REQUIRE(replay::loadFrameInto(dir, m, c, out).isOk());
  CHECK(out.data == buffer);
  CHECK(out.at<cv::Vec3b>(0, 0) == cv::Vec3b(0, 0, 0));
  CHECK(out.at<cv::Vec3b>(6, 5) == cv::Vec3b(1, 2, 3));
  REQUIRE(replay::loadFrameInto(dir, m, f, out).isOk());
  CHECK(out.data == buffer);
  CHECK(same(out, full));
  m.scan.widthPx = 65;  // the manifest's size differs from the PNG's
  const Status s = replay::loadFrameInto(dir, m, f, out);
  CHECK(s.code() == Error::kBadInput);
  CHECK(s.reason().find("64x48") != std::string::npos);
}
