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

// Σ_k w[k] (h² − ‖x_k − p‖²)³ over ranges [begin, end) of per-axis
// coordinate arrays, summed sixteen at a time where the CPU has AVX-512
// (float builds), one at a time otherwise; total() scales by Poly6's
// coefficient. One accumulator across every range added, so that a sum
// over grid rows and one over a packed copy of the same points round alike.
template <int D>
class Poly6Accumulator {
 public:
  Poly6Accumulator(const Poly6<D>& kernel, const Vec<D>& p)
      : h2_(kernel.radius() * kernel.radius()), kc_(kernel.coefficient()), p_(p) {
#if defined(__AVX512F__)
    if constexpr (kVectorSums) {
      for (int d = 0; d < D; ++d) pv_[d] = _mm512_set1_ps(p[d]);
      h2v_ = _mm512_set1_ps(h2_);
      acc_ = _mm512_setzero_ps();
    }
#endif
  }
  void add(const Real* const* xs, const Real* w, size_t begin, size_t end) {
    if constexpr (kVectorSums) {
#if defined(__AVX512F__)
      for (size_t k = begin; k < end; k += 16) {
        const __mmask16 live = end - k >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (end - k)) - 1);
        __m512 d2 = _mm512_setzero_ps();
        for (int d = 0; d < D; ++d) {
          const __m512 dd = _mm512_sub_ps(_mm512_maskz_loadu_ps(live, xs[d] + k), pv_[d]);
          d2 = _mm512_fmadd_ps(dd, dd, d2);
        }
        const __mmask16 hit = _mm512_mask_cmp_ps_mask(live, d2, h2v_, _CMP_LT_OQ);
        const __m512 t = _mm512_maskz_sub_ps(hit, h2v_, d2);
        acc_ = _mm512_fmadd_ps(_mm512_mul_ps(_mm512_mul_ps(t, t), t), _mm512_maskz_loadu_ps(hit, w + k), acc_);
      }
#endif
    } else {
      for (size_t k = begin; k < end; ++k) {
        Real d2 = 0;
        for (int d = 0; d < D; ++d) d2 += (xs[d][k] - p_[d]) * (xs[d][k] - p_[d]);
        if (d2 < h2_) {
          const Real t = h2_ - d2;
          sum_ += w[k] * t * t * t;
        }
      }
    }
  }
  Real total() const {
#if defined(__AVX512F__)
    if constexpr (kVectorSums) return kc_ * _mm512_reduce_add_ps(acc_);
#endif
    return kc_ * sum_;
  }

 private:
  Real h2_, kc_;
  Vec<D> p_;
  Real sum_ = 0;
#if defined(__AVX512F__)
  __m512 pv_[D], h2v_, acc_;
#endif
};

// Σ_k weight[k] W(‖x_k − p‖, h) over the grid's static points, weight given
// in the grid's cell order (staticOrder()).
template <int D>
Real poly6Sum(const NeighborhoodSearch<D>& grid, const Poly6<D>& kernel, const Vec<D>& p, const Real* weight) {
  const Real* xs[D];
  for (int d = 0; d < D; ++d) xs[d] = grid.staticSorted(d);
  Poly6Accumulator<D> sum(kernel, p);
  grid.forEachStaticRange(p, kernel.radius(), [&](uint32_t b, uint32_t e) { sum.add(xs, weight, b, e); });
  return sum.total();
}

// (Σ_{k in [begin, end)} a[d][k])_d: one per-axis sum over a particle's
// pair range (its pair gradients, say). Sixteen at a time with one
// horizontal sum per axis where the CPU has AVX-512 (float builds): GCC's
// `omp simd reduction` over such short ranges stores its lanes and adds
// them one scalar at a time, which cost more than the loop itself.
template <int D>
Vec<D> sumRanges(const Real* const* a, size_t begin, size_t end) {
  Vec<D> out;
  if constexpr (kVectorSums) {
#if defined(__AVX512F__)
    __m512 acc[D];
    for (int d = 0; d < D; ++d) acc[d] = _mm512_setzero_ps();
    for (size_t k = begin; k < end; k += 16) {
      const __mmask16 live = end - k >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (end - k)) - 1);
      for (int d = 0; d < D; ++d) acc[d] = _mm512_add_ps(acc[d], _mm512_maskz_loadu_ps(live, a[d] + k));
    }
    for (int d = 0; d < D; ++d) out[d] = _mm512_reduce_add_ps(acc[d]);
#endif
  } else {
    out.setZero();
    for (size_t k = begin; k < end; ++k)
      for (int d = 0; d < D; ++d) out[d] += a[d][k];
  }
  return out;
}

}  // namespace fc
