// Scene-file parsing: every invalid input is a SceneError naming the key
// path; every shipped scene parses and survives a save/load round trip.
#include "io/scene.h"
#include "sph/limits.h"
#include "sph/pipeline.h"
#include "sph/sampling/lattice.h"
#include "sph/settings.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

namespace fc {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

// A small valid 2D scene; each bad-input test breaks exactly one thing.
json baseScene2D() {
  return json::parse(R"({
    "name": "unit",
    "dimension": 2,
    "particle_radius": 0.05,
    "domain": {"min": [0, 0], "max": [2, 2]},
    "phases": [{"name": "water", "rest_density": 1000, "viscosity": 0.01}],
    "fluid_blocks": [{"min": [0, 0], "max": [0.5, 1], "phase": "water"}],
    "obstacles": [{"type": "box", "min": [1.5, 0], "max": [2, 0.5]}],
    "solver": {"method": "dfsph", "density_tolerance_pct": 0.1},
    "settings": {"frame_rate": 60, "cfl_factor": 1},
    "effects": ["viscosity_standard", {"name": "viscosity_xsph", "coefficient": 0.05}]
  })");
}

json baseScene3D() {
  return json::parse(R"({
    "dimension": 3,
    "particle_radius": 0.05,
    "domain": {"min": [0, 0, 0], "max": [2, 2, 1]},
    "fluid_blocks": [{"min": [0, 0, 0], "max": [0.5, 1, 1]}]
  })");
}

// Parses `scene` expecting a SceneError at `path` whose what() also contains
// every string of `mentions`.
template <int D = 2>
void expectError(const json& scene, const std::string& path, const std::vector<std::string>& mentions = {}) {
  try {
    parseScene<D>(scene);
    FAIL() << "expected SceneError at '" << path << "' for scene " << scene.dump();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, path) << e.what();
    const std::string what = e.what();
    if (!path.empty()) {
      EXPECT_EQ(what.rfind(path + ": ", 0), 0u) << "what() must start with the path: " << what;
    }
    for (const auto& m : mentions) EXPECT_NE(what.find(m), std::string::npos) << "'" << m << "' missing in: " << what;
  }
}

template <int D>
size_t fluidParticles(const SimulationSetup<D>& s) {
  size_t n = 0;
  for (const auto& b : s.fluidBlocks) n += latticeCount(b.box, 2 * s.particleRadius);
  return n;
}

std::string sceneDir() { return std::string(FLOWCLIP_SOURCE_DIR) + "/scenes"; }

std::vector<fs::path> sceneFiles() {
  std::vector<fs::path> files;
  for (const auto& dir : {fs::path(sceneDir()), fs::path(sceneDir()) / "bench"})
    for (const auto& e : fs::directory_iterator(dir))
      if (e.path().extension() == ".json") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  return files;
}

// ------------------------------------------------------------ file level ---

TEST(SceneFile, MalformedJsonNamesFileLineAndColumn) {
  try {
    parseSceneText("{\n  \"dimension\": 2,,\n}", "broken.json");
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "");
    EXPECT_NE(std::string(e.what()).find("broken.json:2:"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("malformed JSON"), std::string::npos) << e.what();
  }
}

TEST(SceneFile, NumberOverflowIsMalformedWithPosition) {
  // nlohmann rejects 1e999 instead of producing inf; it must still be a SceneError.
  try {
    parseSceneText("{\"dimension\": 2,\n \"particle_radius\": 1e999}", "big.json");
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "");
    EXPECT_NE(std::string(e.what()).find("big.json:2:"), std::string::npos) << e.what();
  }
}

TEST(SceneFile, DuplicateKeyIsAnError) {
  try {
    parseSceneText(R"({"fluid_blocks": [{"min": [0, 0]}, {"min": [0, 0], "min": [1, 1]}]})", "dup.json");
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "fluid_blocks[1].min");
    EXPECT_NE(std::string(e.what()).find("duplicate key"), std::string::npos) << e.what();
  }
}

TEST(SceneFile, MissingFile) {
  try {
    loadSceneJson("/nonexistent/scene.json");
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "");
    EXPECT_NE(std::string(e.what()).find("/nonexistent/scene.json"), std::string::npos) << e.what();
  }
}

TEST(SceneFile, LoadsFromDisk) {
  const fs::path tmp = fs::temp_directory_path() / "flowclip_test_scene.json";
  std::ofstream(tmp) << baseScene2D().dump(2);
  const json j = loadSceneJson(tmp.string());
  EXPECT_EQ(j, baseScene2D());
  fs::remove(tmp);
}

// ------------------------------------------------------------ dimension ---

TEST(SceneDimension, MustBeTwoOrThree) {
  json j = baseScene2D();
  j["dimension"] = 4;
  EXPECT_THROW(sceneDimension(j), SceneError);
  expectError(j, "dimension", {"2 or 3"});
}

TEST(SceneDimension, Missing) {
  json j = baseScene2D();
  j.erase("dimension");
  expectError(j, "dimension", {"missing"});
}

TEST(SceneDimension, WrongDimensionForParser) {
  expectError<3>(baseScene2D(), "dimension");
}

TEST(SceneDimension, RootMustBeObject) {
  expectError(json::array({1, 2}), "", {"object"});
}

// ---------------------------------------------------------- unknown keys ---

TEST(SceneUnknownKey, TopLevel) {
  json j = baseScene2D();
  j["gravty"] = {0, -9.81};
  expectError(j, "gravty", {"unknown key", "gravity"});
}

TEST(SceneUnknownKey, NestedInFluidBlock) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["velocty"] = {0, 0};
  expectError(j, "fluid_blocks[0].velocty", {"unknown key"});
}

TEST(SceneUnknownKey, NestedInDomain) {
  json j = baseScene2D();
  j["domain"]["size"] = 2;
  expectError(j, "domain.size");
}

TEST(SceneUnknownKey, NestedInPhase) {
  json j = baseScene2D();
  j["phases"][0]["density"] = 1000;
  expectError(j, "phases[0].density", {"rest_density"});
}

TEST(SceneUnknownKey, NestedInObstacle) {
  json j = baseScene2D();
  j["obstacles"][0]["radius"] = 1;  // a box has no radius
  expectError(j, "obstacles[0].radius");
}

TEST(SceneUnknownKey, SolverParameter) {
  json j = baseScene2D();
  j["solver"]["density_tolerance"] = 0.1;
  expectError(j, "solver.density_tolerance", {"density_tolerance_pct"});
}

TEST(SceneUnknownKey, WcsphDoesNotTakeDfsphParameters) {
  json j = baseScene2D();
  j["solver"]["method"] = "wcsph";
  expectError(j, "solver.density_tolerance_pct", {"stiffness"});
}

TEST(SceneUnknownKey, SettingsParameter) {
  json j = baseScene2D();
  j["settings"]["framerate"] = 30;
  expectError(j, "settings.framerate", {"frame_rate"});
}

TEST(SceneUnknownKey, EffectParameter) {
  json j = baseScene2D();
  j["effects"][1]["coef"] = 0.1;
  expectError(j, "effects[1].coef", {"coefficient"});
}

// ------------------------------------------------------------ wrong types ---

TEST(SceneWrongType, StringForNumber) {
  json j = baseScene2D();
  j["particle_radius"] = "0.05";
  expectError(j, "particle_radius", {"number", "string"});
}

TEST(SceneWrongType, NumberForString) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["phase"] = 0;
  expectError(j, "fluid_blocks[0].phase", {"string"});
}

TEST(SceneWrongType, NullIsNotAbsent) {
  json j = baseScene2D();
  j["gravity"] = nullptr;
  expectError(j, "gravity");
}

TEST(SceneWrongType, NonIntegerForIntegerParam) {
  json j = baseScene2D();
  j["settings"]["reorder_interval"] = 2.5;
  expectError(j, "settings.reorder_interval", {"integer"});
}

TEST(SceneWrongType, IntegralFloatIsAnInteger) {
  json j = baseScene2D();
  j["settings"]["reorder_interval"] = 10.0;
  EXPECT_EQ(parseScene<2>(j).settings.reorderInterval, 10);
}

TEST(SceneWrongType, NumberForBooleanParam) {
  json j = baseScene2D();
  j["solver"]["divergence_solve"] = 1;
  expectError(j, "solver.divergence_solve", {"true or false"});
}

TEST(SceneWrongType, BooleanForNumber) {
  json j = baseScene2D();
  j["solver"]["density_tolerance_pct"] = true;
  expectError(j, "solver.density_tolerance_pct", {"number"});
}

TEST(SceneWrongType, VectorComponent) {
  json j = baseScene2D();
  j["domain"]["max"][1] = "2";
  expectError(j, "domain.max[1]");
}

TEST(SceneWrongType, EffectEntry) {
  json j = baseScene2D();
  j["effects"][0] = 3;
  expectError(j, "effects[0]");
}

TEST(SceneWrongType, MaxParticlesNotInteger) {
  json j = baseScene2D();
  j["max_particles"] = 1000.5;
  expectError(j, "max_particles", {"integer"});
}

// ------------------------------------------------------- values and ranges ---

TEST(SceneValue, NegativeRadius) {
  json j = baseScene2D();
  j["particle_radius"] = -0.01;
  expectError(j, "particle_radius", {"> 0"});
}

TEST(SceneValue, ZeroRadius) {
  json j = baseScene2D();
  j["particle_radius"] = 0;
  expectError(j, "particle_radius");
}

TEST(SceneValue, RadiusTooLargeForDomain) {
  json j = baseScene2D();
  j["particle_radius"] = 0.6;
  expectError(j, "particle_radius", {"too large"});
}

TEST(SceneValue, RadiusTooSmallForDomain) {
  json j = baseScene2D();
  j["particle_radius"] = 1e-6;
  expectError(j, "particle_radius", {"too small"});
}

TEST(SceneValue, BadRadiusOverride) {
  EXPECT_THROW(parseScene<2>(baseScene2D(), -1), SceneError);
}

TEST(SceneValue, VectorOfWrongLength) {
  json j = baseScene2D();
  j["gravity"] = {0, -9.81, 0};
  expectError(j, "gravity", {"2 components"});
}

TEST(SceneValue, BlockVectorOfWrongLength3D) {
  json j = baseScene3D();
  j["fluid_blocks"][0]["min"] = {0, 0};
  expectError<3>(j, "fluid_blocks[0].min", {"3 components"});
}

TEST(SceneValue, HugeParamIsOutOfRange) {
  json j = baseScene2D();
  j["solver"]["density_tolerance_pct"] = 1e300;
  expectError(j, "solver.density_tolerance_pct", {"outside", "[0.0001, 10] %"});
}

TEST(SceneValue, HugeCoordinate) {
  // Does not fit a float Real; with double Real it fails as outside the domain.
  json j = baseScene2D();
  j["fluid_blocks"][0]["max"][0] = 1e300;
  expectError(j, "fluid_blocks[0].max[0]");
}

TEST(SceneValue, OutOfRangeSetting) {
  json j = baseScene2D();
  j["settings"]["cfl_factor"] = 5;
  expectError(j, "settings.cfl_factor", {"[0.01, 2]"});
}

TEST(SceneValue, OutOfRangeEffectParam) {
  json j = baseScene2D();
  j["effects"][1]["coefficient"] = -0.5;
  expectError(j, "effects[1].coefficient", {"[0, 1]"});
}

TEST(SceneValue, DtMinAboveDtMax) {
  json j = baseScene2D();
  j["settings"]["dt_min"] = 0.01;
  j["settings"]["dt_max"] = 0.001;
  expectError(j, "settings.dt_min", {"dt_max"});
}

TEST(SceneValue, DomainMinNotBelowMax) {
  json j = baseScene2D();
  j["domain"]["min"] = {0, 3};
  expectError(j, "domain", {"min[1]"});
}

TEST(SceneValue, DomainMissing) {
  json j = baseScene2D();
  j.erase("domain");
  expectError(j, "domain", {"missing"});
}

TEST(SceneValue, DurationMustBePositive) {
  json j = baseScene2D();
  j["duration"] = 0;
  expectError(j, "duration");
}

TEST(SceneValue, MaxParticlesOutOfRange) {
  json j = baseScene2D();
  j["max_particles"] = 60000000;
  expectError(j, "max_particles", {"50000000"});
}

TEST(SceneValue, NameMustNotBeEmpty) {
  json j = baseScene2D();
  j["name"] = "";
  expectError(j, "name");
}

// ---------------------------------------------------------------- phases ---

TEST(ScenePhase, UnknownPhase) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["phase"] = "oil";
  expectError(j, "fluid_blocks[0].phase", {"oil", "water"});
}

TEST(ScenePhase, DuplicatePhase) {
  json j = baseScene2D();
  j["phases"].push_back({{"name", "water"}});
  expectError(j, "phases[1].name", {"duplicate", "phases[0]"});
}

TEST(ScenePhase, NonPositiveRestDensity) {
  json j = baseScene2D();
  j["phases"][0]["rest_density"] = 0;
  expectError(j, "phases[0].rest_density", {"> 0"});
}

TEST(ScenePhase, NegativeViscosity) {
  json j = baseScene2D();
  j["phases"][0]["viscosity"] = -1e-3;
  expectError(j, "phases[0].viscosity", {">= 0"});
}

TEST(ScenePhase, ColorOutOfRange) {
  json j = baseScene2D();
  j["phases"][0]["color"] = {0.1, 2, 0.3};
  expectError(j, "phases[0].color[1]");
}

TEST(ScenePhase, EmptyList) {
  json j = baseScene2D();
  j["phases"] = json::array();
  expectError(j, "phases");
}

TEST(ScenePhase, SecondPhaseIsReferenced) {
  json j = baseScene2D();
  j["phases"].push_back({{"name", "oil"}, {"rest_density", 800}});
  j["fluid_blocks"][0]["phase"] = "oil";
  const auto s = parseScene<2>(j);
  EXPECT_EQ(s.fluidBlocks[0].phase, 1);
  EXPECT_FLOAT_EQ(s.phases[1].restDensity, 800);
  EXPECT_FLOAT_EQ(s.phases[1].viscosity, 0);
}

// ---------------------------------------------------------- fluid blocks ---

TEST(SceneFluidBlock, NoBlocks) {
  json j = baseScene2D();
  j["fluid_blocks"] = json::array();
  expectError(j, "fluid_blocks", {"no liquid"});
}

TEST(SceneFluidBlock, MissingBlocks) {
  json j = baseScene2D();
  j.erase("fluid_blocks");
  expectError(j, "fluid_blocks", {"missing"});
}

TEST(SceneFluidBlock, MinNotBelowMax) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["max"] = {0.5, 0};
  expectError(j, "fluid_blocks[0]", {"min[1]"});
}

TEST(SceneFluidBlock, OutsideDomain) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["max"] = {2.5, 1};
  expectError(j, "fluid_blocks[0].max[0]", {"outside the domain", "[0, 2]"});
}

TEST(SceneFluidBlock, BelowDomain) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["min"] = {0, -0.1};
  expectError(j, "fluid_blocks[0].min[1]", {"outside the domain"});
}

TEST(SceneFluidBlock, OnDomainFaceWithinTolerance) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["min"] = {-1e-7, 0};
  EXPECT_NO_THROW(parseScene<2>(j));
}

TEST(SceneFluidBlock, ThinnerThanAParticle) {
  json j = baseScene2D();
  j["fluid_blocks"][0]["max"] = {0.05, 1};  // 0.05 m < one diameter (0.1 m)
  expectError(j, "fluid_blocks[0]", {"no particle"});
}

TEST(SceneFluidBlock, OverlappingBlocks) {
  json j = baseScene2D();
  j["fluid_blocks"].push_back({{"min", {0.25, 0.5}}, {"max", {1, 1.5}}});
  expectError(j, "fluid_blocks[1]", {"overlaps fluid_blocks[0]"});
}

TEST(SceneFluidBlock, TouchingBlocksAreFine) {
  json j = baseScene2D();
  j["fluid_blocks"].push_back({{"min", {0.5, 0}}, {"max", {1, 1}}});
  const auto s = parseScene<2>(j);
  EXPECT_EQ(fluidParticles(s), 2u * 5u * 10u);
}

TEST(SceneFluidBlock, InsideObstacle) {
  json j = baseScene2D();
  j["obstacles"][0] = {{"type", "box"}, {"min", {0.2, 0.2}}, {"max", {0.3, 0.3}}};
  expectError(j, "fluid_blocks[0]", {"inside obstacles[0]"});
}

TEST(SceneFluidBlock, WithinOneRadiusOfSphere) {
  json j = baseScene2D();
  // Nearest particle centre is at (0.45, 0.95): 0.03 m from a disk of radius
  // 0.2 centred 0.23 m away, closer than the particle radius 0.05 m.
  j["obstacles"][0] = {{"type", "disk"}, {"center", {0.45 + 0.23, 0.95}}, {"radius", 0.2}};
  expectError(j, "fluid_blocks[0]", {"obstacles[0]", "closer than particle_radius"});
}

TEST(SceneFluidBlock, TouchingObstacleFaceIsFine) {
  json j = baseScene2D();
  j["obstacles"][0] = {{"type", "box"}, {"min", {0.5, 0}}, {"max", {0.8, 0.5}}};
  EXPECT_NO_THROW(parseScene<2>(j));
}

TEST(SceneFluidBlock, TooManyParticles) {
  json j = baseScene2D();
  j["max_particles"] = 20;  // the block holds 5 x 10 = 50
  expectError(j, "fluid_blocks", {"50", "20", "max_particles"});
}

TEST(SceneFluidBlock, OverrideCountsAgainstMaxParticles) {
  json j = baseScene2D();
  j["max_particles"] = 50;
  EXPECT_NO_THROW(parseScene<2>(j));
  try {
    parseScene<2>(j, 0.025);
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "fluid_blocks");
    EXPECT_NE(std::string(e.what()).find("200"), std::string::npos) << e.what();
  }
}

// ------------------------------------------------------------- obstacles ---

TEST(SceneObstacle, SphereRadiusMustBePositive) {
  json j = baseScene2D();
  j["obstacles"][0] = {{"type", "sphere"}, {"center", {1.5, 1.5}}, {"radius", 0}};
  expectError(j, "obstacles[0].radius", {"> 0"});
}

TEST(SceneObstacle, UnknownType) {
  json j = baseScene2D();
  j["obstacles"][0]["type"] = "cylinder";
  expectError(j, "obstacles[0].type", {"box", "sphere"});
}

TEST(SceneObstacle, DiskIsTwoDimensionalOnly) {
  json j = baseScene3D();
  j["obstacles"] = json::array({{{"type", "disk"}, {"center", {1.5, 1.5, 0.5}}, {"radius", 0.2}}});
  expectError<3>(j, "obstacles[0].type", {"2D only"});
}

TEST(SceneObstacle, BoxMinNotBelowMax) {
  json j = baseScene2D();
  j["obstacles"][0]["max"] = {1.5, 0.5};
  expectError(j, "obstacles[0]", {"min[0]"});
}

// ------------------------------------------------------ solver and effects ---

TEST(SceneSolver, UnknownMethod) {
  json j = baseScene2D();
  j["solver"]["method"] = "pcisph";
  expectError(j, "solver.method", {"pcisph", "dfsph", "wcsph"});
}

TEST(SceneSolver, DefaultsToDfsph) {
  json j = baseScene2D();
  j.erase("solver");
  const auto s = parseScene<2>(j);
  EXPECT_EQ(s.solver.name, "dfsph");
  EXPECT_TRUE(s.solver.values.has("density_tolerance_pct"));
}

TEST(SceneEffect, UnknownEffect) {
  json j = baseScene2D();
  j["effects"][0] = "viscosity";
  expectError(j, "effects[0]", {"viscosity_standard", "viscosity_xsph"});
}

TEST(SceneEffect, UnknownEffectInObjectForm) {
  json j = baseScene2D();
  j["effects"][1]["name"] = "surface_tension_magic";
  expectError(j, "effects[1].name", {"surface_tension_magic"});
}

TEST(SceneEffect, DuplicateEffect) {
  json j = baseScene2D();
  j["effects"][1] = "viscosity_standard";
  expectError(j, "effects[1]", {"duplicate", "effects[0]"});
}

TEST(SceneEffect, ObjectFormWithoutName) {
  json j = baseScene2D();
  j["effects"][1].erase("name");
  expectError(j, "effects[1].name", {"missing"});
}

TEST(SceneEffect, ParamsAreRead) {
  json j = baseScene2D();
  j["effects"][1]["coefficient"] = 0.2;
  const auto s = parseScene<2>(j);
  ASSERT_EQ(s.effects.size(), 2u);
  EXPECT_EQ(s.effects[0].name, "viscosity_standard");
  EXPECT_EQ(s.effects[1].name, "viscosity_xsph");
  EXPECT_DOUBLE_EQ(s.effects[1].values.get("coefficient"), 0.2);
}

// -------------------------------------------------------------- defaults ---

TEST(SceneDefaults, AbsentKeysGetDefaults) {
  const auto s = parseScene<3>(baseScene3D());
  EXPECT_EQ(s.name, "scene");
  EXPECT_EQ(s.gravity, Vec3(0, Real(-9.81), 0));
  ASSERT_EQ(s.phases.size(), 1u);
  EXPECT_EQ(s.phases[0].name, "water");
  EXPECT_EQ(s.fluidBlocks[0].phase, 0);
  EXPECT_EQ(s.solver.name, "dfsph");
  EXPECT_TRUE(s.effects.empty());
  EXPECT_TRUE(s.obstacles.empty());
  EXPECT_DOUBLE_EQ(s.settings.frameRate, 60);
  EXPECT_DOUBLE_EQ(s.duration, 2);
  EXPECT_EQ(s.maxParticles, 2000000u);
}

TEST(SceneDefaults, ZeroGravityAllowed) {
  json j = baseScene2D();
  j["gravity"] = {0, 0};
  EXPECT_EQ(parseScene<2>(j).gravity, Vec2::Zero());
}

// -------------------------------------------------- shipped scene files ---

template <int D>
void checkRoundTrip(const SimulationSetup<D>& a, const std::string& label) {
  const json saved = sceneToJson(a);
  const SimulationSetup<D> b = parseScene<D>(saved);
  EXPECT_EQ(a.name, b.name) << label;
  EXPECT_EQ(a.particleRadius, b.particleRadius) << label;
  EXPECT_EQ(a.domain.min, b.domain.min) << label;
  EXPECT_EQ(a.domain.max, b.domain.max) << label;
  EXPECT_EQ(a.gravity, b.gravity) << label;
  EXPECT_EQ(a.duration, b.duration) << label;
  EXPECT_EQ(a.maxParticles, b.maxParticles) << label;
  ASSERT_EQ(a.phases.size(), b.phases.size()) << label;
  for (size_t i = 0; i < a.phases.size(); ++i) {
    EXPECT_EQ(a.phases[i].name, b.phases[i].name) << label;
    EXPECT_EQ(a.phases[i].restDensity, b.phases[i].restDensity) << label;
    EXPECT_EQ(a.phases[i].viscosity, b.phases[i].viscosity) << label;
    EXPECT_EQ(a.phases[i].color, b.phases[i].color) << label;
  }
  ASSERT_EQ(a.fluidBlocks.size(), b.fluidBlocks.size()) << label;
  for (size_t i = 0; i < a.fluidBlocks.size(); ++i) {
    EXPECT_EQ(a.fluidBlocks[i].box.min, b.fluidBlocks[i].box.min) << label;
    EXPECT_EQ(a.fluidBlocks[i].box.max, b.fluidBlocks[i].box.max) << label;
    EXPECT_EQ(a.fluidBlocks[i].phase, b.fluidBlocks[i].phase) << label;
    EXPECT_EQ(a.fluidBlocks[i].velocity, b.fluidBlocks[i].velocity) << label;
  }
  ASSERT_EQ(a.obstacles.size(), b.obstacles.size()) << label;
  for (size_t i = 0; i < a.obstacles.size(); ++i) {
    EXPECT_EQ(a.obstacles[i].shape, b.obstacles[i].shape) << label;
    EXPECT_EQ(a.obstacles[i].box.min, b.obstacles[i].box.min) << label;
    EXPECT_EQ(a.obstacles[i].box.max, b.obstacles[i].box.max) << label;
    EXPECT_EQ(a.obstacles[i].center, b.obstacles[i].center) << label;
    EXPECT_EQ(a.obstacles[i].radius, b.obstacles[i].radius) << label;
    EXPECT_EQ(a.obstacles[i].placement.file, b.obstacles[i].placement.file) << label;
    EXPECT_EQ(a.obstacles[i].placement.scale, b.obstacles[i].placement.scale) << label;
    EXPECT_EQ(a.obstacles[i].placement.translation, b.obstacles[i].placement.translation) << label;
    EXPECT_EQ(a.obstacles[i].placement.rotationDeg, b.obstacles[i].placement.rotationDeg) << label;
  }
  EXPECT_EQ(a.solver.name, b.solver.name) << label;
  EXPECT_EQ(a.solver.values.all(), b.solver.values.all()) << label;
  EXPECT_TRUE(a.settings == b.settings) << label;
  ASSERT_EQ(a.effects.size(), b.effects.size()) << label;
  for (size_t i = 0; i < a.effects.size(); ++i) {
    EXPECT_EQ(a.effects[i].name, b.effects[i].name) << label;
    EXPECT_EQ(a.effects[i].values.all(), b.effects[i].values.all()) << label;
  }
  // Saving is a fixed point: the second save writes exactly the first.
  EXPECT_EQ(saved, sceneToJson(b)) << label;
}

TEST(SceneFiles, EveryShippedSceneParsesAndRoundTrips) {
  const auto files = sceneFiles();
  ASSERT_GE(files.size(), 8u) << "scenes/ and scenes/bench/ should hold the demo and benchmark scenes";
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    json j;
    ASSERT_NO_THROW(j = loadSceneJson(f.string()));
    try {
      if (sceneDimension(j) == 2) {
        const auto s = parseScene<2>(j);
        EXPECT_TRUE(fluidParticles(s) > 0 || !s.emitters.empty()) << "no liquid and no emitter";
        checkRoundTrip(s, f.string());
      } else {
        const auto s = parseScene<3>(j);
        EXPECT_TRUE(fluidParticles(s) > 0 || !s.emitters.empty()) << "no liquid and no emitter";
        checkRoundTrip(s, f.string());
      }
    } catch (const SceneError& e) {
      ADD_FAILURE() << f << ": " << e.what();
    }
  }
}

TEST(SceneFiles, RoundTripWithObstaclesPhasesAndEffectParams) {
  json j = baseScene2D();
  j["phases"].push_back({{"name", "oil"}, {"rest_density", 800}, {"color", {1, 0.8, 0.1}}});
  j["fluid_blocks"].push_back({{"min", {0.5, 0}}, {"max", {1, 0.5}}, {"phase", "oil"}, {"velocity", {1, 0}}});
  j["obstacles"].push_back({{"type", "disk"}, {"center", {1.2, 1.5}}, {"radius", 0.25}});
  j["settings"]["reorder_interval"] = 7;
  j["solver"]["divergence_solve"] = false;
  checkRoundTrip(parseScene<2>(j), "2D");
  json k = baseScene3D();
  k["obstacles"] = json::array({{{"type", "sphere"}, {"center", {1.5, 1, 0.5}}, {"radius", 0.3}}});
  k["solver"] = {{"method", "wcsph"}, {"stiffness", 1e5}};
  checkRoundTrip(parseScene<3>(k), "3D");
}

TEST(SceneFiles, ExpectedResolutions) {
  auto count2 = [](const char* name) { return fluidParticles(parseScene<2>(loadSceneJson(sceneDir() + "/" + name))); };
  auto count3 = [](const char* name) { return fluidParticles(parseScene<3>(loadSceneJson(sceneDir() + "/" + name))); };
  EXPECT_EQ(count2("dambreak2d.json"), 5000u);
  EXPECT_EQ(count3("dambreak3d.json"), 31250u);
  EXPECT_EQ(count2("hydrostatic2d.json"), 2500u);
  EXPECT_EQ(count3("hydrostatic3d.json"), 3375u);
  EXPECT_EQ(count3("bench/dambreak3d_r010.json"), 117649u);  // 49^3, as SPlisHSPlasH samples it
  EXPECT_EQ(count3("bench/dambreak3d_r0125.json"), 59319u);  // 39^3
  EXPECT_EQ(count2("bench/dambreak2d_r010.json"), 5476u);  // 74^2
  EXPECT_EQ(count2("bench/dambreak2d_r005.json"), 22201u);  // 149^2
}

TEST(SceneFiles, HalvingTheRadiusMultipliesTheCountByTwoToTheD) {
  const json j2 = loadSceneJson(sceneDir() + "/dambreak2d.json");
  const auto a2 = parseScene<2>(j2);
  const auto b2 = parseScene<2>(j2, a2.particleRadius / 2);
  EXPECT_FLOAT_EQ(b2.particleRadius, a2.particleRadius / 2);
  EXPECT_NEAR(double(fluidParticles(b2)) / double(fluidParticles(a2)), 4.0, 0.2);

  const json j3 = loadSceneJson(sceneDir() + "/dambreak3d.json");
  const auto a3 = parseScene<3>(j3);
  const auto b3 = parseScene<3>(j3, a3.particleRadius / 2);
  EXPECT_NEAR(double(fluidParticles(b3)) / double(fluidParticles(a3)), 8.0, 0.4);
}

// ------------------------------------------------------------ documentation ---

std::string readText(const std::string& file) {
  std::ifstream in(file);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(SceneDocs, ExampleParses) {
  const std::string doc = readText(sceneDir() + "/README.md");
  const size_t section = doc.find("## Example");
  ASSERT_NE(section, std::string::npos);
  const size_t begin = doc.find("```json\n", section);
  ASSERT_NE(begin, std::string::npos);
  const size_t end = doc.find("```", begin + 8);
  const json j = parseSceneText(doc.substr(begin + 8, end - begin - 8), "README example");
  const auto s = parseScene<2>(j);
  EXPECT_EQ(s.obstacles.size(), 1u);
}

}  // namespace
}  // namespace fc

namespace fc {
namespace {

TEST(SceneCamera, IsReadCheckedAndSavedBack) {
  json s = baseScene2D();
  s["camera"] = {{"position", {1, 0.8, 2.5}}, {"target", {1, 0.5, 0}}, {"lens_mm", 35}};
  const SimulationSetup<2> setup = parseScene<2>(s);
  ASSERT_TRUE(setup.camera.set);
  EXPECT_EQ(setup.camera.position, (std::array<double, 3>{1, 0.8, 2.5}));
  EXPECT_EQ(setup.camera.target, (std::array<double, 3>{1, 0.5, 0}));
  EXPECT_EQ(setup.camera.lensMm, 35);
  EXPECT_EQ(sceneToJson(setup)["camera"], s["camera"]);
  EXPECT_FALSE(sceneToJson(parseScene<2>(baseScene2D())).contains("camera"));

  json bad = s;
  bad["camera"]["position"] = {1, 0.8};  // 3D in every scene
  expectError(bad, "camera.position", {"3 components"});
  bad = s;
  bad["camera"]["target"] = bad["camera"]["position"];
  expectError(bad, "camera.target", {"must differ"});
  bad = s;
  bad["camera"]["lens_mm"] = 1;
  expectError(bad, "camera.lens_mm", {"[5, 500]"});
  bad = s;
  bad["camera"]["fov"] = 40;
  expectError(bad, "camera.fov");
  bad = s;
  bad["camera"].erase("target");
  expectError(bad, "camera.target");
}

TEST(SceneCamera, EveryGalleryScenesCameraLooksAtItsLiquid) {
  // The camera's target lies inside the domain and the camera outside the liquid's blocks.
  for (const auto& path : sceneFiles()) {
    const json j = loadSceneJson(path.string());
    if (!j.contains("camera")) continue;
    const auto& c = j["camera"];
    const int dim = j["dimension"];
    for (int d = 0; d < dim; ++d) {
      EXPECT_GE(double(c["target"][d]), double(j["domain"]["min"][d])) << path;
      EXPECT_LE(double(c["target"][d]), double(j["domain"]["max"][d])) << path;
    }
    if (dim == 2) EXPECT_GT(double(c["position"][2]), 0.0) << path << ": a 2D scene is seen from +z";
  }
}

}  // namespace
}  // namespace fc

namespace fc {
namespace {

TEST(SceneScale, IsReadCheckedAndSavedBack) {
  json s = baseScene2D();
  s["scales"] = {{"paper", {{"particle_radius", 0.004}}}, {"final", {{"particle_radius", 0.002}, {"max_particles", 900000}}}};
  const SimulationSetup<2> setup = parseScene<2>(s);
  ASSERT_EQ(setup.scales.size(), 2u);
  EXPECT_EQ(setup.scales.at("paper").particleRadius, 0.004);
  EXPECT_EQ(setup.scales.at("paper").maxParticles, 0u);
  EXPECT_EQ(setup.scales.at("final").maxParticles, 900000u);
  EXPECT_EQ(sceneToJson(setup)["scales"], s["scales"]);
  EXPECT_FALSE(sceneToJson(parseScene<2>(baseScene2D())).contains("scales"));
  // The scene itself runs at its own radius: a scale is only a name until asked for.
  EXPECT_EQ(setup.particleRadius, Real(baseScene2D()["particle_radius"].get<double>()));

  json bad = s;
  bad["scales"]["paper"]["particle_radius"] = -1;
  expectError(bad, "scales.paper.particle_radius", {"> 0"});
  bad = s;
  bad["scales"]["paper"].erase("particle_radius");
  expectError(bad, "scales.paper.particle_radius");
  bad = s;
  bad["scales"]["paper"]["frames"] = 3;
  expectError(bad, "scales.paper.frames");
  bad = s;
  bad["scales"]["final"]["max_particles"] = 0;
  expectError(bad, "scales.final.max_particles", {"[1, "});
  bad = s;
  bad["scales"]["Paper Scale"] = {{"particle_radius", 0.004}};
  expectError(bad, "scales.Paper Scale", {"a-z"});
  bad = s;
  bad["scales"] = 3;
  expectError(bad, "scales");
}

TEST(SceneScale, ApplyingOneGivesAPlainSceneAtItsResolution) {
  json s = baseScene2D();
  s["scales"] = {{"fine", {{"particle_radius", 0.5 * s["particle_radius"].get<double>()}}},
                 {"huge", {{"particle_radius", 0.0005}, {"max_particles", 3}}}};
  const SimulationSetup<2> base = parseScene<2>(s);
  const SimulationSetup<2> fine = parseScene<2>(applySceneScale(s, "fine"));
  EXPECT_EQ(fine.particleRadius, base.particleRadius / 2);
  EXPECT_EQ(sceneToJson(parseScene<2>(s, 0.5 * s["particle_radius"].get<double>())), sceneToJson(fine))
      << "a scale is the same scene as --particle-radius with its value";
  // Its particle cap is checked like the scene's own.
  expectError(applySceneScale(s, "huge"), "fluid_blocks", {"max_particles = 3"});
  try {
    applySceneScale(s, "paper");
    FAIL() << "an unknown scale must be refused";
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "scales.paper");
    EXPECT_NE(std::string(e.what()).find("fine, huge"), std::string::npos) << e.what();
  }
  try {
    applySceneScale(baseScene2D(), "paper");
    FAIL() << "a scene without scales has none to apply";
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("names none"), std::string::npos) << e.what();
  }
}

// A scale may play templates recorded at another resolution than the
// recipe's scale of the same name: the boat plays its own, finer hand.
TEST(SceneScale, AScaleMayNameTheFolderOfTheTemplatesItPlays) {
  json s = baseScene2D();
  const double r = s["particle_radius"].get<double>();
  s["scales"] = {{"fine", {{"particle_radius", 0.5 * r}}},
                 {"paper", {{"particle_radius", 0.5 * r}, {"templates", "paper-boat"}}}};
  const SimulationSetup<2> setup = parseScene<2>(s);
  EXPECT_EQ(setup.scales.at("paper").templates, "paper-boat");
  EXPECT_EQ(setup.scales.at("fine").templates, "");
  EXPECT_EQ(std::filesystem::path(scaledTemplatesDir("templates", s, "paper")), std::filesystem::path("templates/paper-boat"));
  EXPECT_EQ(std::filesystem::path(scaledTemplatesDir("templates", s, "fine")), std::filesystem::path("templates/fine"));
  EXPECT_EQ(sceneToJson(parseScene<2>(applySceneScale(s, "paper"))), sceneToJson(parseScene<2>(applySceneScale(s, "fine"))))
      << "the folder changes where templates come from, not the scene";
  // A folder is one name under the templates directory, never a path out of it.
  for (const json& bad : {json("../etc"), json(""), json("Paper"), json("a/b"), json(3)}) {
    json b = s;
    b["scales"]["paper"]["templates"] = bad;
    expectError(b, "scales.paper.templates");
    try {
      scaledTemplatesDir("templates", b, "paper");
      FAIL() << bad.dump() << " must be refused";
    } catch (const SceneError& e) {
      EXPECT_EQ(e.path, "scales.paper.templates") << bad.dump();
    }
  }
}

// The scenes of the paper's Table 1 carry its resolution as the scale
// "paper": their fluid blocks then hold the paper's liquid count (every one
// of them starts with its liquid in blocks).
TEST(SceneScale, ShippedPaperScalesSeedThePapersLiquid) {
  const std::map<std::string, double> paperLiquid = {
      {"drop2d", 6.7e3},     {"wave2d", 6.7e3},     {"blade2d", 2.2e3},   {"waterjet2d", 6.7e3},
      {"zero_gravity2d", 6.7e3}, {"doubledam2d", 6.7e3}, {"viscous3d", 298.7e3}, {"blade3d", 56.2e3},
      {"letters3d", 298.7e3}, {"multiphase3d", 106.4e3}, {"boat3d", 2.49e6}, {"composition3d", 298.7e3}};
  for (const auto& [name, liquid] : paperLiquid) {
    const json j = loadSceneJson(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/" + name + ".json");
    ASSERT_TRUE(j.contains("scales") && j["scales"].contains("paper")) << name << " has no paper scale";
    const json scaled = applySceneScale(j, "paper");
    size_t seeded = 0;
    if (j["dimension"] == 2) {
      const auto s = parseScene<2>(scaled);
      for (const auto& b : s.fluidBlocks) seeded += latticeCount(b.box, 2 * s.particleRadius);
    } else {
      const auto s = parseScene<3>(scaled);
      for (const auto& b : s.fluidBlocks) seeded += latticeCount(b.box, 2 * s.particleRadius);
    }
    const double ratio = double(seeded) / liquid;
    std::printf("[ measured ] %s at scale paper: %zu particles in its blocks, %.3f of the paper's liquid\n",
                name.c_str(), seeded, ratio);
    EXPECT_NEAR(ratio, 1.0, 0.1) << name;
  }
}

}  // namespace
}  // namespace fc
