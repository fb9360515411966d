// The AVX-512 (F, BW, VL, DQ, CD: OpenCV's "SKX" level) build of the LLE row kernels
// (lle_simd.inl), used only when the CPU has them (checked at run time). As for AVX2, we
// declare to OpenCV's headers what this file is compiled for.
#if !defined(__AVX512BW__) || !defined(__AVX512VL__) || !defined(__AVX512DQ__)
#error "lle_simd_avx512.cpp must be compiled with -mavx512f -mavx512bw -mavx512vl -mavx512dq -mavx512cd"
#endif
#include <immintrin.h>
#define CV_CPU_DISPATCH_MODE AVX512_SKX
#define CV_SSE3 1
#define CV_SSSE3 1
#define CV_SSE4_1 1
#define CV_SSE4_2 1
#define CV_AVX 1
#define CV_AVX2 1
#define CV_AVX_512F 1
#define CV_AVX_512BW 1
#define CV_AVX_512VL 1
#define CV_AVX_512DQ 1
#define CV_AVX_512CD 1
#define CV_AVX512_SKX 1
#define LLE_SIMD_NAME "avx512"
#define LLE_SIMD_NS avx512
// GCC 12 warns inside its own _mm512_alignr_epi32 (an intentionally undefined operand).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include "image/lle_simd.inl"
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif

namespace alacs::image::detail {

const SimdKernels* simdKernelsAvx512() {
  static const bool supported = __builtin_cpu_supports("avx512f") != 0 && __builtin_cpu_supports("avx512bw") != 0 &&
                                __builtin_cpu_supports("avx512vl") != 0 && __builtin_cpu_supports("avx512dq") != 0 &&
                                __builtin_cpu_supports("avx512cd") != 0;
  return supported ? avx512::kernels() : nullptr;
}

}  // namespace alacs::image::detail
