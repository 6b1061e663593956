#include "core/large_allocations.h"

#include <cstdlib>  // defines __GLIBC__ where the C library is glibc

#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace fc {

void reuseLargeAllocations() {
#if defined(__GLIBC__)
  constexpr int kLarge = 1 << 30;  // bytes: a buffer above this is still mapped on its own
  mallopt(M_MMAP_THRESHOLD, kLarge);
  mallopt(M_TRIM_THRESHOLD, kLarge);
#endif
}

}  // namespace fc
