#pragma once
// A session's checkpoints: the simulation's whole state between two frames
// (Simulation::archiveState) every K frames, so that an edit re-simulates
// from the newest checkpoint before the first frame it changes instead of
// from frame 0. Frame 0 is never stored: rebuilding the scene gives it.
//
// Dense: between the every-K grid, the frames in between are kept too, as
// memory allows, so that an edit's first changed frame is one frame's
// compute away (an edit changes frames near where the user looks).
//
// Memory. The store holds at most `capBytes`. Past it, the in-between
// checkpoints go first, farthest from the focus (the playhead) first; then
// the grid thins by dropping every other checkpoint from the oldest on (the
// newest stays), so that the spacing doubles where checkpoints are oldest,
// as Houdini's and Blender's caches keep the frames near the playhead.
//
// Compression. A grid checkpoint is stored compressed when that saves at
// least a tenth: the bytes shuffled by position within a 4-byte word
// (floats' exponents and the high bytes of indices line up) and deflated at
// zlib's fastest level. In-between checkpoints stay raw (saved after every
// frame, their deflate would cost about a tenth of a 3D frame).
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <vector>

namespace fc::service {

class CheckpointStore {
 public:
  struct Figures {
    size_t count = 0;
    size_t bytes = 0;        // stored (compressed where it paid)
    size_t rawBytes = 0;     // before compression
    double saveMs = 0;       // the last checkpoint: archive + compression
    double restoreMs = 0;    // the last restore: decompression + load
  };

  CheckpointStore(int every, size_t capBytes, bool compress, bool dense = false);

  int every() const { return every_; }  // 0: no checkpoints
  bool dense() const { return dense_ && every_ > 0; }
  size_t capBytes() const { return capBytes_; }
  // A checkpoint is due after frame `frame` (every K frames, or every frame
  // when dense; never frame 0).
  bool due(int frame) const { return every_ > 0 && frame > 0 && (dense_ || onGrid(frame)); }
  bool onGrid(int frame) const { return every_ > 0 && frame % every_ == 0; }
  // The frame the user looks at: in-between checkpoints nearest it stay longest.
  void setFocus(int frame) { focus_ = frame; }

  // Stores the archive of frame `frame` (replacing one of that frame).
  void put(int frame, const std::vector<uint8_t>& archive);
  // The newest checkpoint at or before `frame`: its frame and archive
  // (decompressed), or frame 0 and nothing (rebuild the scene).
  int newestAtOrBefore(int frame, std::vector<uint8_t>& archive) const;
  // Its frame only (0: none).
  int newestFrameAtOrBefore(int frame) const;
  // Forgets the checkpoints of frames >= `frame` (an edit changed them).
  void dropFrom(int frame);
  void clear();

  std::vector<int> frames() const;
  Figures figures() const;
  void noteRestoreMs(double ms) { figures_.restoreMs = ms; }

  // Exposed for tests: the codec (shuffle + deflate; inflate + unshuffle).
  static std::vector<uint8_t> compress(const std::vector<uint8_t>& raw);
  static std::vector<uint8_t> decompress(const std::vector<uint8_t>& packed, size_t rawSize);

 private:
  struct Entry {
    std::vector<uint8_t> bytes;
    size_t rawSize = 0;
    bool compressed = false;
  };
  void thin();
  void erase(std::map<int, Entry>::iterator it);

  int every_;
  size_t capBytes_;
  bool compress_;
  bool dense_;
  int focus_ = 0;
  std::map<int, Entry> entries_;
  size_t bytes_ = 0, rawBytes_ = 0;
  Figures figures_;
};

}  // namespace fc::service
