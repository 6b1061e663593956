#pragma once
// Export of simulation frames to one HDF5 file, readable with h5py.
//
// The file layout is a contract, documented in docs/export-format.md:
//   root attributes   format="flowclip-frames", format_version=1, dimension,
//                     scene, particle_radius, frame_rate, domain_min,
//                     domain_max, created_by, phase_names, phase_rest_density
//   /frames/index     uint32  [F]     frame number given to writeFrame
//   /frames/time      float64 [F]     simulation time, s
//   /frames/offset    uint64  [F+1]   frame f = particle rows offset[f]..offset[f+1]
//   /frames/count     uint32  [F]     offset[f+1] - offset[f]
//   /particles/position float32 [N,D]   /particles/velocity float32 [N,D]
//   /particles/density  float32 [N]     /particles/pressure float32 [N]
//   /particles/phase    uint8   [N]     /particles/kind     uint8   [N]
//   /particles/id       uint32  [N]
// A header may leave out density, pressure and id (solverColumns = false,
// for data that does not hold them: a session's replay history) and add a
// root attribute "source" saying where the frames come from.
// Every dataset is extendible and chunked (65536 rows for particle columns)
// with shuffle + deflate. Particle chunks are compressed in parallel by the
// exporter itself (same bytes as HDF5's filters) and written directly.
//
// Publication is atomic: frames go to the hidden stagingPath(path)
// (io/staged_files.h), which is fsynced and renamed to <path>
// (publishStaged) only by a successful close(). Until then an existing file
// at <path> is untouched; after a failure the temporary file is removed and
// <path> is never created or replaced; after a crash recoverPublishing()
// deletes it.
#include "sph/particles.h"
#include "sph/phase.h"
#include <cstdint>
#include <string>
#include <vector>

namespace fc {

struct ExportHeader {
  std::string sceneName;
  int dimension = 0;                  // must equal the exporter's D
  double particleRadius = 0;          // m
  double frameRate = 0;               // frames per second of simulated time
  std::vector<Phase> phases;          // names and rest densities are stored
  std::vector<double> domainMin;      // D values
  std::vector<double> domainMax;      // D values
  std::string createdBy;              // e.g. "flowclip 0.1.0"
  std::string source;                 // root attribute "source" when not empty
  bool solverColumns = true;          // the density, pressure and id datasets
};

// One frame as columns of `count` rows, already in the file's types.
struct ExportColumns {
  size_t count = 0;
  const float* position = nullptr;    // count × D
  const float* velocity = nullptr;    // count × D
  const uint8_t* phase = nullptr;
  const uint8_t* kind = nullptr;
  // Only with header.solverColumns (ignored otherwise):
  const float* density = nullptr;
  const float* pressure = nullptr;
  const uint32_t* id = nullptr;
};

template <int D>
class FrameExporter {
 public:
  // Runs recoverPublishing() on the directory of `path` (the leftovers of
  // an export killed earlier), creates the temporary file tempPath() and
  // writes the header. Throws std::runtime_error naming `path` if the file
  // cannot be created or the header is inconsistent (dimension != D, domain
  // sizes != D).
  FrameExporter(const std::string& path, const ExportHeader& header);
  // Calls close() without throwing. If the exporter is destroyed while an
  // exception unwinds the stack (the run failed), the temporary file is
  // discarded instead of published, so a failed run never replaces <path>.
  ~FrameExporter();

  FrameExporter(const FrameExporter&) = delete;
  FrameExporter& operator=(const FrameExporter&) = delete;

  // Appends one frame: all particles of `fluid`, in storage order. The
  // particle count may differ from frame to frame. Throws std::runtime_error
  // (naming the path) on inconsistent arrays, a negative frame index, a
  // closed exporter or a write error; after a write error the temporary file
  // is removed and the exporter is closed.
  void writeFrame(int frameIndex, double time, const FluidParticles<D>& fluid);
  // The same from columns (every pointer the header's datasets need must be
  // set when count > 0).
  void writeFrame(int frameIndex, double time, const ExportColumns& columns);

  // Finalises the file and renames it to <path> (replacing any existing
  // file). Idempotent. Throws std::runtime_error naming the path on error,
  // after removing the temporary file.
  void close();

  // Discards the temporary file without publishing. Never throws. Idempotent.
  void abort() noexcept;

  bool isOpen() const { return open_; }
  const std::string& path() const { return path_; }
  const std::string& tempPath() const { return tempPath_; }
  int frameCount() const { return int(frames_); }
  uint64_t particleRowCount() const { return rows_; }

 private:
  enum Ds { Position, Velocity, Density, Pressure, PhaseDs, Kind, Id, NumParticleDs = Id + 1,
            FrameIndex = NumParticleDs, FrameTime, FrameOffset, FrameCount, NumDatasets };

  // Particle columns are compressed here (in parallel) and written as whole
  // chunks; each keeps at most one partly filled chunk between frames.
  struct PendingChunk {
    std::vector<unsigned char> bytes;  // one full chunk, zero padded
    uint64_t rows = 0;                 // rows filled
    uint64_t index = 0;                // chunk number in the dataset
  };
  struct ReadyChunk {
    int ds = 0;
    uint64_t index = 0;
    std::vector<unsigned char> bytes;
  };

  [[noreturn]] void fail(const std::string& what);
  void discardFile() noexcept;
  void releaseHandles() noexcept;
  void append(Ds ds, const void* data, int64_t memType, uint64_t rows);
  void stage(Ds ds, const void* rowsData, uint64_t rows);
  void writeReadyChunks();
  void checkFrame(int frameIndex, size_t n);
  void extendParticleDatasets(uint64_t end);
  void finishFrame(int frameIndex, double time, size_t n);

  std::string path_;
  std::string tempPath_;
  bool open_ = false;                 // temp file exists and is ours
  int64_t file_ = -1;                 // hid_t, -1 when not open
  int64_t datasets_[NumDatasets];     // hid_t, -1 when not open
  uint64_t sizes_[NumDatasets] = {};  // rows per frame table
  PendingChunk pending_[NumParticleDs];
  std::vector<ReadyChunk> ready_;
  std::vector<float> scratch_;        // one frame's column converted to float32
  uint64_t frames_ = 0;
  uint64_t rows_ = 0;
  int uncaughtAtCreation_ = 0;
};

}  // namespace fc
