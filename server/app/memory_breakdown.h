#pragma once
// Where a run's memory is, by part, for `flowclip run`'s summary
// (`memory_bytes`): what the simulation's own containers hold (capacities,
// in bytes). The pressure solver's and the effects' per-particle arrays,
// the template grids and the process itself are what peak RSS adds.
#include "core/capacity_bytes.h"
#include "sph/simulation.h"

#include <nlohmann/json.hpp>

#include <cstddef>

namespace fc {

template <int D>
nlohmann::json memoryBreakdown(const Simulation<D>& sim) {
  const auto& f = sim.fluid;
  const size_t liquid = capacityBytes(f.x) + capacityBytes(f.v) + capacityBytes(f.a) + capacityBytes(f.mass) +
                        capacityBytes(f.density) + capacityBytes(f.pressure) + capacityBytes(f.meanPressure) +
                        capacityBytes(f.phase) + capacityBytes(f.kind) + capacityBytes(f.id);
  const NeighborList& lists = sim.search.dynamicNeighbors();
  const size_t neighbourLists = capacityBytes(lists.offsets) + capacityBytes(lists.indices);
  const size_t search = sim.search.memoryBytes();
  const size_t pairTerms = capacityBytes(sim.massGradScale) + capacityBytes(sim.gradScale);
  const size_t boundarySums = capacityBytes(sim.boundaryGradW) + capacityBytes(sim.boundaryFlux) +
                              capacityBytes(sim.boundaryNeighbors) + capacityBytes(sim.boundaryExtrapolation) +
                              capacityBytes(sim.boundaryExcess);
  const auto& b = sim.boundary;
  const size_t samples = capacityBytes(b.x) + capacityBytes(b.v) + capacityBytes(b.volume);
  const size_t model = sim.boundaryModelBytes();
  // The lists are part of what the search reports; the rest of it is its grids and scratch.
  const size_t grids = search > neighbourLists ? search - neighbourLists : 0;
  return {{"liquid_particles", liquid},
          {"neighbour_lists", neighbourLists},
          {"pair_terms", pairTerms},
          {"neighbour_grids", grids},
          {"boundary_sums", boundarySums},
          {"boundary_samples", samples},
          {"boundary_model", model},
          {"counted", liquid + neighbourLists + pairTerms + grids + boundarySums + samples + model}};
}

}  // namespace fc
