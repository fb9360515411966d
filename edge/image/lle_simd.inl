// The LLE row kernels in OpenCV's universal intrinsics: one source for NEON (aarch64),
// SSE2 (x86-64 baseline), AVX2 and AVX-512 (x86-64, chosen at run time). Included by
// lle_simd.cpp, lle_simd_avx2.cpp and lle_simd_avx512.cpp with LLE_SIMD_NS set to a
// namespace of their own, so that the instruction sets never share an inline function.
//
// Contract: the scalar kernels in lle_mask.cpp; the tests require bit-exact agreement.
// The vector loop covers whole vectors; the red row is padded (kRedPad zero bytes each
// side) and bRCE is masked with validLanes, so there is no scalar tail in brceRow.

#include <opencv2/core/hal/intrin.hpp>

#include "image/lle_internal.h"

namespace alacs::image::detail::LLE_SIMD_NS {

#if CV_SIMD

namespace {

using cv::v_uint8;

constexpr int kLanes = v_uint8::nlanes;
static_assert(64 % kLanes == 0, "a mask word holds whole vectors");
constexpr uint64_t kLaneBits = kLanes == 64 ? ~uint64_t{0} : (uint64_t{1} << (kLanes % 64)) - 1;

// Adds the lanes of `r` at full scale (x: its first lane) to `full`, exactly as the scalar
// kernel finds them; a branch rarely taken (a clipped line core, glare).
inline void addFullScale(const v_uint8& r, int x, FullScaleSpan& full) {
  const v_uint8 eq = r == cv::vx_setall_u8(255);
  if (!cv::v_check_any(eq)) return;
  const uint64_t bits = static_cast<uint64_t>(cv::v_signmask(cv::v_reinterpret_as_s8(eq))) & kLaneBits;
  full.add(x + __builtin_ctzll(bits), x + 63 - __builtin_clzll(bits));
}

// The red of each pixel of a row; kOff: less the laser-off frame's. A running maximum tells
// whether any lane of the laser frame's red reached full scale; only then is the row read
// again for where (clipped cores and glare: a minority of rows), which keeps the compare and
// its mask out of the loop that streams the frame.
template <int kRedOffset, bool kOff>
FullScaleSpan redRowT(const uint8_t* on, const uint8_t* off, int w, uint8_t* red) {
  int x = 0;
  v_uint8 peak = cv::vx_setzero_u8();
  for (; x <= w - kLanes; x += kLanes) {
    v_uint8 b0, b1, b2;
    cv::v_load_deinterleave(on + 3 * x, b0, b1, b2);
    const v_uint8 r = kRedOffset == 0 ? b0 : b2;
    peak = cv::v_max(peak, r);
    if constexpr (kOff) {
      v_uint8 o0, o1, o2;
      cv::v_load_deinterleave(off + 3 * x, o0, o1, o2);
      // operator- on u8 saturates: max(0, on - off), as the scalar kernel.
      cv::v_store(red + x, r - (kRedOffset == 0 ? o0 : o2));
    } else {
      cv::v_store(red + x, r);
    }
  }
  FullScaleSpan full;
  if (cv::v_reduce_max(peak) == 255) {
    for (int xf = 0; xf < x; xf += kLanes) {
      v_uint8 b0, b1, b2;
      cv::v_load_deinterleave(on + 3 * xf, b0, b1, b2);
      addFullScale(kRedOffset == 0 ? b0 : b2, xf, full);
    }
  }
  if (x < w) {
    const FullScaleSpan tail = redRowScalar(on + 3 * x, kOff ? off + 3 * x : nullptr, kRedOffset, w - x, red + x);
    if (tail.any()) full.add(x + tail.first, x + tail.last);
  }
  return full;
}

FullScaleSpan redRow(const uint8_t* on, const uint8_t* off, int redOffset, int w, uint8_t* red) {
  if (off == nullptr) return redOffset == 0 ? redRowT<0, false>(on, off, w, red) : redRowT<2, false>(on, off, w, red);
  return redOffset == 0 ? redRowT<0, true>(on, off, w, red) : redRowT<2, true>(on, off, w, red);
}

void averageRows(const uint8_t* above, const uint8_t* mid, const uint8_t* below, int w, uint8_t* out) {
  int x = 0;
  // In 16 bits: outer = (above + below + 1) >> 1, then v_rshr_pack<1> gives (outer + mid + 1) >> 1.
  const cv::v_uint16 one = cv::vx_setall_u16(1);
  for (; x <= w - kLanes; x += kLanes) {
    cv::v_uint16 a0, a1, b0, b1, m0, m1;
    cv::v_expand(cv::vx_load(above + x), a0, a1);
    cv::v_expand(cv::vx_load(below + x), b0, b1);
    cv::v_expand(cv::vx_load(mid + x), m0, m1);
    const cv::v_uint16 t0 = cv::v_shr<1>(a0 + b0 + one) + m0;
    const cv::v_uint16 t1 = cv::v_shr<1>(a1 + b1 + one) + m1;
    cv::v_store(out + x, cv::v_rshr_pack<1>(t0, t1));
  }
  if (x < w) averageRowsScalar(above + x, mid + x, below + x, w - x, out + x);
}

template <bool kLiteral>
uint64_t brceRowT(const uint8_t* red, const uint8_t* validLanes, int wv, int step, int threshold, uint8_t* counts8,
                  uint64_t* bits) {
  uint64_t any = 0;
  const v_uint8 th = cv::vx_setall_u8(static_cast<uint8_t>(threshold));
  const v_uint8 zero = cv::vx_setzero_u8();
  const v_uint8 top = cv::vx_setall_u8(0x7F);  // d + 0x7F (saturating) has its top bit set exactly where d != 0
  for (int x0 = 0; x0 < wv; x0 += 64) {
    uint64_t word = 0;
    for (int k = 0; k < 64; k += kLanes) {
      const int x = x0 + k;
      const v_uint8 c = cv::vx_load(red + x);
      const v_uint8 l = cv::vx_load(red + x - step);
      const v_uint8 r = cv::vx_load(red + x + step);
      // d is non-zero exactly where the scalar kernel marks a candidate: u8 + and -
      // saturate, so no unsigned compare (and no mask register) is needed.
      v_uint8 d;
      if constexpr (kLiteral) {
        // The printed form on uint8: (l - c) and (r - c) wrap modulo 256; each > th.
        d = cv::v_min(cv::v_sub_wrap(l, c) - th, cv::v_sub_wrap(r, c) - th);
      } else {
        // c - l > th  <=>  c -sat (l +sat th) != 0.
        d = cv::v_min(c - (l + th), c - (r + th));
      }
      // Most vectors of a row hold no candidate (the line is a few pixels wide): only
      // those that do read validLanes and the counters. validLanes is 1 where bRCE may
      // fire: one (0 or 1) a lane, counted as it is.
      if ((static_cast<uint64_t>(cv::v_signmask(cv::v_reinterpret_as_s8(d + top))) & kLaneBits) == 0) continue;
      const v_uint8 one = cv::v_min(d, cv::vx_load(validLanes + x));
      cv::v_store(counts8 + x, cv::v_add_wrap(cv::vx_load(counts8 + x), one));
      const v_uint8 m = cv::v_sub_wrap(zero, one);  // 0xFF for a candidate
      word |= (static_cast<uint64_t>(cv::v_signmask(cv::v_reinterpret_as_s8(m))) & kLaneBits) << k;
    }
    bits[x0 / 64] = word;
    any |= word;
  }
  return any;
}

uint64_t brceRow(const uint8_t* red, const uint8_t* validLanes, int wv, int step, int threshold, BrceForm form,
                 uint8_t* counts8, uint64_t* bits) {
  if (form == BrceForm::kLiteral) return brceRowT<true>(red, validLanes, wv, step, threshold, counts8, bits);
  return brceRowT<false>(red, validLanes, wv, step, threshold, counts8, bits);
}

}  // namespace

const SimdKernels* kernels() {
  static const SimdKernels k{LLE_SIMD_NAME, &redRow, &brceRow, &averageRows};
  return &k;
}

#else

const SimdKernels* kernels() { return nullptr; }

#endif

}  // namespace alacs::image::detail::LLE_SIMD_NS
