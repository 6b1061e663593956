#pragma once
// std::sort on the OpenMP threads: each thread sorts a run, then runs are
// merged in pairs, a round at a time. The result is std::sort's (for keys
// whose order is total, as the callers' are).
#include <omp.h>

#include <algorithm>
#include <cstddef>
#include <vector>

namespace fc {

template <class T>
void parallelSort(std::vector<T>& v) {
  const int threads = omp_get_max_threads();
  const size_t n = v.size();
  if (threads < 2 || n < (size_t(1) << 15)) {
    std::sort(v.begin(), v.end());
    return;
  }
  const size_t runs = size_t(threads);
  std::vector<size_t> bound(runs + 1);
  for (size_t r = 0; r <= runs; ++r) bound[r] = n * r / runs;
#pragma omp parallel for schedule(static, 1)
  for (size_t r = 0; r < runs; ++r) std::sort(v.begin() + std::ptrdiff_t(bound[r]), v.begin() + std::ptrdiff_t(bound[r + 1]));
  std::vector<T> scratch(n);
  std::vector<T>*from = &v, *to = &scratch;
  for (size_t width = 1; width < runs; width *= 2) {
#pragma omp parallel for schedule(static, 1)
    for (size_t r = 0; r < runs; r += 2 * width) {
      const size_t lo = bound[r], mid = bound[std::min(r + width, runs)], hi = bound[std::min(r + 2 * width, runs)];
      std::merge(from->begin() + std::ptrdiff_t(lo), from->begin() + std::ptrdiff_t(mid),
                 from->begin() + std::ptrdiff_t(mid), from->begin() + std::ptrdiff_t(hi),
                 to->begin() + std::ptrdiff_t(lo));
    }
    std::swap(from, to);
  }
  if (from != &v) v.swap(scratch);
}

}  // namespace fc
