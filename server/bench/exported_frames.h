#pragma once
// Reading back a frames file written by FrameExporter (docs/export-format.md,
// through io/frames_file.h):
// the columns an analysis of the liquid needs, for every frame at once.
// `flowclip bench accuracy` measures the surge front, the compression and the
// volume of each run from its export.
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

struct ExportReadError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct ExportedFrames {
  int dimension = 0;
  double particleRadius = 0;             // m
  std::vector<double> phaseRestDensity;  // kg/m^3 per phase
  std::vector<double> time;              // s, per frame
  std::vector<uint64_t> offset;          // frame f = rows offset[f]..offset[f+1]
  std::vector<float> position;           // rows × dimension
  std::vector<float> density;            // rows
  std::vector<float> velocity;           // rows × dimension, m/s; empty where the file has none
  std::vector<float> pressure;           // rows, Pa; empty where the file has none
  std::vector<uint8_t> phase;            // rows
  std::vector<uint8_t> kind;             // rows (ParticleKind)

  size_t frames() const { return time.size(); }
};

// Throws ExportReadError naming `path` and what is missing or inconsistent
// (a file without density, as a session's replay history, is refused).
ExportedFrames readExportedFrames(const std::string& path);

}  // namespace fc
