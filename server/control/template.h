#pragma once
// An animation template in memory (paper §3.2): a recorded liquid animation
// in its own canonical space, frame by frame. Control particles are its
// particles; io/ reads and writes it, control/ derives acceleration
// structures (per-frame grids, repulsion layer) from it.
#include "core/aabb.h"
#include <string>
#include <vector>

namespace fc {

template <int D>
struct TemplateFrame {
  std::vector<Vec<D>> x;        // control particle positions, m (template space)
  std::vector<Vec<D>> v;        // velocities, m/s
  std::vector<Real> mass;       // kg (kg/m in 2D)
  std::vector<uint8_t> phase;   // phase index of the recipe scene
  size_t size() const { return x.size(); }
};

struct TemplateHeader {
  std::string name;             // [A-Za-z0-9_-]{1,64}
  int dimension = 0;
  double frameRate = 60;        // frames per second of template time
  double particleRadius = 0;    // m, of the recorded liquid
  double supportRadius = 0;     // h of the recorded liquid, m
  double restDensity = 1000;    // kg/m^3
  std::vector<double> regionMin, regionMax;  // capture region, D values each
  std::string recipe;           // the recipe scene (JSON text) that recorded it
  std::string createdBy;        // program and version
};

template <int D>
struct Template {
  TemplateHeader header;
  std::vector<TemplateFrame<D>> frames;  // empty when the frames are streamed
  size_t streamedFrames = 0;             // the file's frames, read on demand (TemplateAccel)
  size_t frameCount() const { return frames.empty() ? streamedFrames : frames.size(); }
  double duration() const { return frameCount() == 0 ? 0.0 : double(frameCount() - 1) / header.frameRate; }
  AABB<D> region() const {
    AABB<D> b;
    for (int d = 0; d < D; ++d) {
      b.min[d] = Real(header.regionMin.at(d));
      b.max[d] = Real(header.regionMax.at(d));
    }
    return b;
  }
};

// Where a streamed template's frames come from (io/template_file.h's
// TemplateStream): one frame at a time, decoded, from any thread.
template <int D>
class TemplateFrameSource {
 public:
  virtual ~TemplateFrameSource() = default;
  virtual size_t frameCount() const = 0;
  virtual size_t frameParticles(size_t f) const = 0;
  virtual TemplateFrame<D> readFrame(size_t f) const = 0;
};

}  // namespace fc
