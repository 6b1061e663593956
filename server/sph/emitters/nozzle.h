#pragma once
// Inflows (setup.h Emitter): the stage that adds a scene's jets of liquid.
// Built only when the scene lists emitters.
#include "sph/pipeline.h"
#include "sph/setup.h"
#include <memory>
#include <vector>

namespace fc {

template <int D>
std::unique_ptr<Effect<D>> makeEmitters(const std::vector<Emitter<D>>& emitters);

// Points of one layer across a nozzle: a lattice of the given spacing in the
// plane through `center` normal to `direction`, within `radius`.
template <int D>
std::vector<Vec<D>> nozzleLayer(const Emitter<D>& e, Real spacing);

}  // namespace fc
