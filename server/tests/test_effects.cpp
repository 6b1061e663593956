// Non-pressure effects: the pipeline is assembled from the scene's "effects"
// list, standard viscosity decays a Taylor-Green vortex at the analytic rate,
// XSPH smooths velocity noise and conserves momentum, zero gravity keeps a
// block at rest.
//
// FLOWCLIP_TEST_VERBOSE=1 prints one line per frame.
#include "io/scene.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>

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

// A 2D scene: one block in a tank, zero gravity unless the caller sets it.
json scene2D(double radius, std::vector<double> domainMax, std::vector<double> blockMin, std::vector<double> blockMax,
             double viscosity, json effects) {
  json s = {
      {"dimension", 2},
      {"particle_radius", radius},
      {"domain", {{"min", {0, 0}}, {"max", domainMax}}},
      {"gravity", {0, 0}},
      {"phases", json::array({{{"name", "water"}, {"rest_density", 1000}, {"viscosity", viscosity}}})},
      {"fluid_blocks", json::array({{{"min", blockMin}, {"max", blockMax}}})},
  };
  if (!effects.is_null()) s["effects"] = effects;
  return s;
}

template <int D>
Vec<D> momentum(const Simulation<D>& sim) {
  Eigen::Matrix<double, D, 1> p = Eigen::Matrix<double, D, 1>::Zero();
  for (size_t i = 0; i < sim.fluid.size(); ++i) p += double(sim.fluid.mass[i]) * sim.fluid.v[i].template cast<double>();
  return p.template cast<Real>();
}

template <int D>
Eigen::Matrix<double, D, 1> momentumD(const Simulation<D>& sim) {
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

// ---------------------------------------------------------------------------
// 1. Pipeline assembly

using Stages = std::vector<std::string>;

TEST(EffectsPipeline, NoEffectsMeansPressureOnly) {
  const json s = scene2D(0.02, {1, 1}, {0.2, 0.2}, {0.6, 0.6}, 0.01, json());
  Simulation<2> sim(parseScene<2>(s));
  EXPECT_EQ(sim.pipelineStages(), (Stages{"pressure:dfsph"}));
  // An empty list is the same as none.
  Simulation<2> sim2(parseScene<2>(scene2D(0.02, {1, 1}, {0.2, 0.2}, {0.6, 0.6}, 0.01, json::array())));
  EXPECT_EQ(sim2.pipelineStages(), (Stages{"pressure:dfsph"}));
}

TEST(EffectsPipeline, StagesFollowSceneOrder) {
  const json a = json::array({"viscosity_standard", {{"name", "viscosity_xsph"}, {"coefficient", 0.1}}});
  Simulation<2> simA(parseScene<2>(scene2D(0.02, {1, 1}, {0.2, 0.2}, {0.6, 0.6}, 0.01, a)));
  EXPECT_EQ(simA.pipelineStages(), (Stages{"pressure:dfsph", "effect:viscosity_standard", "effect:viscosity_xsph"}));

  const json b = json::array({{{"name", "viscosity_xsph"}}, "viscosity_standard"});
  Simulation<2> simB(parseScene<2>(scene2D(0.02, {1, 1}, {0.2, 0.2}, {0.6, 0.6}, 0.01, b)));
  EXPECT_EQ(simB.pipelineStages(), (Stages{"pressure:dfsph", "effect:viscosity_xsph", "effect:viscosity_standard"}));

  Simulation<2> simX(parseScene<2>(scene2D(0.02, {1, 1}, {0.2, 0.2}, {0.6, 0.6}, 0.01, json::array({"viscosity_xsph"}))));
  EXPECT_EQ(simX.pipelineStages(), (Stages{"pressure:dfsph", "effect:viscosity_xsph"}));

  json w = scene2D(0.02, {1, 1}, {0.2, 0.2}, {0.6, 0.6}, 0.01, json::array({"viscosity_standard"}));
  w["solver"] = {{"method", "wcsph"}};
  Simulation<2> simW(parseScene<2>(w));
  EXPECT_EQ(simW.pipelineStages(), (Stages{"pressure:wcsph", "effect:viscosity_standard"}));

  // 3D assembles the same way.
  const json s3 = {
      {"dimension", 3},
      {"particle_radius", 0.05},
      {"domain", {{"min", {0, 0, 0}}, {"max", {1, 1, 1}}}},
      {"fluid_blocks", json::array({{{"min", {0, 0, 0}}, {"max", {0.5, 0.5, 0.5}}}})},
      {"effects", json::array({"viscosity_xsph", "viscosity_standard"})},
  };
  Simulation<3> sim3(parseScene<3>(s3));
  EXPECT_EQ(sim3.pipelineStages(), (Stages{"pressure:dfsph", "effect:viscosity_xsph", "effect:viscosity_standard"}));
}

}  // namespace
}  // namespace fc
