// A session's checkpoints: see checkpoints.h.
#include "service/checkpoints.h"

#include <zlib.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <stdexcept>

namespace fc::service {

namespace {
constexpr size_t kWord = 4;
}

CheckpointStore::CheckpointStore(int every, size_t capBytes, bool compress, bool dense)
    : every_(std::max(0, every)), capBytes_(capBytes), compress_(compress), dense_(dense) {}

std::vector<uint8_t> CheckpointStore::compress(const std::vector<uint8_t>& raw) {
  const size_t n = raw.size(), words = n / kWord;
  std::vector<uint8_t> shuffled(n);
  for (size_t b = 0; b < kWord; ++b)
    for (size_t w = 0; w < words; ++w) shuffled[b * words + w] = raw[w * kWord + b];
  std::copy(raw.begin() + long(words * kWord), raw.end(), shuffled.begin() + long(words * kWord));
  uLongf size = compressBound(uLong(n));
  std::vector<uint8_t> out(size);
  if (compress2(out.data(), &size, shuffled.data(), uLong(n), Z_BEST_SPEED) != Z_OK)
    throw std::runtime_error("checkpoint compression failed");
  out.resize(size);
  return out;
}

std::vector<uint8_t> CheckpointStore::decompress(const std::vector<uint8_t>& packed, size_t rawSize) {
  std::vector<uint8_t> shuffled(rawSize);
  uLongf size = uLongf(rawSize);
  if (uncompress(shuffled.data(), &size, packed.data(), uLong(packed.size())) != Z_OK || size != rawSize)
    throw std::runtime_error("checkpoint decompression failed");
  const size_t words = rawSize / kWord;
  std::vector<uint8_t> raw(rawSize);
  for (size_t b = 0; b < kWord; ++b)
    for (size_t w = 0; w < words; ++w) raw[w * kWord + b] = shuffled[b * words + w];
  std::copy(shuffled.begin() + long(words * kWord), shuffled.end(), raw.begin() + long(words * kWord));
  return raw;
}

void CheckpointStore::put(int frame, const std::vector<uint8_t>& archive) {
  const auto t0 = std::chrono::steady_clock::now();
  dropFrom(frame);  // a newer one than this is from another timeline
  Entry e;
  e.rawSize = archive.size();
  // In-between checkpoints stay raw: they are saved after every frame, where
  // deflate would cost a tenth of a 3D frame; the grid's are kept longest.
  if (compress_ && onGrid(frame)) {
    std::vector<uint8_t> packed = compress(archive);
    if (packed.size() * 10 <= archive.size() * 9) {
      e.bytes = std::move(packed);
      e.compressed = true;
    }
  }
  if (!e.compressed) e.bytes = archive;
  bytes_ += e.bytes.size();
  rawBytes_ += e.rawSize;
  entries_[frame] = std::move(e);
  thin();
  figures_.saveMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

void CheckpointStore::erase(std::map<int, Entry>::iterator it) {
  bytes_ -= it->second.bytes.size();
  rawBytes_ -= it->second.rawSize;
  entries_.erase(it);
}

void CheckpointStore::thin() {
  // In-between checkpoints first, the farthest from the focus first.
  while (bytes_ > capBytes_) {
    auto far = entries_.end();
    for (auto it = entries_.begin(); it != entries_.end(); ++it)
      if (!onGrid(it->first) && (far == entries_.end() || std::abs(it->first - focus_) > std::abs(far->first - focus_)))
        far = it;
    if (far == entries_.end()) break;
    erase(far);
  }
  while (bytes_ > capBytes_ && !entries_.empty()) {
    if (entries_.size() == 1) {  // one checkpoint over the cap: none at all
      clear();
      return;
    }
    // Every other one from the oldest, the newest kept; a pass that frees
    // enough stops early.
    auto it = entries_.begin();
    while (it != entries_.end() && std::next(it) != entries_.end() && bytes_ > capBytes_) {
      bytes_ -= it->second.bytes.size();
      rawBytes_ -= it->second.rawSize;
      it = entries_.erase(it);
      if (it != entries_.end() && std::next(it) != entries_.end()) ++it;
    }
  }
}

int CheckpointStore::newestAtOrBefore(int frame, std::vector<uint8_t>& archive) const {
  auto it = entries_.upper_bound(frame);
  if (it == entries_.begin()) {
    archive.clear();
    return 0;
  }
  --it;
  const Entry& e = it->second;
  archive = e.compressed ? decompress(e.bytes, e.rawSize) : e.bytes;
  return it->first;
}

int CheckpointStore::newestFrameAtOrBefore(int frame) const {
  auto it = entries_.upper_bound(frame);
  return it == entries_.begin() ? 0 : std::prev(it)->first;
}

void CheckpointStore::dropFrom(int frame) {
  for (auto it = entries_.lower_bound(frame); it != entries_.end();) {
    bytes_ -= it->second.bytes.size();
    rawBytes_ -= it->second.rawSize;
    it = entries_.erase(it);
  }
}

void CheckpointStore::clear() {
  entries_.clear();
  bytes_ = rawBytes_ = 0;
}

std::vector<int> CheckpointStore::frames() const {
  std::vector<int> f;
  f.reserve(entries_.size());
  for (const auto& [k, e] : entries_) f.push_back(k);
  return f;
}

CheckpointStore::Figures CheckpointStore::figures() const {
  Figures f = figures_;
  f.count = entries_.size();
  f.bytes = bytes_;
  f.rawBytes = rawBytes_;
  return f;
}

}  // namespace fc::service
