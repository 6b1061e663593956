// DFSPH's conjugate-gradient solve (`conjugate_gradient`) against its Jacobi
// steps, on the shipped resting columns with Akinci's walls (the symmetric
// system) and on the 1:3 multiphase scene (the number-density form):
// fewer iterations to the same tolerance where the liquid is deep, the
// walls still carrying the liquid's weight, a tighter tolerance settling a
// column as the Jacobi solve does, and Jacobi kept where the walls mirror
// the pressure (an oblique system conjugate gradients cannot solve).
//
// FLOWCLIP_TEST_VERBOSE=1 prints each run's figures.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include "physics_checks.h"

#include <cstdio>
#include <string>
#include <vector>

namespace fc {
namespace {

struct CgRun {
  long densityIterations = 0;
  bool converged = true;
  int saneFailures = 0;
  double worstAvgErrPct = 0;  // the worst substep's average compression at exit
  double worstMaxErrPct = 0;  // the largest single particle's
  double loadOverWeight = 0;  // the walls' vertical load over the liquid's weight, over the run's second half
  double lateKineticEnergy = 0;  // mean over the run's last quarter, J (J/m in 2D)
  double interiorSlope = 0;   // -dp/dy of the exported pressure over the interior at the end, over ρ0 g
  std::vector<Vec3> positions;  // at the end, for bit-for-bit comparisons (z = 0 in 2D)
};

struct CgOptions {
  bool conjugate = false;
  double tolerancePct = 0;   // 0: the scene's
  bool akinci = true;        // Akinci's walls instead of the scene's
  int maxIterations = 0;     // 0: the scene's
};

template <int D>
CgRun runScene(const std::string& sceneFile, double seconds, const CgOptions& o) {
  auto json = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/" + sceneFile);
  json["solver"]["conjugate_gradient"] = o.conjugate;
  if (o.tolerancePct > 0) json["solver"]["density_tolerance_pct"] = o.tolerancePct;
  if (o.maxIterations > 0) json["solver"]["max_iterations"] = o.maxIterations;
  if (o.akinci) json["boundary"] = {{"method", "akinci2012"}};
  const SimulationSetup<D> setup = parseScene<D>(json, 0);
  Simulation<D> sim(setup);
  const auto& f = sim.fluid;
  double mass = 0;
  for (size_t i = 0; i < f.size(); ++i) mass += f.mass[i];
  const double g = setup.gravity.norm();
  CgRun run;
  double load = 0, loadTime = 0, ke = 0;
  int keFrames = 0;
  while (sim.time() < seconds - 1e-9) {
    const FrameStats fs = sim.advanceFrame();
    if (!frameIsSane(sim, fs)) ++run.saneFailures;
    if (!fs.finite) break;
    run.densityIterations += fs.densityIterations;
    run.converged = run.converged && fs.converged;
    run.worstAvgErrPct = std::max(run.worstAvgErrPct, fs.avgDensityErrorPct);
    run.worstMaxErrPct = std::max(run.worstMaxErrPct, fs.maxDensityErrorPct);
    if (sim.time() > seconds / 2) {
      load += fs.boundaryImpulse[1] + fs.contactImpulse[2];
      loadTime += sim.frameDuration();
    }
    if (sim.time() > 0.75 * seconds) ke += fs.kineticEnergy, ++keFrames;
  }
  run.loadOverWeight = loadTime > 0 ? load / loadTime / (mass * g) : 0;
  run.lateKineticEnergy = keFrames ? ke / keFrames : 0;
  // The exported pressure's slope over the interior (three diameters off the floor and the surface).
  const double r = sim.particleRadius(), floorY = setup.domain.min[1], top = volumeSurface(sim);
  double sy = 0, sp = 0, syy = 0, syp = 0;
  size_t n = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    const double y = f.x[i][1], p = f.meanPressure[i];
    if (y > floorY + 6 * r && y < top - 6 * r) sy += y, sp += p, syy += y * y, syp += y * p, ++n;
  }
  if (n > 2) {
    const double slope = (double(n) * syp - sy * sp) / (double(n) * syy - sy * sy);
    run.interiorSlope = -slope / (setup.phases.at(0).restDensity * g);
  }
  for (size_t i = 0; i < f.size(); ++i) {
    Vec3 x = Vec3::Zero();
    for (int d = 0; d < D; ++d) x[d] = f.x[i][d];
    run.positions.push_back(x);
  }
  if (verbose())
    std::printf("%s %s tol %g: %ld density iterations, worst avg %.4f %% max %.3f %%, load/weight %.4f, late KE %.4g, "
                "interior slope %.4f, converged %d\n",
                sceneFile.c_str(), o.conjugate ? "cg" : "jacobi", o.tolerancePct, run.densityIterations,
                run.worstAvgErrPct, run.worstMaxErrPct, run.loadOverWeight, run.lateKineticEnergy, run.interiorSlope,
                int(run.converged));
  return run;
}

template <int D>
void expectFewerIterationsToTheSameTolerance(const std::string& scene, double maxShare) {
  const CgRun jacobi = runScene<D>(scene, 1.0, {.conjugate = false});
  const CgRun cg = runScene<D>(scene, 1.0, {.conjugate = true});
  EXPECT_EQ(cg.saneFailures, 0);
  // It stops on the Jacobi solve's figure, the average compression, at the scene's tolerance (0.01 %),
  // and reaches it in every substep (the Jacobi solve of the 2D column stops at its cap of 300 now and then).
  EXPECT_TRUE(cg.converged);
  EXPECT_LE(cg.worstAvgErrPct, 0.01 + 1e-6);
  // The walls carry the liquid's weight: the solve's impulse on them is accounted for.
  EXPECT_NEAR(cg.loadOverWeight, 1.0, 0.05);
  EXPECT_NEAR(jacobi.loadOverWeight, 1.0, 0.05);
  EXPECT_LT(double(cg.densityIterations), maxShare * double(jacobi.densityIterations))
      << "conjugate gradients " << cg.densityIterations << ", Jacobi " << jacobi.densityIterations;
}

// A 1 m column, 50 particles deep: 77 Jacobi iterations per substep, 18 with conjugate gradients.
TEST(ConjugateGradient, ReachesTheToleranceInFewerIterationsInADeepColumn2D) {
  expectFewerIterationsToTheSameTolerance<2>("hydrostatic2d.json", 0.5);
}

// 0.3 m, 15 particles deep: 13 against 9.
TEST(ConjugateGradient, ReachesTheToleranceInFewerIterationsInADeepColumn3D) {
  expectFewerIterationsToTheSameTolerance<3>("hydrostatic3d.json", 0.85);
}

// At the same tolerance the conjugate-gradient solve leaves a rougher
// residual, and the column settles more slowly; at a tenth of it, it
// settles as the Jacobi solve does, in fewer iterations, with every
// particle nearer its rest density and the interior at ρ0 g.
TEST(ConjugateGradient, AtATenthOfTheToleranceSettlesAColumnAsJacobiDoes) {
  const CgRun jacobi = runScene<2>("hydrostatic2d.json", 2.0, {.conjugate = false});
  const CgRun cg = runScene<2>("hydrostatic2d.json", 2.0, {.conjugate = true, .tolerancePct = 0.001, .maxIterations = 2000});
  EXPECT_EQ(cg.saneFailures, 0);
  EXPECT_TRUE(cg.converged);
  EXPECT_LE(cg.worstAvgErrPct, 0.001 + 1e-6);
  EXPECT_LT(cg.worstMaxErrPct, jacobi.worstMaxErrPct);
  EXPECT_LT(cg.densityIterations, jacobi.densityIterations);
  EXPECT_LT(cg.lateKineticEnergy, 2 * jacobi.lateKineticEnergy)
      << "conjugate gradients " << cg.lateKineticEnergy << " J/m, Jacobi " << jacobi.lateKineticEnergy;
  EXPECT_NEAR(cg.interiorSlope, 1.0, 0.1);  // float rounding alone moves it by several percent
  EXPECT_NEAR(cg.loadOverWeight, 1.0, 0.05);
}

// adami2012 mirrors the pressure with the weight 2: the system is not
// symmetric, and the solve stays Jacobi's, bit for bit.
TEST(ConjugateGradient, KeepsJacobiWhereTheWallsMirrorThePressure) {
  const CgRun jacobi = runScene<2>("hydrostatic2d.json", 0.1, {.conjugate = false, .akinci = false});
  const CgRun cg = runScene<2>("hydrostatic2d.json", 0.1, {.conjugate = true, .akinci = false});
  ASSERT_EQ(jacobi.positions.size(), cg.positions.size());
  for (size_t i = 0; i < cg.positions.size(); ++i) ASSERT_EQ(jacobi.positions[i], cg.positions[i]) << "particle " << i;
  EXPECT_EQ(jacobi.densityIterations, cg.densityIterations);
}

// Two liquids 1:3 (the number-density form, the inner product weighted by
// 1/m): the same tolerance, every frame sane, the walls carrying both.
TEST(ConjugateGradient, SolvesTheNumberDensityFormOfTwoLiquids) {
  const CgRun jacobi = runScene<2>("multiphase2d.json", 0.6, {.conjugate = false});
  const CgRun cg = runScene<2>("multiphase2d.json", 0.6, {.conjugate = true});
  EXPECT_EQ(cg.saneFailures, 0);
  EXPECT_TRUE(cg.converged);
  EXPECT_LE(cg.worstAvgErrPct, 0.05 + 1e-6);  // the scene's tolerance
  EXPECT_LT(cg.densityIterations, jacobi.densityIterations);
  EXPECT_NEAR(cg.loadOverWeight, jacobi.loadOverWeight, 0.05);
  EXPECT_LT(cg.lateKineticEnergy, 2 * jacobi.lateKineticEnergy + 1e-3);
}

}  // namespace
}  // namespace fc
