#pragma once
// The animation-template file (paper §3.2): one HDF5 file per template.
//
// The layout is a contract, documented exactly in templates/README.md
// (format "flowclip-template", format_version 1). In short:
//   root attributes   format, format_version, name, dimension, frame_rate,
//                     frame_count, duration, particle_radius, support_radius,
//                     rest_density, region_min, region_max, recipe, created_by,
//                     position_encoding (+ position_origin, position_step),
//                     velocity_encoding, mass_encoding (+ mass_table)
//   /frames/offset          uint64 [F+1]  frame f = rows offset[f]..offset[f+1]
//   /frames/velocity_scale  float64 [F]   m/s per velocity unit of frame f
//   /particles/position     uint16 [N,D] (quantized) or float32 [N,D]
//   /particles/velocity     int16  [N,D]  v = q * velocity_scale[f]
//   /particles/mass_index   uint8  [N]    index into mass_table (or
//   /particles/mass         float64 [N]   when more than 256 distinct masses)
//   /particles/phase        uint8  [N]
// Chunked, byte-shuffled (multi-byte types) and deflate-compressed. The first
// 512 bytes (an HDF5 user block) hold the CRC-32 and length of the rest.
//
// Precision (what readTemplate returns versus what writeTemplate was given):
//   positions   |error| <= 0.01 * particle_radius per axis (uint16 encoding),
//               float32 rounding otherwise;
//   velocities  |error| <= velocity_scale[f] / 2 per component (plus float
//               rounding), where velocity_scale[f] = max_i,d |v_id| of
//               frame f / 1023, i.e. 0.049 % of the frame's largest component;
//   masses, phases exact.
// Particles of a frame are stored (and read back) sorted by the Morton code of
// their quantized position: the order within a frame carries no meaning.
//
// Writing is atomic: the file is written as "<path>.tmp-<pid>-<n>" in the same
// directory and renamed to <path> only on success; on any failure the
// temporary file is removed and an existing <path> is untouched.
#include "control/template.h"

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>

namespace fc {

// Every failure to write or read a template file; the message names the file
// and what is wrong with it.
struct TemplateError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

inline constexpr int kTemplateFormatVersion = 1;

template <int D>
void writeTemplate(const std::string& path, const Template<D>& tpl);

// Reads and validates the whole file. Throws TemplateError if the file is
// missing, not HDF5, not a template, of another format_version, of another
// dimension than D, damaged (checksum, HDF5 structures: checked before HDF5
// parses them, so that no damage can crash it) or inconsistent (offsets,
// dataset shapes and types, non-finite values, mass indices out of the
// table). Files without a checksum block (written before it existed) still
// read.
template <int D>
Template<D> readTemplate(const std::string& path);

// A template file read frame by frame from the disk, for templates too large
// to hold decoded (TemplateDatabase streams them; control/template_grids.h
// keeps a cache of their frames). Opening verifies the whole file against
// its checksum block by reading it through once, then checks and keeps the
// header, the encodings and the frame index; readFrame reads one frame's
// rows, checks and decodes them exactly as readTemplate does. Throws
// TemplateError for everything readTemplate refuses, and for a file without
// a checksum block (older files: read them whole) or one replaced between
// the check and HDF5 opening it. Thread-safe (HDF5 is built thread-safe).
template <int D>
class TemplateStream final : public TemplateFrameSource<D> {
 public:
  explicit TemplateStream(const std::string& path);
  ~TemplateStream() override;
  const TemplateHeader& header() const;
  size_t frameCount() const override;
  size_t frameParticles(size_t f) const override;
  uint64_t particleFrames() const;  // rows of the particle datasets
  uint64_t bytesOnDisk() const;
  TemplateFrame<D> readFrame(size_t f) const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// True if the file begins with the checksum block that writeTemplate writes
// (TemplateStream reads only such files).
bool startsWithChecksumBlock(const std::string& path);

// The header attributes only (validated), without reading particle data.
TemplateHeader readTemplateHeader(const std::string& path);

struct TemplateFileStats {
  TemplateHeader header;             // as readTemplateHeader gives it
  size_t frames = 0;
  size_t minParticles = 0, maxParticles = 0;  // per frame (0 without frames)
  double avgParticles = 0;
  uint64_t bytesOnDisk = 0;
  double bytesPerParticleFrame = 0;  // bytesOnDisk / total particle-frames (0 if none)
  bool checksummed = false;          // the file has a checksum block (verified); older files have none
};

// Reads the header and the frame-offset index only (one pass over the file:
// callers that want both need not call readTemplateHeader as well).
TemplateFileStats templateFileStats(const std::string& path);

}  // namespace fc
