#pragma once
// The frames a session recorded, oldest first, within a memory cap, and the
// frames an edit made stale (the cache's valid and stale ranges). Not
// thread-safe: the session calls it with its own lock held.
#include "service/frame_snapshot.h"
#include "service/session.h"

#include <nlohmann/json.hpp>

#include <climits>
#include <cstddef>
#include <deque>
#include <string>
#include <vector>

namespace fc::service {

class FrameHistory {
 public:
  bool empty() const { return frames_.empty(); }
  size_t size() const { return frames_.size(); }
  size_t bytes() const { return bytes_; }
  size_t dropped() const { return dropped_; }  // frames dropped by the memory cap since the last clear
  int first() const { return frames_.front()->frame; }  // not empty
  int last() const { return frames_.back()->frame; }    // not empty
  // The newest frame simulated, recorded or live.
  int reached(int liveFrame) const { return empty() ? liveFrame : std::max(last(), liveFrame); }

  // Forgets every frame (a new timeline: frame numbers restart); nothing stale.
  void clear();
  // Appends a frame newer than every recorded one.
  void append(const FramePtr& f);
  // Records a computed frame: replaces the recorded frame of its number
  // (re-simulation) or appends it; the stale range starts after it.
  void store(const FramePtr& f);
  // Drops the oldest frames until the frames and `heldElsewhere` bytes fit `capBytes`.
  void fit(size_t capBytes, size_t heldElsewhere);

  FramePtr find(int frame) const;
  std::vector<FramePtr> all() const { return {frames_.begin(), frames_.end()}; }
  // The recorded frames within [first, last] (gaps allowed).
  std::vector<FramePtr> within(int first, int last) const;
  // Every frame of [first, last]; std::out_of_range naming the kept frames when one is missing.
  std::vector<FramePtr> contiguous(int first, int last) const;
  // Which frames are kept, for error messages.
  std::string keptText() const;

  // Frames from `frame` on are stale (an edit changed them).
  void markStaleFrom(int frame);
  // Frames from `frame` on are stale, whatever was before (a rebuilt simulation).
  void setStaleFrom(int frame);
  int staleFrom() const { return staleFrom_; }  // INT_MAX: none
  bool stale(int frame) const { return frame >= staleFrom_; }
  // StaleFramesError when a frame of [first, last] is stale (exports and
  // templates take only frames of the scene as it is).
  void throwIfStale(int first, int last, int liveFrame) const;

  // {frames, bytes, cap, dropped, first, last}
  nlohmann::json summary(size_t capBytes) const;
  // The cache's ranges: valid [[a, b]] and stale [[a, b]].
  nlohmann::json validRanges() const;
  nlohmann::json staleRanges() const;

 private:
  void normalizeStale();

  std::deque<FramePtr> frames_;
  size_t bytes_ = 0;
  size_t dropped_ = 0;
  int staleFrom_ = INT_MAX;
};

}  // namespace fc::service
