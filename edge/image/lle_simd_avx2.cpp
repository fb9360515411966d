// The AVX2 build of the LLE row kernels (lle_simd.inl), compiled with -mavx2 and used only
// when the CPU has AVX2 (checked at run time). Outside OpenCV's own build its headers
// enable SSE2 only: we declare the instruction sets this file is compiled for, and a
// dispatch mode, which puts OpenCV's intrinsics in a namespace of their own (hal_AVX2).
#if !defined(__AVX2__)
#error "lle_simd_avx2.cpp must be compiled with -mavx2"
#endif
#include <immintrin.h>
#define CV_CPU_DISPATCH_MODE AVX2
#define CV_SSE3 1
#define CV_SSSE3 1
#define CV_SSE4_1 1
#define CV_SSE4_2 1
#define CV_AVX 1
#define CV_AVX2 1
#define LLE_SIMD_NAME "avx2"
#define LLE_SIMD_NS avx2
#include "image/lle_simd.inl"

namespace alacs::image::detail {

const SimdKernels* simdKernelsAvx2() {
  static const bool supported = __builtin_cpu_supports("avx2") != 0;
  return supported ? avx2::kernels() : nullptr;
}

}  // namespace alacs::image::detail
