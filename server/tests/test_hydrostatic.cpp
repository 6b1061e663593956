// Hydrostatic column (DFSPH): water at rest in a closed tank must stay at
// rest, keep its density within the solver tolerance, and carry the
// hydrostatic pressure ρ0·g·depth down to the floor.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

namespace fc {
namespace {

// Set FLOWCLIP_TEST_VERBOSE=1 to print one line per frame.
bool verbose() {
  const char* v = std::getenv("FLOWCLIP_TEST_VERBOSE");
  return v && *v && std::string(v) != "0";
}

// Checks every frame must pass: finite state, the wall guard never acted,
// every particle strictly inside the tank.
template <int D>
::testing::AssertionResult frameIsSane(const Simulation<D>& sim, const FrameStats& fs) {
  if (!fs.finite) return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): non-finite state";
  if (fs.escapedParticles != 0)
    return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): the wall guard put back "
                                         << fs.escapedParticles << " particle(s)";
  const AABB<D>& dom = sim.setup().domain;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const Vec<D>& x = sim.fluid.x[i];
    if (!((x.array() > dom.min.array()).all() && (x.array() < dom.max.array()).all()))
      return ::testing::AssertionFailure() << "frame " << fs.frame << " (t = " << fs.time << " s): particle "
                                           << sim.fluid.id[i] << " at (" << x.transpose() << ") is not strictly inside the domain ("
                                           << dom.min.transpose() << ") - (" << dom.max.transpose() << ")";
  }
  return ::testing::AssertionSuccess();
}

struct HydroFrame {
  double t = 0;
  double avgErrPct = 0, maxErrPct = 0;
  bool converged = true;
  double ke = 0, maxSpeed = 0;
  double bottomPressure = 0;  // mean pressure of the bottom layer, Pa
  double expectedPressure = 0;  // ρ0 g (H - ȳ) for the same particles, Pa
  double surface = 0;  // H, m
  int substeps = 0, densityIterations = 0;
};

struct HydroRun {
  std::vector<HydroFrame> frames;
  double tolerancePct = 0;
  double wallSeconds = 0;
  size_t particles = 0;
};

template <int D>
HydroRun runHydrostatic(const std::string& sceneFile, double radiusOverride, double seconds) {
  const auto json = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/" + sceneFile);
  const SimulationSetup<D> setup = parseScene<D>(json, radiusOverride);
  EXPECT_EQ(setup.solver.name, "dfsph");
  Simulation<D> sim(setup);
  HydroRun run;
  run.tolerancePct = setup.solver.values.get("density_tolerance_pct");
  run.particles = sim.fluid.size();
  const Real r = sim.particleRadius();
  const double rho0 = setup.phases.at(0).restDensity;
  const double g = setup.gravity.norm();
  const double bottomLimit = setup.domain.min[1] + 3 * r;
  const auto t0 = std::chrono::steady_clock::now();
  while (sim.time() < seconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    EXPECT_TRUE(frameIsSane(sim, fs));
    if (::testing::Test::HasFailure()) break;
    HydroFrame f;
    f.t = sim.time();
    f.avgErrPct = fs.avgDensityErrorPct;
    f.maxErrPct = fs.maxDensityErrorPct;
    f.converged = fs.converged;
    f.ke = fs.kineticEnergy;
    f.maxSpeed = fs.maxSpeed;
    f.substeps = fs.substeps;
    f.densityIterations = fs.densityIterations;
    double top = -1e30, psum = 0, ysum = 0;
    size_t nb = 0;
    for (size_t i = 0; i < sim.fluid.size(); ++i) {
      const double y = sim.fluid.x[i][1];
      top = std::max(top, y);
      if (y < bottomLimit) {
        psum += sim.fluid.pressure[i];
        ysum += y;
        ++nb;
      }
    }
    f.surface = top + r;
    f.bottomPressure = nb ? psum / double(nb) : 0;
    f.expectedPressure = nb ? rho0 * g * (f.surface - ysum / double(nb)) : 0;
    if (verbose())
      std::printf("t=%.3f avgErr=%.5f%% maxErr=%.3f%% conv=%d KE=%.3e vmax=%.2e p_bot=%.1f expected=%.1f H=%.4f sub=%d it=%d\n",
                  f.t, f.avgErrPct, f.maxErrPct, int(f.converged), f.ke, f.maxSpeed, f.bottomPressure,
                  f.expectedPressure, f.surface, f.substeps, f.densityIterations);
    run.frames.push_back(f);
  }
  run.wallSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (verbose()) {
    // Pressure profile by lattice row (height bins of one diameter).
    const int rows = int(std::ceil(double(setup.domain.size()[1]) / (2 * r)));
    std::vector<double> ps(rows, 0), ys(rows, 0), rhos(rows, 0);
    std::vector<int> ns(rows, 0);
    double top = -1e30;
    for (size_t i = 0; i < sim.fluid.size(); ++i) top = std::max(top, double(sim.fluid.x[i][1]));
    for (size_t i = 0; i < sim.fluid.size(); ++i) {
      const int k = std::clamp(int((sim.fluid.x[i][1] - setup.domain.min[1]) / (2 * r)), 0, rows - 1);
      ps[k] += sim.fluid.pressure[i];
      ys[k] += sim.fluid.x[i][1];
      rhos[k] += sim.fluid.density[i];
      ns[k]++;
    }
    for (int k = 0; k < rows; ++k)
      if (ns[k])
        std::printf("row %d n=%d y=%.4f p=%.1f rho0 g (H-y)=%.1f ratio=%.3f rho=%.2f\n", k, ns[k], ys[k] / ns[k], ps[k] / ns[k],
                    rho0 * g * (top + r - ys[k] / ns[k]), ps[k] / ns[k] / (rho0 * g * (top + r - ys[k] / ns[k])), rhos[k] / ns[k]);
  }
  return run;
}

// Settle window = the last `window` seconds; start window = the first `window` seconds.
struct HydroSummary {
  double worstAvgErrPct = 0;  // worst frame in the settled window
  double convergedFraction = 0;
  double pressureRatio = 0;  // time-averaged bottom pressure / time-averaged expected
  double keLateMean = 0, keEarlyMax = 0;
};

HydroSummary summarize(const HydroRun& run, double end, double window) {
  HydroSummary s;
  size_t nLate = 0, nConv = 0;
  double pSum = 0, eSum = 0, keSum = 0;
  for (const auto& f : run.frames) {
    if (f.t <= window + 1e-9) s.keEarlyMax = std::max(s.keEarlyMax, f.ke);
    if (f.t > end - window + 1e-9) {
      ++nLate;
      nConv += f.converged;
      s.worstAvgErrPct = std::max(s.worstAvgErrPct, f.avgErrPct);
      pSum += f.bottomPressure;
      eSum += f.expectedPressure;
      keSum += f.ke;
    }
  }
  if (nLate) {
    s.convergedFraction = double(nConv) / double(nLate);
    s.pressureRatio = eSum > 0 ? pSum / eSum : 0;
    s.keLateMean = keSum / double(nLate);
  }
  return s;
}

template <int D>
void hydrostaticTest(const std::string& sceneFile, double radiusOverride, double seconds, double minConvergedFraction,
                     double maxKeRatio) {
  if (const char* e = std::getenv("FC_R")) radiusOverride = std::atof(e);
  if (const char* e = std::getenv("FC_T")) seconds = std::atof(e);
  const double window = 0.5;
  const HydroRun run = runHydrostatic<D>(sceneFile, radiusOverride, seconds);
  ASSERT_FALSE(::testing::Test::HasFailure());
  ASSERT_GE(run.frames.back().t, seconds - 1e-6);
  const HydroSummary s = summarize(run, seconds, window);
  std::printf(
      "[ measured ] %s: %zu particles, %.1f s simulated in %.1f s wall; settled (last %.1f s): worst avg density error "
      "%.5f%% (tolerance %.5f%%), converged %.0f%% of frames, bottom pressure / rho0 g (H - y) = %.4f; KE late mean "
      "%.3e / early max %.3e = %.3e\n",
      sceneFile.c_str(), run.particles, seconds, run.wallSeconds, window, s.worstAvgErrPct, run.tolerancePct,
      100 * s.convergedFraction, s.pressureRatio, s.keLateMean, s.keEarlyMax, s.keLateMean / s.keEarlyMax);

  // Density: DFSPH iterates until the average error is at most the
  // tolerance, so a settled frame may not exceed it (no slack on top).
  for (const auto& f : run.frames)
    if (f.t > seconds - window + 1e-9)
      EXPECT_LE(f.avgErrPct, run.tolerancePct) << "t = " << f.t << " s: average density error above the tolerance";
  EXPECT_GE(s.convergedFraction, minConvergedFraction) << "fraction of settled frames whose solves all converged";

  // Hydrostatic pressure at the floor, within 5 %.
  EXPECT_NEAR(s.pressureRatio, 1.0, 0.05) << "bottom-layer pressure / rho0 g (H - y_mean)";

  // Kinetic energy decays once the column has settled.
  EXPECT_GT(s.keEarlyMax, 0.0);
  EXPECT_LT(s.keLateMean, maxKeRatio * s.keEarlyMax) << "late mean KE / early max KE = " << s.keLateMean / s.keEarlyMax;
}

TEST(Hydrostatic, Dfsph2D) {
  hydrostaticTest<2>("hydrostatic2d.json", 0, 3.0, 0.9, 0.1);
}

TEST(Hydrostatic, Dfsph3D) {
  hydrostaticTest<3>("hydrostatic3d.json", 0, 3.0, 0.9, 0.1);
}

}  // namespace
}  // namespace fc
