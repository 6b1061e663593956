#pragma once
// A running simulation's particles as a ParticleFrame for the exporters.
#include "io/particle_frame.h"
#include "sph/particles.h"

namespace fc {

template <int D>
ParticleFrame particleFrame(const FluidParticles<D>& fluid, int index, double time) {
  ParticleFrame f;
  f.index = index;
  f.time = time;
  const size_t n = fluid.x.size();
  f.position.assign(3 * n, 0.0f);
  f.velocity.assign(3 * n, 0.0f);
  for (size_t i = 0; i < n; ++i)
    for (int d = 0; d < D; ++d) {
      f.position[3 * i + d] = float(fluid.x[i][d]);
      f.velocity[3 * i + d] = float(fluid.v[i][d]);
    }
  f.id.assign(fluid.id.begin(), fluid.id.end());
  f.phase.assign(fluid.phase.begin(), fluid.phase.end());
  f.kind.assign(fluid.kind.begin(), fluid.kind.end());
  f.density.assign(fluid.density.begin(), fluid.density.end());
  return f;
}

}  // namespace fc
