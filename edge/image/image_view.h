// Non-owning views of 8-bit interleaved colour frames, as they come from libcamera, a
// PNG on disk, or the simulator. Pixel centres sit at integer coordinates (OpenCV's
// convention): a line whose centre is reported at column 10.5 lies halfway between
// pixel 10 and pixel 11.
#pragma once

#include <cstddef>
#include <cstdint>

namespace alacs::image {

enum class PixelFormat : uint8_t {
  kRgb888,  // memory order R, G, B
  kBgr888,  // memory order B, G, R (OpenCV's default)
};

constexpr int redOffset(PixelFormat f) { return f == PixelFormat::kRgb888 ? 0 : 2; }

struct ImageView {
  const uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  size_t strideBytes = 0;
  PixelFormat format = PixelFormat::kBgr888;

  const uint8_t* row(int y) const { return data + static_cast<size_t>(y) * strideBytes; }
};

// A rectangle of the frame, in full-frame pixels; [x, x+width) × [y, y+height).
struct Roi {
  int x = 0;
  int y = 0;
  int width = 0;
  int height = 0;
  bool empty() const { return width <= 0 || height <= 0; }
};

}  // namespace alacs::image
