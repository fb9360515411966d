// The LLE row kernels in OpenCV's universal intrinsics: one source for NEON (aarch64),
// SSE2 (x86-64 baseline) and AVX2 (x86-64, chosen at run time). Included by
// lle_simd.cpp and lle_simd_avx2.cpp with LLE_SIMD_NS set to a namespace of their own,
// so that the two instruction sets never share an inline function (ODR).
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
using cv::v_uint16;

constexpr int kLanes = v_uint8::nlanes;
static_assert(64 % kLanes == 0, "a mask word holds whole vectors");

void redRow(const uint8_t* on, const uint8_t* off, int redOffset, int w, uint8_t* red) {
  int x = 0;
  if (off == nullptr) {
    for (; x <= w - kLanes; x += kLanes) {
      v_uint8 b0, b1, b2;
      cv::v_load_deinterleave(on + 3 * x, b0, b1, b2);
      cv::v_store(red + x, redOffset == 0 ? b0 : b2);
    }
  } else {
    for (; x <= w - kLanes; x += kLanes) {
      v_uint8 b0, b1, b2, o0, o1, o2;
      cv::v_load_deinterleave(on + 3 * x, b0, b1, b2);
      cv::v_load_deinterleave(off + 3 * x, o0, o1, o2);
      // operator- on u8 saturates: max(0, on - off), as the scalar kernel.
      cv::v_store(red + x, redOffset == 0 ? b0 - o0 : b2 - o2);
    }
  }
  if (x < w) redRowScalar(on + 3 * x, off == nullptr ? nullptr : off + 3 * x, redOffset, w - x, red + x);
}

template <bool kLiteral>
void brceRowT(const uint8_t* red, const uint8_t* validLanes, int wv, int step, int threshold,
              uint16_t* counts, uint64_t* bits) {
  const v_uint8 th = cv::vx_setall_u8(static_cast<uint8_t>(threshold));
  const v_uint8 one = cv::vx_setall_u8(1);
  for (int x0 = 0; x0 < wv; x0 += 64) {
    uint64_t word = 0;
    for (int k = 0; k < 64; k += kLanes) {
      const int x = x0 + k;
      const v_uint8 c = cv::vx_load(red + x);
      const v_uint8 l = cv::vx_load(red + x - step);
      const v_uint8 r = cv::vx_load(red + x + step);
      v_uint8 m;
      if constexpr (kLiteral) {
        // The printed form on uint8: (l - c) and (r - c) wrap modulo 256.
        m = (cv::v_sub_wrap(l, c) > th) & (cv::v_sub_wrap(r, c) > th);
      } else {
        // c - l > th  <=>  c > sat(l + th): when l + th saturates at 255, neither holds.
        m = (c > l + th) & (c > r + th);
      }
      m = m & cv::vx_load(validLanes + x);
      v_uint16 lo, hi;
      cv::v_expand(m & one, lo, hi);
      cv::v_store(counts + x, cv::vx_load(counts + x) + lo);
      cv::v_store(counts + x + kLanes / 2, cv::vx_load(counts + x + kLanes / 2) + hi);
      word |= static_cast<uint64_t>(static_cast<uint32_t>(cv::v_signmask(m))) << k;
    }
    bits[x0 / 64] = word;
  }
}

void brceRow(const uint8_t* red, const uint8_t* validLanes, int wv, int step, int threshold, BrceForm form,
             uint16_t* counts, uint64_t* bits) {
  if (form == BrceForm::kLiteral)
    brceRowT<true>(red, validLanes, wv, step, threshold, counts, bits);
  else
    brceRowT<false>(red, validLanes, wv, step, threshold, counts, bits);
}

}  // namespace

const SimdKernels* kernels() {
  static const SimdKernels k{LLE_SIMD_NAME, &redRow, &brceRow};
  return &k;
}

#else

const SimdKernels* kernels() { return nullptr; }

#endif

}  // namespace alacs::image::detail::LLE_SIMD_NS
