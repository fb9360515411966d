// The baseline SIMD kernels: NEON on aarch64, SSE2 on x86-64 (see lle_simd.inl), and the
// run-time choice between them and the AVX2 and AVX-512 builds of the same source.
#if defined(__aarch64__) || defined(__ARM_NEON)
#define LLE_SIMD_NAME "neon"
#else
#define LLE_SIMD_NAME "sse2"
#endif
#define LLE_SIMD_NS baseline
#include "image/lle_simd.inl"

namespace alacs::image::detail {

#ifndef ALACS_LLE_AVX2
const SimdKernels* simdKernelsAvx2() { return nullptr; }
#endif
#ifndef ALACS_LLE_AVX512
const SimdKernels* simdKernelsAvx512() { return nullptr; }
#endif

const SimdKernels* simdKernelsBaseline() { return baseline::kernels(); }

const SimdKernels* simdKernels() {
  static const SimdKernels* const best = simdKernelsAvx512() != nullptr ? simdKernelsAvx512()
                                         : simdKernelsAvx2() != nullptr ? simdKernelsAvx2()
                                                                        : simdKernelsBaseline();
  return best;
}

}  // namespace alacs::image::detail
