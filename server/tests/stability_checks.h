#pragma once
// What every case of the stability suite (test_stability.cpp, 2D;
// test_stability_3d.cpp) checks on every frame, and how it runs a case.
#include "sph/simulation.h"
#include "tests/physics_checks.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

namespace fc::stability {

// A tank of the given size (2 or 3 numbers, m) from the origin with the
// scenes' water (1000 kg/m³, ν = 0.001 m²/s, standard viscosity), solver and
// settings, gravity along -y, and no liquid yet.
inline nlohmann::json waterTank(double r, const std::vector<double>& size) {
  nlohmann::json s = nlohmann::json::parse(R"({
    "phases": [{"name": "water", "rest_density": 1000, "viscosity": 0.001}],
    "solver": {"method": "dfsph", "density_tolerance_pct": 0.05, "divergence_tolerance_pct": 0.1},
    "settings": {"frame_rate": 60, "cfl_factor": 1, "dt_max": 0.005},
    "effects": ["viscosity_standard"]
  })");
  std::vector<double> gravity(size.size(), 0.0);
  gravity[1] = -9.81;
  s["dimension"] = size.size();
  s["gravity"] = gravity;
  s["particle_radius"] = r;
  s["domain"] = {{"min", std::vector<double>(size.size(), 0.0)}, {"max", size}};
  s["fluid_blocks"] = nlohmann::json::array();
  return s;
}

constexpr double kG = 9.81;

// Bernoulli: along a free streamline (zero pressure) a parcel that starts at
// speed v at most H above the floor can reach sqrt(v² + 2 g H), v being the
// liquid's initial speed plus the fastest driven motion (a template
// instance's played velocities and track, the per-frame velocity its pull
// can give). Where such a flow hits a wall the jet at the root of the impact
// leaves faster than the incoming flow (water-entry theory: twice the speed
// of the spreading contact line), so the bound is kSplash = 3 times that;
// measured up to 2.5 (the fast sweep, the zero-gravity jet: 2.0; see the
// [ measured ] lines), while a blow-up overshoots it by orders of magnitude.
constexpr double kSplash = 3;
inline double speedBound(double vIn, double height, double vDriven = 0) {
  const double v = vIn + vDriven;
  return kSplash * std::sqrt(v * v + 2 * kG * height);
}

// What a case must keep to, every frame.
struct FrameBounds {
  double maxSpeed = 0;  // m/s, liquid particles and body points (speedBound)
  // Average compression, percent: mean over the liquid of max(ρ/ρ0 − 1, 0),
  // as the solver reports it at exit (worst substep of the frame) and as
  // measured on the positions at the frame's end. 1 % is the volume loss the
  // dam-break tests allow; the solves stop at 0.05-0.1 %.
  double avgDensityErrorPct = 1;
  // No energy source (no instance, no driven body, no inflow): the total
  // energy (kinetic + potential above the tank floor, bodies included) may
  // not rise above its lowest value so far by more than energySlack times the
  // reference energy (its value at the start). Impacts, viscosity and the
  // inelastic wall contact only remove energy; what the slack allows for is
  // the pressure solve's compression at its tolerance being released.
  bool closed = false;
  double energySlack = 0.01;
  // The energy reference is the state at the end of this frame (0: the
  // start), for a case whose first frames release energy stored on purpose.
  int energyFromFrame = 0;
};

// What checkFrameBounds carries from frame to frame, and the extremes it saw
// (printed as [ measured ] lines).
struct RunRecord {
  double referenceEnergy = -1, lowestEnergy = std::numeric_limits<double>::infinity();
  double fastest = 0, solverError = 0, measuredError = 0, energyRise = 0;
  int frames = 0, unconvergedFrames = 0;
  size_t mostTemporary = 0, mostControlled = 0;
};

// Kinetic + potential energy above the tank floor (J, J/m in 2D), of the
// liquid and of the bodies (translation and rotation).
template <int D>
double totalEnergy(const Simulation<D>& sim) {
  const Vec<D> g = sim.setup().gravity;
  const Vec<D> floor = sim.setup().domain.min;
  double e = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i)
    e += double(sim.fluid.mass[i]) *
         (0.5 * double(sim.fluid.v[i].squaredNorm()) - double(g.dot(Vec<D>(sim.fluid.x[i] - floor))));
  if (const RigidBodies<D>* bodies = sim.bodies())
    for (const auto& b : bodies->states()) {
      const auto gd = g.template cast<double>();
      const auto fd = floor.template cast<double>();
      double rotational;
      if constexpr (D == 2) rotational = 0.5 * b.inertia(0, 0) * b.angularVelocity[0] * b.angularVelocity[0];
      else rotational = 0.5 * b.angularVelocity.dot(b.rotation * b.inertia * b.rotation.transpose() * b.angularVelocity);
      e += 0.5 * b.mass * b.velocity.squaredNorm() + rotational - b.mass * gd.dot(b.centre - fd);
    }
  return e;
}

// Average compression (percent) of the liquid at the current positions. It
// refreshes the neighbours and densities, which the next substep then reuses
// (Simulation::refreshNeighbors), so measuring does not change the run.
template <int D>
double measuredDensityErrorPct(Simulation<D>& sim) {
  sim.refreshNeighbors();
  double sum = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i)
    sum += std::max(0.0, double(sim.fluid.density[i]) / double(sim.restDensity(i)) - 1);
  return sim.fluid.size() ? 100 * sum / double(sim.fluid.size()) : 0;
}

// Call once before the first frame: the reference energy.
template <int D>
void startRecord(const Simulation<D>& sim, RunRecord& rec) {
  rec.referenceEnergy = totalEnergy(sim);
  rec.lowestEnergy = rec.referenceEnergy;
}

// The bounds, checked on one frame (see the top of the file).
template <int D>
::testing::AssertionResult checkFrameBounds(Simulation<D>& sim, const FrameStats& fs, const FrameBounds& b,
                                            RunRecord& rec) {
  const ::testing::AssertionResult sane = frameIsSane(sim, fs);  // finite, nothing outside the tank
  if (!sane) return sane;
  auto fail = [&]() -> ::testing::AssertionResult {
    return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): ";
  };
  ++rec.frames;
  rec.unconvergedFrames += fs.converged ? 0 : 1;
  rec.mostTemporary = std::max(rec.mostTemporary, fs.temporaryParticles);
  rec.mostControlled = std::max(rec.mostControlled, fs.controlledParticles);
  // Inside a solid: escapedParticles counts centres inside obstacles and bodies too.
  if (fs.escapedParticles) return fail() << fs.escapedParticles << " particle(s) outside the tank or inside a solid";
  const double bodySpeed = sim.bodies() ? sim.bodies()->maxPointSpeed() : 0.0;
  const double fastest = std::max(fs.maxSpeed, bodySpeed);
  rec.fastest = std::max(rec.fastest, fastest);
  if (!(fastest <= b.maxSpeed))
    return fail() << "max speed " << fs.maxSpeed << " m/s (bodies " << bodySpeed << " m/s) above the case's bound "
                  << b.maxSpeed << " m/s";
  rec.solverError = std::max(rec.solverError, fs.avgDensityErrorPct);
  if (!(fs.avgDensityErrorPct <= b.avgDensityErrorPct))
    return fail() << "average density error at solver exit " << fs.avgDensityErrorPct << " % above "
                  << b.avgDensityErrorPct << " % (converged: " << fs.converged << ")";
  const double measured = measuredDensityErrorPct(sim);
  rec.measuredError = std::max(rec.measuredError, measured);
  if (!(measured <= b.avgDensityErrorPct))
    return fail() << "average density error at the frame's end " << measured << " % above " << b.avgDensityErrorPct
                  << " %";
  const double e = totalEnergy(sim);
  if (!std::isfinite(e)) return fail() << "total energy " << e;
  if (fs.frame <= b.energyFromFrame) rec.referenceEnergy = rec.lowestEnergy = e;
  const double rise = (e - rec.lowestEnergy) / rec.referenceEnergy;
  rec.energyRise = std::max(rec.energyRise, rise);
  if (b.closed) {
    if (rise > b.energySlack)
      return fail() << "total energy " << e << " J rose " << 100 * rise << " % of the initial " << rec.referenceEnergy
                    << " J above its lowest value so far " << rec.lowestEnergy << " J (allowed " << 100 * b.energySlack
                    << " %) without an energy source";
  }
  rec.lowestEnergy = std::min(rec.lowestEnergy, e);
  return ::testing::AssertionSuccess();
}

inline void printRecord(const char* name, const FrameBounds& b, const RunRecord& rec) {
  std::printf("[ measured ] %s: %d frames, max speed %.3g m/s (bound %.3g, %.2f of it), avg density error %.3g %% "
              "(solver) / %.3g %% (frame end), bound %.3g %%; unconverged frames %d",
              name, rec.frames, rec.fastest, b.maxSpeed, rec.fastest / b.maxSpeed, rec.solverError, rec.measuredError,
              b.avgDensityErrorPct, rec.unconvergedFrames);
  if (b.closed) std::printf("; energy rise %.3g %% (slack %.3g %%)", 100 * rec.energyRise, 100 * b.energySlack);
  else if (rec.referenceEnergy > 0) std::printf("; energy rise %.3g %% (not bounded: energy source)", 100 * rec.energyRise);
  else std::printf("; energy not bounded (all of it comes from the inflow)");
  if (rec.mostControlled) std::printf("; up to %zu controlled particles", rec.mostControlled);
  if (rec.mostTemporary) std::printf("; up to %zu temporary particles", rec.mostTemporary);
  std::printf("\n");
}

// The cases are a few hundred particles: on two threads the fork/join of
// every parallel loop costs more than the loop, and on a loaded machine a
// descheduled thread stalls every barrier (up to 100× slower).
struct SingleThread {
  int before = omp_get_max_threads();
  SingleThread() { omp_set_num_threads(1); }
  ~SingleThread() { omp_set_num_threads(before); }
};

// Runs `frames` frames, every one through checkFrameBounds.
template <int D>
void runBounded(Simulation<D>& sim, int frames, const FrameBounds& b, RunRecord& rec, const char* name) {
  startRecord(sim, rec);
  for (int f = 0; f < frames; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(checkFrameBounds(sim, fs, b, rec)) << name;
  }
  printRecord(name, b, rec);
}

}  // namespace fc::stability
