// The implicit viscosity solver of Weiler et al. 2018 [WKBB18] (viscosity_weiler2018):
//  1. one solve conserves momentum, dissipates kinetic energy and leaves rigid
//     motion alone (no walls in reach, zero gravity);
//  2. gravity-driven flow between two vertical no-slip walls reaches the
//     parabolic (plane Poiseuille) profile, the walls carry the liquid's
//     weight, and the velocity scales as 1/nu;
//  3. a Taylor-Green vortex decays at the analytic rate at the scene's time
//     step (10x the explicit viscosity limit), and at a small step the
//     implicit solve agrees with the explicit viscosity_standard;
//  4. honey-like liquids (nu = 2e-3 and 0.1 m^2/s) in a 2D dam break stay
//     finite, bounded and inside the tank at the pressure solver's time step,
//     and spread much slower than water;
//  5. the effect's parameters are validated by the scene parser.
// Scenes are built in code as JSON and go through parseScene, like files.
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <random>
#include <string>
#include <vector>

namespace fc {
namespace {

using nlohmann::json;

bool verbose() {
  const char* v = std::getenv("FLOWCLIP_TEST_VERBOSE");
  return v && *v && std::string(v) != "0";
}

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

constexpr double kG = 9.81;

// One-phase 2D scene.
json scene2D(double radius, std::vector<double> domainMax, std::vector<double> blockMin, std::vector<double> blockMax,
             double nu, double gravity, const json& effects) {
  json s = {
      {"dimension", 2},
      {"particle_radius", radius},
      {"domain", {{"min", {0, 0}}, {"max", domainMax}}},
      {"gravity", {0, -gravity}},
      {"phases", json::array({{{"name", "liquid"}, {"rest_density", 1000}, {"viscosity", nu}}})},
      {"fluid_blocks", json::array({{{"min", blockMin}, {"max", blockMax}}})},
  };
  if (!effects.is_null()) s["effects"] = effects;
  return s;
}

json weiler(double boundaryViscosity, double tolerance = -1) {
  json e = {{"name", "viscosity_weiler2018"}, {"boundary_viscosity", boundaryViscosity}};
  if (tolerance > 0) e["tolerance"] = tolerance;
  return json::array({e});
}

template <int D>
Eigen::Matrix<double, D, 1> momentum(const Simulation<D>& sim) {
  Eigen::Matrix<double, D, 1> p = Eigen::Matrix<double, D, 1>::Zero();
  for (size_t i = 0; i < sim.fluid.size(); ++i) p += double(sim.fluid.mass[i]) * sim.fluid.v[i].template cast<double>();
  return p;
}

template <int D>
double kineticEnergy(const Simulation<D>& sim) {
  double e = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) e += 0.5 * double(sim.fluid.mass[i]) * double(sim.fluid.v[i].squaredNorm());
  return e;
}

double totalMass(const Simulation<2>& sim) {
  double m = 0;
  for (Real mi : sim.fluid.mass) m += mi;
  return m;
}

// ---------------------------------------------------------------------------
// 1. One solve on a free block: pair forces only.

std::unique_ptr<Effect<2>> makeWeiler(Simulation<2>& sim, double boundaryViscosity) {
  const auto* entry = EffectRegistry<2>::instance().find("viscosity_weiler2018");
  EXPECT_NE(entry, nullptr);
  ParamValues pv(entry->params);
  pv.set("boundary_viscosity", boundaryViscosity);
  pv.set("tolerance", 1e-5);
  pv.set("max_iterations", 1000);
  auto e = entry->make(pv);
  e->resize(sim.fluid.size());
  e->init(sim);
  return e;
}

// A 0.2 m block (40 x 40 particles) in the middle of a 1 m tank, nu = 0.1,
// one implicit step of 5 ms: Δt ν / r² = 80, 200x the explicit limit 0.4 r²/ν.
TEST(ViscosityWeiler2018, ConservesMomentumDissipatesAndKeepsRigidMotion) {
  const double nu = 0.1, dt = 0.005;
  Simulation<2> sim(parseScene<2>(scene2D(0.0025, {1, 1}, {0.4, 0.4}, {0.6, 0.6}, nu, 0, json())));
  sim.refreshNeighbors();
  size_t wallNeighbours = 0;
  for (uint16_t c : sim.boundaryNeighbors) wallNeighbours += c > 0;
  ASSERT_EQ(wallNeighbours, 0u) << "the block must not touch a wall";
  auto visc = makeWeiler(sim, nu);  // boundary viscosity on, but no wall in reach

  // (a) Noise about a mean velocity.
  std::mt19937 rng(7);
  auto uniform = [&rng]() { return double(rng()) / double(rng.max()) * 2 - 1; };
  const Vec<2> mean(Real(0.2), Real(-0.1));
  for (auto& v : sim.fluid.v) v = mean + Vec<2>(Real(0.05 * uniform()), Real(0.05 * uniform()));
  const Eigen::Vector2d p0 = momentum(sim);
  double scale = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) scale += double(sim.fluid.mass[i]) * double(sim.fluid.v[i].norm());
  const double m = totalMass(sim);
  const double keFluct0 = kineticEnergy(sim) - 0.5 * p0.squaredNorm() / m;
  const SolverReport rep = visc->solveVelocities(sim, Real(dt));
  const Eigen::Vector2d p1 = momentum(sim);
  const double keFluct1 = kineticEnergy(sim) - 0.5 * p1.squaredNorm() / m;
  std::printf("[ measured ] free block, %zu particles, nu=%g, dt=%g (dt nu / r^2 = %.0f): %d CG iterations, relative "
              "residual %.2e %%, |dP| / sum m|v| = %.2e, fluctuation KE after/before %.4f\n",
              sim.fluid.size(), nu, dt, dt * nu / (0.0025 * 0.0025), rep.iterations, rep.avgErrorPct,
              (p1 - p0).norm() / scale, keFluct1 / keFluct0);
  EXPECT_TRUE(rep.converged);
  EXPECT_GT(rep.iterations, 0);
  // Every term is a pair force: the solve changes momentum by no more than
  // its residual (tolerance 1e-5) and float rounding.
  EXPECT_LT((p1 - p0).norm() / scale, 1e-5) << "momentum changed";
  EXPECT_LT(keFluct1, 0.2 * keFluct0) << "at Δt ν/r² = 20 the noise must be damped strongly";
  EXPECT_GT(keFluct1, 0.0);

  // (b) Rigid translation + rotation: no shear, so v = v* exactly.
  const Vec<2> c(Real(0.5), Real(0.5));
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const Vec<2> d = sim.fluid.x[i] - c;
    sim.fluid.v[i] = mean + Real(2) * Vec<2>(-d[1], d[0]);
  }
  const std::vector<Vec<2>> v0 = sim.fluid.v;
  visc = makeWeiler(sim, nu);  // no warm start from (a)
  visc->solveVelocities(sim, Real(dt));
  double worst = 0, vmax = 0;
  for (size_t i = 0; i < v0.size(); ++i) {
    worst = std::max(worst, double((sim.fluid.v[i] - v0[i]).norm()));
    vmax = std::max(vmax, double(v0[i].norm()));
  }
  std::printf("[ measured ] rigid motion: largest velocity change %.2e of the largest speed\n", worst / vmax);
  EXPECT_LT(worst, 1e-4 * vmax) << "a rigid motion was changed by the viscosity solve";
}

// The same in 3D: a 0.1 m cube (10^3 particles, r = 5 mm) in a 0.5 m tank.
TEST(ViscosityWeiler2018, ConservesMomentumAndDissipates3D) {
  const double nu = 0.1, dt = 0.005;
  const json s = {
      {"dimension", 3},
      {"particle_radius", 0.005},
      {"domain", {{"min", {0, 0, 0}}, {"max", {0.5, 0.5, 0.5}}}},
      {"gravity", {0, 0, 0}},
      {"phases", json::array({{{"name", "liquid"}, {"rest_density", 1000}, {"viscosity", nu}}})},
      {"fluid_blocks", json::array({{{"min", {0.2, 0.2, 0.2}}, {"max", {0.3, 0.3, 0.3}}}})},
  };
  Simulation<3> sim(parseScene<3>(s));
  sim.refreshNeighbors();
  const auto* entry = EffectRegistry<3>::instance().find("viscosity_weiler2018");
  ASSERT_NE(entry, nullptr);
  ParamValues pv(entry->params);
  pv.set("tolerance", 1e-5);
  pv.set("max_iterations", 1000);
  auto visc = entry->make(pv);
  visc->resize(sim.fluid.size());
  visc->init(sim);
  std::mt19937 rng(11);
  auto uniform = [&rng]() { return double(rng()) / double(rng.max()) * 2 - 1; };
  for (auto& v : sim.fluid.v)
    v = Vec<3>(Real(0.1 + 0.05 * uniform()), Real(0.05 * uniform()), Real(-0.1 + 0.05 * uniform()));
  const Eigen::Vector3d p0 = momentum(sim);
  double scale = 0, m = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i)
    scale += double(sim.fluid.mass[i]) * double(sim.fluid.v[i].norm()), m += sim.fluid.mass[i];
  const double fluct0 = kineticEnergy(sim) - 0.5 * p0.squaredNorm() / m;
  const SolverReport rep = visc->solveVelocities(sim, Real(dt));
  const Eigen::Vector3d p1 = momentum(sim);
  const double fluct1 = kineticEnergy(sim) - 0.5 * p1.squaredNorm() / m;
  std::printf("[ measured ] 3D free block, %zu particles, nu=%g, dt=%g: %d CG iterations, |dP| / sum m|v| = %.2e, "
              "fluctuation KE after/before %.4f\n",
              sim.fluid.size(), nu, dt, rep.iterations, (p1 - p0).norm() / scale, fluct1 / fluct0);
  EXPECT_TRUE(rep.converged);
  EXPECT_LT((p1 - p0).norm() / scale, 1e-5);
  EXPECT_LT(fluct1, 0.2 * fluct0);
  EXPECT_GT(fluct1, 0.0);
}

// ---------------------------------------------------------------------------
// 2. Plane Poiseuille flow: a column falling between two no-slip walls.
//
// A 2D column of width W = 0.04 m (20 particles, r = 1 mm) and height 0.16 m
// fills the gap between the two side walls of a 0.3 m tall tank and falls
// under gravity, free surfaces above and below. Its middle part is
// unidirectional with uniform pressure, so the velocity obeys
// u_t = -g + ν u_xx with u(0) = u(W) = 0: it reaches, within a few
// W²/(π²ν) ≈ 0.016 s, the steady profile u(x) = -(g / 2ν) x (W - x), and
// the walls then carry the column's weight. Liquid: ν = 0.01 m²/s. Δt at
// the velocity CFL is up to 125x the explicit limit 0.4 r²/ν.
//
// Measured at t = 0.2 s (12 W²/(π²ν_eff)) over the middle half of the column, per particle
// column: a least-squares parabola u = a x² + b x + c. Its curvature gives
// the effective viscosity ν_eff = g / (2a), its roots the effective no-slip
// planes. Expected from the operator (docs/physics/viscosity.md): ν_eff ≈ 0.65-0.75 ν, the
// shear response of the 2(d+2) Laplacian at two particle spacings per
// support radius (0.65 on the resting lattice, 0.73 with rows sliding).
// The boundary samples carry v_b = 0 where a mirrored ghost would carry -u,
// which halves their drag: boundary_viscosity = 2ν puts the no-slip plane on
// the wall surface (measured 0.01 r inside), boundary_viscosity = ν 1.24 r
// behind it.

struct ChannelRun {
  double nuEff = 0;           // g / (2a) of the fitted parabola
  double wall0 = 0, wall1 = 0;  // its roots, m (walls at 0 and W)
  double fitRmsRel = 0;       // rms residual of the fit / |peak|
  double peak = 0;            // fitted velocity at W/2, m/s (negative: down)
  double meanVy = 0;          // mean v_y of the measured particles at the end
  double meanVyEarlier = 0;   // the same 0.05 s earlier
  double wallForceOverWeight = 0;  // viscous + pressure force of the boundary, y, over M g (last 0.05 s)
  double dPdtOverWeight = 0;       // momentum rate over M g (last 0.05 s)
  int substeps = 0, iterations = 0, maxIterations = 0;
  bool converged = true, finite = true;
  size_t escaped = 0, particles = 0;
  double maxDt = 0, wallSeconds = 0;
};

ChannelRun fallingChannel(double nu, double until, double boundaryViscosity) {
  const double W = 0.04, r = 0.001;
  json s = scene2D(r, {W, 0.3}, {0, 0.12}, {W, 0.28}, nu, kG, weiler(boundaryViscosity));
  Simulation<2> sim(parseScene<2>(s));
  ChannelRun run;
  run.particles = sim.fluid.size();
  const double m = totalMass(sim);
  const auto t0 = std::chrono::steady_clock::now();
  double impulseY = 0, windowFrom = until - 0.05;
  Eigen::Vector2d pFrom = Eigen::Vector2d::Zero();
  auto middleMean = [&sim]() {
    std::vector<Real> ys;
    for (const auto& x : sim.fluid.x) ys.push_back(x[1]);
    std::sort(ys.begin(), ys.end());
    const Real lo = ys[ys.size() / 4], hi = ys[3 * ys.size() / 4];
    double sum = 0;
    size_t cnt = 0;
    for (size_t i = 0; i < sim.fluid.size(); ++i)
      if (sim.fluid.x[i][1] >= lo && sim.fluid.x[i][1] <= hi) sum += sim.fluid.v[i][1], ++cnt;
    return sum / double(cnt);
  };
  while (sim.time() < until - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    run.substeps += fs.substeps;
    run.iterations += fs.viscosityIterations;
    run.maxIterations = std::max(run.maxIterations, fs.substeps ? fs.viscosityIterations / fs.substeps : 0);
    run.converged = run.converged && fs.viscosityConverged;
    run.finite = run.finite && fs.finite;
    run.escaped += fs.escapedParticles;
    run.maxDt = std::max(run.maxDt, fs.maxDt);
    if (verbose())
      std::printf("  channel nu=%g t=%.4f mean v_y(middle)=%.5f vmax=%.4f substeps=%d dt=[%.2e, %.2e] CG=%d%s "
                  "wall F_y/Mg=%.4f\n",
                  nu, fs.time, middleMean(), fs.maxSpeed, fs.substeps, fs.minDt, fs.maxDt, fs.viscosityIterations,
                  fs.viscosityConverged ? "" : " (not converged)", fs.boundaryImpulse[1] * 60 / (m * kG));
    if (!fs.finite) break;
    if (std::abs(fs.time - windowFrom) < 1e-6) {
      run.meanVyEarlier = middleMean();
      pFrom = momentum(sim);
    } else if (fs.time > windowFrom + 1e-6) {
      impulseY += fs.boundaryImpulse[1];
    }
  }
  run.wallSeconds = secondsSince(t0);
  run.meanVy = middleMean();
  run.wallForceOverWeight = impulseY / 0.05 / (m * kG);
  run.dPdtOverWeight = (momentum(sim) - pFrom)[1] / 0.05 / (m * kG);

  // Per particle column (bins of 2r across the gap), in the middle half.
  std::vector<Real> ys;
  for (const auto& x : sim.fluid.x) ys.push_back(x[1]);
  std::sort(ys.begin(), ys.end());
  const Real lo = ys[ys.size() / 4], hi = ys[3 * ys.size() / 4];
  const int bins = int(std::lround(W / (2 * r)));
  std::vector<double> sx(bins, 0), su(bins, 0);
  std::vector<int> cnt(bins, 0);
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const auto& x = sim.fluid.x[i];
    if (x[1] < lo || x[1] > hi) continue;
    const int b = std::clamp(int(x[0] / (2 * r)), 0, bins - 1);
    sx[b] += x[0], su[b] += sim.fluid.v[i][1], ++cnt[b];
  }
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
  std::vector<double> bx, bu;
  for (int b = 0; b < bins; ++b) {
    if (!cnt[b]) continue;
    const double x = sx[b] / cnt[b], u = su[b] / cnt[b];
    bx.push_back(x), bu.push_back(u);
    const Eigen::Vector3d phi(x * x, x, 1);
    A += phi * phi.transpose();
    rhs += phi * u;
  }
  const Eigen::Vector3d c = A.ldlt().solve(rhs);
  double res2 = 0;
  for (size_t k = 0; k < bx.size(); ++k) {
    const double f = c[0] * bx[k] * bx[k] + c[1] * bx[k] + c[2];
    res2 += (bu[k] - f) * (bu[k] - f);
    if (verbose())
      std::printf("  profile x=%.5f u=%.5f fit=%.5f analytic=%.5f\n", bx[k], bu[k], f,
                  -kG / (2 * nu) * bx[k] * (W - bx[k]));
  }
  run.peak = c[0] * W * W / 4 + c[1] * W / 2 + c[2];
  run.fitRmsRel = std::sqrt(res2 / double(bx.size())) / std::abs(run.peak);
  run.nuEff = kG / (2 * c[0]);
  const double disc = std::sqrt(std::max(0.0, c[1] * c[1] - 4 * c[0] * c[2]));
  run.wall0 = (-c[1] - disc) / (2 * c[0]);
  run.wall1 = (-c[1] + disc) / (2 * c[0]);
  return run;
}

void printChannel(double nu, const ChannelRun& c) {
  const double W = 0.04, peak = -kG * W * W / (8 * nu);
  std::printf("[ measured ] channel nu=%g, %zu particles: fitted nu_eff/nu = %.4f, no-slip planes at %.3f r and "
              "W %+.3f r, fit rms %.2f %% of peak, peak %.4f m/s (analytic %.4f: ratio %.4f), mean v_y middle %.5f "
              "(0.05 s earlier %.5f), wall force / weight %.4f, dP/dt / weight %+.4f; %d substeps (dt max %.2e = "
              "%.0fx the explicit limit 0.4 r^2/nu), %d CG iterations (%.1f per substep, worst frame %d per substep), "
              "%s, %.2f s wall\n",
              nu, c.particles, c.nuEff / nu, c.wall0 / 0.001, (c.wall1 - W) / 0.001, 100 * c.fitRmsRel, c.peak, peak,
              c.peak / peak, c.meanVy, c.meanVyEarlier, c.wallForceOverWeight, c.dPdtOverWeight, c.substeps, c.maxDt,
              c.maxDt / (0.4 * 1e-6 / nu), c.iterations, double(c.iterations) / std::max(1, c.substeps),
              c.maxIterations, c.converged ? "converged" : "NOT converged", c.wallSeconds);
}

TEST(ViscosityWeiler2018, PoiseuilleProfileBetweenNoSlipWalls) {
  const double nu = 0.01, W = 0.04, r = 0.001;
  const ChannelRun c = fallingChannel(nu, 0.2, 2 * nu);
  printChannel(nu, c);
  ASSERT_TRUE(c.finite);
  EXPECT_EQ(c.escaped, 0u);
  EXPECT_TRUE(c.converged) << "a viscosity solve hit max_iterations";
  EXPECT_GT(c.maxDt, 20 * 0.4 * r * r / nu) << "the run must use time steps far beyond the explicit limit";
  // Steady in the middle: its mean velocity changes by less than 5 % of g
  // per second (the column's ends are not steady: its lower surface is
  // Rayleigh-Taylor unstable and sheds drops that fall freely).
  EXPECT_LT(std::abs(c.meanVy - c.meanVyEarlier) / 0.05, 0.05 * kG) << "the middle of the column is not steady";
  // Momentum balance over the last 0.05 s: the boundary impulse the solvers
  // report (viscous friction + pressure) is everything besides gravity.
  EXPECT_NEAR(c.wallForceOverWeight, 1.0 + c.dPdtOverWeight, 0.01) << "momentum balance does not close";
  EXPECT_GT(c.wallForceOverWeight, 0.8) << "the walls must carry most of the weight";
  // The profile is a parabola, symmetric, vanishing at the walls...
  EXPECT_LT(c.fitRmsRel, 0.02) << "the profile is not parabolic";
  EXPECT_NEAR(c.wall0 + c.wall1, W, 0.2 * r) << "the profile is not symmetric";
  EXPECT_NEAR(c.wall0, 0.0, 0.25 * r) << "left no-slip plane";
  EXPECT_NEAR(c.wall1, W, 0.25 * r) << "right no-slip plane";
  // ...whose curvature is g/ν_eff with ν_eff the operator's shear response.
  EXPECT_GT(c.nuEff / nu, 0.62);
  EXPECT_LT(c.nuEff / nu, 0.82);

  // boundary_viscosity = ν: the same parabola, its no-slip planes behind
  // the walls (measured 1.24 r).
  const ChannelRun half = fallingChannel(nu, 0.2, nu);
  printChannel(nu, half);
  EXPECT_LT(half.fitRmsRel, 0.02);
  EXPECT_LT(half.wall0, -0.5 * r);
  EXPECT_GT(half.wall0, -2 * r);
  EXPECT_NEAR(half.nuEff / nu, c.nuEff / nu, 0.05) << "the wall coefficient must not change the bulk";

  // Twice the viscosity (and wall coefficient): half the velocity, the same
  // ν_eff / ν.
  const ChannelRun twice = fallingChannel(2 * nu, 0.2, 4 * nu);
  printChannel(2 * nu, twice);
  const double ratio = c.peak / twice.peak;
  std::printf("[ measured ] peak velocity nu=%g / nu=%g: %.4f (analytic 2)\n", nu, 2 * nu, ratio);
  EXPECT_NEAR(ratio, 2.0, 0.1);
  EXPECT_NEAR(twice.nuEff / (2 * nu), c.nuEff / nu, 0.05) << "the operator's shear response must not depend on nu";
}

// ---------------------------------------------------------------------------
// 3. Taylor-Green vortex in a closed, full, free-slip tank, as in
// test_effects.cpp: v = U (sin kx cos ky, -cos kx sin ky), k = π/L, L = 0.5 m,
// r = 5 mm (2 500 particles), U = 0.1 m/s, ν = 0.02, zero gravity, masses
// rescaled to start at rest density. KE decays as exp(-4νk²t). At the
// default settings the step is dt_max = 5 ms, 10x the explicit limit
// 0.4 r²/ν = 0.5 ms that viscosity_standard imposes.

constexpr double kTgL = 0.5, kTgR = 0.005, kTgU = 0.1;

struct DecayRun {
  double rate = 0;       // fitted KE decay rate over [0.05 s, until]
  double midRate = 0;    // the same over [0.05, 0.2] s
  double earlyRate = 0;  // the same over the frames up to 0.1 s
  double expected = 0, keMax = 0, ke0 = 0;
  int substeps = 0, iterations = 0;
  double maxDt = 0;
  bool finite = true, converged = true;
};

DecayRun taylorGreen(double nu, const json& settings, double until, const json& effects) {
  json s = scene2D(kTgR, {kTgL, kTgL}, {0, 0}, {kTgL, kTgL}, nu, 0, effects);
  if (!settings.is_null()) s["settings"] = settings;
  Simulation<2> sim(parseScene<2>(s));
  // Start at rest density (see test_effects.cpp): m / Σ_j W(x_j) on the infinite lattice.
  {
    const double sp = 2 * kTgR;
    double sum = 0;
    for (int i = -3; i <= 3; ++i)
      for (int j = -3; j <= 3; ++j) sum += sim.kernel.W(Vec<2>(Real(sp * i), Real(sp * j)));
    for (Real& m : sim.fluid.mass) m = Real(double(m) / (sum * sp * sp));
  }
  const double k = std::numbers::pi / kTgL;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const double x = sim.fluid.x[i][0], y = sim.fluid.x[i][1];
    sim.fluid.v[i] = Vec<2>(Real(kTgU * std::sin(k * x) * std::cos(k * y)), Real(-kTgU * std::cos(k * x) * std::sin(k * y)));
  }
  DecayRun run;
  run.expected = 4 * nu * k * k;
  run.ke0 = run.keMax = kineticEnergy(sim);
  double st = 0, sl = 0, stt = 0, stl = 0, et = 0, el = 0, ett = 0, etl = 0, mt = 0, ml = 0, mtt = 0, mtl = 0;
  int n = 0, ne = 0, nm = 0;
  while (sim.time() < until - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    run.substeps += fs.substeps;
    run.iterations += fs.viscosityIterations;
    run.converged = run.converged && fs.viscosityConverged;
    run.maxDt = std::max(run.maxDt, fs.maxDt);
    if (!fs.finite) {
      run.finite = false;
      break;
    }
    const double t = fs.time, l = std::log(fs.kineticEnergy);
    if (verbose())
      std::printf("  TG nu=%g t=%.4f ln(KE/KE0)=%+.4f substeps=%d dt max %.2e CG=%d\n", nu, t, l - std::log(run.ke0),
                  fs.substeps, fs.maxDt, fs.viscosityIterations);
    if (t >= 0.05 - 1e-9) st += t, sl += l, stt += t * t, stl += t * l, ++n;
    if (t <= 0.1 + 1e-9) et += t, el += l, ett += t * t, etl += t * l, ++ne;
    if (t >= 0.05 - 1e-9 && t <= 0.2 + 1e-9) mt += t, ml += l, mtt += t * t, mtl += t * l, ++nm;
    run.keMax = std::max(run.keMax, fs.kineticEnergy);
    if (fs.kineticEnergy > 2 * run.ke0) break;
  }
  run.rate = n > 1 ? -(n * stl - st * sl) / (n * stt - st * st) : 0;
  run.midRate = nm > 1 ? -(nm * mtl - mt * ml) / (nm * mtt - mt * mt) : 0;
  run.earlyRate = ne > 1 ? -(ne * etl - et * el) / (ne * ett - et * et) : 0;
  return run;
}

TEST(ViscosityWeiler2018, TaylorGreenDecayAtSceneTimeStepAndUnderRefinement) {
  const double nu = 0.02;
  const json fineSteps = {{"dt_max", 0.0005}};
  const auto t0 = std::chrono::steady_clock::now();
  const DecayRun big = taylorGreen(nu, json(), 0.35, weiler(0));  // default settings: dt = dt_max = 5 ms
  const double bigSeconds = secondsSince(t0);
  // The small-step runs stop at 0.2 s (they take 10x the substeps).
  const DecayRun fine = taylorGreen(nu, fineSteps, 0.2, weiler(0));
  const DecayRun expl = taylorGreen(nu, fineSteps, 0.2, json::array({"viscosity_standard"}));
  for (const auto& [name, r] : {std::pair{"viscosity_weiler2018", &big}, std::pair{"viscosity_weiler2018", &fine},
                                std::pair{"viscosity_standard", &expl}})
    std::printf("[ measured ] Taylor-Green nu=%g, %s, dt max %.1e s (%.1fx the explicit limit): KE decay rate / "
                "analytic %.4f up to 0.1 s, %.4f over 0.05-0.2 s, %.4f over 0.05-0.35 s (analytic 4 nu k^2 = %.4f "
                "1/s); KE max/KE0 %.4f; %d substeps, %.2f CG iterations per substep\n",
                nu, name, r->maxDt, r->maxDt / (0.4 * kTgR * kTgR / nu), r->earlyRate / r->expected,
                r->midRate / r->expected, r->rate / r->expected, r->expected, r->keMax / r->ke0, r->substeps,
                double(r->iterations) / std::max(1, r->substeps));
  std::printf("[ measured ] decay rate at dt 5 ms / 0.5 ms: %.4f over 0.05-0.2 s (first 0.1 s: %.4f); implicit / "
              "explicit at 0.5 ms: %.4f (first 0.1 s: %.4f); the 5 ms run took %.2f s wall\n",
              big.midRate / fine.midRate, big.earlyRate / fine.earlyRate, fine.midRate / expl.midRate,
              fine.earlyRate / expl.earlyRate, bigSeconds);
  ASSERT_TRUE(big.finite && fine.finite && expl.finite);
  EXPECT_TRUE(big.converged && fine.converged);
  EXPECT_GT(big.maxDt, 5 * 0.4 * kTgR * kTgR / nu) << "the default run must step beyond the explicit limit";
  EXPECT_LE(big.keMax, 1.0001 * big.ke0) << "viscosity may only dissipate";
  // Against the analytic rate 4 nu k^2 at the scene's step (measured 1.04x
  // over the first 0.1 s, 1.14x over 0.05-0.35 s).
  EXPECT_NEAR(big.earlyRate / big.expected, 1.0, 0.15);
  EXPECT_NEAR(big.rate / big.expected, 1.0, 0.3);
  // Temporal refinement: at a small step the implicit solve is the explicit
  // operator (same spatial discretisation; measured 0.98x)...
  EXPECT_NEAR(fine.midRate / expl.midRate, 1.0, 0.05) << "implicit and explicit must agree at a small step";
  EXPECT_NEAR(fine.earlyRate / expl.earlyRate, 1.0, 0.05) << "implicit and explicit must agree at a small step";
  // ...and 10x the step lowers the rate by a first-order amount (measured
  // 0.92x: implicit Euler damps the stiff part of the discrete spectrum, the
  // modes with λΔt ≳ 1, at ln(1 + λΔt)/Δt < λ).
  EXPECT_GT(big.midRate / fine.midRate, 0.85);
  EXPECT_LT(big.midRate / fine.midRate, 1.0);
}

// ---------------------------------------------------------------------------
// 4. Honey dam break (2D): a column a = 0.1 m wide, 2a high (r = 2.5 mm,
// 3 200 particles) against the left wall of a 1 m tank, no-slip walls
// (boundary_viscosity = 2ν), default time-step settings (CFL, dt_max 5 ms):
// no viscous limit. Water (no viscosity effect) for comparison. Over 0.4 s
// (the water front does not reach the far wall): all finite, nothing
// escapes; the viscous liquids never move faster than √(2 g H) (free fall
// from the column's top) nor rise above their initial height, and their
// fronts advance much less than the water front. (Water's front may exceed
// √(2 g H): Ritter's inviscid front runs at 2√(g H). At ν = 1e-3 the front
// reaches 1.91 m/s, 3.5 % below the bound: a real front speed, the same at
// dt_max 2 ms, too close to the bound to assert, hence 2e-3 here.)
// Measured: the thick liquid's largest speeds (up to ~1 m/s, against a
// ~0.3 m/s slump) are single particles of the bottom row squeezed sideways:
// DFSPH's density solve at Δt ≥ 3 ms in a 0.2 m deep quasi-static column
// (80 rows) does not hold the bottom row; water at rest in the same column
// reaches 2.6 m/s that way, and at dt_max 2 ms both stay calm (0.07 m/s
// for the thick liquid, 0.4 m/s for water).

struct DamRun {
  double front = 0;        // 99.5th percentile of x + r at the end, m
  double top = 0;          // highest y + r over the run, m
  double vmax = 0;         // largest frame-end speed over the run, m/s
  double maxDt = 0;
  int substeps = 0, iterations = 0;
  bool finite = true, converged = true;
  size_t escaped = 0;
  double wallSeconds = 0;
};

DamRun damBreak(double nu, double until) {
  const double a = 0.1, r = 0.0025;
  json effects = nu > 0 ? weiler(2 * nu) : json();  // no slip (see section 2)
  Simulation<2> sim(parseScene<2>(scene2D(r, {1.0, 0.3}, {0, 0}, {a, 2 * a}, nu, kG, effects)));
  DamRun run;
  const auto t0 = std::chrono::steady_clock::now();
  while (sim.time() < until - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    run.substeps += fs.substeps;
    run.iterations += fs.viscosityIterations;
    run.converged = run.converged && fs.viscosityConverged;
    run.finite = run.finite && fs.finite;
    run.escaped += fs.escapedParticles;
    run.maxDt = std::max(run.maxDt, fs.maxDt);
    run.vmax = std::max(run.vmax, fs.maxSpeed);
    for (const auto& x : sim.fluid.x) run.top = std::max(run.top, double(x[1]) + r);
    if (verbose())
      std::printf("  dam nu=%g t=%.3f vmax=%.3f KE=%.3e substeps=%d dt max %.2e CG=%d%s\n", nu, fs.time, fs.maxSpeed,
                  fs.kineticEnergy, fs.substeps, fs.maxDt, fs.viscosityIterations,
                  fs.viscosityConverged ? "" : " (not converged)");
    if (!fs.finite) break;
  }
  run.wallSeconds = secondsSince(t0);
  std::vector<Real> xs;
  for (const auto& x : sim.fluid.x) xs.push_back(x[0]);
  std::sort(xs.begin(), xs.end());
  run.front = double(xs[size_t(0.995 * double(xs.size() - 1))]) + r;
  return run;
}

TEST(ViscosityWeiler2018, HoneyDamBreakStableAtPressureTimeStepAndSlow) {
  const double a = 0.1, r = 0.0025, T = 0.4;
  const double vBound = std::sqrt(2 * kG * 2 * a);
  const DamRun water = damBreak(0, T);
  const DamRun honey = damBreak(2e-3, T);   // 2000x water, a runny honey
  const DamRun thick = damBreak(0.1, T);    // 1e5x water
  for (const auto& [name, nu, d] : {std::tuple{"water", 1e-6, &water}, std::tuple{"honey", 2e-3, &honey},
                                    std::tuple{"thick", 0.1, &thick}})
    std::printf("[ measured ] dam break %s (nu=%g): front at t=%.1f s %.4f m (%.2f a), highest point %.4f m, max "
                "speed %.3f m/s (bound sqrt(2gH) = %.3f), dt max %.2e s (%.1fx the explicit limit 0.4 r^2/nu), %d "
                "substeps, %.1f CG iterations per substep, %s, %.2f s wall\n",
                name, nu, T, d->front, d->front / a, d->top, d->vmax, vBound, d->maxDt,
                d->maxDt / (0.4 * r * r / nu), d->substeps, double(d->iterations) / std::max(1, d->substeps),
                d->converged ? "converged" : "NOT converged", d->wallSeconds);
  for (const DamRun* d : {&water, &honey, &thick}) {
    ASSERT_TRUE(d->finite);
    EXPECT_EQ(d->escaped, 0u);
  }
  for (const DamRun* d : {&honey, &thick}) {
    EXPECT_LT(d->vmax, vBound) << "faster than free fall from the column's top";
    EXPECT_LT(d->top, 2 * a + 2 * r) << "the liquid rose above its initial height";
  }
  EXPECT_TRUE(honey.converged && thick.converged);
  // The thick liquid runs at the pressure solver's step, far beyond the
  // explicit limit (the honey at ~4x: 0.4 r²/ν = 1.25 ms).
  EXPECT_GT(thick.maxDt, 20 * 0.4 * r * r / 0.1);
  EXPECT_GT(water.front, 3 * a) << "water must surge";
  EXPECT_LT(honey.front - a, 0.8 * (water.front - a)) << "honey must spread slower than water";
  EXPECT_LT(thick.front - a, 0.2 * (water.front - a)) << "a 1e5x-water liquid must barely spread";
  EXPECT_LT(thick.front, honey.front) << "more viscous spreads less";
}

// ---------------------------------------------------------------------------
// 5. Parameters: declared once, validated by the scene parser.

template <int D = 2>
void expectError(const json& scene, const std::string& path, const std::vector<std::string>& mentions = {}) {
  try {
    parseScene<D>(scene);
    FAIL() << "expected SceneError at '" << path << "' for scene " << scene.dump();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, path) << e.what();
    const std::string what = e.what();
    EXPECT_EQ(what.rfind(path + ": ", 0), 0u) << "what() must start with the path: " << what;
    for (const auto& m : mentions) EXPECT_NE(what.find(m), std::string::npos) << "'" << m << "' missing in: " << what;
  }
}

json paramScene(const json& effect) {
  return scene2D(0.05, {2, 2}, {0, 0}, {0.5, 1}, 0.01, kG, json::array({"viscosity_xsph", effect}));
}

TEST(ViscosityWeiler2018, ParametersValidated) {
  registerBuiltinSolversAndEffects();
  const auto* entry = EffectRegistry<2>::instance().find("viscosity_weiler2018");
  ASSERT_NE(entry, nullptr);
  for (const char* name : {"tolerance", "max_iterations", "boundary_viscosity", "warm_start"}) {
    const ParamSpec* spec = findSpec(entry->params, name);
    ASSERT_NE(spec, nullptr) << name;
    EXPECT_FALSE(spec->help.empty()) << name;
    EXPECT_LE(spec->min, spec->def) << name;
    EXPECT_LE(spec->def, spec->max) << name;
  }
  EXPECT_EQ(findSpec(entry->params, "boundary_viscosity")->unit, "m^2/s");
  EXPECT_NE(EffectRegistry<3>::instance().find("viscosity_weiler2018"), nullptr);

  // Valid values are taken as written.
  const json ok = {{"name", "viscosity_weiler2018"}, {"tolerance", 1e-4}, {"max_iterations", 50},
                   {"boundary_viscosity", 0.5}, {"warm_start", false}};
  const auto setup = parseScene<2>(paramScene(ok));
  ASSERT_EQ(setup.effects.size(), 2u);
  EXPECT_EQ(setup.effects[1].name, "viscosity_weiler2018");
  EXPECT_DOUBLE_EQ(setup.effects[1].values.get("tolerance"), 1e-4);
  EXPECT_DOUBLE_EQ(setup.effects[1].values.get("max_iterations"), 50);
  EXPECT_DOUBLE_EQ(setup.effects[1].values.get("boundary_viscosity"), 0.5);
  EXPECT_DOUBLE_EQ(setup.effects[1].values.get("warm_start"), 0);
  Simulation<2> sim(setup);
  EXPECT_EQ(sim.pipelineStages(),
            (std::vector<std::string>{"pressure:dfsph", "effect:viscosity_xsph", "effect:viscosity_weiler2018"}));

  auto with = [](const char* key, const json& value) {
    json e = {{"name", "viscosity_weiler2018"}};
    e[key] = value;
    return paramScene(e);
  };
  expectError(with("tolerance", 0.5), "effects[1].tolerance", {"0.1"});
  expectError(with("tolerance", 0), "effects[1].tolerance");
  expectError(with("max_iterations", 0), "effects[1].max_iterations", {"10000"});
  expectError(with("max_iterations", 2.5), "effects[1].max_iterations");
  expectError(with("boundary_viscosity", -1), "effects[1].boundary_viscosity", {"1000"});
  expectError(with("warm_start", 2), "effects[1].warm_start");
  expectError(with("tolerance", "small"), "effects[1].tolerance");
  expectError(with("tolerence", 1e-3), "effects[1].tolerence", {"tolerance"});
}

}  // namespace
}  // namespace fc
