#pragma once
// Reading a frames file written by FrameExporter (docs/export-format.md),
// frame by frame: `flowclip export` turns one into surfaces and meshes, and
// `flowclip bench accuracy` measures its runs from theirs
// (bench/exported_frames.h reads every frame at once through it).
#include "io/particle_frame.h"
#include <hdf5.h>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

struct FramesFileError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class FramesFile {
 public:
  // Opens `path` read-only and checks that it is a frames file of this
  // version (format "flowclip-frames", format_version 1) with consistent
  // frame tables. Throws FramesFileError naming the path and the problem.
  explicit FramesFile(const std::string& path);
  ~FramesFile();
  FramesFile(const FramesFile&) = delete;
  FramesFile& operator=(const FramesFile&) = delete;

  const std::string& path() const { return path_; }
  const std::string& scene() const { return scene_; }
  int dimension() const { return dimension_; }
  double particleRadius() const { return particleRadius_; }
  double frameRate() const { return frameRate_; }
  const std::vector<double>& phaseRestDensity() const { return phaseRestDensity_; }
  const std::vector<std::string>& phaseNames() const { return phaseNames_; }
  size_t frames() const { return time_.size(); }
  const std::vector<double>& times() const { return time_; }
  const std::vector<uint32_t>& indices() const { return index_; }
  const std::vector<uint64_t>& offsets() const { return offset_; }
  uint64_t rows() const { return offset_.empty() ? 0 : offset_.back(); }
  bool has(const char* dataset) const;

  // Rows [begin, begin + count) of a particle dataset with `cols` columns
  // (0: one-dimensional), converted to memType.
  template <class T>
  std::vector<T> read(const char* dataset, hid_t memType, int cols, uint64_t begin, uint64_t count) const;

  // Frame f (0-based position in the file) in 3D: a 2D file's particles at
  // z = 0; id and density empty when the file has none.
  ParticleFrame frame(size_t f) const;

  [[noreturn]] void fail(const std::string& what) const;

 private:
  std::string path_;
  hid_t file_ = -1;
  std::string scene_;
  int dimension_ = 0;
  double particleRadius_ = 0, frameRate_ = 0;
  std::vector<double> phaseRestDensity_;
  std::vector<std::string> phaseNames_;
  std::vector<double> time_;
  std::vector<uint32_t> index_;
  std::vector<uint64_t> offset_;
};

}  // namespace fc
