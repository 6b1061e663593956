#pragma once
// Scene-level simulation settings: declared once here.
#include "sph/parameters.h"

namespace fc {

inline const ParamSpecs& simulationSettingsSpecs() {
  static const ParamSpecs specs = {
      {"frame_rate", "1/s", 1, 1000, 60, "frames per simulated second; substeps fit exactly into a frame"},
      {"cfl_factor", "", 0.01, 2, 1.0, "time step = cfl_factor * 0.4 * particle diameter / max speed"},
      {"dt_min", "s", 1e-7, 0.1, 1e-5, "smallest substep"},
      {"dt_max", "s", 1e-6, 0.1, 0.005, "largest substep"},
      {"reorder_interval", "steps", 0, 100000, 25,
       "reorder particles along the Morton curve every N substeps (0: never)", ParamType::Integer},
      {"boundary_layers", "", 1, 4, 2, "layers of boundary particles sampling walls and obstacles", ParamType::Integer},
      {"contact_distance", "r", 0, 1, 0.25,
       "particle centres are kept this many particle radii away from solid surfaces"},
      {"density_formulation", "", 0, 2, 0,
       "0: automatic (number density when the phases' rest densities differ, else the mass sum); 1: mass sum "
       "rho_i = sum_j m_j W_ij; 2: number density rho_i = m_i sum_j W_ij (Solenthaler & Pajarola 2008)",
       ParamType::Integer},
      {"unconverged_step_scale", "", 0.05, 1, 0.5,
       "after a substep whose solve stopped at its iteration limit, the next substeps' time step is multiplied by "
       "this, once more for every further such substep (down to 1/64 of the step); 1: never shrink"},
      {"step_recovery", "", 1, 4, 1.1,
       "per substep whose solves all converged, a shrunk time step grows back by this factor, up to the full step"},
      {"max_substeps_per_frame", "", 10, 1e7, 10000,
       "a frame that needs more substeps stops with an error instead of running on (a collapsed time step means "
       "the simulation has become unstable)",
       ParamType::Integer},
  };
  return specs;
}

}  // namespace fc
