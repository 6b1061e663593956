#pragma once
// Scene-level simulation settings (a scene's "settings" object): declared once here.
#include "sph/parameters.h"

namespace fc {

struct SimulationSettings {
  double frameRate;
  double cflFactor;
  double dtMin;
  double dtMax;
  int reorderInterval;
  int boundaryLayers;
  double contactDistance;
  int densityFormulation;
  double unconvergedStepScale;
  double stepRecovery;
  int maxSubstepsPerFrame;
  double pressureWindow;
  bool operator==(const SimulationSettings&) const = default;
};

inline const ParamTable<SimulationSettings>& simulationSettingsTable() {
  using S = SimulationSettings;
  static const ParamTable<S> table = {
      {.name = "frame_rate", .unit = "1/s", .min = 1, .max = 1000, .def = 60,
       .help = "frames per simulated second; substeps fit exactly into a frame", .member = &S::frameRate},
      {.name = "cfl_factor", .min = 0.01, .max = 2, .def = 1.0,
       .help = "time step = cfl_factor * 0.4 * particle diameter / max speed", .member = &S::cflFactor},
      {.name = "dt_min", .unit = "s", .min = 1e-7, .max = 0.1, .def = 1e-5,
       .help = "smallest substep (at most dt_max)", .member = &S::dtMin},
      {.name = "dt_max", .unit = "s", .min = 1e-6, .max = 0.1, .def = 0.005, .help = "largest substep",
       .member = &S::dtMax},
      {.name = "reorder_interval", .unit = "steps", .min = 0, .max = 100000, .def = 25,
       .help = "reorder particles along the Morton curve every N substeps (0: never)", .member = &S::reorderInterval},
      {.name = "boundary_layers", .min = 1, .max = 4, .def = 2,
       .help = "layers of boundary particles sampling walls and obstacles", .member = &S::boundaryLayers},
      {.name = "contact_distance", .unit = "r", .min = 0, .max = 1, .def = 0.25,
       .help = "particle centres are kept this many particle radii away from solid surfaces (the contact part of "
               "the boundary model: boundary particles push only through pressure, which a liquid particle below "
               "rest density does not have)",
       .member = &S::contactDistance},
      {.name = "density_formulation", .min = 0, .max = 2, .def = 0,
       .help = "how densities are summed. 0, automatic: the number density when the scene's phases have different "
               "rest densities, the mass sum otherwise (a single-phase scene runs exactly as with 1); 1, the mass "
               "sum rho_i = sum_j m_j W_ij (standard SPH); 2, the number density rho_i = m_i sum_j W_ij of "
               "Solenthaler & Pajarola 2008, with the pressure force and the DFSPH factors in its volume form. "
               "Under the number density the time step (its CFL part and dt_max) is scaled by "
               "sqrt(rho0_min/rho0_max), 0.58 at 1:3 (needed for stability; equal rest densities: 1)",
       .member = &S::densityFormulation},
      {.name = "unconverged_step_scale", .min = 0.05, .max = 1, .def = 0.5,
       .help = "after a substep in which a solve (divergence, density, implicit viscosity) stopped at its "
               "iteration limit, the following substeps' time step is multiplied by this, once more for every "
               "further such substep, down to 1/64 of the step (dt_min stays the floor); 1: never shrink. Frames "
               "report it as unconverged_substeps and step_scale",
       .member = &S::unconvergedStepScale},
      {.name = "step_recovery", .min = 1, .max = 4, .def = 1.1,
       .help = "after every substep whose solves all converged, a shrunk time step grows back by this factor, up "
               "to the full step (from 1/64: 44 substeps at 1.1)",
       .member = &S::stepRecovery},
      {.name = "max_substeps_per_frame", .min = 10, .max = 1e7, .def = 10000,
       .help = "a frame that needs more substeps stops with an error (the session goes to its error state, "
               "flowclip run exits with status 3) instead of running on: a time step that collapsed means the "
               "simulation has become unstable",
       .member = &S::maxSubstepsPerFrame},
      {.name = "pressure_window", .unit = "s", .min = 0, .max = 10, .def = 0,
       .help = "the exported pressure is the solver's pressure averaged over about this much simulated time "
               "(an exponential average over the substeps; 0: one frame), in Pa: steady for a liquid at rest, "
               "where the solver's own value varies from substep to substep",
       .member = &S::pressureWindow},
  };
  return table;
}

inline const ParamSpecs& simulationSettingsSpecs() { return simulationSettingsTable().specs(); }

}  // namespace fc
