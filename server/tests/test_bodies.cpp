// Moving bodies (sph/bodies/rigid_bodies.h): a body of half the liquid's density
// floats about half submerged; a dropped body does not tunnel through the
// floor; a kinematic blade turns the liquid its way; a scene without bodies
// has no body stage; bad body input is a SceneError naming the key.
#include "io/scene.h"
#include "sph/simulation.h"
#include "tests/physics_checks.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <type_traits>

namespace fc {
namespace {

using nlohmann::json;

// A 2D pool, depth `depth`, in a tank w × 0.5 m, particle radius r.
json pool2D(double r, double width, double depth, const json& bodies) {
  json s = json::parse(R"({
    "dimension": 2,
    "domain": {"min": [0, 0], "max": [0.6, 0.5]},
    "gravity": [0, -9.81],
    "phases": [{"name": "water", "rest_density": 1000, "viscosity": 0.001}],
    "solver": {"method": "dfsph", "density_tolerance_pct": 0.05, "divergence_tolerance_pct": 0.1},
    "settings": {"frame_rate": 60, "cfl_factor": 1, "dt_max": 0.004},
    "effects": [{"name": "viscosity_standard", "boundary_viscosity": 0}]
  })");
  s["particle_radius"] = r;
  s["domain"]["max"][0] = width;
  s["fluid_blocks"] = json::array({{{"min", {0, 0}}, {"max", {width, depth}}, {"phase", "water"}}});
  s["bodies"] = bodies;
  return s;
}

// Height of the free surface away from x in [skipLo, skipHi]: the mean of the
// highest particle centre per column of width 4r, plus r.
double surfaceHeight(const Simulation<2>& sim, double skipLo, double skipHi) {
  const double r = sim.particleRadius();
  const double w = sim.setup().domain.max[0];
  const int columns = int(w / (4 * r));
  std::vector<double> top(size_t(columns), -1);
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const double x = sim.fluid.x[i][0], y = sim.fluid.x[i][1];
    if (x > skipLo && x < skipHi) continue;
    const int c = std::clamp(int(x / (4 * r)), 0, columns - 1);
    top[size_t(c)] = std::max(top[size_t(c)], y);
  }
  double sum = 0;
  int n = 0;
  for (double t : top)
    if (t > 0) sum += t, ++n;
  return n ? sum / n + r : 0;
}

TEST(Bodies, HalfDensityBoxFloatsHalfSubmerged) {
  const double r = 0.005, depth = 0.16, bh = 0.06, bw = 0.12;
  // Placed with its centre on the surface (half submerged already), so that
  // the test measures where it settles, not a long bobbing.
  json body = {{"name", "boat"},  {"type", "box"},     {"size", {bw, bh}}, {"position", {0.3, depth}},
               {"motion", "dynamic"}, {"density", 500}, {"carve_fluid", true}};
  Simulation<2> sim(parseScene<2>(pool2D(r, 0.6, depth, json::array({body}))));
  ASSERT_NE(sim.bodies(), nullptr);
  ASSERT_EQ(sim.bodies()->states().size(), 1u);
  const auto& boat = sim.bodies()->states()[0];
  EXPECT_NEAR(boat.mass, 500 * bw * bh, 1e-6 * boat.mass);
  FrameChecks checks;
  const int frames = 80, averaged = 20;
  double draftSum = 0, lo = 1e9, hi = -1e9;
  for (int f = 0; f < frames; ++f) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    ASSERT_EQ(fs.bodies.size(), 1u);
    EXPECT_LT(std::abs(fs.bodies[0].velocity[1]), 1.0) << "frame " << fs.frame;
    if (f >= frames - averaged) {
      // Draft = surface − bottom, averaged over the last frames (it bobs gently).
      draftSum += surfaceHeight(sim, 0.3 - bw, 0.3 + bw) - (boat.centre.y() - bh / 2);
      lo = std::min(lo, boat.centre.y());
      hi = std::max(hi, boat.centre.y());
    }
  }
  checks.finish(frames);
  const double draft = draftSum / averaged;
  std::printf("floating box: draft %.4f m (Archimedes: %.4f), bobbing %.4f m peak to peak, tilt %.2f deg\n", draft,
              bh / 2, hi - lo, boat.angle * 180 / 3.14159265);
  // Archimedes: draft = (ρ_body / ρ_liquid) · height = h/2. Within 15 %:
  // the liquid's surface is resolved to about a particle radius (r = 13 % of h/2).
  EXPECT_NEAR(draft, bh / 2, 0.15 * bh / 2);
  EXPECT_LT(hi - lo, 0.2 * bh);
  EXPECT_LT(std::abs(boat.angle), 10 * 3.14159265 / 180);
}

TEST(Bodies, DroppedBodyDoesNotTunnelThroughTheFloor) {
  const double r = 0.005, size = 0.08;
  // A heavy box falls 0.3 m into a shallow pool (it hits the floor at about 2.4 m/s).
  json body = {{"name", "brick"}, {"type", "box"},      {"size", {size, size}}, {"position", {0.3, 0.4}},
               {"motion", "dynamic"}, {"density", 3000}};
  Simulation<2> sim(parseScene<2>(pool2D(r, 0.6, 0.05, json::array({body}))));
  const auto& brick = sim.bodies()->states()[0];
  FrameChecks checks;
  double lowest = 1e9;
  size_t wallContacts = 0;
  const int frames = 60;
  for (int f = 0; f < frames; ++f) {
    const FrameStats fs = sim.advanceFrame();
    if (!checks.check(sim, fs)) break;
    lowest = std::min(lowest, brick.centre.y() - size / 2);
    wallContacts += fs.bodies[0].wallContacts;
  }
  checks.finish(frames);
  std::printf("dropped box: lowest bottom %.5f m, final centre y %.4f m, vy %.4f m/s, %zu wall-contact substeps\n", lowest,
              brick.centre.y(), brick.velocity.y(), wallContacts);
  // It reaches the floor (the samples stop a radius inside its surface, so
  // its bottom rests on the floor within a radius), never below it.
  EXPECT_GT(wallContacts, 0u);
  EXPECT_GE(lowest, -r);
  EXPECT_LT(brick.centre.y() - size / 2, 2 * r);
  EXPECT_LT(std::abs(brick.velocity.y()), 0.1);
}

// Angular momentum of the liquid about point c, Σ m (x − c) × v (2D: z).
double angularMomentum(const Simulation<2>& sim, const Eigen::Vector2d& c) {
  double L = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    const Eigen::Vector2d x = sim.fluid.x[i].cast<double>() - c, v = sim.fluid.v[i].cast<double>();
    L += double(sim.fluid.mass[i]) * (x.x() * v.y() - x.y() * v.x());
  }
  return L;
}

TEST(Bodies, KinematicBladeTurnsTheLiquidItsWay) {
  for (double omega : {180.0, -180.0}) {
    json blade = {{"name", "blade"}, {"type", "box"}, {"size", {0.2, 0.02}}, {"position", {0.3, 0.12}},
                  {"motion", "kinematic"}, {"angular_velocity", omega}, {"carve_fluid", true}};
    Simulation<2> sim(parseScene<2>(pool2D(0.005, 0.6, 0.25, json::array({blade}))));
    FrameChecks checks;
    for (int f = 0; f < 30; ++f)
      if (!checks.check(sim, sim.advanceFrame())) break;
    checks.finish(30);
    const auto& s = sim.bodies()->states()[0];
    EXPECT_NEAR(s.angle, omega * 3.14159265358979 / 180 * 0.5, 1e-6);  // 30 frames = 0.5 s
    const double L = angularMomentum(sim, Eigen::Vector2d(0.3, 0.12));
    std::printf("blade at %+.0f deg/s: liquid angular momentum %.3e kg m^2/s per m\n", omega, L);
    EXPECT_GT(L * omega, 0) << "the liquid must turn the blade's way";
    EXPECT_GT(std::abs(L), 1e-3);
  }
}

TEST(Bodies, KeyedBodyFollowsItsKeysAndRepeats) {
  json paddle = {{"name", "paddle"}, {"type", "box"}, {"size", {0.02, 0.2}}, {"motion", "kinematic"},
                 {"keys", {{{"time", 0}, {"position", {0.05, 0.15}}}, {{"time", 0.5}, {"position", {0.15, 0.15}}},
                           {{"time", 1.0}, {"position", {0.05, 0.15}}}}},
                 {"period", 1.0}, {"carve_fluid", true}};
  Simulation<2> sim(parseScene<2>(pool2D(0.005, 0.6, 0.1, json::array({paddle}))));
  const auto& s = sim.bodies()->states()[0];
  std::vector<double> xs;
  for (int f = 0; f < 75; ++f) {
    const FrameStats fs = sim.advanceFrame();
    ASSERT_TRUE(fs.finite);
    if (fs.frame == 15 || fs.frame == 30 || fs.frame == 45 || fs.frame == 75) xs.push_back(s.centre.x());
  }
  ASSERT_EQ(xs.size(), 4u);
  EXPECT_NEAR(xs[0], 0.10, 1e-6);  // t = 0.25: halfway out
  EXPECT_NEAR(xs[1], 0.15, 1e-6);  // t = 0.5: the middle key
  EXPECT_NEAR(xs[2], 0.10, 1e-6);  // t = 0.75: halfway back
  EXPECT_NEAR(xs[3], 0.10, 1e-6);  // t = 1.25: repeated
  EXPECT_NEAR(s.velocity.x(), 0.2, 1e-6);
}

// 3D: a body turning about y at 45°/s is reported at Euler (0, 45, 0) after
// 1 s, its samples moved with it (rigidly: distances to the centre kept).
TEST(Bodies, Kinematic3DTurnsAndIsReported) {
  json s = json::parse(R"({
    "dimension": 3, "particle_radius": 0.03,
    "domain": {"min": [0, 0, 0], "max": [0.9, 0.6, 0.9]},
    "fluid_blocks": [{"min": [0, 0, 0], "max": [0.9, 0.15, 0.9]}],
    "bodies": [{"name": "paddle", "type": "box", "size": [0.4, 0.1, 0.06], "position": [0.45, 0.35, 0.45],
                "motion": "kinematic", "angular_velocity": [0, 45, 0]}]
  })");
  Simulation<3> sim(parseScene<3>(s));
  const auto& b = sim.bodies()->states()[0];
  std::vector<double> r0;
  for (size_t i = 0; i < b.count; ++i) r0.push_back((sim.boundary.x[b.first + i].cast<double>() - b.centre).norm());
  FrameStats fs;
  for (int f = 0; f < 60; ++f) fs = sim.advanceFrame();
  ASSERT_TRUE(fs.finite);
  ASSERT_EQ(fs.bodies.size(), 1u);
  EXPECT_NEAR(fs.bodies[0].rotationDeg[0], 0, 1e-3);
  EXPECT_NEAR(fs.bodies[0].rotationDeg[1], 45, 1e-3);
  EXPECT_NEAR(fs.bodies[0].rotationDeg[2], 0, 1e-3);
  for (size_t i = 0; i < b.count; ++i)
    EXPECT_NEAR((sim.boundary.x[b.first + i].cast<double>() - b.centre).norm(), r0[i], 1e-5) << i;
  // A sample's velocity is ω × r.
  const Eigen::Vector3d r = sim.boundary.x[b.first].cast<double>() - b.centre;
  const Eigen::Vector3d w(0, 45 * 3.14159265358979 / 180, 0);
  EXPECT_NEAR((sim.boundary.v[b.first].cast<double>() - w.cross(r)).norm(), 0, 1e-5);
}

// A simulation rebuilt mid-scene (a session's settings edit) continues its
// bodies: the dynamic one where it was with its velocity, the kinematic one
// at the scene time (not back at its t = 0 pose). A dynamic body's initial
// velocity is its velocity at the start.
TEST(Bodies, RebuiltSimulationContinuesItsBodies) {
  json bodies = json::array(
      {{{"name", "ball"}, {"type", "disk"}, {"radius", 0.04}, {"position", {0.2, 0.35}}, {"motion", "dynamic"},
        {"density", 800}, {"velocity", {0.5, 0}}},
       {{"name", "blade"}, {"type", "box"}, {"size", {0.1, 0.02}}, {"position", {0.45, 0.3}}, {"motion", "kinematic"},
        {"angular_velocity", 90}}});
  const SimulationSetup<2> setup = parseScene<2>(pool2D(0.01, 0.6, 0.1, bodies));
  Simulation<2> a(setup);
  EXPECT_NEAR(a.bodies()->states()[0].velocity.x(), 0.5, 1e-9);
  for (int f = 0; f < 12; ++f) ASSERT_TRUE(a.advanceFrame().finite);
  Simulation<2> b(setup);
  b.continueBodiesFrom(a, a.time());
  const auto& ball0 = a.bodies()->states()[0];
  const auto& ball1 = b.bodies()->states()[0];
  EXPECT_NEAR((ball1.centre - ball0.centre).norm(), 0, 1e-12);
  EXPECT_NEAR((ball1.velocity - ball0.velocity).norm(), 0, 1e-12);
  EXPECT_NEAR(ball1.angle, ball0.angle, 1e-12);
  // The blade at scene time 0.2 s + b's own clock: 18° now, 18° + 90°·(1/60) after a frame.
  EXPECT_NEAR(b.bodies()->states()[1].angle, a.bodies()->states()[1].angle, 1e-9);
  ASSERT_TRUE(b.advanceFrame().finite);
  EXPECT_NEAR(b.bodies()->states()[1].angle * 180 / 3.14159265358979, 90 * (13.0 / 60), 1e-6);
}

TEST(Bodies, SceneWithoutBodiesHasNone) {
  Simulation<2> sim(parseScene<2>(pool2D(0.01, 0.6, 0.1, json::array())));
  EXPECT_EQ(sim.bodies(), nullptr);
  const FrameStats fs = sim.advanceFrame();
  EXPECT_TRUE(fs.bodies.empty());
}

void expectBodyError(const json& bodies, const std::string& path, const std::string& mentions) {
  try {
    parseScene<2>(pool2D(0.01, 0.6, 0.1, bodies));
    ADD_FAILURE() << "expected a SceneError at " << path;
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, path) << e.what();
    EXPECT_NE(std::string(e.what()).find(mentions), std::string::npos) << e.what();
  }
}

TEST(Bodies, BadInputNamesTheKey) {
  const json ok = {{"name", "b"}, {"type", "box"}, {"size", {0.1, 0.1}}, {"position", {0.3, 0.3}}, {"motion", "dynamic"},
                   {"density", 500}};
  ASSERT_NO_THROW(parseScene<2>(pool2D(0.01, 0.6, 0.1, json::array({ok}))));
  auto with = [&](const char* k, const json& v) {
    json b = ok;
    if (v.is_null()) b.erase(k);
    else b[k] = v;
    return json::array({b});
  };
  // A body in the liquid at the start, without carve_fluid.
  expectBodyError(with("position", {0.3, 0.05}), "bodies[0]", "overlaps fluid_blocks[0]");
  expectBodyError(with("position", {0.58, 0.3}), "bodies[0].position", "outside the domain");
  expectBodyError(with("motion", "floating"), "bodies[0].motion", "unknown motion");
  expectBodyError(with("density", -1), "bodies[0].density", "must be > 0");
  expectBodyError(with("density", nullptr), "bodies[0].density", "missing required key");
  expectBodyError(with("size", {0.1, 0}), "bodies[0].size[1]", "must be > 0");
  expectBodyError(with("type", "torus"), "bodies[0].type", "unknown body type");
  expectBodyError(with("keys", json::array({{{"time", 0}, {"position", {0.3, 0.3}}}})), "bodies[0].keys", "no keys");
  expectBodyError(with("spin", 3), "bodies[0].spin", "unknown key");
  json twice = json::array({ok, ok});
  expectBodyError(twice, "bodies[1].name", "duplicate body name");
  // A keyed body is checked against the domain at every key, and takes no rotation of its own.
  json keyed = {{"name", "p"}, {"type", "box"}, {"size", {0.05, 0.1}}, {"motion", "kinematic"},
                {"keys", {{{"time", 0}, {"position", {0.3, 0.3}}}, {{"time", 1}, {"position", {0.59, 0.3}}}}}};
  expectBodyError(json::array({keyed}), "bodies[0].keys[1].position", "outside the domain");
  keyed["keys"][1]["position"] = {0.4, 0.3};
  keyed["rotation"] = 10;
  expectBodyError(json::array({keyed}), "bodies[0].rotation", "no rotation");
}

}  // namespace
}  // namespace fc

namespace fc {
namespace {

// Every shipped scene assembles exactly what it names: its pressure solver,
// then its effects in order, a body stage only with bodies (and nothing
// else: template control is added by the instances' binding, outside).
TEST(Pipeline, ShippedScenesAssembleOnlyWhatTheyName) {
  namespace fs = std::filesystem;
  size_t scenes = 0;
  for (const auto& dir : {fs::path(FLOWCLIP_SOURCE_DIR) / "scenes", fs::path(FLOWCLIP_SOURCE_DIR) / "scenes" / "bench"})
    for (const auto& e : fs::directory_iterator(dir)) {
      if (e.path().extension() != ".json") continue;
      const json scene = loadSceneJson(e.path().string());
      std::vector<std::string> expected = {"pressure:" + scene.value("solver", json::object()).value("method", "dfsph")};
      for (const json& eff : scene.value("effects", json::array()))
        expected.push_back("effect:" + (eff.is_string() ? eff.get<std::string>() : eff["name"].get<std::string>()));
      const bool bodies = scene.contains("bodies") && !scene["bodies"].empty();
      if (scene.contains("emitters") && !scene["emitters"].empty()) expected.push_back("emitters");
      const double coarse = scene["dimension"] == 3 ? 0.03 : 0.01;
      auto check = [&](auto dim) {
        constexpr int D = decltype(dim)::value;
        Simulation<D> sim(parseScene<D>(scene, coarse));
        EXPECT_EQ(sim.pipelineStages(), expected) << e.path();
        EXPECT_EQ(sim.bodies() != nullptr, bodies) << e.path();
      };
      if (scene["dimension"] == 3) check(std::integral_constant<int, 3>{});
      else check(std::integral_constant<int, 2>{});
      ++scenes;
    }
  EXPECT_GE(scenes, 15u);
}

}  // namespace
}  // namespace fc
