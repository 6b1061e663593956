// Multiphase liquids: phases of different rest densities in one tank, with
// the number-density interface treatment of Solenthaler & Pajarola 2008 [SP08]
// (settings "density_formulation", automatic when rest densities differ).
//  1. The formulation is chosen once at setup: automatic (number density
//     only when rest densities differ), or as the scene says; on a 1:3
//     lattice the number density reads both phases at rest density.
//  2. A light phase (1000 kg/m³) placed under a heavy one (3000 kg/m³) rises
//     above it (Rayleigh-Taylor) without the liquid gaining height, with a
//     bounded density error and no NaN.
//  3. The same ratio layered at rest (heavy at the bottom) stays at rest: the
//     interface stays flat and as tightly spaced as the bulk, each phase keeps
//     its volume, and no particle changes phase. The mass sum in the same
//     scene opens a gap at the interface (the spurious interface tension the
//     number density removes), with DFSPH and with WCSPH.
// Single-phase scenes are unchanged: Hydrostatic.* and DamBreak.* run the
// mass sum, with no per-particle branch (the formulation is never switched
// on for one phase; see docs/physics/multiphase.md).
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include "physics_checks.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <array>
#include <map>
#include <string>
#include <vector>

namespace fc {
namespace {

using nlohmann::json;

// A 2D tank with a light phase "oil" (1000 kg/m³) and a heavy phase "heavy"
// (3000 kg/m³), both of kinematic viscosity `viscosity` (0: no viscosity
// effect); blocks are {min, max, phase}. DFSPH at 0.05 % density tolerance.
json twoPhaseScene(double radius, const std::vector<double>& domainMax, const json& blocks, int formulation,
                   double viscosity = 0) {
  json s = {
      {"dimension", 2},
      {"particle_radius", radius},
      {"domain", {{"min", {0, 0}}, {"max", domainMax}}},
      {"phases", json::array({{{"name", "oil"}, {"rest_density", 1000}, {"viscosity", viscosity}, {"color", {0.95, 0.75, 0.2}}},
                              {{"name", "heavy"}, {"rest_density", 3000}, {"viscosity", viscosity}, {"color", {0.2, 0.4, 0.9}}}})},
      {"fluid_blocks", blocks},
      {"solver", {{"method", "dfsph"}, {"density_tolerance_pct", 0.05}}},
      {"settings", {{"density_formulation", formulation}}},
  };
  if (viscosity > 0) s["effects"] = json::array({"viscosity_standard"});
  return s;
}

json block(double x0, double y0, double x1, double y1, const char* phase) {
  return {{"min", {x0, y0}}, {"max", {x1, y1}}, {"phase", phase}};
}

struct PhaseStats {
  double comY[2] = {0, 0};    // centre of mass height per phase, m
  double mass[2] = {0, 0};    // kg/m
  size_t count[2] = {0, 0};
};

PhaseStats phaseStats(const Simulation<2>& sim) {
  PhaseStats s;
  double m[2] = {0, 0};
  const auto& f = sim.fluid;
  for (size_t i = 0; i < f.size(); ++i) {
    const int p = f.phase[i];
    m[p] += f.mass[i];
    s.comY[p] += double(f.mass[i]) * f.x[i][1];
    ++s.count[p];
  }
  for (int p = 0; p < 2; ++p) s.comY[p] /= m[p], s.mass[p] = m[p];
  return s;
}

// The interface between a heavy layer below and a light one above, per
// column of one particle diameter: the highest heavy and the lowest light
// particle, and the highest light one (the free surface). Columns within a
// support radius (two diameters) of a side wall are the "wall columns": the
// heavy phase climbs the walls there by a row or two (a contact line), so
// they are measured apart.
//  spacing: mean vertical distance between the highest heavy and the lowest
//    light particle over the interior columns, in particle diameters (1 on
//    the initial lattice);
//  flatnessRms, flatnessSpread: RMS and max - min of the interior columns'
//    interface heights (midway between the two), in diameters; wallRise: the
//    largest deviation of a wall column from their mean, in diameters;
//  misplaced: interior heavy particles above the mean interface + one
//    diameter plus interior light particles below it - one diameter;
//  interfaceHeight: the mean interface height, m (the heavy layer's
//    thickness: its volume per width);
//  surfaceHeight: the mean free-surface height (top light particle + r), m.
struct Interface {
  double spacing = 0, flatnessRms = 0, flatnessSpread = 0, wallRise = 0;
  size_t misplaced = 0;
  double interfaceHeight = 0, surfaceHeight = 0;
};

Interface measureInterface(const Simulation<2>& sim) {
  const auto& f = sim.fluid;
  const double r = sim.particleRadius(), d = 2 * r;
  const auto& dom = sim.setup().domain;
  const int columns = int(std::floor((dom.max[0] - dom.min[0]) / d + 1e-6));
  const int wall = int(std::ceil(sim.supportRadius() / d));
  std::vector<double> top(columns, -1e30), bottom(columns, 1e30), surface(columns, -1e30);
  auto column = [&](const Vec<2>& x) { return std::clamp(int((x[0] - dom.min[0]) / d), 0, columns - 1); };
  for (size_t i = 0; i < f.size(); ++i) {
    const int c = column(f.x[i]);
    if (f.phase[i] == 1) {
      top[c] = std::max(top[c], double(f.x[i][1]));
    } else {
      bottom[c] = std::min(bottom[c], double(f.x[i][1]));
      surface[c] = std::max(surface[c], double(f.x[i][1]));
    }
  }
  Interface out;
  std::vector<double> y, yWall;
  double gap = 0, surf = 0, all = 0;
  int n = 0;
  for (int c = 0; c < columns; ++c) {
    if (top[c] < -1e29 || bottom[c] > 1e29) continue;
    const double yc = 0.5 * (bottom[c] + top[c]);
    all += yc, surf += surface[c] + r, ++n;
    if (c < wall || c >= columns - wall) {
      yWall.push_back(yc);
      continue;
    }
    gap += bottom[c] - top[c];
    y.push_back(yc);
  }
  if (y.empty()) return out;
  out.interfaceHeight = all / n - double(dom.min[1]);
  out.surfaceHeight = surf / n - double(dom.min[1]);
  double mean = 0;
  for (double v : y) mean += v;
  mean /= double(y.size());
  double var = 0;
  for (double v : y) var += (v - mean) * (v - mean);
  out.spacing = gap / double(y.size()) / d;
  out.flatnessRms = std::sqrt(var / double(y.size())) / d;
  out.flatnessSpread = (*std::max_element(y.begin(), y.end()) - *std::min_element(y.begin(), y.end())) / d;
  for (double v : yWall) out.wallRise = std::max(out.wallRise, std::abs(v - mean) / d);
  for (size_t i = 0; i < f.size(); ++i) {
    const int c = column(f.x[i]);
    if (c < wall || c >= columns - wall) continue;
    if (f.phase[i] == 1 && f.x[i][1] > mean + d) ++out.misplaced;
    if (f.phase[i] == 0 && f.x[i][1] < mean - d) ++out.misplaced;
  }
  return out;
}

// Per phase, Σ m_i / max(ρ_i, ρ0_i): the volume the phase fills as the
// solver sees it, compression counted, the density deficit of particles at
// the free surface (which DFSPH leaves alone) not.
std::array<double, 2> compressedVolume(const Simulation<2>& sim) {
  std::array<double, 2> v{0, 0};
  const auto& f = sim.fluid;
  for (size_t i = 0; i < f.size(); ++i)
    v[f.phase[i]] += double(f.mass[i]) / std::max(double(f.density[i]), double(sim.restDensity(i)));
  return v;
}

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// ---------------------------------------------------------------------------
// 1. Selection at setup

TEST(Multiphase, FormulationChosenOnceAtSetup) {
  const json blocks = json::array({block(0, 0, 0.2, 0.1, "heavy"), block(0, 0.1, 0.2, 0.2, "oil")});
  // Automatic: different rest densities select the number density.
  EXPECT_TRUE(Simulation<2>(parseScene<2>(twoPhaseScene(0.01, {0.2, 0.3}, blocks, 0))).numberDensity());
  EXPECT_FALSE(Simulation<2>(parseScene<2>(twoPhaseScene(0.01, {0.2, 0.3}, blocks, 1))).numberDensity());
  // Automatic with equal rest densities (two colours of water) or one phase:
  // the mass sum, exactly as single-phase scenes always ran.
  json same = twoPhaseScene(0.01, {0.2, 0.3}, blocks, 0);
  same["phases"][1]["rest_density"] = 1000;
  EXPECT_FALSE(Simulation<2>(parseScene<2>(same)).numberDensity());
  json single = same;
  single.erase("settings");
  single["phases"] = json::array({{{"name", "oil"}}});
  single["fluid_blocks"] = json::array({block(0, 0, 0.2, 0.2, "oil")});
  EXPECT_FALSE(Simulation<2>(parseScene<2>(single)).numberDensity());
  // Forced on for one phase: equal masses make it the same density.
  single["settings"] = {{"density_formulation", 2}};
  Simulation<2> forced(parseScene<2>(single));
  single["settings"] = {{"density_formulation", 1}};
  Simulation<2> massSum(parseScene<2>(single));
  EXPECT_TRUE(forced.numberDensity());
  forced.refreshNeighbors();
  massSum.refreshNeighbors();
  ASSERT_EQ(forced.fluid.size(), massSum.fluid.size());
  for (size_t i = 0; i < forced.fluid.size(); ++i)
    EXPECT_NEAR(forced.fluid.density[i], massSum.fluid.density[i], 1e-4 * massSum.fluid.density[i]) << i;
  // Out of range is a scene error naming the key.
  json bad = twoPhaseScene(0.01, {0.2, 0.3}, blocks, 3);
  try {
    parseScene<2>(bad);
    ADD_FAILURE() << "density_formulation 3 was accepted";
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "settings.density_formulation");
  }
}

// At a 1:3 interface on the initial lattice, the number density gives both
// phases their rest density; the mass sum over- and underestimates them.
TEST(Multiphase, InterfaceDensityOnTheLattice) {
  const double r = 0.005;
  const json blocks = json::array({block(0, 0, 0.3, 0.1, "heavy"), block(0, 0.1, 0.3, 0.2, "oil")});
  for (int formulation : {1, 2}) {
    Simulation<2> sim(parseScene<2>(twoPhaseScene(r, {0.3, 0.3}, blocks, formulation)));
    sim.refreshNeighbors();
    const auto& f = sim.fluid;
    double worst[2] = {0, 0};  // largest |ρ/ρ0 - 1| within two diameters of the interface, per phase
    for (size_t i = 0; i < f.size(); ++i) {
      const double y = f.x[i][1];
      if (std::abs(y - 0.1) > 4 * r || f.x[i][0] < 0.05 || f.x[i][0] > 0.25) continue;
      worst[f.phase[i]] = std::max(worst[f.phase[i]], std::abs(double(f.density[i] / sim.restDensity(i)) - 1));
    }
    std::printf("[ measured ] %s on the lattice at the 1:3 interface: largest |rho/rho0 - 1| light %.4f%%, heavy %.4f%%\n",
                formulation == 1 ? "mass sum" : "number density", 100 * worst[0], 100 * worst[1]);
    if (formulation == 2) {
      EXPECT_LT(worst[0], 1e-4);
      EXPECT_LT(worst[1], 1e-4);
    } else {
      EXPECT_GT(worst[0], 0.2);  // a light particle counts heavy neighbours as compression
      EXPECT_GT(worst[1], 0.1);
    }
  }
}

// ---------------------------------------------------------------------------
// 2. Rayleigh-Taylor: light under heavy rises.
//
// 0.32 m wide tank, r = 0.004 m, no viscosity: the light phase below (0.1 m
// on average, with a step of ±0.02 m in the middle to seed the instability),
// the heavy one above (0.1 m on average); 1 000 particles, 2.5 s.
TEST(Multiphase, LightPhaseUnderHeavyRises) {
  const double r = 0.004;
  const json blocks = json::array({block(0, 0, 0.16, 0.12, "oil"), block(0.16, 0, 0.32, 0.08, "oil"),
                                   block(0, 0.12, 0.16, 0.2, "heavy"), block(0.16, 0.08, 0.32, 0.2, "heavy")});
  Simulation<2> sim(parseScene<2>(twoPhaseScene(r, {0.32, 0.35}, blocks, 0)));
  ASSERT_TRUE(sim.numberDensity());
  const PhaseStats start = phaseStats(sim);
  ASSERT_LT(start.comY[0], start.comY[1]);
  const double startTotal = (start.comY[0] * start.mass[0] + start.comY[1] * start.mass[1]) / (start.mass[0] + start.mass[1]);
  FrameChecks checks;
  const double rate = sim.setup().settings.frameRate;
  const int frames = int(std::lround(2.5 * rate));
  double worstAvg = 0, worstMax = 0, maxSpeed = 0, highestTotal = startTotal;
  int unconverged = 0, crossedAt = -1;
  PhaseStats s = start;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < frames; ++k) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    worstAvg = std::max(worstAvg, fs.avgDensityErrorPct);
    worstMax = std::max(worstMax, fs.maxDensityErrorPct);
    maxSpeed = std::max(maxSpeed, fs.maxSpeed);
    unconverged += fs.converged ? 0 : 1;
    s = phaseStats(sim);
    highestTotal = std::max(highestTotal, (s.comY[0] * s.mass[0] + s.comY[1] * s.mass[1]) / (s.mass[0] + s.mass[1]));
    if (crossedAt < 0 && s.comY[0] > s.comY[1]) crossedAt = fs.frame;
    if (verbose())
      std::printf("t=%.3f light y=%.4f heavy y=%.4f avgErr=%.4f%% maxErr=%.3f%% vmax=%.3f substeps=%d it=%d+%d\n", fs.time,
                  s.comY[0], s.comY[1], fs.avgDensityErrorPct, fs.maxDensityErrorPct, fs.maxSpeed, fs.substeps,
                  fs.divergenceIterations, fs.densityIterations);
  }
  checks.finish(frames);
  std::printf("[ measured ] light under heavy (1:3, %zu particles, %.1f s wall): centres of mass light %.4f -> %.4f m, "
              "heavy %.4f -> %.4f m; light above heavy from t = %.2f s; the liquid's centre of mass at most %.2f mm above "
              "its start; max speed %.2f m/s; worst average density error %.4f%%, worst particle %.2f%%, %d unconverged "
              "frames\n",
              sim.fluid.size(), secondsSince(t0), start.comY[0], s.comY[0], start.comY[1], s.comY[1], crossedAt / rate,
              1e3 * (highestTotal - startTotal), maxSpeed, worstAvg, worstMax, unconverged);
  EXPECT_GT(s.comY[0], s.comY[1]) << "the light phase's centre of mass ends above the heavy one's";
  // Full inversion: the two centres trade places (measured: exactly).
  EXPECT_GT(s.comY[0] - s.comY[1], 0.8 * (start.comY[1] - start.comY[0]));
  // No energy from nowhere: the liquid as a whole only sinks as it overturns
  // (the warm-started density solve launched it by 0.1 m, see sph/pressure/dfsph.cpp).
  EXPECT_LT(highestTotal - startTotal, 2 * r) << "rise of the liquid's centre of mass, m";
  // Bounded density error: the solver's average at exit near its tolerance
  // (0.05 %; the first frame starts from zero pressure), every particle
  // within a few percent, and at most a few frames at the iteration cap.
  EXPECT_LT(worstAvg, 0.2) << "average density error at solver exit, percent";
  EXPECT_LT(worstMax, 5.0) << "largest particle density error at solver exit, percent";
  EXPECT_LE(unconverged, 3);
}

// ---------------------------------------------------------------------------
// 3. Layered at rest, heavy below: stays put.
//
// 0.6 m wide tank, r = 0.004 m: heavy 0.096 m at the bottom, light 0.096 m
// on top, 1 800 particles, 2 s. Both of kinematic viscosity 5e-4 m²/s
// (viscosity_standard): an inviscid DFSPH layer that starts on the lattice
// keeps sloshing at 0.15-0.2 m/s (single-phase alike: two phases of equal
// density measure the same), which would hide what the interface does.
struct RestRun {
  double maxSpeedLate = 0;       // largest speed over the last second, m/s
  double spacing = 0;            // interface spacing at the end, in diameters
  double flatnessRms = 0;        // worst RMS of the interior interface heights over the run, in diameters
  double flatnessSpread = 0;     // worst spread, in diameters
  double wallRise = 0;           // worst deviation of a wall column, in diameters
  size_t misplacedMax = 0;
  double volumeChange[2] = {0, 0};  // largest |V/V_0 - 1| per phase over the run (compressedVolume)
  double heavyLayerChange = 0;      // largest |h/h_0 - 1| of the interface height
  double surfaceChange = 0;         // free-surface height at the end minus at the start, in r
  bool phasesKept = true;
  size_t countChanges = 0;
  double worstAvgErr = 0;
  double wall = 0;
  size_t particles = 0;
};

RestRun runLayeredAtRest(int formulation, double seconds) {
  const double r = 0.004;
  const json blocks = json::array({block(0, 0, 0.6, 0.096, "heavy"), block(0, 0.096, 0.6, 0.192, "oil")});
  Simulation<2> sim(parseScene<2>(twoPhaseScene(r, {0.6, 0.3}, blocks, formulation, 5e-4)));
  RestRun run;
  run.particles = sim.fluid.size();
  std::map<uint32_t, uint8_t> phaseOf;
  for (size_t i = 0; i < sim.fluid.size(); ++i) phaseOf[sim.fluid.id[i]] = sim.fluid.phase[i];
  const PhaseStats start = phaseStats(sim);
  sim.refreshNeighbors();
  const std::array<double, 2> v0 = compressedVolume(sim);
  const Interface itf0 = measureInterface(sim);
  Interface itf = itf0;
  FrameChecks checks;
  const double rate = sim.setup().settings.frameRate;
  const int frames = int(std::lround(seconds * rate));
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < frames; ++k) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    const PhaseStats s = phaseStats(sim);
    itf = measureInterface(sim);
    const std::array<double, 2> v = compressedVolume(sim);
    for (int p = 0; p < 2; ++p) {
      run.volumeChange[p] = std::max(run.volumeChange[p], std::abs(v[p] / v0[p] - 1));
      run.countChanges += s.count[p] != start.count[p] ? 1 : 0;
    }
    run.heavyLayerChange = std::max(run.heavyLayerChange, std::abs(itf.interfaceHeight / itf0.interfaceHeight - 1));
    run.flatnessRms = std::max(run.flatnessRms, itf.flatnessRms);
    run.flatnessSpread = std::max(run.flatnessSpread, itf.flatnessSpread);
    run.wallRise = std::max(run.wallRise, itf.wallRise);
    run.misplacedMax = std::max(run.misplacedMax, itf.misplaced);
    run.spacing = itf.spacing;
    run.worstAvgErr = std::max(run.worstAvgErr, fs.avgDensityErrorPct);
    if (fs.time > seconds - 1.0 + 1e-9) run.maxSpeedLate = std::max(run.maxSpeedLate, fs.maxSpeed);
    if (verbose())
      std::printf("t=%.3f vmax=%.4f spacing=%.3f flat=%.3f/%.3f wall=%.2f misplaced=%zu dV=%.4f%% %.4f%% "
                  "interface=%.5f surface=%.5f avgErr=%.4f%% it=%d+%d\n",
                  fs.time, fs.maxSpeed, itf.spacing, itf.flatnessRms, itf.flatnessSpread, itf.wallRise, itf.misplaced,
                  100 * (v[0] / v0[0] - 1), 100 * (v[1] / v0[1] - 1), itf.interfaceHeight, itf.surfaceHeight,
                  fs.avgDensityErrorPct, fs.divergenceIterations, fs.densityIterations);
  }
  checks.finish(frames);
  run.wall = secondsSince(t0);
  run.surfaceChange = (itf.surfaceHeight - itf0.surfaceHeight) / r;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    auto it = phaseOf.find(sim.fluid.id[i]);
    run.phasesKept = run.phasesKept && it != phaseOf.end() && it->second == sim.fluid.phase[i];
  }
  run.phasesKept = run.phasesKept && sim.fluid.size() == phaseOf.size();
  return run;
}

void printRestRun(const char* what, const RestRun& r) {
  std::printf("[ measured ] 1:3 layered at rest, %s (%zu particles, %.1f s wall): max speed over the last second %.4f "
              "m/s; interface spacing %.3f diameters, worst RMS %.3f / spread %.2f diameters away from the walls, %zu "
              "misplaced, the heavy phase up to %.2f diameters up the walls; largest volume change light %.3f%%, heavy "
              "%.3f%%, heavy layer thickness %.3f%%; free surface moved %.2f r; worst average density error %.4f%%\n",
              what, r.particles, r.wall, r.maxSpeedLate, r.spacing, r.flatnessRms, r.flatnessSpread, r.misplacedMax,
              r.wallRise, 100 * r.volumeChange[0], 100 * r.volumeChange[1], 100 * r.heavyLayerChange, r.surfaceChange,
              r.worstAvgErr);
}

TEST(Multiphase, LayeredAtRestStaysStable) {
  const RestRun nd = runLayeredAtRest(0, 2.0);
  printRestRun("number density", nd);
  // The fastest particle of the last second: 0.041 and 0.053 m/s in builds whose sums differ only in rounding.
  EXPECT_LT(nd.maxSpeedLate, 0.065) << "m/s";
  EXPECT_LT(nd.flatnessRms, 0.25) << "RMS of the interface heights away from the walls, particle diameters";
  EXPECT_LT(nd.flatnessSpread, 1.5) << "spread of the interface heights away from the walls, particle diameters";
  EXPECT_LT(nd.wallRise, 2.5) << "the heavy phase's rise along the side walls, particle diameters";
  EXPECT_EQ(nd.misplacedMax, 0u) << "particles more than a diameter on the wrong side of the interface";
  EXPECT_NEAR(nd.spacing, 1.0, 0.1) << "interface spacing, particle diameters";
  EXPECT_LT(nd.volumeChange[0], 0.005) << "light phase volume";
  EXPECT_LT(nd.volumeChange[1], 0.005) << "heavy phase volume";
  EXPECT_LT(nd.heavyLayerChange, 0.01) << "heavy layer thickness";
  EXPECT_TRUE(nd.phasesKept) << "every particle id keeps its phase";
  EXPECT_EQ(nd.countChanges, 0u) << "frames in which a phase's particle count changed";
}

// The same scene with the mass sum (density_formulation 1): the light
// particles along the interface count their heavy neighbours as compression
// and are pushed off, opening a gap (the spurious interface tension).
TEST(Multiphase, MassSumOpensAGapAtTheInterface) {
  const RestRun ms = runLayeredAtRest(1, 1.0);
  printRestRun("mass sum", ms);
  EXPECT_GT(ms.spacing, 1.2) << "interface spacing, particle diameters (number density: 1.0)";
  EXPECT_TRUE(ms.phasesKept);
}

}  // namespace
}  // namespace fc


namespace fc {
namespace {
// WCSPH takes the same formulation (the equation of state of ρ_i = m_i δ_i
// and [SP08]'s force): a 1:3 layering stays layered, finite and closed at the
// interface; the mass sum in the same scene blows the interface apart.
struct WcsphRun {
  double spacing = 0, rms = 0, worstAvg = 0, wall = 0;
  size_t misplaced = 0, particles = 0;
};

WcsphRun runWcsphLayered(int formulation) {
  const double r = 0.005;
  const json blocks = json::array({block(0, 0, 0.3, 0.05, "heavy"), block(0, 0.05, 0.3, 0.1, "oil")});
  json scene = twoPhaseScene(r, {0.3, 0.2}, blocks, formulation);
  scene["solver"] = {{"method", "wcsph"}};
  Simulation<2> sim(parseScene<2>(scene));
  EXPECT_EQ(sim.numberDensity(), formulation != 1);
  FrameChecks checks;
  WcsphRun run;
  run.particles = sim.fluid.size();
  const int frames = 30;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < frames; ++k) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    run.worstAvg = std::max(run.worstAvg, fs.avgDensityErrorPct);
    const Interface itf = measureInterface(sim);
    run.misplaced = std::max(run.misplaced, itf.misplaced);
    run.spacing = itf.spacing;
    run.rms = itf.flatnessRms;
  }
  checks.finish(frames);
  run.wall = secondsSince(t0);
  return run;
}

TEST(Multiphase, WcsphLayeredAtRest) {
  const WcsphRun nd = runWcsphLayered(0), ms = runWcsphLayered(1);
  for (const WcsphRun* r : {&nd, &ms})
    std::printf("[ measured ] WCSPH 1:3 layered, %s (%zu particles, 0.5 s in %.1f s wall): interface spacing %.3f "
                "diameters, RMS %.3f diameters, %zu misplaced, worst average compression %.3f%%\n",
                r == &nd ? "number density" : "mass sum", r->particles, r->wall, r->spacing, r->rms, r->misplaced,
                r->worstAvg);
  EXPECT_EQ(nd.misplaced, 0u);
  EXPECT_LT(nd.spacing, 1.25) << "number density interface spacing, diameters";
  EXPECT_LT(nd.worstAvg, 1.0) << "WCSPH average compression, percent (B = 50 kPa)";
  // The mass sum breaks the interface up: particles of one phase end in the
  // other's layer and the interface turns ragged (measured 13 and 21
  // misplaced, RMS 1.7 and 2.8 diameters, in builds whose sums differ only
  // in rounding; how wide its gap ends, 1.2 or 1.9 diameters, varies).
  EXPECT_GE(ms.misplaced, 5u) << "the mass sum's mixed interface";
  EXPECT_GT(ms.rms, nd.rms + 1.0) << "the mass sum's ragged interface, diameters";
}
}  // namespace
}  // namespace fc

namespace fc {
namespace {
// The demo scene: two phases of rest densities 1000 and 3000, so the number
// density is on; it parses and keeps its documented size.
TEST(Multiphase, DemoSceneParses) {
  const auto setup = parseScene<2>(loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/multiphase2d.json"));
  ASSERT_EQ(setup.phases.size(), 2u);
  EXPECT_EQ(setup.phases[1].restDensity / setup.phases[0].restDensity, Real(3));
  Simulation<2> sim(setup);
  EXPECT_TRUE(sim.numberDensity());
  EXPECT_EQ(sim.fluid.size(), 2725u);  // scenes/README.md: 2 500 + 225
}
}  // namespace
}  // namespace fc
