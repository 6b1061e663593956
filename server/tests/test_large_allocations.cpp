// reuseLargeAllocations (core/large_allocations.h): after it, a buffer of
// hundreds of MB comes from the heap and, freed, stays there for the next
// frame's, where glibc would map it afresh and unmap it.
#include "core/large_allocations.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <memory>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace fc {
namespace {

TEST(LargeAllocations, ComeFromTheHeapAndStayForReuse) {
#if defined(__GLIBC__)
  constexpr size_t kBig = size_t(256) << 20;
  const size_t mappedBefore = mallinfo2().hblkhd;
  reuseLargeAllocations();
  {
    std::unique_ptr<char[]> big(new char[kBig]);
    big[kBig - 1] = 1;
    EXPECT_EQ(mallinfo2().hblkhd, mappedBefore) << "mapped on its own";
  }
  EXPECT_GE(mallinfo2().fordblks, kBig) << "given back to the system when freed";
#else
  GTEST_SKIP() << "glibc's allocator only";
#endif
}

}  // namespace
}  // namespace fc
