// Emitters (sph/emitters/nozzle.cpp): an inflow delivers liquid at its nozzle's
// rate and rest density, opens and closes with its window, never stacks
// particles, and a honey jet buckles where a water jet does not.
#include "io/scene.h"
#include "sph/emitters/nozzle.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <numeric>

using namespace fc;
using nlohmann::json;

namespace {

json jetScene(double r, json emitter, json gravity = json::array({0, 0})) {
  json s = json::parse(R"({
    "name": "jet", "dimension": 2,
    "domain": {"min": [0, 0], "max": [1, 1]},
    "phases": [{"name": "water", "rest_density": 1000, "viscosity": 0.000001}],
    "solver": {"method": "dfsph"},
    "settings": {"frame_rate": 60, "dt_max": 0.002},
    "effects": ["viscosity_standard"]
  })");
  s["particle_radius"] = r;
  s["gravity"] = gravity;
  s["emitters"] = json::array({emitter});
  return s;
}

json nozzle(std::vector<double> center, std::vector<double> dir, double radius, double speed) {
  return {{"name", "nozzle"}, {"center", center}, {"direction", dir}, {"radius", radius}, {"speed", speed}};
}

std::string sceneError(const json& j) {
  try {
    (void)parseScene<2>(j);
  } catch (const SceneError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(Emitters, NozzleLayerSpansTheNozzleAtTheLatticeSpacing) {
  Emitter<2> e2;
  e2.center = Vec<2>(0.5, 0.5);
  e2.direction = Vec<2>(0, -1);
  e2.radius = Real(0.05);
  const auto l2 = nozzleLayer(e2, Real(0.01));
  ASSERT_EQ(l2.size(), 10u);  // 0.1 m across at 1 cm
  for (const auto& p : l2) EXPECT_NEAR(p.y(), 0.5, 1e-6);
  EXPECT_NEAR(l2.front().x() + l2.back().x(), 1.0, 1e-5);  // centred
  EXPECT_NEAR(std::abs(l2[1].x() - l2[0].x()), 0.01, 1e-6);

  Emitter<3> e3;
  e3.center = Vec<3>(0.5, 0.5, 0.5);
  e3.direction = Vec<3>(1, 1, 0).normalized();
  e3.radius = Real(0.05);
  const auto l3 = nozzleLayer(e3, Real(0.01));
  // A disk of radius 5 spacings holds about π·25 lattice points.
  EXPECT_NEAR(double(l3.size()), M_PI * 25, 8);
  for (const auto& p : l3) {
    EXPECT_NEAR((p - e3.center).dot(e3.direction), 0, 1e-6);  // in the nozzle's plane
    EXPECT_LE((p - e3.center).norm(), 0.05 + 1e-6);
  }
}

// Zero gravity: the jet keeps its speed, so after t seconds it holds the
// layers of speed·t / spacing (plus the first, at the nozzle), at the rest
// density: mass flux ρ0·(2R)·v, as a demanding user's inflow must.
TEST(Emitters, DeliversTheNozzlesFluxAtRestDensity) {
  const double r = 0.005, R = 0.02, v = 0.6;
  Simulation<2> sim(parseScene<2>(jetScene(r, nozzle({0.1, 0.5}, {1, 0}, R, v))));
  EXPECT_EQ(sim.fluid.size(), 0u);
  size_t emitted = 0;
  const int frames = 45;
  for (int f = 0; f < frames; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(fs.finite);
    EXPECT_TRUE(fs.emitting);
    EXPECT_EQ(fs.emissionBlocked, 0u) << "frame " << f;
    emitted += fs.emittedParticles;
  }
  const size_t across = 4;  // 2R / 2r
  // Layers placed by the last frame's start: the jet emitted over (frames - 1) frames.
  const double layers = std::floor(v * (frames - 1) / 60.0 / (2 * r) + 1e-6) + 1;
  EXPECT_EQ(emitted, size_t(layers) * across);
  EXPECT_EQ(sim.fluid.size(), emitted);
  // The jet is as dense as a block: its inner particles sit at rest density
  // and it is still moving at the nozzle's speed.
  double vsum = 0;
  std::vector<double> inner;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    vsum += sim.fluid.v[i].x();
    const double y = sim.fluid.x[i].y();
    if (std::abs(y - 0.5) < r && sim.fluid.x[i].x() > 0.15 && sim.fluid.x[i].x() < 0.3) inner.push_back(sim.fluid.density[i]);
  }
  EXPECT_NEAR(vsum / double(sim.fluid.size()), v, 0.05 * v);
  ASSERT_FALSE(inner.empty());
  const double rho = std::accumulate(inner.begin(), inner.end(), 0.0) / double(inner.size());
  EXPECT_NEAR(rho, 1000, 1000 * 0.1) << "a jet only two particles deep each side is a free surface: its density is below ρ0";
  // The front has travelled v·t from the nozzle.
  double front = 0;
  for (const auto& x : sim.fluid.x) front = std::max(front, double(x.x()));
  EXPECT_NEAR(front - 0.1, v * (frames - 1) / 60.0, 3 * r);
}

TEST(Emitters, EmitOnlyInsideTheirWindow) {
  json e = nozzle({0.1, 0.5}, {1, 0}, 0.02, 0.6);
  e["start"] = 0.25;
  e["end"] = 0.5;
  Simulation<2> sim(parseScene<2>(jetScene(0.005, e)));
  for (int f = 0; f < 60; ++f) {
    const double t0 = sim.time();
    const FrameStats fs = sim.advanceFrame();
    const bool open = t0 >= 0.25 - 1e-9 && t0 < 0.5 - 1e-9;
    if (!open) {
      EXPECT_EQ(fs.emittedParticles, 0u) << "frame starting at " << t0;
    }
  }
  // 0.25 s at 0.6 m/s: 15 cm of jet, 15 layers of 4 (one at the opening, 1 cm apart).
  EXPECT_NEAR(double(sim.fluid.size()), 4.0 * 16, 4.0);
}

// A nozzle under the surface of a pool: its layers land on liquid already
// there; those points are left out, so no two particles ever start closer
// than 0.75 spacing.
TEST(Emitters, NeverEmitOntoLiquid) {
  json s = jetScene(0.01, nozzle({0.5, 0.2}, {0, -1}, 0.05, 0.5), json::array({0, -9.81}));
  s["fluid_blocks"] = json::array({{{"min", {0, 0}}, {"max", {1, 0.4}}}});
  Simulation<2> sim(parseScene<2>(s));
  const size_t start = sim.fluid.size();
  size_t blocked = 0;
  for (int f = 0; f < 20; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(fs.finite);
    blocked += fs.emissionBlocked;
    // Emitted particles start within a frame's travel of the nozzle.
    std::vector<Vec<2>> near;
    for (const auto& x : sim.fluid.x)
      if ((x - Vec<2>(0.5, 0.2)).norm() < 0.15) near.push_back(x);
    double minDist2 = 1e30;
    for (size_t i = 0; i < near.size(); ++i)
      for (size_t j = i + 1; j < near.size(); ++j) minDist2 = std::min(minDist2, double((near[i] - near[j]).squaredNorm()));
    EXPECT_GT(std::sqrt(minDist2), 0.3 * 0.02) << "frame " << f;
  }
  EXPECT_GT(blocked, 0u);
  EXPECT_LT(sim.fluid.size() - start, blocked);
}

TEST(Emitters, MaxParticlesStopsTheJetAndSaysSo) {
  json s = jetScene(0.005, nozzle({0.1, 0.5}, {1, 0}, 0.02, 0.6));
  s["duration"] = 0.1;       // validation estimates what the duration emits
  s["max_particles"] = 40;   // fewer than 0.5 s of jet
  Simulation<2> sim(parseScene<2>(s));
  size_t blocked = 0;
  for (int f = 0; f < 30; ++f) blocked += sim.advanceFrame().emissionBlocked;
  EXPECT_EQ(sim.fluid.size(), 40u);
  EXPECT_GT(blocked, 0u);
}

TEST(Emitters, BadEmittersAreClearErrors) {
  auto err = [](json e) { return sceneError(jetScene(0.005, e)); };
  EXPECT_NE(err(nozzle({0.1, 0.5}, {0, 0}, 0.02, 1)).find("emitters[0].direction: must not be zero"), std::string::npos);
  EXPECT_NE(err(nozzle({0.1, 0.5}, {1, 0}, 0.02, 0)).find("emitters[0].speed"), std::string::npos);
  EXPECT_NE(err(nozzle({0.1, 0.5}, {1, 0}, 0.02, 500)).find("emitters[0].speed"), std::string::npos);
  EXPECT_NE(err(nozzle({0.1, 0.5}, {1, 0}, -1, 1)).find("emitters[0].radius"), std::string::npos);
  // The nozzle reaches through the floor.
  EXPECT_NE(err(nozzle({0.1, 0.05}, {1, 0}, 0.1, 1)).find("emitters[0].center"), std::string::npos);
  json e = nozzle({0.1, 0.5}, {1, 0}, 0.02, 1);
  e["phase"] = "oil";
  EXPECT_NE(err(e).find("emitters[0].phase: unknown phase 'oil'"), std::string::npos);
  e = nozzle({0.1, 0.5}, {1, 0}, 0.02, 1);
  e["rate"] = 3;
  EXPECT_NE(err(e).find("emitters[0]"), std::string::npos);
  e = nozzle({0.1, 0.5}, {1, 0}, 0.02, 1);
  e["start"] = 1;
  e["end"] = 0.5;
  EXPECT_NE(err(e).find("emitters[0].end"), std::string::npos);
  json s = jetScene(0.005, nozzle({0.1, 0.5}, {1, 0}, 0.02, 1));
  s["obstacles"] = json::array({{{"type", "disk"}, {"center", {0.1, 0.5}}, {"radius", 0.05}}});
  EXPECT_NE(sceneError(s).find("inside or within a particle radius of obstacles[0]"), std::string::npos);
  s = jetScene(0.005, nozzle({0.1, 0.5}, {1, 0}, 0.02, 1));
  s["max_particles"] = 100;
  EXPECT_NE(sceneError(s).find("emitters: the fluid blocks and the emitters"), std::string::npos);
}

TEST(Emitters, RoundTripThroughTheSceneFile) {
  json e = nozzle({0.1, 0.5}, {3, 4}, 0.02, 0.6);
  e["end"] = 1.5;
  const auto a = parseScene<2>(jetScene(0.005, e));
  const auto b = parseScene<2>(sceneToJson(a));
  ASSERT_EQ(b.emitters.size(), 1u);
  EXPECT_NEAR(b.emitters[0].direction.x(), 0.6, 1e-6);
  EXPECT_NEAR(b.emitters[0].radius, 0.02, 1e-7);
  EXPECT_EQ(b.emitters[0].end, 1.5);
  EXPECT_EQ(sceneToJson(b), sceneToJson(a));
  // A scene without emitters has no emitter stage.
  json plain = jetScene(0.005, e);
  plain.erase("emitters");
  plain["fluid_blocks"] = json::array({{{"min", {0, 0}}, {"max", {0.2, 0.2}}}});
  Simulation<2> sim(parseScene<2>(plain));
  const auto& st = sim.pipelineStages();
  EXPECT_EQ(std::count(st.begin(), st.end(), "emitters"), 0);
  EXPECT_FALSE(sim.advanceFrame().emitting);
}

namespace {

// How far the jet has folded: above the floor's film (y ≥ 5 cm) and near
// the nozzle's axis (±10 cm), the largest offset of a 2 cm band's median x
// from the axis. A straight jet: 0; a buckled one: of the order of its width.
struct JetShape {
  double fold = 0;      // m
  double nearAxis = 0;  // fraction of the liquid within ±10 cm of the axis
};

JetShape jetShape(const Simulation<2>& sim, double axis) {
  JetShape s;
  size_t near = 0;
  for (const auto& x : sim.fluid.x) near += std::abs(x.x() - axis) < 0.1 ? 1 : 0;
  s.nearAxis = double(near) / double(std::max<size_t>(1, sim.fluid.size()));
  for (double y0 = 0.05; y0 < 0.25; y0 += 0.02) {
    std::vector<double> xs;
    for (const auto& x : sim.fluid.x)
      if (std::abs(x.x() - axis) < 0.1 && x.y() >= y0 && x.y() < y0 + 0.02) xs.push_back(x.x());
    if (xs.size() < 4) continue;
    std::nth_element(xs.begin(), xs.begin() + long(xs.size() / 2), xs.end());
    s.fold = std::max(s.fold, std::abs(xs[xs.size() / 2] - axis));
  }
  return s;
}

}  // namespace

// Viscous buckling: scenes/honey_jet2d.json, a 3 cm jet of a liquid
// 500 000× as viscous as water (ν = 0.5 m²/s, implicit viscosity) falling
// 30 cm at 0.4 m/s, arrives faster than it can spread: it heaps and folds
// sideways, as honey poured on toast. The same jet of water spreads into a
// film and stays straight above it. Measured (r = 3 mm, 1.5 s): honey fold
// 0.056 m, all of it within 10 cm of the axis; water fold 0.003 m, 21 %.
TEST(Emitters, HoneyJetBucklesWaterJetDoesNot) {
  json honey = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/honey_jet2d.json");
  json water = honey;
  water["phases"][0]["viscosity"] = 1e-6;
  water["effects"] = json::array({"viscosity_standard"});
  auto run = [](const json& scene) {
    Simulation<2> sim(parseScene<2>(scene));
    const double R = sim.setup().emitters.at(0).radius;
    for (int f = 0; f < 90; ++f) {
      const FrameStats fs = sim.advanceFrame();
      EXPECT_TRUE(fs.finite) << "frame " << f;
      EXPECT_EQ(fs.escapedParticles, 0u) << "frame " << f;
      EXPECT_LT(fs.maxSpeed, 0.4 + std::sqrt(2 * 9.81 * 0.3) + 0.5) << "frame " << f;
    }
    return std::make_pair(jetShape(sim, sim.setup().emitters.at(0).center.x()), R);
  };
  const auto [h, R] = run(honey);
  const auto [w, Rw] = run(water);
  EXPECT_GT(h.fold, 2 * R) << "the honey jet did not fold";
  EXPECT_GT(h.nearAxis, 0.9) << "the honey spread like water";
  EXPECT_LT(w.fold, 0.5 * Rw) << "the water jet bent";
  EXPECT_LT(w.nearAxis, 0.5) << "the water heaped";
}
