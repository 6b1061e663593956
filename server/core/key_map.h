#pragma once
// A hash map from 64-bit keys to 32-bit values with open addressing (linear
// probing) in one array: several times faster than std::unordered_map for
// the millions of cell and block lookups of a surface reconstruction, and
// safe to read from many threads once built. No erase.
#include <cstddef>
#include <cstdint>
#include <vector>

namespace fc {

class KeyMap {
 public:
  static constexpr uint64_t kEmpty = ~uint64_t(0);  // never a key
  static constexpr uint32_t kMissing = ~uint32_t(0);

  explicit KeyMap(size_t expected = 16) { rehash(expected); }

  size_t size() const { return size_; }

  // The value of `key`, kMissing when absent.
  uint32_t find(uint64_t key) const {
    for (size_t i = slot(key);; i = (i + 1) & mask_) {
      if (keys_[i] == key) return values_[i];
      if (keys_[i] == kEmpty) return kMissing;
    }
  }
  bool contains(uint64_t key) const { return find(key) != kMissing; }

  // The value slot of `key`, inserted with `value` when absent; the bool
  // says whether it was inserted.
  std::pair<uint32_t*, bool> insert(uint64_t key, uint32_t value) {
    if (2 * (size_ + 1) > keys_.size()) rehash(2 * (size_ + 1));
    for (size_t i = slot(key);; i = (i + 1) & mask_) {
      if (keys_[i] == key) return {&values_[i], false};
      if (keys_[i] == kEmpty) {
        keys_[i] = key;
        values_[i] = value;
        ++size_;
        return {&values_[i], true};
      }
    }
  }

  // Calls f(key, value) for every entry, in no particular order.
  template <class F>
  void forEach(F&& f) const {
    for (size_t i = 0; i < keys_.size(); ++i)
      if (keys_[i] != kEmpty) f(keys_[i], values_[i]);
  }

 private:
  size_t slot(uint64_t key) const {
    // Murmur3's finaliser: neighbouring cells' keys differ in a few low bits.
    key ^= key >> 33;
    key *= 0xff51afd7ed558ccdULL;
    key ^= key >> 33;
    key *= 0xc4ceb9fe1a85ec53ULL;
    key ^= key >> 33;
    return size_t(key) & mask_;
  }
  void rehash(size_t expected) {
    size_t capacity = 16;
    while (capacity < 2 * expected) capacity *= 2;
    std::vector<uint64_t> oldKeys(capacity, kEmpty);
    std::vector<uint32_t> oldValues(capacity);
    oldKeys.swap(keys_);
    oldValues.swap(values_);
    mask_ = capacity - 1;
    size_ = 0;
    for (size_t i = 0; i < oldKeys.size(); ++i)
      if (oldKeys[i] != kEmpty) insert(oldKeys[i], oldValues[i]);
  }

  std::vector<uint64_t> keys_;
  std::vector<uint32_t> values_;
  size_t mask_ = 0, size_ = 0;
};

}  // namespace fc
