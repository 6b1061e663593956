// A session's recorded frames and their stale range: see frame_history.h.
#include "service/frame_history.h"

#include <algorithm>

namespace fc::service {

namespace {
template <class It>
It lowerBound(It begin, It end, int frame) {
  return std::lower_bound(begin, end, frame, [](const FramePtr& f, int n) { return f->frame < n; });
}
}  // namespace

void FrameHistory::clear() {
  frames_.clear();
  bytes_ = 0;
  dropped_ = 0;
  staleFrom_ = INT_MAX;
}

void FrameHistory::append(const FramePtr& f) {
  frames_.push_back(f);
  bytes_ += f->byteSize;
}

void FrameHistory::store(const FramePtr& f) {
  if (!frames_.empty() && f->frame <= last()) {
    auto it = lowerBound(frames_.begin(), frames_.end(), f->frame);
    if (it != frames_.end() && (*it)->frame == f->frame) {
      bytes_ = bytes_ - (*it)->byteSize + f->byteSize;
      *it = f;
    }
    // else: dropped by the memory cap before; it stays dropped.
  } else {
    append(f);
  }
  if (staleFrom_ <= f->frame) staleFrom_ = f->frame + 1;
  normalizeStale();
}

void FrameHistory::fit(size_t capBytes, size_t heldElsewhere) {
  while (bytes_ + heldElsewhere > capBytes && !frames_.empty()) {
    bytes_ -= frames_.front()->byteSize;
    frames_.pop_front();
    ++dropped_;
  }
  normalizeStale();
}

FramePtr FrameHistory::find(int frame) const {
  auto it = lowerBound(frames_.begin(), frames_.end(), frame);
  return it != frames_.end() && (*it)->frame == frame ? *it : nullptr;
}

std::vector<FramePtr> FrameHistory::within(int first, int last) const {
  std::vector<FramePtr> out;
  for (auto it = lowerBound(frames_.begin(), frames_.end(), first); it != frames_.end() && (*it)->frame <= last; ++it)
    out.push_back(*it);
  return out;
}

std::vector<FramePtr> FrameHistory::contiguous(int first, int last) const {
  std::vector<FramePtr> out;
  auto it = lowerBound(frames_.begin(), frames_.end(), first);
  for (long long f = first; f <= last; ++f, ++it) {
    if (it == frames_.end() || (*it)->frame != f)
      throw std::out_of_range("frame " + std::to_string(f) + " is not in the history (" + keptText() + ")");
    out.push_back(*it);
  }
  return out;
}

std::string FrameHistory::keptText() const {
  return frames_.empty() ? std::string("the history is empty")
                         : "frames " + std::to_string(first()) + " to " + std::to_string(last()) + " are kept";
}

void FrameHistory::markStaleFrom(int frame) {
  staleFrom_ = std::min(staleFrom_, frame);
  normalizeStale();
}

void FrameHistory::setStaleFrom(int frame) {
  staleFrom_ = frame;
  normalizeStale();
}

void FrameHistory::normalizeStale() {
  if (frames_.empty() || staleFrom_ > last()) staleFrom_ = INT_MAX;
}

void FrameHistory::throwIfStale(int first, int last, int liveFrame) const {
  if (staleFrom_ == INT_MAX || staleFrom_ > last) return;
  throw StaleFramesError("frames " + std::to_string(std::max(first, staleFrom_)) + " to " + std::to_string(last) +
                         " are stale: an edit changed them and the session is re-simulating them (now at frame " +
                         std::to_string(liveFrame) + "); try again once the cache is valid");
}

nlohmann::json FrameHistory::summary(size_t capBytes) const {
  using nlohmann::json;
  return {{"frames", frames_.size()},
          {"bytes", bytes_},
          {"cap", capBytes},
          {"dropped", dropped_},
          {"first", frames_.empty() ? json(nullptr) : json(first())},
          {"last", frames_.empty() ? json(nullptr) : json(last())}};
}

nlohmann::json FrameHistory::validRanges() const {
  nlohmann::json valid = nlohmann::json::array();
  if (frames_.empty()) return valid;
  const int staleFrom = std::max(first(), staleFrom_);
  if (staleFrom > first()) valid.push_back({first(), std::min(last(), staleFrom - 1)});
  return valid;
}

nlohmann::json FrameHistory::staleRanges() const {
  nlohmann::json stale = nlohmann::json::array();
  if (frames_.empty()) return stale;
  const int staleFrom = std::max(first(), staleFrom_);
  if (staleFrom <= last()) stale.push_back({staleFrom, last()});
  return stale;
}

}  // namespace fc::service
