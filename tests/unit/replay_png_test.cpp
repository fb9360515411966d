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

namespace {

// CRC-32 of the PNG specification (ISO 3309), bit by bit: a test needs a few bytes.
uint32_t pngCrc(const std::string& bytes) {
  uint32_t c = 0xFFFFFFFFU;
  for (const char ch : bytes) {
    c ^= static_cast<uint8_t>(ch);
    for (int k = 0; k < 8; ++k) c = (c & 1U) != 0 ? 0xEDB88320U ^ (c >> 1) : c >> 1;
  }
  return c ^ 0xFFFFFFFFU;
}

std::string bigEndian(uint32_t v) {
  return {static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8), static_cast<char>(v)};
}

// One chunk: length, type, data, CRC over type and data.
std::string chunk(const std::string& type, const std::string& data) {
  return bigEndian(static_cast<uint32_t>(data.size())) + type + data + bigEndian(pngCrc(type + data));
}

// A PNG whose header declares `width` x `height` at `depth` bits and colour type
// `colour`, with valid CRCs and an IDAT of one empty stored zlib block.
std::string pngWithHeader(uint32_t width, uint32_t height, uint8_t depth, uint8_t colour) {
  const std::string ihdr = bigEndian(width) + bigEndian(height) + std::string{static_cast<char>(depth),
                                                                               static_cast<char>(colour), 0, 0, 0};
  const std::string zlibEmpty("\x78\x01\x01\x00\x00\xff\xff\x00\x00\x00\x01", 11);
  return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) + chunk("IDAT", zlibEmpty) + chunk("IEND", "");
}

}  // namespace

TEST_CASE("A PNG header beyond the limits is refused before anything is allocated", "[replay][png]") {
  const test::TempDir tmp("alacs_png");
  CHECK(pngCrc("IEND") == 0xAE426082U);  // the CRC every PNG ends with
  cv::Mat out;
  const std::string huge = tmp.write("huge.png", pngWithHeader(60000, 60000, 8, 2));
  const Status s = replay::readPng(huge, out);
  CHECK(s.code() == Error::kBadInput);
  CHECK(s.reason().find("huge.png") != std::string::npos);
  CHECK(s.reason().find("60000 x 60000") != std::string::npos);
  CHECK(out.empty());
  cv::Mat view(10, 10, CV_8UC3);
  CHECK(replay::readPngInto(huge, view).code() == Error::kBadInput);

  // Each side within the limit, but the pixels beyond the decoded-bytes cap.
  const std::string wide = tmp.write("wide.png", pngWithHeader(replay::kMaxPngSidePx, replay::kMaxPngSidePx, 8, 2));
  CHECK(replay::readPng(wide, out).reason().find("8192 x 8192") != std::string::npos);
  // One side only.
  CHECK(replay::readPng(tmp.write("tall.png", pngWithHeader(16, replay::kMaxPngSidePx + 1, 8, 2)), out).code() ==
        Error::kBadInput);
  // Zero pixels, and bit depths the colour type does not allow.
  CHECK(replay::readPng(tmp.write("empty.png", pngWithHeader(0, 16, 8, 2)), out).code() == Error::kBadInput);
  const Status depth = replay::readPng(tmp.write("depth.png", pngWithHeader(16, 16, 4, 2)), out);
  CHECK(depth.code() == Error::kBadInput);
  CHECK(depth.reason().find("bit depth 4") != std::string::npos);
  CHECK(replay::readPng(tmp.write("colour.png", pngWithHeader(16, 16, 8, 5)), out).code() == Error::kBadInput);
  // A small header passes the checks; its empty image data is libpng's error, not a crash.
  CHECK(replay::readPng(tmp.write("small.png", pngWithHeader(16, 16, 8, 2)), out).code() == Error::kBadInput);
}

TEST_CASE("A PNG cut anywhere is an error naming the file, never a crash", "[replay][png]") {
  const test::TempDir tmp("alacs_png");
  const std::string whole = tmp.file("whole.png");
  cv::Mat img(24, 40, CV_8UC3);
  cv::randu(img, 0, 256);
  REQUIRE(replay::writePng(whole, img, 0).isOk());
  std::ifstream in(whole, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  cv::Mat out;
  for (size_t n : {size_t{0}, size_t{7}, size_t{8}, size_t{20}, size_t{33}, size_t{40}, bytes.size() / 3,
                   bytes.size() - 13, bytes.size() - 1}) {
    const Status s = replay::readPng(tmp.write("cut.png", bytes.substr(0, n)), out);
    INFO(n << " of " << bytes.size() << " bytes: " << s.toString());
    CHECK(s.code() == Error::kBadInput);
    CHECK(s.reason().find("cut.png") != std::string::npos);
  }
  std::string flipped = bytes;  // a byte of the image data changed: the CRC or zlib says so
  flipped[bytes.size() / 2] = static_cast<char>(flipped[bytes.size() / 2] ^ 0x55);
  CHECK(replay::readPng(tmp.write("flipped.png", flipped), out).code() == Error::kBadInput);
}
