#pragma once
// A vector whose resize() leaves new trivially constructible elements
// uninitialised: buffers that parallel loops fill whole are then first
// touched by those loops, on their threads, not zeroed on one before.
#include <memory>
#include <type_traits>
#include <utility>
#include <vector>

namespace fc {

template <class T>
struct DefaultInitAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = DefaultInitAllocator<U>;
  };
  DefaultInitAllocator() = default;
  template <class U>
  DefaultInitAllocator(const DefaultInitAllocator<U>&) noexcept {}
  // Default-initialise (nothing, for trivial types) where std::allocator value-initialises.
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

template <class T>
using FillVector = std::vector<T, DefaultInitAllocator<T>>;

}  // namespace fc
