#pragma once
// Checks shared by the physics tests (hydrostatic column, dam break).
#include "sph/simulation.h"
#include <gtest/gtest.h>
#include <cstdlib>
#include <string>

namespace fc {

inline bool verbose() {
  const char* v = std::getenv("FLOWCLIP_TEST_VERBOSE");
  return v && *v && std::string(v) != "0";
}

// The height (y) of the surface a liquid of the simulation's mass has when it
// fills the tank's floor at rest density: Σ m/ρ0 over the floor's area, above
// the floor. A resting column's depth counts from it (the top row's centres
// ride up and down by a fraction of r).
template <int D>
double volumeSurface(const Simulation<D>& sim) {
  const AABB<D>& dom = sim.setup().domain;
  double floorArea = 1, volume = 0;
  for (int d = 0; d < D; ++d)
    if (d != 1) floorArea *= double(dom.size()[d]);
  for (size_t i = 0; i < sim.fluid.size(); ++i) volume += double(sim.fluid.mass[i]) / sim.restDensity(i);
  return double(dom.min[1]) + volume / floorArea;
}

// The checks every frame must pass: finite state and every particle
// strictly inside the tank. (Particle centres are kept a contact distance
// off the walls by the solver's contact model; how often that has to act is
// counted and bounded separately, see FrameChecks.)
template <int D>
::testing::AssertionResult frameIsSane(const Simulation<D>& sim, const FrameStats& fs) {
  if (!fs.finite) return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): non-finite state";
  const AABB<D>& dom = sim.setup().domain;
  if (fs.escapedParticles != 0)
    return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): "
                                         << fs.escapedParticles << " particle(s) outside the tank at the end of the frame";
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const Vec<D>& x = sim.fluid.x[i];
    if (!((x.array() > dom.min.array()).all() && (x.array() < dom.max.array()).all()))
      return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): particle "
                                           << sim.fluid.id[i] << " at (" << x.transpose()
                                           << ") is not strictly inside the domain (" << dom.min.transpose() << ") - ("
                                           << dom.max.transpose() << ")";
  }
  return ::testing::AssertionSuccess();
}

// Applies frameIsSane to every frame. The first failing frame is reported
// where it happens; the run goes on (unless the state is no longer finite)
// so that the other measurements are still reported, and finish() adds how
// many frames failed in all. It also totals the contact corrections, and the
// particle centres that had crossed a wall surface within a substep before
// the contact model put them back.
struct FrameChecks {
  int failedFrames = 0;
  size_t contacts = 0, crossed = 0, lateContacts = 0;
  double particleSteps = 0;
  template <int D>
  bool check(const Simulation<D>& sim, const FrameStats& fs) {
    contacts += fs.wallContacts;
    crossed += fs.crossedSurface;
    particleSteps += double(fs.particles) * fs.substeps;
    const ::testing::AssertionResult ok = frameIsSane(sim, fs);
    if (!ok && failedFrames++ == 0) ADD_FAILURE() << ok.message();
    return fs.finite;
  }
  void finish(int frames) const {
    EXPECT_EQ(failedFrames, 0) << failedFrames << " of " << frames
                               << " frames failed the per-frame checks (finite, every particle strictly inside the "
                                  "domain)";
  }
};

}  // namespace fc
