// libFuzzer target for LLE's image entry point. The input chooses the frame's size,
// stride, pixel format, ROI and parameters (out-of-range values included) and supplies the
// pixels; extractLine must return a result or a clear error, never crash (ASan/UBSan
// watch), and when it succeeds:
//   - the SIMD kernels and the scalar kernels give identical results;
//   - the floating-point reference takes the same decisions and agrees within 1/64 px;
//   - samples are ascending by row, inside the ROI, with a confidence in [0, 1].
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "image/lle.h"

using namespace alacs::image;

namespace {

struct Reader {
  const uint8_t* p;
  size_t n;
  uint8_t byte() {
    if (n == 0) return 0;
    --n;
    return *p++;
  }
  int16_t i16() { return static_cast<int16_t>(byte() | (byte() << 8)); }
};

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_lle: invariant broken: %s\n", what);
  std::abort();
}

void checkLine(const LaserLine& l, const Roi& roi) {
  for (size_t i = 0; i < l.rows.size(); ++i) {
    const RowSample& s = l.rows[i];
    if (i > 0 && l.rows[i - 1].row > s.row) fail("rows not ascending");
    if (s.row < roi.y || s.row >= roi.y + roi.height) fail("row outside the ROI");
    if (!(s.confidence >= 0.0F && s.confidence <= 1.0F)) fail("confidence outside [0, 1]");
    if (!std::isfinite(s.column)) fail("non-finite column");
  }
  if (l.coverage < 0.0 || l.coverage > 1.0) fail("coverage outside [0, 1]");
}

bool same(const LaserLine& a, const LaserLine& b) {
  if (a.rows.size() != b.rows.size() || a.segments.size() != b.segments.size() || a.valid != b.valid ||
      a.coeffs != b.coeffs || a.inliers != b.inliers)
    return false;
  for (size_t i = 0; i < a.rows.size(); ++i) {
    const RowSample& x = a.rows[i];
    const RowSample& y = b.rows[i];
    if (x.row != y.row || x.columnQ8 != y.columnQ8 || x.centroidQ8 != y.centroidQ8 || x.status != y.status ||
        x.segment != y.segment || x.confidence != y.confidence || x.saturated != y.saturated)
      return false;
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Reader in{data, size};
  const int w = 1 + static_cast<int>((in.byte() | (in.byte() << 8)) % 320);
  const int h = 1 + static_cast<int>(in.byte() % 96);
  const uint8_t fmt = in.byte();
  const uint8_t strideByte = in.byte();
  Roi roi;
  roi.x = in.i16() % 400;
  roi.y = in.i16() % 120;
  roi.width = in.i16() % 400;
  roi.height = in.i16() % 120;
  LleParams p;
  p.brceStep = in.byte() % 70;
  p.brceThreshold = in.byte();
  p.noiseTheta = in.byte() % 40;
  p.noiseGamma = in.byte() % 12;
  p.polyOrder = in.byte() % 8;
  p.minRows = p.polyOrder + 1 + in.byte() % 12;
  const uint8_t flags = in.byte();
  p.method = (flags & 1) ? LleMethod::kPaper : LleMethod::kRobust;
  p.brceForm = (flags & 2) ? BrceForm::kLiteral : BrceForm::kMeaning;
  p.keepOtherSegments = (flags & 4) == 0;
  const bool useOff = (flags & 8) != 0;
  p.maxPeaksPerRow = 1 + in.byte() % 9;
  p.minSegmentRows = in.byte() % 10;
  p.maxGapRows = in.byte() % 8;
  p.maxJumpPx = 0.25 * (in.byte() % 40);
  p.smoothOrder = in.byte() % 4;
  p.smoothRows = in.byte() % 40;
  p.outlierPx = 0.1 * (in.byte() % 60);

  // The frame: exactly h rows of `stride` bytes, so that any over-read is reported.
  size_t stride = static_cast<size_t>(w) * 3U + (strideByte & 7U);
  if (strideByte & 0x80) stride = static_cast<size_t>(w) * 3U - 1U;  // too small: must be refused
  std::vector<uint8_t> px(stride * static_cast<size_t>(h));
  std::vector<uint8_t> offPx(px.size());
  for (size_t i = 0; i < px.size(); ++i) {
    px[i] = in.n > 0 ? in.byte() : static_cast<uint8_t>(i * 37U);
    // A third of the ambient, or (every 5th byte) all of it: where the frame is at 255 the
    // laser-off frame is then too, as under glare (RunSums::clipped).
    offPx[i] = i % 5U == 0 ? px[i] : static_cast<uint8_t>(px[i] / 3U);
  }
  ImageView frame{px.data(), w, h, stride, static_cast<PixelFormat>(fmt % 3)};
  ImageView off{offPx.data(), w, h, stride, frame.format};

  LleWorkspace ws;
  LaserLine simd, scalar, ref;
  const alacs::Status s1 = extractLine(frame, roi, p, ws, simd, useOff ? &off : nullptr);
  if (!s1) {
    if (s1.reason().empty()) fail("an error without a reason");
    if (s1.code() != alacs::Error::kBadInput && s1.code() != alacs::Error::kInvalidArgument) fail("unexpected error code");
    if (!simd.rows.empty()) fail("rows left after an error");
    return 0;
  }
  checkLine(simd, roi);
  p.kernels = LleKernels::kScalar;
  if (!extractLine(frame, roi, p, ws, scalar, useOff ? &off : nullptr)) fail("scalar path refused what SIMD took");
  if (!same(simd, scalar)) fail("SIMD and scalar kernels differ");
  if (!extractLineReference(frame, roi, p, ref, useOff ? &off : nullptr)) fail("reference refused what fixed took");
  if (ref.rows.size() != simd.rows.size() || ref.valid != simd.valid) fail("reference decided otherwise");
  for (size_t i = 0; i < ref.rows.size(); ++i) {
    if (ref.rows[i].row != simd.rows[i].row || ref.rows[i].status != simd.rows[i].status) fail("reference decided otherwise");
    if (std::abs(ref.rows[i].column - simd.rows[i].column) > 1.0F / 64.0F) fail("fixed point off the reference by > 1/64 px");
  }
  // The allocating overload (which takes no laser-off frame) gives the same.
  if (!useOff) {
    p.kernels = LleKernels::kAuto;
    const alacs::Result<LaserLine> r = extractLine(frame, roi, p, ws);
    if (!r || !same(*r, simd)) fail("Result overload differs");
  }
  return 0;
}
