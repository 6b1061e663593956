// The stability suite in 3D (`ctest -L stability`, docs/physics/stability.md):
// the hard cases of test_stability.cpp where they are hardest, with the
// scene's default boundary model. Every frame passes the same checks
// (stability_checks.h: finite, inside the tank and outside every solid,
// under the case's speed bound, the average density error under its bound,
// energy not rising where nothing feeds it) and the cases with temporary
// particles get the scene's liquid count back. Each case is one to three
// thousand particles at r = 1-2 cm, well under a simulated second, on one
// thread.
#include "control/control.h"
#include "io/recipe.h"
#include "io/scene.h"
#include "sph/emitters/nozzle.h"
#include "sph/simulation.h"
#include "tests/stability_checks.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

namespace fc {
namespace {

using nlohmann::json;
using namespace stability;

// A 3D tank with the scenes' water and solver settings.
json tank3D(double r, double x, double y, double z) { return waterTank(r, {x, y, z}); }

json block3D(std::vector<double> lo, std::vector<double> hi, const char* phase = "water") {
  return {{"min", lo}, {"max", hi}, {"phase", phase}};
}

// Runs `frames` frames of a closed scene (nothing feeds its energy) under
// the speed bound, single-threaded; returns the simulation for the case's
// own checks.
std::unique_ptr<Simulation<3>> runClosed3D(const json& scene, double maxSpeed, int frames, const char* name,
                                           RunRecord& rec) {
  auto sim = std::make_unique<Simulation<3>>(parseScene<3>(scene));
  FrameBounds b;
  b.maxSpeed = maxSpeed;
  b.closed = true;
  runBounded(*sim, frames, b, rec, name);
  return sim;
}

double maxX(const Simulation<3>& sim) {
  double m = -1e9;
  for (const auto& x : sim.fluid.x) m = std::max(m, double(x.x()));
  return m;
}

}  // namespace

// A column 0.3 m high collapses and its front, at about 2 sqrt(g H) =
// 3.4 m/s, hits a block on the floor head-on, then the far wall.
TEST(Stability, DamBreak3DHitsAnObstacleAtFullSpeed) {
  SingleThread one;
  json s = tank3D(0.01, 0.8, 0.45, 0.16);
  s["fluid_blocks"].push_back(block3D({0, 0, 0}, {0.2, 0.3, 0.16}));
  s["obstacles"] = json::array({{{"type", "box"}, {"min", {0.42, 0, 0.05}}, {"max", {0.48, 0.08, 0.11}}}});
  RunRecord rec;
  const auto sim = runClosed3D(s, speedBound(0, 0.3), 40, "3D dam break on an obstacle", rec);
  if (HasFatalFailure()) return;
  EXPECT_GT(maxX(*sim), 0.7) << "the front must have passed the obstacle";
}

// A paddle 0.3 m long turning about the vertical at 1 900 °/s in a pool:
// its tips move at 5 m/s, three times the speed at which the CFL condition
// (0.4 particle diameters per step) takes over from dt_max, so every step
// is the CFL step of the tips.
TEST(Stability, FastBlade3DAtTheCflLimit) {
  SingleThread one;
  const double r = 0.01, halfLength = 0.15, omegaDeg = 1900;
  const double tip = omegaDeg * M_PI / 180 * std::hypot(halfLength, 0.01);
  json s = tank3D(r, 0.4, 0.3, 0.4);
  s["fluid_blocks"].push_back(block3D({0, 0, 0}, {0.4, 0.1, 0.4}));
  s["bodies"] = json::array({{{"name", "blade"},
                              {"type", "box"},
                              {"size", {2 * halfLength, 0.06, 0.02}},
                              {"position", {0.2, 0.06, 0.2}},
                              {"motion", "kinematic"},
                              {"angular_velocity", {0, omegaDeg, 0}},
                              {"carve_fluid", true}}});
  Simulation<3> sim(parseScene<3>(s));
  FrameBounds b;
  b.maxSpeed = speedBound(0, 0.1, tip);
  RunRecord rec;
  startRecord(sim, rec);
  const double cflStep = 0.4 * 2 * r / tip;
  double longestStep = 0;
  for (int f = 0; f < 30; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(checkFrameBounds(sim, fs, b, rec)) << "fast blade";
    longestStep = std::max(longestStep, fs.maxDt);
  }
  printRecord("3D fast blade", b, rec);
  std::printf("[ measured ] 3D fast blade: tip %.2f m/s, longest step %.3g ms, the tips' CFL step %.3g ms\n", tip,
              1e3 * longestStep, 1e3 * cflStep);
  EXPECT_LE(longestStep, cflStep * 1.0001) << "the tips must set every step";
  EXPECT_GT(rec.fastest, 0.3 * tip) << "the blade must have thrown the liquid";
}

namespace {

// A pool 0.4 × 0.4 m, `depth` deep, with one dynamic sphere.
json poolWithSphere(double depth, double radius, double density, std::vector<double> centre) {
  json s = tank3D(0.01, 0.4, 0.5, 0.4);
  s["fluid_blocks"].push_back(block3D({0, 0, 0}, {0.4, depth, 0.4}));
  s["bodies"] = json::array({{{"name", "ball"},
                              {"type", "sphere"},
                              {"radius", radius},
                              {"position", centre},
                              {"motion", "dynamic"},
                              {"density", density},
                              {"carve_fluid", true}}});
  return s;
}

}  // namespace

// A granite ball (3 000 kg/m³) falls 0.2 m into a pool, hits it at 2 m/s,
// goes down to the floor and stays there. Its energy is counted with the
// liquid's: nothing feeds the system.
TEST(Stability, HeavyBall3DDroppedIntoAPool) {
  SingleThread one;
  const double radius = 0.04, depth = 0.1;
  RunRecord rec;
  const auto sim = runClosed3D(poolWithSphere(depth, radius, 3000, {0.2, 0.34, 0.2}), speedBound(0, 0.38), 45,
                               "3D heavy ball dropped", rec);
  if (HasFatalFailure()) return;
  const auto& ball = sim->bodies()->states()[0];
  std::printf("[ measured ] 3D heavy ball: centre %.4f m above the floor, speed %.3g m/s after 0.75 s\n",
              ball.centre.y(), ball.velocity.norm());
  EXPECT_LT(ball.centre.y(), radius + 0.02) << "the ball must rest on the floor";
  EXPECT_GT(ball.centre.y(), radius - 0.01) << "the ball must not sink into the floor";
}

// A cork ball (200 kg/m³) held at the bottom of a pool and let go: buoyancy
// five times its weight shoots it up through the surface; it falls back and
// floats.
TEST(Stability, LightBall3DReleasedUnderwater) {
  SingleThread one;
  const double radius = 0.04, depth = 0.15;
  RunRecord rec;
  const auto sim = runClosed3D(poolWithSphere(depth, radius, 200, {0.2, 0.05, 0.2}), speedBound(0, depth), 60,
                               "3D light ball released underwater", rec);
  if (HasFatalFailure()) return;
  const auto& ball = sim->bodies()->states()[0];
  std::printf("[ measured ] 3D light ball: centre %.4f m, the surface at %.3f m, speed %.3g m/s after 1 s\n",
              ball.centre.y(), depth, ball.velocity.norm());
  EXPECT_GT(ball.centre.y(), depth - 0.5 * radius) << "the ball must have come up to float";
}

namespace {

// A closed hollow box (outer size `outer`, walls `wall` thick) as an OBJ:
// the outer surface facing out, the inner one facing into the cavity.
void writeHollowBox(const std::string& path, double outer, double wall) {
  std::ofstream f(path);
  auto box = [&](double lo, double hi, int base, bool inward) {
    for (int i = 0; i < 8; ++i)
      f << "v " << ((i & 1) ? hi : lo) << ' ' << ((i & 2) ? hi : lo) << ' ' << ((i & 4) ? hi : lo) << '\n';
    // The six faces, counter-clockwise seen from outside the box.
    const int quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
    for (const auto& q : quads) {
      f << 'f';
      if (inward)
        for (int k = 3; k >= 0; --k) f << ' ' << base + q[k];
      else
        for (int k = 0; k < 4; ++k) f << ' ' << base + q[k];
      f << '\n';
    }
  };
  box(0, outer, 1, false);
  box(wall, outer - wall, 9, true);
}

}  // namespace

// A dam break onto a mesh obstacle with walls one particle diameter thick
// and sharp edges: a closed hollow box 0.14 m wide, turned 45° about the
// vertical so that an edge meets the flow. The liquid runs around it, over
// it and against the far wall; none may get into a wall or through one into
// the cavity.
TEST(Stability, DamBreak3DOnAThinWalledHollowMesh) {
  SingleThread one;
  const double r = 0.01, outer = 0.14, wall = r;
  const std::string mesh = (std::filesystem::temp_directory_path() /
                            ("flowclip_hollow_box_" + std::to_string(::getpid()) + ".obj")).string();
  writeHollowBox(mesh, outer, wall);
  json s = tank3D(r, 0.9, 0.45, 0.3);
  s["fluid_blocks"].push_back(block3D({0, 0, 0}, {0.2, 0.3, 0.3}));
  const double cx = 0.5, cz = 0.15;
  // Vertex x goes to R_y(45°) x + t: the box's centre (outer/2, ·, outer/2) to (cx, ·, cz).
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 4, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d t = Eigen::Vector3d(cx, 0, cz) - R * Eigen::Vector3d(outer / 2, 0, outer / 2);
  s["obstacles"] = json::array(
      {{{"type", "mesh"}, {"file", mesh}, {"rotation", {0, 45, 0}}, {"translation", {t.x(), t.y(), t.z()}}}});
  Simulation<3> sim(parseScene<3>(s));
  std::filesystem::remove(mesh);
  json walls = s;
  walls.erase("obstacles");
  const size_t meshSamples = sim.boundary.size() - Simulation<3>(parseScene<3>(walls)).boundary.size();
  // The cavity in the mesh's own frame.
  auto inCavity = [&](const Vec<3>& x) {
    const Eigen::Vector3d local = R.transpose() * (x.cast<double>() - t);
    return (local.array() > wall).all() && (local.array() < outer - wall).all();
  };
  FrameBounds b;
  b.maxSpeed = speedBound(0, 0.3);
  b.closed = true;
  RunRecord rec;
  startRecord(sim, rec);
  size_t nearest = 0;
  for (int f = 0; f < 45; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(checkFrameBounds(sim, fs, b, rec)) << "thin-walled mesh";
    for (size_t i = 0; i < sim.fluid.size(); ++i)
      ASSERT_FALSE(inCavity(sim.fluid.x[i])) << "frame " << fs.frame << ": particle " << sim.fluid.id[i] << " at ("
                                             << sim.fluid.x[i].transpose() << ") got through a wall into the cavity";
    size_t near = 0;
    for (const auto& x : sim.fluid.x) near += sim.setup().obstacles[0].signedDistance(x) < 2 * r ? 1 : 0;
    nearest = std::max(nearest, near);
  }
  printRecord("3D thin-walled hollow mesh", b, rec);
  std::printf("[ measured ] 3D thin-walled hollow mesh: %zu boundary samples; up to %zu particles within a diameter "
              "of its walls\n", meshSamples, nearest);
  EXPECT_GT(nearest, 100u) << "the flow must have reached the mesh";
  EXPECT_GT(maxX(sim), 0.8) << "the front must have passed the mesh";
}

namespace {

// The hand3d template (templates/recipes/hand3d.json: a hand-shaped block
// of water falling onto a thin pool), its first 0.6 s: the fall and the
// splash. Recorded once per test process.
std::shared_ptr<const TemplateAccel<3>> handTemplate() {
  static const std::shared_ptr<const TemplateAccel<3>> accel = [] {
    Recipe recipe = loadRecipe(std::string(FLOWCLIP_SOURCE_DIR) + "/templates/recipes/hand3d.json");
    recipe.captures.at(0).seconds = 0.6;
    auto tpl = std::make_shared<const Template<3>>(std::move(captureTemplates<3>(recipe).at(0)));
    return std::make_shared<const TemplateAccel<3>>(TemplateAccel<3>::build(tpl));
  }();
  return accel;
}

}  // namespace

// The hand template reversed (the splash gathers into a hand that rises off
// the pool), scaled 1.3 × 1 × 1.3 and turned 30° about the vertical, on a
// pool 0.12 m deep: the hand forms in the air where the scene has no
// liquid, so temporary particles are seeded, and they must all be gone a
// few frames after the instance ends.
TEST(Stability, Instance3DScaledRotatedReversedSeedsTemporaryParticles) {
  SingleThread one;
  const double depth = 0.12;
  json s = tank3D(0.02, 1.2, 1.2, 1.2);
  s["fluid_blocks"].push_back(block3D({0, 0, 0}, {1.2, depth, 1.2}));
  Simulation<3> sim(parseScene<3>(s));
  const auto accel = handTemplate();
  const Template<3>& tpl = *accel->source;
  BoundInstance<3> bound;
  bound.accel = accel;
  bound.spec.name = "hand";
  bound.spec.templateName = "hand3d";
  bound.spec.time.start = 0.05;
  bound.spec.time.reverse = true;
  TransformKey<3> k;
  k.scale = Eigen::Vector3d(1.3, 1.0, 1.3);
  k.rotationDeg = {0, 30, 0};
  // The template's pool (its bottom 0.06 m) on the scene's pool.
  const AABB<3> region = tpl.region();
  k.translation = Eigen::Vector3d(0.6, depth - 0.06 + (double(region.center().y()) - double(region.min.y())), 0.6);
  bound.spec.transform.keys = {k};
  ControlSettings settings = controlSettingsTable().defaults();
  settings.temporaryGraceFrames = 5;
  settings.temporaryFadeShare = 1;
  // The driven motion: the template's fastest particle at the largest scale,
  // and the pull's cap (2 h_T / T per frame, control.cpp).
  double vTemplate = 0;
  for (const auto& fr : tpl.frames)
    for (const auto& u : fr.v) vTemplate = std::max(vTemplate, double(u.norm()));
  const double vDriven = 1.3 * vTemplate + 2 * tpl.header.supportRadius * 1.3 / sim.frameDuration();
  sim.addEffect(std::make_unique<Control<3>>(std::vector<BoundInstance<3>>{bound}, settings), "control");
  const size_t original = sim.fluid.size();
  const double end = bound.spec.time.start + bound.spec.time.sceneDuration(tpl.duration());
  const int frames = int(std::ceil(end / sim.frameDuration() - 1e-9)) + 7;
  FrameBounds b;
  b.maxSpeed = speedBound(0, 1.2, vDriven);
  RunRecord rec;
  startRecord(sim, rec);
  FrameStats fs;
  bool wasActive = false;
  for (int f = 0; f < frames; ++f) {
    fs = sim.advanceFrame();
    ASSERT_TRUE(checkFrameBounds(sim, fs, b, rec)) << "3D instance";
    ASSERT_EQ(fs.instances.size(), 1u);
    wasActive = wasActive || fs.instances[0].active;
    ASSERT_EQ(fs.particles - fs.temporaryParticles, original) << "frame " << fs.frame;
  }
  printRecord("3D instance scaled, rotated, reversed", b, rec);
  EXPECT_TRUE(wasActive);
  EXPECT_FALSE(fs.instances[0].active) << "the run must outlast the instance";
  EXPECT_GT(rec.mostControlled, 0u) << "the instance never reached the liquid";
  EXPECT_GE(rec.mostTemporary, 50u) << "the hand forming in the air must seed temporary particles";
  EXPECT_EQ(fs.temporaryParticles, 0u) << "temporary particles left 7 frames after the end";
  EXPECT_EQ(sim.fluid.size(), original);
}

// Two liquids of rest densities 1:10: a cube of water falls 0.1 m into a
// pool of a light liquid (100 kg/m³), goes through it and spreads on the
// floor under it.
TEST(Stability, Multiphase3DDensityRatio1To10) {
  SingleThread one;
  json s = tank3D(0.01, 0.3, 0.4, 0.2);
  s["phases"] = json::array({{{"name", "water"}, {"rest_density", 1000}, {"viscosity", 0.001}},
                             {{"name", "light"}, {"rest_density", 100}, {"viscosity", 0.001}}});
  s["fluid_blocks"].push_back(block3D({0, 0, 0}, {0.3, 0.1, 0.2}, "light"));
  s["fluid_blocks"].push_back(block3D({0.09, 0.2, 0.04}, {0.21, 0.32, 0.16}, "water"));
  Simulation<3> sim(parseScene<3>(s));
  ASSERT_TRUE(sim.numberDensity());
  FrameBounds b;
  b.maxSpeed = speedBound(0, 0.32);
  b.closed = true;
  RunRecord rec;
  runBounded(sim, 45, b, rec, "3D multiphase 1:10");
  if (HasFatalFailure()) return;
  double heavy = 0, light = 0;
  size_t nh = 0, nl = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i)
    (sim.fluid.phase[i] == 0 ? (heavy += sim.fluid.x[i].y(), nh++) : (light += sim.fluid.x[i].y(), nl++));
  std::printf("[ measured ] 3D multiphase 1:10: mean height of the heavy liquid %.4f m, of the light %.4f m\n",
              heavy / double(nh), light / double(nl));
  EXPECT_LT(heavy / double(nh), light / double(nl)) << "the heavy liquid must have sunk under the light one";
}

// Zero gravity: a nozzle 10 cm wide shoots water at 3 m/s across an empty
// tank for 0.2 s; the jet hits the far wall and spreads over it. Its energy comes
// from the inflow, so energy is not bounded, but the count is: once the
// nozzle closes, no particle comes or goes.
TEST(Stability, ZeroGravity3DEmitterJetHitsAWall) {
  SingleThread one;
  const double speed = 3;
  json s = tank3D(0.01, 0.5, 0.3, 0.3);
  s["gravity"] = {0, 0, 0};
  s["emitters"] = json::array({{{"name", "nozzle"},
                                {"center", {0.03, 0.15, 0.15}},
                                {"direction", {1, 0, 0}},
                                {"radius", 0.05},
                                {"speed", speed},
                                {"end", 0.2}}});
  Simulation<3> sim(parseScene<3>(s));
  FrameBounds b;
  b.maxSpeed = speedBound(speed, 0);
  RunRecord rec;
  startRecord(sim, rec);
  size_t atClose = 0, emitted = 0;
  for (int f = 0; f < 40; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(checkFrameBounds(sim, fs, b, rec)) << "zero-gravity jet";
    if (fs.time > 0.2 + 1.5 * sim.frameDuration()) {
      if (atClose == 0) atClose = fs.particles;
      ASSERT_EQ(fs.particles, atClose) << "frame " << fs.frame << ": the nozzle is closed";
    }
    emitted = fs.particles;
  }
  printRecord("3D zero-gravity jet", b, rec);
  // The nozzle's flux: one layer of the nozzle's lattice points per spacing
  // travelled, for 0.2 s.
  const Real spacing = 2 * sim.particleRadius();
  const double layer = double(nozzleLayer(sim.setup().emitters[0], spacing).size());
  const double expected = layer * speed * 0.2 / double(spacing);
  std::printf("[ measured ] 3D zero-gravity jet: %zu particles emitted (the nozzle's flux: %.0f)\n", emitted, expected);
  EXPECT_NEAR(double(emitted), expected, 0.1 * expected);
  EXPECT_GT(maxX(sim), 0.45) << "the jet must have reached the far wall";
}

}  // namespace fc
