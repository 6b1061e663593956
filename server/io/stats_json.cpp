#include "io/stats_json.h"

namespace fc {

nlohmann::json frameStatsToJson(const FrameStats& s, bool controlled) {
  nlohmann::json j = {{"frame", s.frame},
                      {"time", s.time},
                      {"wall_ms", s.wallMs},
                      {"substeps", s.substeps},
                      {"divergence_iterations", s.divergenceIterations},
                      {"density_iterations", s.densityIterations},
                      {"avg_density_error_pct", s.avgDensityErrorPct},
                      {"max_density_error_pct", s.maxDensityErrorPct},
                      {"converged", s.converged},
                      {"unconverged_substeps", s.unconvergedSubsteps},
                      {"step_scale", s.stepScale},
                      {"viscosity_iterations", s.viscosityIterations},
                      {"viscosity_converged", s.viscosityConverged},
                      {"finite", s.finite},
                      {"particles", s.particles},
                      {"boundary_particles", s.boundaryParticles},
                      {"escaped_particles", s.escapedParticles},
                      {"wall_contacts", s.wallContacts},
                      {"crossed_surface", s.crossedSurface},
                      {"max_speed", s.maxSpeed},
                      {"kinetic_energy", s.kineticEnergy},
                      {"min_dt", s.minDt},
                      {"max_dt", s.maxDt},
                      {"neighbor_ms", s.neighborMs},
                      {"density_ms", s.densityMs},
                      {"divergence_ms", s.divergenceMs},
                      {"non_pressure_ms", s.nonPressureMs},
                      {"pressure_ms", s.pressureMs},
                      {"avg_neighbors", s.avgNeighbors}};
  if (s.emitting) {
    j["emitted_particles"] = s.emittedParticles;
    j["emission_blocked"] = s.emissionBlocked;
  }
  // Moving bodies, only in scenes that have them.
  if (!s.bodies.empty()) {
    nlohmann::json bodies = nlohmann::json::array();
    for (const auto& b : s.bodies)
      bodies.push_back({{"name", b.name},
                        {"position", b.position},
                        {"velocity", b.velocity},
                        {"rotation_deg", b.rotationDeg},
                        {"force", b.force},
                        {"wall_contacts", b.wallContacts}});
    j["bodies"] = bodies;
  }
  if (!controlled) return j;
  // The paper's Table 1 columns, per frame.
  j["liquid_particles"] = s.particles - s.temporaryParticles;
  j["temporary_particles"] = s.temporaryParticles;
  j["control_particles"] = s.controlParticles;
  j["repulsion_particles"] = s.repulsionParticles;
  j["controlled_particles"] = s.controlledParticles;
  j["seeded_particles"] = s.seededParticles;
  j["removed_particles"] = s.removedParticles;
  j["control_ms"] = s.controlMs;
  j["simulation_ms"] = s.wallMs - s.controlMs;
  nlohmann::json inst = nlohmann::json::array();
  for (const auto& i : s.instances)
    inst.push_back({{"name", i.name},
                    {"active", i.active},
                    {"template_frame", i.templateFrame},
                    {"fidelity", i.fidelity},
                    {"controlled_particles", i.controlled},
                    {"control_particles", i.controlParticles},
                    {"repulsion_particles", i.repulsionParticles}});
  j["instances"] = inst;
  return j;
}

}  // namespace fc
