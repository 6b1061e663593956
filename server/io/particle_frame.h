#pragma once
// One frame of particles as the exporters and the surface reconstruction
// read it, from a running simulation or from a frames file (io/frames_file.h).
#include <cstddef>
#include <cstdint>
#include <vector>

namespace fc {

// One frame of particles, positions and velocities in 3D (a 2D scene's at
// z = 0), the columns of a frames file (docs/export-format.md).
struct ParticleFrame {
  int index = 0;                  // frame number
  double time = 0;                // s
  std::vector<float> position;    // count × 3, m
  std::vector<float> velocity;    // count × 3, m/s
  std::vector<uint32_t> id;       // empty when the source has none
  std::vector<uint8_t> phase;
  std::vector<uint8_t> kind;      // 0 liquid, 1 temporary, 2 boundary
  std::vector<float> density;     // empty when the source has none
  size_t count() const { return kind.size(); }
};

// Whether a particle of this kind belongs to the liquid's surface (liquid
// and temporary particles do; boundary samples do not).
inline bool formsSurface(uint8_t kind) { return kind == 0 || kind == 1; }

}  // namespace fc
