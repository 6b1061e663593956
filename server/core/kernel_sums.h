#pragma once
// Kernel sums over a NeighborhoodSearch's static points, read straight from
// its cell-sorted arrays: a row of candidates is tested and summed sixteen
// at a time where the CPU has AVX-512 (float builds), one at a time
// otherwise. Both paths skip pairs at or beyond h, where Poly6 is zero.
#include "core/kernels.h"
#include "core/neighborhood_search.h"
#include <type_traits>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif

namespace fc {

#if defined(__AVX512F__)
inline constexpr bool kVectorSums = std::is_same_v<Real, float>;
#else
inline constexpr bool kVectorSums = false;
#endif

// Σ_k weight[k] W(‖x_k − p‖, h) over the grid's static points, weight given
// in the grid's cell order (staticOrder()).
template <int D>
Real poly6Sum(const NeighborhoodSearch<D>& grid, const Poly6<D>& kernel, const Vec<D>& p, const Real* weight) {
  const Real h2 = kernel.radius() * kernel.radius(), kc = kernel.coefficient();
  const Real* xs[D];
  for (int d = 0; d < D; ++d) xs[d] = grid.staticSorted(d);
  Real sum = 0;
  if constexpr (kVectorSums) {
#if defined(__AVX512F__)
    __m512 pv[D];
    for (int d = 0; d < D; ++d) pv[d] = _mm512_set1_ps(p[d]);
    const __m512 h2v = _mm512_set1_ps(h2);
    __m512 acc = _mm512_setzero_ps();
    grid.forEachStaticRange(p, kernel.radius(), [&](uint32_t b, uint32_t e) {
      for (uint32_t k = b; k < e; k += 16) {
        const __mmask16 live = e - k >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (e - k)) - 1);
        __m512 d2 = _mm512_setzero_ps();
        for (int d = 0; d < D; ++d) {
          const __m512 dd = _mm512_sub_ps(_mm512_maskz_loadu_ps(live, xs[d] + k), pv[d]);
          d2 = _mm512_fmadd_ps(dd, dd, d2);
        }
        const __mmask16 hit = _mm512_mask_cmp_ps_mask(live, d2, h2v, _CMP_LT_OQ);
        const __m512 t = _mm512_maskz_sub_ps(hit, h2v, d2);
        acc = _mm512_fmadd_ps(_mm512_mul_ps(_mm512_mul_ps(t, t), t), _mm512_maskz_loadu_ps(hit, weight + k), acc);
      }
    });
    sum = _mm512_reduce_add_ps(acc);
#endif
  } else {
    grid.forEachStaticRange(p, kernel.radius(), [&](uint32_t b, uint32_t e) {
      for (uint32_t k = b; k < e; ++k) {
        Real d2 = 0;
        for (int d = 0; d < D; ++d) d2 += (xs[d][k] - p[d]) * (xs[d][k] - p[d]);
        if (d2 < h2) {
          const Real t = h2 - d2;
          sum += weight[k] * t * t * t;
        }
      }
    });
  }
  return kc * sum;
}

}  // namespace fc
