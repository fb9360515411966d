#include "replay/png_io.h"

#include <fcntl.h>
#include <png.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
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

uint32_t bigEndian32(const png_byte* p) {
  return (uint32_t{p[0]} << 24) | (uint32_t{p[1]} << 16) | (uint32_t{p[2]} << 8) | uint32_t{p[3]};
}

// Checks the IHDR chunk (the 25 bytes after the signature) before libpng sees the file:
// the declared size, bit depth and colour type. libpng checks the CRC when it reads the
// chunk again.
Status checkHeader(const std::string& path, const png_byte* ihdr) {
  if (bigEndian32(ihdr) != 13 || std::memcmp(ihdr + 4, "IHDR", 4) != 0)
    return {Error::kBadInput, "'" + path + "': the PNG does not start with its IHDR header"};
  const uint32_t width = bigEndian32(ihdr + 8);
  const uint32_t height = bigEndian32(ihdr + 12);
  const int depth = ihdr[16];
  const int colour = ihdr[17];
  const std::string declared = std::to_string(width) + " x " + std::to_string(height);
  if (width == 0 || height == 0)
    return {Error::kBadInput, "'" + path + "': the PNG header declares " + declared + " pixels"};
  if (width > kMaxPngSidePx || height > kMaxPngSidePx ||
      uint64_t{width} * height * 3U > uint64_t{kMaxPngDecodedBytes})
    return {Error::kBadInput, "'" + path + "': the PNG header declares " + declared + " pixels, beyond the limit of " +
                                  std::to_string(kMaxPngSidePx) + " x " + std::to_string(kMaxPngSidePx) + " and " +
                                  std::to_string(kMaxPngDecodedBytes >> 20) + " MiB decoded"};
  // The combinations of the PNG specification (11.2.2).
  bool valid = false;
  switch (colour) {
    case PNG_COLOR_TYPE_GRAY: valid = depth == 1 || depth == 2 || depth == 4 || depth == 8 || depth == 16; break;
    case PNG_COLOR_TYPE_PALETTE: valid = depth == 1 || depth == 2 || depth == 4 || depth == 8; break;
    case PNG_COLOR_TYPE_RGB:
    case PNG_COLOR_TYPE_GRAY_ALPHA:
    case PNG_COLOR_TYPE_RGB_ALPHA: valid = depth == 8 || depth == 16; break;
    default: break;
  }
  if (!valid)
    return {Error::kBadInput, "'" + path + "' (" + declared + "): the PNG header declares colour type " +
                                  std::to_string(colour) + " at bit depth " + std::to_string(depth) +
                                  ", not a valid combination"};
  return Status::ok();
}

// Decodes `file` (owned from here on) into `out`: allocated (or reused) when `allocate`,
// else it must have the size. `path` names it in errors.
Status decode(FILE* file, const std::string& path, cv::Mat& out, bool allocate) {
  PngState s;
  s.file = file;
  png_byte head[8 + 25] = {};  // the signature, then the IHDR chunk: length, type, 13 bytes, CRC
  const size_t got = std::fread(head, 1, sizeof head, s.file);
  if (got < 8 || png_sig_cmp(head, 0, 8) != 0) return {Error::kBadInput, "'" + path + "' is not a PNG file"};
  if (got < sizeof head) return {Error::kBadInput, "'" + path + "': the PNG is cut short in its header"};
  if (Status st = checkHeader(path, head + 8); !st) return st;
  if (std::fseek(s.file, 8, SEEK_SET) != 0) return {Error::kIo, "cannot read '" + path + "': " + std::strerror(errno)};
  s.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &s, onError, onWarning);
  if (s.png == nullptr) return {Error::kInternal, "libpng: out of memory"};
  s.info = png_create_info_struct(s.png);
  if (s.info == nullptr) return {Error::kInternal, "libpng: out of memory"};
  if (setjmp(png_jmpbuf(s.png))) return {Error::kBadInput, "'" + path + "': " + s.message};
  png_set_user_limits(s.png, kMaxPngSidePx, kMaxPngSidePx);
  png_set_chunk_malloc_max(s.png, kMaxPngChunkBytes);
  png_set_chunk_cache_max(s.png, 64);  // ancillary chunks kept (sPLT, text, unknown)
  png_init_io(s.png, s.file);
  png_set_sig_bytes(s.png, 8);
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

Status openAndDecode(const std::string& path, cv::Mat& out, bool allocate) {
  FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr)
    return {errno == ENOENT ? Error::kNotFound : Error::kIo, "cannot open '" + path + "': " + std::strerror(errno)};
  return decode(file, path, out, allocate);
}

}  // namespace

Status readPng(const std::string& path, cv::Mat& out) { return openAndDecode(path, out, true); }

Status readPngInto(const std::string& path, cv::Mat& dst) { return openAndDecode(path, dst, false); }

Status readPngInto(int fd, const std::string& name, cv::Mat& dst) {
  const int own = ::fcntl(fd, F_DUPFD_CLOEXEC, 0);
  if (own < 0) return {Error::kIo, "cannot read '" + name + "': " + std::strerror(errno)};
  FILE* file = ::fdopen(own, "rb");
  if (file == nullptr) {
    ::close(own);
    return {Error::kIo, "cannot read '" + name + "': " + std::strerror(errno)};
  }
  return decode(file, name, dst, false);
}

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
