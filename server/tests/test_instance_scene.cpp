// Scene "control" and "instances" keys (io/scene.h parseSceneControl,
// sceneControlToJson) and binding instances to templates
// (io/instance_binding.h): every invalid input is a SceneError naming the key
// path; valid instances parse to the expected specs with the documented
// defaults and survive a save/load round trip; binding shares templates.
#include "io/instance_binding.h"
#include "io/scene.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include "tests/hdf5_test_util.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <limits>
#include <string>
#include <vector>

namespace fc {
namespace {

using nlohmann::json;
using fc::test::TempDir;

const double kInf = std::numeric_limits<double>::infinity();

std::vector<Phase> twoPhases() {
  Phase water;
  water.name = "water";
  Phase ink;
  ink.name = "ink";
  return {water, ink};
}

// A scene holding one instance `inst` (and nothing else of control).
json sceneWith(const json& inst, int dimension = 2) {
  return json{{"dimension", dimension}, {"instances", json::array({inst})}};
}

std::vector<std::string> kInstanceKeysForDocs() {
  return {"name", "template", "phase", "transform", "start", "crop_begin", "crop_end", "speed", "reverse"};
}

json minimal2D() { return json{{"template", "drop2d"}}; }

json full2D() {
  return json::parse(R"({
    "name": "splash",
    "template": "drop2d",
    "phase": "ink",
    "transform": [
      {"time": 0, "translation": [0.5, 1.0], "rotation": 30, "scale": 2, "reflect": [true, false]},
      {"time": 1.5, "translation": [1.5, 0.25], "rotation": -45.5, "scale": [0.5, 3]}
    ],
    "start": 0.25, "crop_begin": 0.1, "crop_end": 0.8, "speed": 1.5, "reverse": true,
    "attraction_weight": 0.5, "velocity_weight": 0.07, "repulsion_weight": 0.3,
    "repulsion": false, "temporary_particles": false,
    "seed_threshold": 0.4, "removal_threshold": 0.45, "seed_distance": 0.6,
    "falloff_width": 0.1, "falloff_decay": 2
  })");
}

json full3D() {
  return json::parse(R"({
    "name": "wave",
    "template": "wave3d",
    "transform": [
      {"time": 0.5, "translation": [1, 2, 3], "rotation": [10, 20, 30], "scale": [1, 2, 0.5],
       "reflect": [false, true, true]}
    ],
    "start": 2, "crop_begin": 0.5, "speed": 0.5,
    "attraction_weight": 0.1, "temporary_particles": false, "falloff_width": 0.2
  })");
}

// Runs `parse` expecting a SceneError at `path` whose what() starts with the
// path and contains every fragment of `mentions`.
template <class F>
void expectSceneError(F&& parse, const std::string& path, const std::vector<std::string>& mentions = {}) {
  try {
    parse();
    ADD_FAILURE() << "expected SceneError at '" << path << "'";
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, path) << e.what();
    const std::string what = e.what();
    if (!path.empty()) {
      EXPECT_EQ(what.rfind(path + ": ", 0), 0u) << "what() must start with the path: " << what;
    }
    for (const auto& m : mentions) EXPECT_NE(what.find(m), std::string::npos) << "'" << m << "' missing in: " << what;
  }
}

template <int D = 2>
void expectError(const json& scene, const std::string& path, const std::vector<std::string>& mentions = {}) {
  SCOPED_TRACE(scene.dump());
  expectSceneError([&] { parseSceneControl<D>(scene, twoPhases()); }, path, mentions);
}

// The same instance with one key replaced (or removed when value is null).
json with(json inst, const std::string& k, const json& value) {
  if (value.is_null())
    inst.erase(k);
  else
    inst[k] = value;
  return inst;
}

template <int D>
void expectSpecEqual(const InstanceSpec<D>& a, const InstanceSpec<D>& b) {
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.templateName, b.templateName);
  EXPECT_EQ(a.phase, b.phase);
  EXPECT_EQ(a.time.start, b.time.start);
  EXPECT_EQ(a.time.cropBegin, b.time.cropBegin);
  EXPECT_EQ(a.time.cropEnd, b.time.cropEnd);
  EXPECT_EQ(a.time.speed, b.time.speed);
  EXPECT_EQ(a.time.reverse, b.time.reverse);
  EXPECT_TRUE(a.params == b.params);
  ASSERT_EQ(a.transform.keys.size(), b.transform.keys.size());
  for (size_t k = 0; k < a.transform.keys.size(); ++k) {
    const auto& ka = a.transform.keys[k];
    const auto& kb = b.transform.keys[k];
    EXPECT_EQ(ka.time, kb.time);
    EXPECT_EQ(ka.translation, kb.translation);
    EXPECT_EQ(ka.rotationDeg, kb.rotationDeg);
    EXPECT_EQ(ka.scale, kb.scale);
    EXPECT_EQ(ka.reflect, kb.reflect);
  }
}

// ------------------------------------------------------------- valid input ---

TEST(InstanceSceneParse, AbsentKeysGiveNoInstancesAndDefaultSettings) {
  const auto c = parseSceneControl<2>(json{{"dimension", 2}}, twoPhases());
  EXPECT_TRUE(c.instances.empty());
  EXPECT_TRUE(c.settings == controlSettingsTable().defaults());
  EXPECT_EQ(c.settings.temporaryGraceFrames, 60);
  EXPECT_FALSE(c.settings.forcesEverySubstep);
}

TEST(InstanceSceneParse, ControlSettings) {
  const json j = {{"control", {{"forces_every_substep", true}, {"temporary_grace_frames", 12}}}};
  const auto c = parseSceneControl<2>(j, twoPhases());
  EXPECT_TRUE(c.settings.forcesEverySubstep);
  EXPECT_EQ(c.settings.temporaryGraceFrames, 12);
  EXPECT_EQ(c.settings.fidelityCell, 4);  // default kept
}

TEST(InstanceSceneParse, Defaults2D) {
  const auto c = parseSceneControl<2>(sceneWith(minimal2D()), twoPhases());
  ASSERT_EQ(c.instances.size(), 1u);
  const InstanceSpec<2>& s = c.instances[0];
  EXPECT_EQ(s.name, "drop2d");
  EXPECT_EQ(s.templateName, "drop2d");
  EXPECT_EQ(s.phase, 0);
  EXPECT_TRUE(s.transform.keys.empty());
  EXPECT_EQ(s.time.start, 0);
  EXPECT_EQ(s.time.cropBegin, 0);
  EXPECT_EQ(s.time.cropEnd, -1);
  EXPECT_EQ(s.time.speed, 1);
  EXPECT_FALSE(s.time.reverse);
  EXPECT_TRUE(s.params == instanceParamTable(2).defaults());
  EXPECT_DOUBLE_EQ(s.params.attractionWeight, 0.2);
  EXPECT_DOUBLE_EQ(s.params.velocityWeight, 0.03);
  EXPECT_DOUBLE_EQ(s.params.repulsionWeight, 0.1);
  EXPECT_TRUE(s.params.repulsion);
  EXPECT_TRUE(s.params.temporaryParticles);
}

TEST(InstanceSceneParse, Defaults3D) {
  const auto c = parseSceneControl<3>(sceneWith(json{{"template", "wave3d"}}, 3), twoPhases());
  ASSERT_EQ(c.instances.size(), 1u);
  const InstanceSpec<3>& s = c.instances[0];
  EXPECT_EQ(s.name, "wave3d");
  EXPECT_TRUE(s.params == instanceParamTable(3).defaults());
  EXPECT_DOUBLE_EQ(s.params.attractionWeight, 0.06);
  EXPECT_DOUBLE_EQ(s.params.velocityWeight, 0.01);
  EXPECT_DOUBLE_EQ(s.params.repulsionWeight, 0.04);
}

TEST(InstanceSceneParse, Full2D) {
  const auto c = parseSceneControl<2>(sceneWith(full2D()), twoPhases());
  ASSERT_EQ(c.instances.size(), 1u);
  const InstanceSpec<2>& s = c.instances[0];
  EXPECT_EQ(s.name, "splash");
  EXPECT_EQ(s.templateName, "drop2d");
  EXPECT_EQ(s.phase, 1);
  ASSERT_EQ(s.transform.keys.size(), 2u);
  const auto& k0 = s.transform.keys[0];
  EXPECT_EQ(k0.time, 0);
  EXPECT_EQ(k0.translation, Eigen::Vector2d(0.5, 1.0));
  EXPECT_EQ(k0.rotationDeg[0], 30);
  EXPECT_EQ(k0.scale, Eigen::Vector2d(2, 2));
  EXPECT_EQ(k0.reflect, (std::array<bool, 2>{true, false}));
  const auto& k1 = s.transform.keys[1];
  EXPECT_EQ(k1.time, 1.5);
  EXPECT_EQ(k1.translation, Eigen::Vector2d(1.5, 0.25));
  EXPECT_EQ(k1.rotationDeg[0], -45.5);
  EXPECT_EQ(k1.scale, Eigen::Vector2d(0.5, 3));
  EXPECT_EQ(k1.reflect, (std::array<bool, 2>{false, false}));
  EXPECT_EQ(s.time.start, 0.25);
  EXPECT_EQ(s.time.cropBegin, 0.1);
  EXPECT_EQ(s.time.cropEnd, 0.8);
  EXPECT_EQ(s.time.speed, 1.5);
  EXPECT_TRUE(s.time.reverse);
  EXPECT_EQ(s.params.attractionWeight, 0.5);
  EXPECT_EQ(s.params.velocityWeight, 0.07);
  EXPECT_EQ(s.params.repulsionWeight, 0.3);
  EXPECT_FALSE(s.params.repulsion);
  EXPECT_FALSE(s.params.temporaryParticles);
  EXPECT_EQ(s.params.seedThreshold, 0.4);
  EXPECT_EQ(s.params.removalThreshold, 0.45);
  EXPECT_EQ(s.params.seedDistance, 0.6);
  EXPECT_EQ(s.params.falloffWidth, 0.1);
  EXPECT_EQ(s.params.falloffDecay, 2);
}

TEST(InstanceSceneParse, Full3D) {
  const auto c = parseSceneControl<3>(sceneWith(full3D(), 3), twoPhases());
  ASSERT_EQ(c.instances.size(), 1u);
  const InstanceSpec<3>& s = c.instances[0];
  EXPECT_EQ(s.name, "wave");
  EXPECT_EQ(s.templateName, "wave3d");
  EXPECT_EQ(s.phase, 0);
  ASSERT_EQ(s.transform.keys.size(), 1u);
  const auto& k = s.transform.keys[0];
  EXPECT_EQ(k.time, 0.5);
  EXPECT_EQ(k.translation, Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(k.rotationDeg, (std::array<double, 3>{10, 20, 30}));
  EXPECT_EQ(k.scale, Eigen::Vector3d(1, 2, 0.5));
  EXPECT_EQ(k.reflect, (std::array<bool, 3>{false, true, true}));
  EXPECT_EQ(s.time.start, 2);
  EXPECT_EQ(s.time.cropBegin, 0.5);
  EXPECT_EQ(s.time.cropEnd, -1);
  EXPECT_EQ(s.time.speed, 0.5);
  EXPECT_FALSE(s.time.reverse);
  EXPECT_EQ(s.params.attractionWeight, 0.1);
  EXPECT_DOUBLE_EQ(s.params.velocityWeight, 0.01);   // 3D default
  EXPECT_DOUBLE_EQ(s.params.repulsionWeight, 0.04);  // 3D default
  EXPECT_FALSE(s.params.temporaryParticles);
  EXPECT_EQ(s.params.falloffWidth, 0.2);
}

TEST(InstanceSceneParse, TransformKeyDefaults) {
  const auto c = parseSceneControl<3>(
      sceneWith(json{{"template", "t"}, {"transform", json::parse(R"([{"translation": [1, 2, 3]}])")}}, 3),
      twoPhases());
  const auto& k = c.instances[0].transform.keys.at(0);
  EXPECT_EQ(k.time, 0);
  EXPECT_EQ(k.rotationDeg, (std::array<double, 3>{0, 0, 0}));
  EXPECT_EQ(k.scale, Eigen::Vector3d(1, 1, 1));
  EXPECT_EQ(k.reflect, (std::array<bool, 3>{false, false, false}));
}

TEST(InstanceSceneParse, DefaultNamesAreUnique) {
  // Unnamed instances take the template's name, then "<template>-<k>",
  // skipping names written explicitly (even by a later instance).
  const json j = {{"instances", json::array({minimal2D(), minimal2D(), json{{"template", "other"}},
                                              json{{"template", "x"}, {"name", "drop2d-2"}}, minimal2D()})}};
  const auto c = parseSceneControl<2>(j, twoPhases());
  ASSERT_EQ(c.instances.size(), 5u);
  EXPECT_EQ(c.instances[0].name, "drop2d");
  EXPECT_EQ(c.instances[1].name, "drop2d-3");
  EXPECT_EQ(c.instances[2].name, "other");
  EXPECT_EQ(c.instances[3].name, "drop2d-2");
  EXPECT_EQ(c.instances[4].name, "drop2d-4");
}

TEST(InstanceSceneParse, ParseSceneAcceptsControlKeys) {
  json scene = json::parse(R"({
    "dimension": 2, "particle_radius": 0.05,
    "domain": {"min": [0, 0], "max": [2, 2]},
    "phases": [{"name": "water"}, {"name": "ink"}],
    "fluid_blocks": [{"min": [0, 0], "max": [0.5, 1]}]
  })");
  scene["control"] = {{"temporary_grace_frames", 30}};
  scene["instances"] = json::array({full2D()});
  const auto setup = parseScene<2>(scene);
  const auto c = parseSceneControl<2>(scene, setup.phases);
  EXPECT_EQ(c.instances.at(0).phase, 1);
  EXPECT_EQ(c.settings.temporaryGraceFrames, 30);
}

TEST(InstanceSceneParse, RoundTrip2D) {
  json j = {{"control", {{"forces_every_substep", true}, {"fidelity_cell", 3}}},
            {"instances", json::array({full2D(), minimal2D(), minimal2D()})}};
  const auto a = parseSceneControl<2>(j, twoPhases());
  const json saved = sceneControlToJson<2>(a, twoPhases());
  ASSERT_TRUE(saved.contains("control"));
  ASSERT_TRUE(saved.contains("instances"));
  // Every key is written (crop_end only when set).
  for (const auto& s : instanceParamSpecs(2)) EXPECT_TRUE(saved["instances"][0].contains(s.name)) << s.name;
  for (const auto& s : controlSettingsSpecs()) EXPECT_TRUE(saved["control"].contains(s.name)) << s.name;
  for (const char* k : {"name", "template", "phase", "transform", "start", "crop_begin", "speed", "reverse"})
    EXPECT_TRUE(saved["instances"][1].contains(k)) << k;
  EXPECT_TRUE(saved["instances"][0].contains("crop_end"));
  EXPECT_FALSE(saved["instances"][1].contains("crop_end"));
  EXPECT_EQ(saved["instances"][0]["phase"], "ink");
  EXPECT_EQ(saved["instances"][0]["repulsion"], false);

  const auto b = parseSceneControl<2>(parseSceneText(saved.dump(2)), twoPhases());
  EXPECT_TRUE(a.settings == b.settings);
  ASSERT_EQ(a.instances.size(), b.instances.size());
  for (size_t i = 0; i < a.instances.size(); ++i) expectSpecEqual(a.instances[i], b.instances[i]);
  EXPECT_EQ(sceneControlToJson<2>(b, twoPhases()), saved);
}

TEST(InstanceSceneParse, RoundTrip3D) {
  json second = full3D();
  second["name"] = "second";
  second["crop_end"] = 0.75;
  second["transform"].push_back(json::parse(R"({"time": 3, "translation": [0, 0, 0.125], "scale": 0.3})"));
  const json j = {{"instances", json::array({full3D(), second})}};
  const auto a = parseSceneControl<3>(j, twoPhases());
  const json saved = sceneControlToJson<3>(a, twoPhases());
  EXPECT_EQ(saved["instances"][0]["transform"][0]["rotation"], json::array({10, 20, 30}));
  const auto b = parseSceneControl<3>(parseSceneText(saved.dump()), twoPhases());
  EXPECT_TRUE(a.settings == b.settings);
  ASSERT_EQ(a.instances.size(), b.instances.size());
  for (size_t i = 0; i < a.instances.size(); ++i) expectSpecEqual(a.instances[i], b.instances[i]);
  EXPECT_EQ(sceneControlToJson<3>(b, twoPhases()), saved);
}

// ----------------------------------------------------------------- errors ---

TEST(InstanceSceneErrors, ControlSection) {
  expectError(json{{"control", json::array()}}, "control", {"expected an object"});
  expectError(json{{"control", {{"bogus", 1}}}}, "control.bogus", {"unknown parameter", "temporary_grace_frames"});
  expectError(json{{"control", {{"temporary_grace_frames", -1}}}}, "control.temporary_grace_frames",
              {"outside the allowed range"});
  expectError(json{{"control", {{"temporary_grace_frames", 2.5}}}}, "control.temporary_grace_frames",
              {"expected an integer"});
  expectError(json{{"control", {{"forces_every_substep", 1}}}}, "control.forces_every_substep", {"true or false"});
  expectError(json{{"control", {{"fidelity_cell", kInf}}}}, "control.fidelity_cell", {"not finite"});
}

TEST(InstanceSceneErrors, InstancesMustBeAnArrayOfObjects) {
  expectError(json{{"instances", json::object()}}, "instances", {"expected an array"});
  expectError(json{{"instances", json::array({"drop2d"})}}, "instances[0]", {"expected an object"});
}

TEST(InstanceSceneErrors, DimensionMismatch) {
  expectError<3>(sceneWith(minimal2D(), 2), "dimension", {"2D", "3D"});
}

TEST(InstanceSceneErrors, UnknownKeys) {
  expectError(sceneWith(with(minimal2D(), "bogus", 1)), "instances[0].bogus",
              {"unknown parameter", "template", "crop_end", "attraction_weight", "falloff_width"});
  json inst = full2D();
  inst["transform"][1]["skew"] = 1;
  expectError(sceneWith(inst), "instances[0].transform[1].skew", {"unknown key", "translation"});
}

TEST(InstanceSceneErrors, Template) {
  expectError(sceneWith(json::object()), "instances[0].template", {"missing required key"});
  expectError(sceneWith(json{{"template", 3}}), "instances[0].template", {"expected a string"});
  expectError(sceneWith(json{{"template", "../drop"}}), "instances[0].template", {"invalid template name", "../drop"});
  expectError(sceneWith(json{{"template", ""}}), "instances[0].template", {"invalid template name"});
}

TEST(InstanceSceneErrors, Names) {
  expectError(sceneWith(with(minimal2D(), "name", 3)), "instances[0].name", {"expected a string"});
  expectError(sceneWith(with(minimal2D(), "name", "")), "instances[0].name", {"must not be empty"});
  const json a = with(minimal2D(), "name", "same");
  const json j = {{"instances", json::array({a, minimal2D(), a})}};
  expectError(j, "instances[2].name", {"duplicate instance name 'same'", "instances[0].name"});
}

TEST(InstanceSceneErrors, Phase) {
  expectError(sceneWith(with(minimal2D(), "phase", "oil")), "instances[0].phase",
              {"unknown phase 'oil'", "water, ink"});
  expectError(sceneWith(with(minimal2D(), "phase", 1)), "instances[0].phase", {"expected a string"});
}

TEST(InstanceSceneErrors, WrongTypes) {
  auto key0 = [](const std::string& k, const json& v) {
    json inst = full2D();
    inst["transform"][0][k] = v;
    return sceneWith(inst);
  };
  expectError(sceneWith(with(minimal2D(), "transform", json::object())), "instances[0].transform",
              {"expected an array"});
  expectError(sceneWith(with(minimal2D(), "transform", json::array({1}))), "instances[0].transform[0]",
              {"expected an object"});
  expectError(key0("translation", "here"), "instances[0].transform[0].translation", {"array of 2 numbers"});
  expectError(key0("translation", json::array({1})), "instances[0].transform[0].translation", {"expected 2 components"});
  expectError(key0("translation", json::array({1, "2"})), "instances[0].transform[0].translation[1]",
              {"expected a number"});
  expectError(key0("time", "0"), "instances[0].transform[0].time", {"expected a number"});
  expectError(key0("rotation", json::array({30})), "instances[0].transform[0].rotation", {"expected a number"});
  expectError(key0("scale", "big"), "instances[0].transform[0].scale", {"number (uniform scale) or an array"});
  expectError(key0("reflect", true), "instances[0].transform[0].reflect", {"array of 2 booleans"});
  expectError(key0("reflect", json::array({true})), "instances[0].transform[0].reflect", {"expected 2 components"});
  expectError(key0("reflect", json::array({1, 0})), "instances[0].transform[0].reflect[0]", {"true or false"});
  expectError(sceneWith(with(minimal2D(), "reverse", "yes")), "instances[0].reverse", {"true or false"});
  expectError(sceneWith(with(minimal2D(), "start", "0")), "instances[0].start", {"expected a number"});
  expectError(sceneWith(with(minimal2D(), "repulsion", 1)), "instances[0].repulsion", {"true or false"});
  expectError(sceneWith(with(minimal2D(), "attraction_weight", "0.2")),
              "instances[0].attraction_weight", {"expected a number"});

  // 3D rotation is three Euler angles.
  json inst = full3D();
  inst["transform"][0]["rotation"] = 45;
  expectError<3>(sceneWith(inst, 3), "instances[0].transform[0].rotation", {"array of 3 numbers"});
  inst["transform"][0]["rotation"] = json::array({1, 2});
  expectError<3>(sceneWith(inst, 3), "instances[0].transform[0].rotation", {"expected 3 components"});
}

TEST(InstanceSceneErrors, MissingTranslation) {
  json inst = full2D();
  inst["transform"][1].erase("translation");
  expectError(sceneWith(inst), "instances[0].transform[1].translation", {"missing required key"});
}

TEST(InstanceSceneErrors, NonFiniteNumbers) {
  // JSON cannot write inf; a json value built in C++ can.
  json inst = full2D();
  inst["transform"][0]["translation"][1] = kInf;
  expectError(sceneWith(inst), "instances[0].transform[0].translation[1]", {"not finite"});
  inst = full2D();
  inst["transform"][1]["time"] = kInf;
  expectError(sceneWith(inst), "instances[0].transform[1].time", {"not finite"});
  inst = full2D();
  inst["transform"][0]["rotation"] = -kInf;
  expectError(sceneWith(inst), "instances[0].transform[0].rotation", {"not finite"});
  inst = full2D();
  inst["transform"][0]["scale"] = kInf;
  expectError(sceneWith(inst), "instances[0].transform[0].scale", {"not finite"});
  inst = full2D();
  inst["transform"][1]["scale"][0] = std::numeric_limits<double>::quiet_NaN();
  expectError(sceneWith(inst), "instances[0].transform[1].scale[0]", {"not finite"});
  expectError(sceneWith(with(minimal2D(), "start", kInf)), "instances[0].start", {"not finite"});
  expectError(sceneWith(with(minimal2D(), "speed", kInf)), "instances[0].speed", {"not finite"});
  expectError(sceneWith(with(minimal2D(), "crop_end", kInf)), "instances[0].crop_end", {"not finite"});
  expectError(sceneWith(with(minimal2D(), "attraction_weight", kInf)), "instances[0].attraction_weight",
              {"not finite"});
}

TEST(InstanceSceneErrors, ScaleMustBePositive) {
  json inst = full2D();
  inst["transform"][1]["scale"] = 0;
  expectError(sceneWith(inst), "instances[0].transform[1].scale", {"must be > 0", "reflect"});
  inst["transform"][1]["scale"] = json::array({1, -2});
  expectError(sceneWith(inst), "instances[0].transform[1].scale[1]", {"-2", "must be > 0"});
  inst["transform"][1]["scale"] = json::array({0, 1});
  expectError(sceneWith(inst), "instances[0].transform[1].scale[0]", {"must be > 0"});
}

TEST(InstanceSceneErrors, KeysInStrictlyIncreasingTime) {
  json inst = full2D();
  inst["transform"].push_back(json::parse(R"({"time": 1.5, "translation": [0, 0]})"));
  expectError(sceneWith(inst), "instances[0].transform[2].time", {"strictly increasing"});
  inst = full2D();
  inst["transform"][1]["time"] = -1;
  expectError(sceneWith(inst), "instances[0].transform[1].time", {"strictly increasing"});
  // time defaults to 0 in every key, so two keys without time collide.
  inst = full2D();
  inst["transform"][1].erase("time");
  expectError(sceneWith(inst), "instances[0].transform[1].time", {"strictly increasing"});
}

TEST(InstanceSceneErrors, TimeMap) {
  expectError(sceneWith(with(minimal2D(), "speed", 0)), "instances[0].speed", {"must be > 0"});
  expectError(sceneWith(with(minimal2D(), "speed", -1)), "instances[0].speed", {"must be > 0", "reverse"});
  expectError(sceneWith(with(minimal2D(), "crop_begin", -0.1)), "instances[0].crop_begin", {"must be >= 0"});
  expectError(sceneWith(with(minimal2D(), "crop_end", -1)), "instances[0].crop_end", {"must be >= 0"});
  json inst = with(minimal2D(), "crop_begin", 0.5);
  expectError(sceneWith(with(inst, "crop_end", 0.5)), "instances[0].crop_end", {"greater than crop_begin"});
  expectError(sceneWith(with(inst, "crop_end", 0.2)), "instances[0].crop_end", {"greater than crop_begin"});
  expectError(sceneWith(with(minimal2D(), "crop_end", 0)), "instances[0].crop_end", {"greater than crop_begin"});
}

TEST(InstanceSceneErrors, ParamsOutOfRange) {
  expectError(sceneWith(with(minimal2D(), "seed_distance", 5)), "instances[0].seed_distance",
              {"outside the allowed range", "[0.1, 2] h"});
  expectError(sceneWith(with(minimal2D(), "attraction_weight", -0.1)), "instances[0].attraction_weight",
              {"outside the allowed range"});
  expectError<3>(sceneWith(with(full3D(), "falloff_decay", 11), 3), "instances[0].falloff_decay",
                 {"outside the allowed range"});
}

// Names appear in URLs: nothing outside [A-Za-z0-9_-]{1,64}.
TEST(InstanceSceneErrors, NamesOutsideTheUrlAlphabet) {
  for (const std::string& name : std::vector<std::string>{"../x", "a b", std::string(65, 'x'), "caf\xc3\xa9"})
    expectError(json{{"instances", json::array({with(minimal2D(), "name", name)})}}, "instances[0].name");
}

TEST(InstanceSceneErrors, LaterInstanceIsNamed) {
  const json j = {{"instances", json::array({minimal2D(), with(minimal2D(), "speed", 0)})}};
  expectError(j, "instances[1].speed");
}

// ---------------------------------------------------------------- binding ---

using fc::test::writeSmallTemplate;

template <int D>
std::vector<InstanceSpec<D>> specsFrom(const json& instances) {
  return parseSceneControl<D>(json{{"instances", instances}}, twoPhases()).instances;
}

// Two 2D templates (a: 13 frames = 0.2 s, b: 7 frames = 0.1 s) and a 3D one.
struct BindFixture {
  TempDir tmp;
  std::string dir = tmp.file("templates");
  BindFixture() {
    writeSmallTemplate<2>(dir, "a", 13, {0.1, 0.2}, {0.5, 0.4});
    writeSmallTemplate<2>(dir, "b", 7, {0, 0}, {1, 1});
    writeSmallTemplate<3>(dir, "c3", 4, {0, 0, 0}, {0.2, 0.4, 0.6});
  }
};

TEST(InstanceSceneBind, SharesTemplatesAndFillsDefaultTransform) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  const auto specs = specsFrom<2>(json::parse(R"([
    {"template": "a"},
    {"template": "b", "crop_begin": 0.05, "crop_end": 0.1},
    {"template": "a", "name": "moved", "transform": [{"translation": [2, 3], "rotation": 90}], "speed": 2}
  ])"));
  const auto bound = bindInstances<2>(specs, db);
  ASSERT_EQ(bound.size(), 3u);
  EXPECT_EQ(bound[0].accel.get(), bound[2].accel.get());  // one template, one accel
  EXPECT_NE(bound[0].accel.get(), bound[1].accel.get());
  EXPECT_EQ(bound[0].templ().header.name, "a");
  EXPECT_EQ(bound[1].templ().header.name, "b");
  EXPECT_EQ(bound[0].accel->frameCount(), 13u);
  EXPECT_EQ(bound[1].accel->frameCount(), 7u);
  // The accel points into the database's loaded template, which it keeps alive.
  const auto loaded = db.load<2>("a");
  EXPECT_EQ(bound[0].accel.get(), &loaded->accel);

  // Empty track: one key at time 0 at the region centre (played where recorded).
  ASSERT_EQ(bound[0].spec.transform.keys.size(), 1u);
  const TransformKey<2>& k = bound[0].spec.transform.keys[0];
  EXPECT_EQ(k.time, 0);
  EXPECT_EQ(k.translation, bound[0].centre().cast<double>());
  EXPECT_NEAR(k.translation[0], 0.3, 1e-6);
  EXPECT_NEAR(k.translation[1], 0.3, 1e-6);
  EXPECT_EQ(k.scale, Eigen::Vector2d(1, 1));
  EXPECT_EQ(k.rotationDeg[0], 0);
  // So the template maps onto itself.
  const Affine<2> m = bound[0].spec.transform.templateToWorld(0.5, bound[0].centre());
  const Vec<2> x(Real(0.17), Real(0.33));
  EXPECT_NEAR(double((m.linear * x + m.translation - x).norm()), 0, 1e-6);

  // A given track is kept as written; the rest of the spec too.
  ASSERT_EQ(bound[2].spec.transform.keys.size(), 1u);
  EXPECT_EQ(bound[2].spec.transform.keys[0].translation, Eigen::Vector2d(2, 3));
  EXPECT_EQ(bound[2].spec.transform.keys[0].rotationDeg[0], 90);
  EXPECT_EQ(bound[2].spec.name, "moved");
  EXPECT_EQ(bound[2].spec.time.speed, 2);
  EXPECT_EQ(bound[1].spec.time.cropEnd, 0.1);
}

TEST(InstanceSceneBind, ThreeD) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  const auto bound = bindInstances<3>(specsFrom<3>(json::parse(R"([{"template": "c3"}, {"template": "c3"}])")), db);
  ASSERT_EQ(bound.size(), 2u);
  EXPECT_EQ(bound[0].accel.get(), bound[1].accel.get());
  EXPECT_EQ(bound[1].spec.name, "c3-2");
  const auto& t = bound[0].spec.transform.keys.at(0).translation;
  EXPECT_NEAR(t[0], 0.1, 1e-6);
  EXPECT_NEAR(t[1], 0.2, 1e-6);
  EXPECT_NEAR(t[2], 0.3, 1e-6);
}

TEST(InstanceSceneBind, NoInstances) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  EXPECT_TRUE(bindInstances<2>({}, db).empty());
}

TEST(InstanceSceneBind, UnknownTemplate) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  const auto specs = specsFrom<2>(json::parse(R"([{"template": "a"}, {"template": "nope"}])"));
  expectSceneError([&] { bindInstances<2>(specs, db); }, "instances[1].template",
                   {"no template 'nope'", fx.dir, "a (2D)", "b (2D)", "c3 (3D)"});
  // An empty directory says so.
  TemplateDatabase empty(fx.tmp.file("missing"));
  expectSceneError([&] { bindInstances<2>(specs, empty); }, "instances[0].template", {"(none)"});
}

TEST(InstanceSceneBind, DimensionMismatch) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  expectSceneError([&] { bindInstances<2>(specsFrom<2>(json::parse(R"([{"template": "c3"}])")), db); },
                   "instances[0].template", {"'c3' is 3D", "scene is 2D"});
  expectSceneError([&] { bindInstances<3>(specsFrom<3>(json::parse(R"([{"template": "c3"}, {"template": "a"}])")), db); },
                   "instances[1].template", {"'a' is 2D", "scene is 3D"});
}

TEST(InstanceSceneBind, UnreadableTemplate) {
  BindFixture fx;
  std::ofstream(fx.dir + "/broken.h5") << "not a template";
  TemplateDatabase db(fx.dir);
  expectSceneError([&] { bindInstances<2>(specsFrom<2>(json::parse(R"([{"template": "broken"}])")), db); },
                   "instances[0].template", {"cannot read template 'broken'", "not an HDF5 file"});
}

TEST(InstanceSceneBind, InvalidNameFromOutsideTheParser) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  std::vector<InstanceSpec<2>> specs(1);
  specs[0].templateName = "../a";
  specs[0].params = instanceParamTable(2).defaults();
  expectSceneError([&] { bindInstances<2>(specs, db); }, "instances[0].template", {"invalid template name"});
}

TEST(InstanceSceneBind, TimeMapAgainstTemplateDuration) {
  BindFixture fx;
  TemplateDatabase db(fx.dir);
  // Template a lasts 0.2 s.
  auto bindOne = [&](const json& inst) { bindInstances<2>(specsFrom<2>(json::array({json{{"template", "a"}}, inst})), db); };
  expectSceneError([&] { bindOne(json{{"template", "a"}, {"crop_end", 10}}); }, "instances[1].crop_end",
                   {"past the template's end"});
  expectSceneError([&] { bindOne(json{{"template", "a"}, {"crop_begin", 0.5}}); }, "instances[1].crop_begin",
                   {"past the template's end"});
  // crop_begin at the end leaves nothing to play.
  expectSceneError([&] { bindOne(json{{"template", "a"}, {"crop_begin", 0.2}}); }, "instances[1].crop_end",
                   {"greater than crop_begin"});
  EXPECT_NO_THROW(bindOne(json{{"template", "a"}, {"crop_begin", 0.05}, {"crop_end", 0.2}}));
  // Specs built outside the parser are checked too.
  std::vector<InstanceSpec<2>> specs = specsFrom<2>(json::array({json{{"template", "a"}}}));
  specs[0].time.speed = 0;
  expectSceneError([&] { bindInstances<2>(specs, db); }, "instances[0].speed", {"positive"});
  specs = specsFrom<2>(json::array({json{{"template", "a"}}}));
  specs[0].transform.keys.resize(1);
  specs[0].transform.keys[0].scale[1] = -1;
  expectSceneError([&] { bindInstances<2>(specs, db); }, "instances[0].transform[0].scale[1]", {"positive"});
}

// ---------------------------------------------------------- documentation ---

std::string readme() {
  std::ifstream in(std::string(FLOWCLIP_SOURCE_DIR) + "/scenes/README.md");
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The declared parameters are in the generated parameter reference
// (tests/test_parameter_reference.py); the structural keys are written here.
TEST(InstanceSceneDocs, EveryStructuralKeyIsDocumented) {
  const std::string doc = readme();
  ASSERT_FALSE(doc.empty());
  for (const char* section : {"### `control`", "### `instances[i]`", "| `control` |", "| `instances` |"})
    EXPECT_NE(doc.find(section), std::string::npos) << section;
  std::vector<std::string> keys = kInstanceKeysForDocs();
  for (const char* k : {"time", "translation", "rotation", "scale", "reflect"}) keys.push_back(k);
  for (const auto& k : keys) EXPECT_NE(doc.find("| `" + k + "` |"), std::string::npos) << k << " is not documented";
}

TEST(InstanceSceneDocs, ExampleParses) {
  const std::string doc = readme();
  const size_t section = doc.find("### `instances[i]`");
  ASSERT_NE(section, std::string::npos);
  const size_t begin = doc.find("```json\n", section);
  ASSERT_NE(begin, std::string::npos);
  const size_t end = doc.find("```", begin + 8);
  const json j = parseSceneText("{" + doc.substr(begin + 8, end - begin - 8) + "}", "README instances example");
  const auto c = parseSceneControl<2>(j, twoPhases());
  ASSERT_EQ(c.instances.size(), 1u);
  EXPECT_EQ(c.instances[0].transform.keys.size(), 2u);
}

}  // namespace
}  // namespace fc
