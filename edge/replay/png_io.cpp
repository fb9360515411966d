#include "replay/png_io.h"

#include <png.h>

#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>

namespace alacs::replay {

namespace {

// libpng reports errors by longjmp to the setjmp of the function that drives it; the
// message is kept here. Between setjmp and the end of the decode no object with a
// destructor is created (the jump would skip it).
struct PngState {
  png_structp png = nullptr;
  png_infop info = nullptr;
  FILE* file = nullptr;
  bool writing = false;
  char message[200] = {};

  ~PngState() {
    if (png != nullptr) {
      if (writing)
        png_destroy_write_struct(&png, info != nullptr ? &info : nullptr);
      else
        png_destroy_read_struct(&png, info != nullptr ? &info : nullptr, nullptr);
    }
    if (file != nullptr) std::fclose(file);
  }
};

void onError(png_structp png, png_const_charp msg) {
  auto* s = static_cast<PngState*>(png_get_error_ptr(png));
  std::snprintf(s->message, sizeof s->message, "%s", msg);
  png_longjmp(png, 1);
}

void onWarning(png_structp, png_const_charp) {}

// Decodes into `out`: allocated (or reused) when `allocate`, else it must have the size.
Status decode(const std::string& path, cv::Mat& out, bool allocate) {
  PngState s;
  s.file = std::fopen(path.c_str(), "rb");
  if (s.file == nullptr)
    return {errno == ENOENT ? Error::kNotFound : Error::kIo, "cannot open '" + path + "': " + std::strerror(errno)};
  png_byte sig[8] = {};
  if (std::fread(sig, 1, sizeof sig, s.file) != sizeof sig || png_sig_cmp(sig, 0, sizeof sig) != 0)
    return {Error::kBadInput, "'" + path + "' is not a PNG file"};
  s.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &s, onError, onWarning);
  if (s.png == nullptr) return {Error::kInternal, "libpng: out of memory"};
  s.info = png_create_info_struct(s.png);
  if (s.info == nullptr) return {Error::kInternal, "libpng: out of memory"};
  if (setjmp(png_jmpbuf(s.png))) return {Error::kBadInput, "'" + path + "': " + s.message};
  png_init_io(s.png, s.file);
  png_set_sig_bytes(s.png, sizeof sig);
  png_read_info(s.png, s.info);
  const png_uint_32 width = png_get_image_width(s.png, s.info);
  const png_uint_32 height = png_get_image_height(s.png, s.info);
  const int colour = png_get_color_type(s.png, s.info);
  const int depth = png_get_bit_depth(s.png, s.info);
  // To 8-bit BGR, as imread(IMREAD_COLOR).
  if (colour == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(s.png);
  if (colour == PNG_COLOR_TYPE_GRAY && depth < 8) png_set_expand_gray_1_2_4_to_8(s.png);
  if (depth == 16) png_set_strip_16(s.png);
  if ((colour & PNG_COLOR_MASK_ALPHA) != 0) png_set_strip_alpha(s.png);
  if (colour == PNG_COLOR_TYPE_GRAY || colour == PNG_COLOR_TYPE_GRAY_ALPHA) png_set_gray_to_rgb(s.png);
  png_set_bgr(s.png);
  const int passes = png_set_interlace_handling(s.png);
  png_read_update_info(s.png, s.info);
  if (png_get_rowbytes(s.png, s.info) != static_cast<size_t>(width) * 3U)
    return {Error::kBadInput, "'" + path + "': unsupported PNG layout"};
  if (width > 1U << 15 || height > 1U << 15) return {Error::kBadInput, "'" + path + "': image too large"};
  const int w = static_cast<int>(width);
  const int h = static_cast<int>(height);
  if (allocate) {
    out.create(h, w, CV_8UC3);  // kept when it already has this size and type
  } else if (out.type() != CV_8UC3 || out.cols != w || out.rows != h) {
    return {Error::kBadInput, "'" + path + "' is " + std::to_string(w) + "x" + std::to_string(h) + ", expected " +
                                  std::to_string(out.cols) + "x" + std::to_string(out.rows)};
  }
  for (int pass = 0; pass < passes; ++pass)
    for (int y = 0; y < h; ++y) png_read_row(s.png, out.ptr<png_byte>(y), nullptr);
  png_read_end(s.png, nullptr);
  return Status::ok();
}

}  // namespace

Status readPng(const std::string& path, cv::Mat& out) { return decode(path, out, true); }

Status readPngInto(const std::string& path, cv::Mat& dst) { return decode(path, dst, false); }

Status writePng(const std::string& path, const cv::Mat& image, int level) {
  if (image.empty() || (image.type() != CV_8UC3 && image.type() != CV_8UC1))
    return {Error::kInvalidArgument, "PNG '" + path + "': an 8-bit BGR or grey image is needed"};
  if (level < 0 || level > 9) return {Error::kInvalidArgument, "PNG compression level must be 0..9"};
  PngState s;
  s.writing = true;
  s.file = std::fopen(path.c_str(), "wb");
  if (s.file == nullptr) return {Error::kIo, "cannot write '" + path + "': " + std::strerror(errno)};
  s.png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &s, onError, onWarning);
  if (s.png == nullptr) return {Error::kInternal, "libpng: out of memory"};
  s.info = png_create_info_struct(s.png);
  if (s.info == nullptr) return {Error::kInternal, "libpng: out of memory"};
  if (setjmp(png_jmpbuf(s.png))) return {Error::kIo, "cannot write '" + path + "': " + s.message};
  png_init_io(s.png, s.file);
  const bool colour = image.channels() == 3;
  png_set_IHDR(s.png, s.info, static_cast<png_uint_32>(image.cols), static_cast<png_uint_32>(image.rows), 8,
               colour ? PNG_COLOR_TYPE_RGB : PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_set_compression_level(s.png, level);
  png_write_info(s.png, s.info);
  if (colour) png_set_bgr(s.png);
  for (int y = 0; y < image.rows; ++y) png_write_row(s.png, image.ptr<png_byte>(y));
  png_write_end(s.png, nullptr);
  FILE* f = s.file;
  s.file = nullptr;
  if (std::fflush(f) != 0 || std::ferror(f) != 0) {
    std::fclose(f);
    return {Error::kIo, "cannot write '" + path + "': " + std::strerror(errno)};
  }
  if (std::fclose(f) != 0) return {Error::kIo, "cannot write '" + path + "': " + std::strerror(errno)};
  return Status::ok();
}

}  // namespace alacs::replay
