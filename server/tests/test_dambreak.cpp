// Dam break after Martin & Moyce (1952) [MM52]: a water column of width a and
// height 2a collapses from the left wall of a tank at least 5a long. For
// DFSPH and WCSPH, in 2D and 3D: nothing leaves the tank, the surge front
// advances monotonically and reaches the far side, volume is conserved, and
// the front position in Martin & Moyce's dimensionless units is plausible.
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame.
#include "bench/accuracy_metrics.h"
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include <omp.h>
#include "physics_checks.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace fc {
namespace {


struct DamFrame {
  double t = 0;
  double front = 0;        // robust front: 99.9th percentile of x + r, from the left wall, m
  double frontMax = 0;     // max x + r, from the left wall, m (reported only)
  double height = 0;       // the liquid's height at the left wall (centres within 2r of it): 99.5th percentile of y + r, m
  double volumeRatio = 1;  // Σ m / max(ρ, ρ0) over the initial Σ m / ρ0
};

struct DamRun {
  std::vector<DamFrame> frames;
  double a = 0, height = 0, tankLength = 0, r = 0, g = 0;
  size_t particles = 0;
  double wallSeconds = 0;
  bool reachedFarWall = false;
};

// The threads' particle blocks (Simulation::threadParticles) cover every
// particle once, in order, and hold equal work once the dam break flows:
// pairs plus the per-particle share, to within one particle.
TEST(ThreadBlocks, CoverTheParticlesWithEqualPairWork3D) {
  const auto json = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/dambreak3d.json");
  Simulation<3> sim(parseScene<3>(json, 0.04));
  for (int f = 0; f < 20; ++f) sim.advanceFrame();
  sim.refreshNeighbors();
  const int threads = omp_get_max_threads();
  std::vector<std::pair<long, long>> blocks(size_t(threads), {-1, -1});
  int team = 0;
#pragma omp parallel num_threads(threads)
  {
    blocks[size_t(omp_get_thread_num())] = sim.threadParticles();
#pragma omp single
    team = omp_get_num_threads();
  }
  ASSERT_EQ(team, threads);
  const long n = long(sim.fluid.size());
  const uint32_t* off = sim.pairOffsets();
  const double particleWork = double(Simulation<3>::kParticleWorkInPairs);
  long next = 0;
  std::vector<double> work;
  for (const auto& [first, last] : blocks) {
    EXPECT_EQ(first, next) << "blocks must be contiguous";
    EXPECT_LE(first, last);
    next = last;
    work.push_back(double(off[last] - off[first]) + particleWork * double(last - first));
  }
  EXPECT_EQ(next, n);
  const double total = double(off[n]) + particleWork * double(n);
  // The split's granularity: one particle's share and pairs.
  uint32_t mostPairs = 0;
  for (long i = 0; i < n; ++i) mostPairs = std::max(mostPairs, off[i + 1] - off[i]);
  const double granularity = particleWork + double(mostPairs);
  for (double w : work) EXPECT_NEAR(w, total / threads, granularity) << "a block's work";
  // The scene must need the balancing: blocks of equal particle counts would
  // be further apart than that (with more than one thread).
  if (threads > 1) {
    const long half = n / threads;
    const double equalCount = double(off[half]) + particleWork * double(half);
    EXPECT_GT(std::abs(equalCount - total / threads), 4 * granularity)
        << n << " particles: equal counts are already balanced, the test shows nothing";
  }
}

// Runs until the front is within 2r of the far wall, or maxSeconds.
// `edit` changes the scene before it is parsed.
template <int D>
DamRun runDamBreak(const std::string& sceneFile, double radiusOverride, const std::string& solver, double maxSeconds,
                   FrameChecks& checks, const std::function<void(nlohmann::json&)>& edit = {}) {
  auto json = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/" + sceneFile);
  if (edit) edit(json);
  SimulationSetup<D> setup = parseScene<D>(json, radiusOverride);
  if (solver == "wcsph") {
    setup.solver.name = "wcsph";
    setup.solver.values = ParamValues();  // the solver's defaults
  }
  EXPECT_EQ(setup.solver.name, solver);
  Simulation<D> sim(setup);
  DamRun run;
  const AABB<D>& dom = setup.domain;
  EXPECT_EQ(setup.fluidBlocks.size(), 1u);
  const AABB<D>& column = setup.fluidBlocks.at(0).box;
  EXPECT_EQ(column.min[0], dom.min[0]) << "the column must stand against the left wall";
  EXPECT_EQ(column.min[1], dom.min[1]) << "the column must stand on the floor";
  run.a = column.max[0] - dom.min[0];
  run.height = column.max[1] - dom.min[1];
  run.tankLength = dom.size()[0];
  run.r = sim.particleRadius();
  run.g = setup.gravity.norm();
  run.particles = sim.fluid.size();
  const auto& f = sim.fluid;
  const size_t n = f.size();
  double volume0 = 0;
  for (size_t i = 0; i < n; ++i) volume0 += f.mass[i] / sim.restDensity(i);
  const double tScale = std::sqrt(2 * run.g / run.a);
  // The 99.9th percentile: the front is where the bulk of the surge is, not
  // where the single fastest droplet is. An SPH surge tip is one or two
  // particles thick and sheds single particles ahead of it; Martin & Moyce
  // tracked the leading edge of the water, not spray. 0.1 % of the particles
  // (5 in 2D, 6 in 3D here) may lie ahead of this front.
  const size_t k = size_t(std::ceil(0.999 * double(n))) - 1;
  std::vector<Real> xs(n);
  std::vector<Real> ys;
  const auto t0 = std::chrono::steady_clock::now();
  while (sim.time() < maxSeconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    DamFrame d;
    d.t = sim.time();
    // Surface particles have too few neighbours, so their SPH density is
    // below ρ0 although they are not expanded (kernel deficiency); counting
    // them at m/ρ would invent volume. Taking max(ρ, ρ0) counts only
    // compression, which is what an incompressible solver must prevent. The
    // densities are those of the frame's last substep (before its advection).
    double volume = 0;
    ys.clear();
    for (size_t i = 0; i < n; ++i) {
      xs[i] = f.x[i][0];
      volume += f.mass[i] / std::max(f.density[i], sim.restDensity(i));
      if (f.x[i][0] - dom.min[0] < 2 * run.r) ys.push_back(f.x[i][1]);
    }
    if (!ys.empty()) {
      const size_t top = size_t(std::ceil(0.995 * double(ys.size()))) - 1;
      std::nth_element(ys.begin(), ys.begin() + long(top), ys.end());
      d.height = double(ys[top]) + run.r - dom.min[1];
    }
    d.volumeRatio = volume / volume0;
    std::nth_element(xs.begin(), xs.begin() + long(k), xs.end());
    d.front = double(xs[k]) + run.r - dom.min[0];
    d.frontMax = double(*std::max_element(xs.begin() + long(k), xs.end())) + run.r - dom.min[0];
    if (verbose())
      std::printf("t=%.4f T=%.3f front %.4f m (Z=%.3f), max %.4f (Z=%.3f), V/V0=%.5f, KE=%.3e, vmax=%.2f, "
                  "density error avg %.3f%% max %.2f%%, substeps %d, escaped %zu\n",
                  d.t, d.t * tScale, d.front, d.front / run.a, d.frontMax, d.frontMax / run.a, d.volumeRatio,
                  fs.kineticEnergy, fs.maxSpeed, fs.avgDensityErrorPct, fs.maxDensityErrorPct, fs.substeps,
                  fs.escapedParticles);
    run.frames.push_back(d);
    if (d.front >= run.tankLength - 2 * run.r) {
      run.reachedFarWall = true;
      break;
    }
  }
  run.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return run;
}

// Bounds on the RMS against Martin & Moyce (see the measured table below):
// the simulated surge runs ahead of the experiment at every resolution
// (docs/benchmarks/accuracy.md), so they catch a run that goes wrong, not a
// match to the experiment.
constexpr double kSurgeRmsBound = 0.4;
constexpr double kHeightRmsBound = 0.05;

// Against Martin & Moyce's series: the surge front (T <= 3) and the
// residual height of the column at the wall (their Table 6), RMS over the
// experiment's points the run covers.
struct MartinMoyce {
  double surgeRms = 0, surgeLead = 0, heightRms = 0;
  SurgeCurve surge, height;  // the experiment's points the run covers
};

MartinMoyce againstMartinMoyce(const DamRun& run) {
  const double tScale = std::sqrt(2 * run.g / run.a);  // Martin & Moyce's T = t sqrt(2g/a)
  SurgeCurve surge, height;
  for (const DamFrame& d : run.frames) {
    surge.T.push_back(d.t * tScale);
    surge.Z.push_back(d.front / run.a);
    height.T.push_back(d.t * std::sqrt(run.g / run.a));
    height.Z.push_back(d.height / run.height);
  }
  const auto within = [](const SurgeCurve& ref, const SurgeCurve& sim, double last) {
    SurgeCurve out;
    for (size_t i = 0; i < ref.T.size(); ++i)
      if (ref.T[i] >= sim.T.front() && ref.T[i] <= std::min(sim.T.back(), last))
        out.T.push_back(ref.T[i]), out.Z.push_back(ref.Z[i]);
    return out;
  };
  const std::string data = std::string(FLOWCLIP_SOURCE_DIR) + "/bench/data/";
  MartinMoyce mm;
  mm.surge = within(readSurgeCurve(data + "martin_moyce_1952.csv"), surge, 3.0);
  mm.height = within(readSurgeCurve(data + "martin_moyce_1952_height.csv", "tau,H"), height, 1e9);
  if (!mm.surge.T.empty()) mm.surgeRms = surgeRms(surge, mm.surge), mm.surgeLead = surgeBias(surge, mm.surge);
  if (!mm.height.T.empty()) mm.heightRms = surgeRms(height, mm.height);
  return mm;
}

// maxVolumeLoss: bound on 1 - V/V0 over every frame.
template <int D>
void damBreakTest(const std::string& sceneFile, double radiusOverride, const std::string& solver,
                  double maxVolumeLoss, double heightRmsBound = kHeightRmsBound) {
  FrameChecks checks;
  const DamRun run = runDamBreak<D>(sceneFile, radiusOverride, solver, 1.2, checks);
  checks.finish(int(run.frames.size()));
  ASSERT_FALSE(run.frames.empty());
  // Martin & Moyce's setup: height 2a (their n² = 2), tank at least 5a long.
  EXPECT_NEAR(run.height, 2 * run.a, 1e-6);
  EXPECT_GE(run.tankLength, 5 * run.a);

  const double tScale = std::sqrt(2 * run.g / run.a);  // Martin & Moyce's T = t sqrt(2g/a)
  const double tolerance = 0.1 * run.r;                // per frame
  double worstVolume = 1, worstVolumeT = 0, worstStep = 1e30, worstStepT = 0, zAt2 = -1, furthest = 0;
  int backwardFrames = 0;
  for (size_t i = 0; i < run.frames.size(); ++i) {
    const DamFrame& d = run.frames[i];
    furthest = std::max(furthest, d.front);
    if (d.volumeRatio < worstVolume) worstVolume = d.volumeRatio, worstVolumeT = d.t;
    if (i == 0) continue;
    const DamFrame& p = run.frames[i - 1];
    // Monotonic until the front is within 2r of the far wall (the run stops
    // at the first frame where it is).
    const double step = d.front - p.front;
    if (step < -tolerance) ++backwardFrames;
    if (step < worstStep) worstStep = step, worstStepT = d.t;
    const double T0 = p.t * tScale, T1 = d.t * tScale;
    if (T0 <= 2 && T1 > 2) zAt2 = (p.front + (d.front - p.front) * (2 - T0) / (T1 - T0)) / run.a;
  }
  std::printf("[ measured ] %s %s: %zu particles (r = %g m), a = %g m, %.3f s simulated in %.1f s wall, far wall %s; "
              "front reached %.3f a (max particle %.3f a); Z(T=2) = %.3f; smallest front step %.3f r (t = %.3f s); "
              "worst V/V0 = %.5f at t = %.3f s; contact corrections %.4f%% of particle-steps, centres across a wall "
              "%zu (%.5f%%)\n",
              sceneFile.c_str(), solver.c_str(), run.particles, run.r, run.a, run.frames.back().t, run.wallSeconds,
              run.reachedFarWall ? "reached" : "not reached", furthest / run.a, run.frames.back().frontMax / run.a, zAt2,
              worstStep / run.r, worstStepT, worstVolume, worstVolumeT, 100 * checks.contacts / checks.particleSteps,
              checks.crossed, 100 * checks.crossed / checks.particleSteps);
  // The SPH boundary keeps the liquid off the walls; the contact model
  // catches spray and the toe of the surge: measured 0.016-0.022 % of
  // particle-steps in 2D, 1.7-2.2 % in 3D (where more of the liquid is
  // surface along the side walls). Bounds 0.1 % and 4 %.
  EXPECT_LT(checks.contacts / checks.particleSteps, D == 2 ? 1e-3 : 4e-2) << "contact corrections per particle-step";
  EXPECT_LT(checks.crossed / checks.particleSteps, 1e-5) << "centres across a wall surface per particle-step";

  EXPECT_EQ(backwardFrames, 0) << "frames in which the front moved back by more than 0.1 r; worst step "
                               << worstStep / run.r << " r at t = " << worstStepT << " s";
  EXPECT_GE(furthest, 3 * run.a) << "the front must reach at least 3a";
  EXPECT_GE(worstVolume, 1 - maxVolumeLoss) << "volume lost (compression) at t = " << worstVolumeT << " s";
  // Martin & Moyce's surge front is at Z = x/a of about 2.4-2.9 at
  // T = t sqrt(2g/a) = 2. SPH with a frictionless floor tends to run ahead of
  // the experiment; the window [2, 3.5] allows for that and still catches a
  // front that is much too slow or too fast.
  ASSERT_GE(zAt2, 0) << "the run ended before T = 2";
  EXPECT_GE(zAt2, 2.0) << "surge front Z at T = 2";
  EXPECT_LE(zAt2, 3.5) << "surge front Z at T = 2";

  const MartinMoyce mm = againstMartinMoyce(run);
  const double surgeError = mm.surgeRms, heightError = mm.heightRms, surgeLead = mm.surgeLead;
  const SurgeCurve& mmSurge = mm.surge;
  const SurgeCurve& mmHeight = mm.height;
  ASSERT_GE(mmSurge.T.size(), 10u) << "the run must cover Martin & Moyce's surge up to T = 3";
  ASSERT_GE(mmHeight.T.size(), 8u) << "the run must cover most of their column heights";
  std::printf("[ measured ] %s %s against Martin & Moyce: surge front RMS %.3f in Z over %zu points (T <= 3; mean lead "
              "%+.3f), residual column height RMS %.3f over %zu points (tau <= %.2f)\n",
              sceneFile.c_str(), solver.c_str(), surgeError, mmSurge.T.size(), surgeLead, heightError,
              mmHeight.T.size(), mmHeight.T.back());
  EXPECT_LT(surgeError, kSurgeRmsBound) << "surge front RMS in Z against Martin & Moyce, T <= 3";
  EXPECT_LT(heightError, heightRmsBound) << "residual column height RMS against Martin & Moyce";
}

// Measured (before the contact model existed, particles did cross walls:
// the boundary only pushes through pressure, which a particle below rest
// density does not have):
//   solver  dim  particles  reaches far wall  Z(T=2)  worst V/V0
//   DFSPH   2D   5 000      t = 0.683 s       2.59    0.9989
//   WCSPH   2D   5 000      t = 0.683 s       2.57    0.9897
//   DFSPH   3D   6 750      t = 0.667 s       2.60    0.9992
//   WCSPH   3D   6 750      t = 0.683 s       2.58    0.9887
// The front (99.9th percentile) never moved back in any frame. Z(T=2) agrees
// across solvers and dimensions within 0.03, so the surge check stays.
// Against Martin & Moyce: surge RMS 0.240 / 0.231 (2D DFSPH / WCSPH) and
// 0.256 / 0.236 (3D), the front ahead by 0.22-0.24 on average; residual
// column height RMS 0.013 / 0.016 (2D) and 0.016 / 0.025 (3D).
// WCSPH (B = 50 kPa, γ = 7: sound speed 18.7 m/s against surge speeds up to
// 5 m/s) compresses by up to 1.2 %; its bound is 2 %. DFSPH's volume stays
// within 0.1 % (worst V/V0 0.9991 in 2D, 0.9992 in 3D); its bound is 0.5 %.

// 2D at the scene's resolution (r = 0.005 m).
TEST(DamBreak, Dfsph2D) { damBreakTest<2>("dambreak2d.json", 0, "dfsph", 0.005); }
TEST(DamBreak, Wcsph2D) { damBreakTest<2>("dambreak2d.json", 0, "wcsph", 0.02); }

// 3D coarsened from the scene's r = 0.01 m (31 250 particles; WCSPH's
// acoustic time step of 0.43 ms makes that about 35 s of CPU, too much for
// the suite) to r = 1/60 m: 6 750 particles, and the 0.5 m column is exactly
// 15 diameters wide, so the lattice fills it (the front starts at exactly a).
// The scene's resolution shows the same wall crossings (25 with DFSPH, 50
// with WCSPH in the first 0.1 s).
TEST(DamBreak, Dfsph3D) { damBreakTest<3>("dambreak3d.json", 1.0 / 60, "dfsph", 0.005); }
TEST(DamBreak, Wcsph3D) { damBreakTest<3>("dambreak3d.json", 1.0 / 60, "wcsph", 0.02); }

// Martin & Moyce removed a diaphragm; the scenes release the column at
// once. A gate lifted at a finite speed (a kinematic body against the
// column's free face, the tank made tall enough for it) holds the surge
// back while it clears the floor when it is fast; a slow one turns the
// column into a sluice whose jet under the gate runs ahead of the surge.
// The surge's lead over the experiment per gate speed is printed
// (docs/physics/pressure-solvers.md): how much of the lead a release
// explains.
TEST(DamBreak, AGateLiftedAtFiniteSpeedHoldsTheSurgeBack) {
  const double lift = 1.8;  // m: the gate's bottom clears the 1 m column with room to spare
  std::map<double, double> lead;  // gate speed (0: none, the release at once) -> mean lead in Z
  for (double speed : {0.0, 8.0, 6.0, 4.0, 2.0, 1.0}) {
    const auto gate = [&](nlohmann::json& j) {
      j["domain"]["max"][1] = 3.0;
      if (speed <= 0) return;
      const double x = 0.5 + 1e-4 + 0.01, y = 0.55;  // a 2 cm gate against the 0.5 m column's face
      j["bodies"] = nlohmann::json::array(
          {{{"name", "gate"}, {"type", "box"}, {"size", {0.02, 1.1}}, {"motion", "kinematic"},
            {"keys", {{{"time", 0.0}, {"position", {x, y}}}, {{"time", lift / speed}, {"position", {x, y + lift}}}}}}});
    };
    FrameChecks checks;
    const DamRun run = runDamBreak<2>("dambreak2d.json", 0.01, "dfsph", 1.2, checks, gate);
    checks.finish(int(run.frames.size()));
    ASSERT_FALSE(run.frames.empty());
    const MartinMoyce mm = againstMartinMoyce(run);
    std::printf("[ measured ] dam break 2D (r = 0.01 m), %s: surge front RMS %.3f in Z against Martin & Moyce, mean "
                "lead %+.3f; residual column height RMS %.3f\n",
                speed > 0 ? ("gate lifted at " + std::to_string(speed).substr(0, 3) + " m/s").c_str() : "no gate",
                mm.surgeRms, mm.surgeLead, mm.heightRms);
    ASSERT_GE(mm.surge.T.size(), 10u) << "the run must cover Martin & Moyce's surge up to T = 3";
    lead[speed] = mm.surgeLead;
  }
  // Measured: lead +0.23 without a gate, +0.14 with one at 4 m/s, +0.41 at 1 m/s.
  EXPECT_LT(lead[4.0], lead[0.0] - 0.05) << "a gate lifted at 4 m/s must hold the surge back";
  EXPECT_GT(lead[1.0], lead[4.0] + 0.1) << "a gate lifted at 1 m/s makes a sluice jet that runs ahead";
}

// Martin & Moyce's tank had walls the water sticks to; the scenes' walls
// are free-slip (`viscosity_standard`'s boundary_viscosity 0). No-slip walls
// (boundary_viscosity twice the liquid's viscosity) slow the surge's tip,
// which runs over the floor one or two particles thick, and also hold the
// column back against the wall behind it, whose fall the experiment's
// residual heights record: at the scenes' viscosity (ν = 0.001 m²/s, a
// thousand times water's) the wall's layer is far thicker than the
// experiment's. The figures are printed per resolution
// (docs/physics/pressure-solvers.md). viscosity: the liquid's, m^2/s (0:
// the scene's).
template <int D>
MartinMoyce damBreakWithWalls(const std::string& sceneFile, double radius, bool noSlip, double viscosity = 0) {
  double nu = 0;
  const auto walls = [&](nlohmann::json& j) {
    if (viscosity > 0) j["phases"][0]["viscosity"] = viscosity;
    nu = j["phases"][0]["viscosity"].get<double>();
    j["effects"] = nlohmann::json::array({{{"name", "viscosity_standard"}, {"boundary_viscosity", noSlip ? 2 * nu : 0.0}}});
  };
  FrameChecks checks;
  const DamRun run = runDamBreak<D>(sceneFile, radius, "dfsph", 1.2, checks, walls);
  checks.finish(int(run.frames.size()));
  const MartinMoyce mm = againstMartinMoyce(run);
  std::printf("[ measured ] %s (r = %g m, viscosity %g m^2/s), %s walls: surge front RMS %.3f in Z against Martin & "
              "Moyce, mean lead %+.3f; residual column height RMS %.3f\n",
              sceneFile.c_str(), run.r, nu, noSlip ? "no-slip" : "free-slip", mm.surgeRms, mm.surgeLead,
              mm.heightRms);
  EXPECT_GE(mm.surge.T.size(), 10u) << "the run must cover Martin & Moyce's surge up to T = 3";
  return mm;
}

// Measured, surge lead free-slip -> no-slip (residual height RMS): 2D
// r = 0.01 m +0.23 -> +0.16 (0.014 -> 0.061), r = 0.005 m +0.23 -> +0.15
// (0.013 -> 0.108); 3D r = 1/60 m +0.24 -> +0.11 (0.016 -> 0.070).
TEST(DamBreak, NoSlipWallsHoldTheSurgeBackAndTheColumnAtTheWall) {
  const auto expectFriction = [](const MartinMoyce& freeSlip, const MartinMoyce& noSlip) {
    EXPECT_LT(noSlip.surgeLead, freeSlip.surgeLead - 0.05) << "no-slip walls must hold the surge back";
    EXPECT_GT(noSlip.heightRms, freeSlip.heightRms + 0.03) << "no-slip walls hold the column at the wall";
  };
  for (double r : {0.01, 0.005}) {
    const MartinMoyce freeSlip = damBreakWithWalls<2>("dambreak2d.json", r, false);
    expectFriction(freeSlip, damBreakWithWalls<2>("dambreak2d.json", r, true));
  }
  const MartinMoyce freeSlip3D = damBreakWithWalls<3>("dambreak3d.json", 1.0 / 60, false);
  expectFriction(freeSlip3D, damBreakWithWalls<3>("dambreak3d.json", 1.0 / 60, true));
  // At water's viscosity the wall's layer is far thinner than a particle:
  // no-slip walls change nothing (measured: lead +0.243 and +0.238).
  const MartinMoyce water = damBreakWithWalls<2>("dambreak2d.json", 0.005, false, 1e-6);
  const MartinMoyce waterNoSlip = damBreakWithWalls<2>("dambreak2d.json", 0.005, true, 1e-6);
  EXPECT_NEAR(waterNoSlip.surgeLead, water.surgeLead, 0.02);
  EXPECT_GT(water.surgeLead, 0.15) << "the lead at water's viscosity";
}

// Martin & Moyce's own scale (scenes/validation/martin_moyce2d.json and
// 3d: a = 2.25 in = 5.715 cm, water's viscosity and surface tension,
// `sigma` 0.0728 N/m). The
// shipped dam breaks are nine times larger, where surface tension does
// nothing; at the experiment's scale it holds the thin surge tip back and
// takes away about half the lead the larger scenes show.
// Measured, lead (surge RMS) without -> with surface tension: 2D (5 000
// particles) +0.24 -> +0.11 (0.13), residual height RMS 0.046; 3D (6 750)
// +0.26 -> +0.15 (0.16), height RMS 0.024. The column's residual height
// then differs more from the experiment's (RMS 0.046 in 2D against the
// larger scenes' 0.013), so its bound here is 0.06.
constexpr double kTensionHeightRmsBound = 0.06;
template <int D>
void surfaceTensionAtTheExperimentsScale(const std::string& sceneFile, double rmsBound) {
  const auto measure = [&](bool tension) {
    FrameChecks checks;
    const auto edit = [&](nlohmann::json& j) {
      if (!tension) j["effects"] = nlohmann::json::array({"viscosity_standard"});
    };
    const DamRun run = runDamBreak<D>(sceneFile, 0, "dfsph", 1.2, checks, edit);
    checks.finish(int(run.frames.size()));
    const MartinMoyce mm = againstMartinMoyce(run);
    std::printf("[ measured ] %s (%zu particles, r = %g m), %s surface tension: surge front RMS %.3f in Z against "
                "Martin & Moyce, mean lead %+.3f; residual column height RMS %.3f\n",
                sceneFile.c_str(), run.particles, run.r, tension ? "with" : "without", mm.surgeRms, mm.surgeLead,
                mm.heightRms);
    EXPECT_GE(mm.surge.T.size(), 10u) << "the run must cover Martin & Moyce's surge up to T = 3";
    return mm;
  };
  const MartinMoyce without = measure(false), with = measure(true);
  EXPECT_LT(with.surgeLead, without.surgeLead - 0.08) << "surface tension must hold the surge back at this scale";
  EXPECT_LT(with.surgeRms, rmsBound) << "surge front RMS against Martin & Moyce, T <= 3";
  EXPECT_LT(with.heightRms, kTensionHeightRmsBound) << "residual column height RMS against Martin & Moyce";
}

TEST(DamBreak, AtTheExperimentsScaleSurfaceTensionHoldsTheSurgeBack2D) {
  surfaceTensionAtTheExperimentsScale<2>("validation/martin_moyce2d.json", 0.16);
}
TEST(DamBreak, AtTheExperimentsScaleSurfaceTensionHoldsTheSurgeBack3D) {
  surfaceTensionAtTheExperimentsScale<3>("validation/martin_moyce3d.json", 0.2);
}

// The same checks as the shipped dam breaks' (front, volume, walls).
TEST(DamBreak, AtTheExperimentsScale2D) {
  damBreakTest<2>("validation/martin_moyce2d.json", 0, "dfsph", 0.005, kTensionHeightRmsBound);
}
TEST(DamBreak, AtTheExperimentsScale3D) {
  damBreakTest<3>("validation/martin_moyce3d.json", 0, "dfsph", 0.005, kTensionHeightRmsBound);
}

}  // namespace
}  // namespace fc
