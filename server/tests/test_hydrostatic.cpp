// Hydrostatic column (DFSPH, the shipped scenes with their adami2012
// boundary): water at rest in a closed tank must stay in the tank, settle
// (kinetic energy decays), keep its average density error within the solver
// tolerance, and carry the hydrostatic pressure ρ0·g·depth down to the floor.
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame and the settled pressure
// profile by row.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include "physics_checks.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

namespace fc {
namespace {

struct HydroFrame {
  double t = 0;
  double avgErrPct = 0;
  bool converged = true;
  double ke = 0;
  double floorPressure = 0;     // the liquid's load on the floor per unit area (Pa; Pa·m in 2D)
  double contactShare = 0;      // the share of it carried by the contact model
  double expectedFloor = 0;     // ρ0 g H̄ with H̄ the mean liquid height (volume / floor area)
  double bottomPressure = 0;    // mean pressure of the bottom layer (y < floor + 3r), Pa
  double expectedPressure = 0;  // ρ0 g (H - ȳ) for the same particles, Pa
  double wallRowRatio = 0;      // the same ratio for the row touching the floor alone (y < floor + 2r)
  double interiorSlopeRatio = 0;  // -dp/dy / (ρ0 g), least squares over the interior
  double minWallGap = 0;        // closest approach of any particle to any wall, in r
};

struct HydroRun {
  std::vector<HydroFrame> frames;
  double tolerancePct = 0;
  double wallSeconds = 0;
  size_t particles = 0;
  double radius = 0;
  double mass = 0;  // kg (kg/m in 2D)
};

template <int D>
HydroRun runHydrostatic(const std::string& sceneFile, double radiusOverride, double seconds, FrameChecks& checks) {
  const auto json = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/" + sceneFile);
  const SimulationSetup<D> setup = parseScene<D>(json, radiusOverride);
  EXPECT_EQ(setup.solver.name, "dfsph");
  Simulation<D> sim(setup);
  HydroRun run;
  run.tolerancePct = setup.solver.values.get("density_tolerance_pct");
  run.particles = sim.fluid.size();
  run.radius = sim.particleRadius();
  for (size_t i = 0; i < sim.fluid.size(); ++i) run.mass += sim.fluid.mass[i];
  const double r = sim.particleRadius();
  const double rho0 = setup.phases.at(0).restDensity;
  const double g = setup.gravity.norm();
  const double floorY = setup.domain.min[1];
  const auto& f = sim.fluid;
  const double surface = volumeSurface(sim);
  double floorArea = 1;
  for (int d = 0; d < D; ++d)
    if (d != 1) floorArea *= double(setup.domain.size()[d]);
  const auto t0 = std::chrono::steady_clock::now();
  while (sim.time() < seconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    HydroFrame h;
    h.t = sim.time();
    h.avgErrPct = fs.avgDensityErrorPct;
    h.converged = fs.converged;
    h.ke = fs.kineticEnergy;
    double gap = 1e30;
    for (size_t i = 0; i < f.size(); ++i) {
      for (int d = 0; d < D; ++d)
        gap = std::min({gap, double(f.x[i][d] - setup.domain.min[d]), double(setup.domain.max[d] - f.x[i][d])});
    }
    const double H = surface;
    h.minWallGap = gap / r;
    // Bottom layer, wall row, and a least-squares fit p = a + b y over the
    // interior (away from the floor and the surface by three diameters).
    double pB = 0, yB = 0, pW = 0, yW = 0;
    size_t nB = 0, nW = 0;
    double sy = 0, sp = 0, syy = 0, syp = 0;
    size_t nI = 0;
    for (size_t i = 0; i < f.size(); ++i) {
      // The pressure a user reads (exports' /particles/pressure), not the last substep's solve.
      const double y = f.x[i][1], p = f.meanPressure[i];
      if (y < floorY + 3 * r) pB += p, yB += y, ++nB;
      if (y < floorY + 2 * r) pW += p, yW += y, ++nW;
      if (y > floorY + 6 * r && y < H - 6 * r) sy += y, sp += p, syy += y * y, syp += y * p, ++nI;
    }
    // The pressure on the bottom: the momentum the boundary gave the liquid
    // over the frame (summed by the solver where it applies it, every
    // substep), per second and per unit floor area. At rest it must carry
    // the weight.
    const double load = fs.boundaryImpulse[1] / sim.frameDuration();
    double mass = 0;
    for (size_t i = 0; i < f.size(); ++i) mass += f.mass[i];
    // Plus what the contact model carried at the floor over the frame.
    const double contactForce = fs.contactImpulse[2] / sim.frameDuration();
    h.floorPressure = (load + contactForce) / floorArea;
    h.contactShare = contactForce / (load + contactForce);
    h.expectedFloor = rho0 * g * (mass / rho0 / floorArea);
    if (nB) {
      h.bottomPressure = pB / double(nB);
      h.expectedPressure = rho0 * g * (H - yB / double(nB));
    }
    if (nW) h.wallRowRatio = (pW / double(nW)) / (rho0 * g * (H - yW / double(nW)));
    if (nI > 2) {
      const double slope = (double(nI) * syp - sy * sp) / (double(nI) * syy - sy * sy);
      h.interiorSlopeRatio = -slope / (rho0 * g);
    }
    if (verbose())
      std::printf("t=%.3f avgErr=%.5f%% maxErr=%.3f%% conv=%d KE=%.3e vmax=%.2e p_bottom=%.0f expected=%.0f "
                  "wallRow=%.3f slope=%.3f H=%.4f gap=%.3fr substeps=%d iterations=%d+%d\n",
                  h.t, h.avgErrPct, fs.maxDensityErrorPct, int(h.converged), h.ke, fs.maxSpeed, h.bottomPressure,
                  h.expectedPressure, h.wallRowRatio, h.interiorSlopeRatio, H, h.minWallGap, fs.substeps,
                  fs.divergenceIterations, fs.densityIterations);
    run.frames.push_back(h);
  }
  run.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (verbose()) {
    // Final pressure profile by height bins of one diameter.
    double top = -1e30;
    for (size_t i = 0; i < f.size(); ++i) top = std::max(top, double(f.x[i][1]));
    const int rows = int(std::ceil((top - floorY) / (2 * r))) + 1;
    std::vector<double> ps(rows, 0), ys(rows, 0);
    std::vector<int> ns(rows, 0);
    for (size_t i = 0; i < f.size(); ++i) {
      const int k = std::clamp(int((f.x[i][1] - floorY) / (2 * r)), 0, rows - 1);
      ps[k] += f.meanPressure[i], ys[k] += f.x[i][1], ns[k]++;
    }
    for (int k = 0; k < rows; ++k)
      if (ns[k])
        std::printf("row %2d: %4d particles, y = %.4f, p = %8.1f, p / rho0 g (H - y) = %.3f\n", k, ns[k], ys[k] / ns[k],
                    ps[k] / ns[k], ps[k] / ns[k] / (rho0 * g * (top + r - ys[k] / ns[k])));
  }
  return run;
}

// seconds: run length; the settled window is its last 0.5 s, the start
// window its first 0.5 s. maxKeRatio: bound on (mean KE, settled) / (max KE, start).
template <int D>
void hydrostaticTest(const std::string& sceneFile, double radiusOverride, double seconds, double maxKeRatio,
                     double maxContactFraction) {
  const double window = 0.5;
  FrameChecks checks;
  const HydroRun run = runHydrostatic<D>(sceneFile, radiusOverride, seconds, checks);
  checks.finish(int(run.frames.size()));
  ASSERT_FALSE(run.frames.empty());
  ASSERT_GE(run.frames.back().t, seconds - 1e-6) << "the run stopped early";

  size_t nLate = 0, nConverged = 0, aboveTolerance = 0;
  double worstErr = 0, worstErrT = 0, pSum = 0, eSum = 0, keSum = 0, keEarlyMax = 0, wallRow = 0, slope = 0;
  double floorSum = 0, floorExpected = 0, contactShare = 0;
  double minGap = 1e30;
  for (const HydroFrame& h : run.frames) {
    minGap = std::min(minGap, h.minWallGap);
    if (h.t <= window + 1e-9) keEarlyMax = std::max(keEarlyMax, h.ke);
    if (h.t <= seconds - window + 1e-9) continue;
    ++nLate;
    nConverged += h.converged;
    if (h.avgErrPct > run.tolerancePct) ++aboveTolerance;
    if (h.avgErrPct > worstErr) worstErr = h.avgErrPct, worstErrT = h.t;
    floorSum += h.floorPressure;
    contactShare += h.contactShare;
    floorExpected += h.expectedFloor;
    pSum += h.bottomPressure;
    eSum += h.expectedPressure;
    keSum += h.ke;
    wallRow += h.wallRowRatio;
    slope += h.interiorSlopeRatio;
  }
  ASSERT_GT(nLate, 0u);
  const double convergedFraction = double(nConverged) / double(nLate);
  const double pressureRatio = pSum / eSum;
  const double floorRatio = floorSum / floorExpected;
  const double contactFraction = double(checks.contacts) / checks.particleSteps;
  const double keLate = keSum / double(nLate);
  const double keRatio = keLate / keEarlyMax;
  std::printf("[ measured ] %s: %zu particles (r = %g m), %.1f s simulated in %.1f s wall. Settled (last %.1f s, %zu frames): "
              "worst average density error %.5f%% (tolerance %.5f%%), %zu frames above it, converged in %.0f%% of frames; "
              "floor load / rho0 g H = %.4f (%.1f%% of it through contacts); bottom-layer particle pressure / rho0 g (H - y) = %.4f (wall row alone "
              "%.3f, interior -dp/dy / rho0 g = %.3f); KE settled mean %.3e / start max %.3e = %.2e; closest approach "
              "to a wall %.3f r; contact corrections %zu (%.3f%% of particle-steps), centres across a wall %zu\n",
              sceneFile.c_str(), run.particles, run.radius, seconds, run.wallSeconds, window, nLate, worstErr,
              run.tolerancePct, aboveTolerance, 100 * convergedFraction, floorRatio, 100 * contactShare / double(nLate),
              pressureRatio,
              wallRow / double(nLate), slope / double(nLate), keLate, keEarlyMax, keRatio, minGap, checks.contacts,
              100 * contactFraction, checks.crossed);

  // Density: DFSPH iterates until the average error is at most the scene's
  // tolerance, so no settled frame may exceed it (no slack on top).
  EXPECT_EQ(aboveTolerance, 0u) << "settled frames whose average density error exceeds density_tolerance_pct = "
                                << run.tolerancePct << " %; worst " << worstErr << " % at t = " << worstErrT << " s";
  // Most settled frames must converge (a solve may hit its iteration cap
  // now and then): at least 90 %.
  EXPECT_GE(convergedFraction, 0.9) << "fraction of settled frames in which every solve reached its tolerance";

  // Hydrostatic pressure on the floor, time-averaged, within 5 %: the load
  // the floor carries per unit area against ρ0 g H̄ (measured 1.0000 in 2D,
  // 1.0002 in 3D). (The row of particles touching the floor reads 1.02 ρ0 g
  // depth in 2D and 1.00 in 3D with the scenes' adami2012 boundary; with
  // akinci2012's term alone about 1.7: test_readable_pressure.cpp.)
  EXPECT_NEAR(floorRatio, 1.0, 0.05) << "floor load / rho0 g H, time-averaged over the last " << window << " s";
  // Inside the column the pressure a user reads grows as ρ0 g per metre of
  // depth: measured 1.021 (2D) and 1.034 (3D), within 8 %. (The last
  // substep's solver pressures carry the column's residual sloshing and
  // measured 0.97-1.28 in 3D between builds; test_readable_pressure.cpp
  // holds every depth band to 3 %.)
  EXPECT_NEAR(slope / double(nLate), 1.0, 0.08) << "interior -dp/dy / (rho0 g)";
  // No particle centre crossed a wall surface, and the contact model rarely
  // had to act (measured: 0.002 % of particle-steps in 2D, 0.007 % in 3D,
  // the surface particles along the side walls).
  EXPECT_EQ(checks.crossed, 0u) << "particle centres that crossed a wall surface within a substep";
  EXPECT_LT(contactFraction, maxContactFraction) << "contact corrections per particle-step";

  // The column settles: kinetic energy decays, and the liquid's RMS speed
  // over the last 0.5 s, sqrt(2 KE / M), is below 1 cm/s (measured 3.6 mm/s
  // in 2D, 4.3 mm/s in 3D).
  EXPECT_GT(keEarlyMax, 0.0);
  EXPECT_LT(keRatio, maxKeRatio) << "mean KE over the last " << window << " s / max KE over the first " << window << " s";
  const double rmsSpeed = std::sqrt(2 * keLate / run.mass);
  std::printf("[ measured ] %s: settled RMS speed %.2f mm/s\n", sceneFile.c_str(), 1000 * rmsSpeed);
  EXPECT_LT(rmsSpeed, 0.01) << "RMS speed of the settled column, m/s";
}

// 2D: 1 m of water in a 1 m wide tank at the scene's resolution (r = 0.01 m,
// 2 500 particles, 50 layers), 3 s: the pressure gradient needs a deep column
// and the kinetic-energy bound needs the column to settle.
// KE ratio measured (settled mean / start max): 7.3e-3 (start max 0.90
// J/m, settled mean 6.5e-3 J/m). The bound 0.02 keeps a factor 2.7 of
// margin and is 5x tighter than the plan's 0.1.
TEST(Hydrostatic, Dfsph2D) { hydrostaticTest<2>("hydrostatic2d.json", 0, 3.0, 0.02, 1e-3); }

// 3D: 0.3 m of water in a 0.3 x 0.45 x 0.3 m tank at the scene's resolution
// (r = 0.01 m, 3 375 particles, 15 layers), 3 s: 15 layers is the fewest
// that still has an interior between the wall rows.
// KE ratio measured: 3.8e-2 (start max 6.6e-3 J, settled mean 2.5e-4 J).
// With the scene's adami2012 boundary the rows do not sink at the start, so
// the start is ten times calmer than with akinci2012 (0.063 J) and the
// ratio larger although the settled energy is half (5.5e-4 to 7.8e-4 J
// with akinci2012): the bound is the plan's 0.1, and the RMS speed check
// is the absolute one.
TEST(Hydrostatic, Dfsph3D) { hydrostaticTest<3>("hydrostatic3d.json", 0, 3.0, 0.1, 0.02); }

}  // namespace
}  // namespace fc
