#pragma once
// A recorded frame: the liquid quantized to 16 bits per axis (positions in
// the domain's box, velocities in the frame's own symmetric box), the
// frame's stats and what the stream shows of each instance. Made by the
// session's thread from its simulation; template frames are cut from them.
#include "control/instance.h"
#include "control/template.h"
#include "io/stats_json.h"
#include "sph/simulation.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace fc::service {

// What the stream shows of one template instance in a frame.
struct InstanceSnapshot {
  std::string name;
  std::string templateName;
  int phase = 0;                  // index into the scene's phases
  bool active = false;            // playing during the frame
  int templateFrame = -1;         // template frame played (-1: inactive)
  double fidelity = -1;           // occupancy IoU (-1: not measured)
  // Template space -> world at the frame's time: a homogeneous 4x4 matrix in
  // column-major order (three.js Matrix4.elements); a 2D scene uses the
  // top-left x/y block and leaves z as identity.
  std::array<double, 16> toWorld{};
  std::array<double, 3> regionMin{}, regionMax{};  // capture region, template space (z = 0 in 2D)
  double falloffWidth = 0;        // m (world), the falloff band around the region
};

// One recorded frame, immutable once published (shared by the history, the
// latest-frame slot and every consumer). Per particle it holds 4·D + 2 bytes
// (10 in 2D, 14 in 3D): 16-bit position and velocity per axis, kind, phase.
struct FrameSnapshot {
  static constexpr double kQuantizationLevels = 65535.0;

  int dimension = 2;
  int frame = 0;                  // scene frame number (0: initial state)
  double time = 0;                // scene time at the frame's end, s
  // Quantization box: the scene's domain (z = 0 in 2D). Axis d of particle i
  // is positions[i * dimension + d] = round((x − min) / (max − min) · 65535),
  // clamped to [0, 65535]: error <= (max − min) / 131070.
  std::array<double, 3> domainMin{}, domainMax{};
  // Velocities in a symmetric box per frame and axis, velocityMax[d] =
  // max_i |v_id| (m/s, 0 in 2D's z): axis d of particle i is
  // velocities[i * dimension + d] = round((v / velocityMax[d] + 1) / 2 · 65535),
  // error <= velocityMax[d] / 65535. An axis at rest in the whole frame
  // (velocityMax 0) stores 32768 and decodes to exactly 0.
  std::array<double, 3> velocityMax{};
  std::vector<uint16_t> positions;   // liquid particles (all kinds), dimension values each
  std::vector<uint16_t> velocities;  // same particles, dimension values each
  std::vector<uint8_t> kind;         // ParticleKind (Liquid, Temporary)
  std::vector<uint8_t> phase;        // index into the scene's phases
  FrameStats stats;                  // of the frame (frame 0: counts only)
  std::vector<InstanceSnapshot> instances;
  size_t byteSize = 0;               // bytes() at publication

  size_t particles() const { return kind.size(); }
  // Dequantized coordinate (m).
  double position(size_t particle, int axis) const {
    return domainMin[size_t(axis)] + double(positions[particle * size_t(dimension) + size_t(axis)]) /
                                         kQuantizationLevels * (domainMax[size_t(axis)] - domainMin[size_t(axis)]);
  }
  // Dequantized velocity component (m/s).
  double velocity(size_t particle, int axis) const {
    return (double(velocities[particle * size_t(dimension) + size_t(axis)]) * (2 / kQuantizationLevels) - 1) *
           velocityMax[size_t(axis)];
  }
  // Memory held by this snapshot (what the history cap counts).
  size_t bytes() const;
  // What a frame of `particles` particles and `instances` instances holds in
  // the history (instance names not counted): memory per 1000 frames is
  // 1000 · estimateBytes(...), i.e. (4·D + 2) bytes per particle-frame plus
  // a fixed part per frame.
  static size_t estimateBytes(int dimension, size_t particles, size_t instances);
};
using FramePtr = std::shared_ptr<const FrameSnapshot>;

// The simulation's current state as the recorded frame `fs` (the instances'
// records from `instances` at the frame's time).
template <int D>
FramePtr snapshotOf(const Simulation<D>& sim, const AABB<D>& domain, const std::vector<BoundInstance<D>>& instances,
                    const FrameStats& fs);

// One template frame per recorded frame: the liquid particles (Liquid and
// Temporary) whose dequantized position lies in the closed box [lo, hi],
// with their mass from `phaseMass`.
template <int D>
void templateFramesOf(const std::vector<FramePtr>& frames, const std::vector<double>& lo,
                      const std::vector<double>& hi, const std::vector<Real>& phaseMass,
                      std::vector<TemplateFrame<D>>& out);

}  // namespace fc::service
