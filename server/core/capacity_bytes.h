#pragma once
// The heap a vector holds (its capacity, not its size), for the memory
// figures a run, the template cache and the frame history report.
#include <cstddef>
#include <vector>

namespace fc {

template <class T, class A>
size_t capacityBytes(const std::vector<T, A>& v) {
  return v.capacity() * sizeof(T);
}

}  // namespace fc
