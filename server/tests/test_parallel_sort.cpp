// parallelSort (core/parallel_sort.h): std::sort's result on any thread
// count, for runs that divide evenly and runs that do not.
#include "core/parallel_sort.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

namespace fc {
namespace {

TEST(ParallelSort, IsStdSortOnEveryThreadCount) {
  std::mt19937_64 rng(7);
  const int threads = omp_get_max_threads();
  for (const size_t n : {size_t(0), size_t(1), size_t(1000), size_t(40000), size_t(100003)}) {
    std::vector<std::pair<uint64_t, uint32_t>> keys(n);
    // Few distinct keys, so that the index decides many comparisons.
    for (size_t i = 0; i < n; ++i) keys[i] = {rng() % 997, uint32_t(rng())};
    std::vector<std::pair<uint64_t, uint32_t>> expected = keys;
    std::sort(expected.begin(), expected.end());
    for (const int t : {1, 2, 3, 5, 8}) {
      SCOPED_TRACE(testing::Message() << n << " keys on " << t << " threads");
      omp_set_num_threads(t);
      std::vector<std::pair<uint64_t, uint32_t>> sorted = keys;
      parallelSort(sorted);
      EXPECT_EQ(sorted, expected);
    }
  }
  omp_set_num_threads(threads);
}

}  // namespace
}  // namespace fc
