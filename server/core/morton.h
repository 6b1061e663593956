#pragma once
// Morton (Z-order) codes of non-negative cell coordinates.
#include <cstdint>

namespace fc {

inline uint64_t spreadBits2(uint64_t x) {  // 32 bits -> every 2nd bit
  x &= 0xffffffffull;
  x = (x | (x << 16)) & 0x0000ffff0000ffffull;
  x = (x | (x << 8)) & 0x00ff00ff00ff00ffull;
  x = (x | (x << 4)) & 0x0f0f0f0f0f0f0f0full;
  x = (x | (x << 2)) & 0x3333333333333333ull;
  x = (x | (x << 1)) & 0x5555555555555555ull;
  return x;
}
inline uint64_t spreadBits3(uint64_t x) {  // 21 bits -> every 3rd bit
  x &= 0x1fffffull;
  x = (x | (x << 32)) & 0x1f00000000ffffull;
  x = (x | (x << 16)) & 0x1f0000ff0000ffull;
  x = (x | (x << 8)) & 0x100f00f00f00f00full;
  x = (x | (x << 4)) & 0x10c30c30c30c30c3ull;
  x = (x | (x << 2)) & 0x1249249249249249ull;
  return x;
}
inline uint64_t morton2(uint32_t x, uint32_t y) { return spreadBits2(x) | (spreadBits2(y) << 1); }
inline uint64_t morton3(uint32_t x, uint32_t y, uint32_t z) {
  return spreadBits3(x) | (spreadBits3(y) << 1) | (spreadBits3(z) << 2);
}

}  // namespace fc
