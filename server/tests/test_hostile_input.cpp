// Input that once took the process down, and the guards against it: bytes
// that are not UTF-8 echoed in errors, JSON nested without end, numbers
// beyond double, values outside their physical range, frames that never
// end (the watchdog), limits a request tried to raise, a template deleted
// while a session uses it. Each case answers a clear error and the process
// goes on.
#include "core/text.h"
#include "io/json_text.h"
#include "io/scene.h"
#include "service/rest_api.h"
#include "sph/limits.h"
#include "sph/simulation.h"
#include "tests/hdf5_test_util.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <thread>

namespace fc {
namespace {

using nlohmann::json;
using fc::test::TempDir;
using namespace std::chrono_literals;

std::string nested(size_t depth, char open = '[', char close = ']') {
  return std::string(depth, open) + std::string(depth, close);
}

// ---------------------------------------------------------------- text ---

TEST(HostileText, PrintableKeepsUtf8AndEscapesEverythingElse) {
  EXPECT_TRUE(isValidUtf8("plain ascii"));
  EXPECT_TRUE(isValidUtf8("d\xC3\xA9j\xC3\xA0 \xE2\x82\xAC \xF0\x9F\x92\xA7"));  // déjà € 💧
  for (const char* bad : {"\xFF", "\xC0\xAE", "\xE0\x80\xAF", "\xED\xA0\x80", "\xF4\x90\x80\x80", "ab\xC3"})
    EXPECT_FALSE(isValidUtf8(bad)) << printable(bad);
  EXPECT_EQ(printable("dr\xFFop"), "dr\\xFFop");
  EXPECT_EQ(printable("\xC0\xAE"), "\\xC0\\xAE");
  EXPECT_EQ(printable("a\nb\x7F"), "a\\x0Ab\\x7F");
  EXPECT_EQ(printable("d\xC3\xA9j\xC3\xA0"), "d\xC3\xA9j\xC3\xA0");
  const std::string cut = printable(std::string(1000, 'x'), 50);
  EXPECT_LE(cut.size(), 53u);
  EXPECT_EQ(cut.substr(cut.size() - 3), "...");
  // Whatever the bytes, the result serialises as JSON.
  std::string all;
  for (int c = 0; c < 256; ++c) all.push_back(char(c));
  EXPECT_TRUE(isValidUtf8(printable(all)));
  EXPECT_NO_THROW((void)json(printable(all)).dump());
}

// ---------------------------------------------------------------- JSON ---

// The error parseJsonText throws for `text` (a failure, and a Syntax error
// with an empty message, when it accepts it).
JsonTextError refusal(const std::string& text, const JsonTextOptions& options = {}) {
  try {
    parseJsonText(text, options);
  } catch (const JsonTextError& e) {
    return e;
  }
  ADD_FAILURE() << "accepted: " << printable(text, 80);
  return JsonTextError(JsonTextError::Kind::Syntax, "", "", "");
}

TEST(HostileJson, NestingBeyondTheLimitIsAnErrorNotAStackOverflow) {
  JsonTextOptions o;
  o.maxDepth = 128;
  EXPECT_NO_THROW(parseJsonText(nested(128), o));
  for (size_t depth : {129u, 1000u, 100000u, 1000000u}) {
    const JsonTextError e = refusal(nested(depth), o);
    EXPECT_EQ(e.kind, JsonTextError::Kind::TooDeep) << depth;
    EXPECT_NE(std::string(e.what()).find("deeper than 128"), std::string::npos) << e.what();
  }
  // Objects too, and the path says where the limit was met.
  std::string deep;
  for (int i = 0; i < 200; ++i) deep += "{\"a\":";
  deep += "1" + std::string(200, '}');
  EXPECT_EQ(refusal(deep, o).path.substr(0, 6), "a.a.a.");
}

TEST(HostileJson, NumberOverflowNamesTheKeyPath) {
  const JsonTextError e = refusal(R"({"settings": {"cfl_factor": 0.5, "dt_max": 1e999}})");
  EXPECT_EQ(e.kind, JsonTextError::Kind::NumberOutOfRange);
  EXPECT_EQ(e.path, "settings.dt_max");
  EXPECT_EQ(e.where, "1:44");
  EXPECT_NE(std::string(e.what()).find("1e999"), std::string::npos) << e.what();
  EXPECT_EQ(refusal(R"({"keys": [1, 2, -1e400]})").path, "keys[2]");
}

TEST(HostileJson, InvalidUtf8IsASyntaxErrorWithAPrintableMessage) {
  const JsonTextError e = refusal("{\"scene\":\"dr\xFFop\"}");
  EXPECT_EQ(e.kind, JsonTextError::Kind::Syntax);
  EXPECT_TRUE(isValidUtf8(e.what())) << printable(e.what());
  EXPECT_EQ(e.where.substr(0, 2), "1:");
}

TEST(HostileJson, DuplicateKeysAreRefusedAtTheirPath) {
  const JsonTextError e = refusal(R"({"a": {"b": 1, "b": 2}})");
  EXPECT_EQ(e.kind, JsonTextError::Kind::DuplicateKey);
  EXPECT_EQ(e.path, "a.b");
}

// --------------------------------------------------------------- scenes ---

TEST(HostileScene, DeeplyNestedSceneFileIsAnErrorNamingTheFile) {
  TempDir tmp;
  const std::string file = tmp.file("deep.json");
  std::ofstream(file) << "{\"name\": " << nested(80000) << "}";
  try {
    loadSceneJson(file);
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find(file), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("nested deeper than"), std::string::npos) << e.what();
  }
}

TEST(HostileScene, ASceneThatIsNotAnObjectNamesTheFile) {
  TempDir tmp;
  const std::string file = tmp.file("null.json");
  std::ofstream(file) << "null";
  try {
    loadSceneJson(file);
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find(file), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("got null"), std::string::npos) << e.what();
  }
}

void expectRejectedAt(json scene, const std::string& path, const std::string& text) {
  try {
    parseScene<2>(scene);
    FAIL() << path << " was accepted";
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, path) << e.what();
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
  }
}

TEST(HostileScene, ValuesOutsideTheirPhysicalRangeAreRefusedByKey) {
  json base = fc::test::smallTankScene();
  EXPECT_NO_THROW(parseScene<2>(base));
  json g = base;
  g["gravity"] = {0, -1e30};
  expectRejectedAt(g, "gravity", "physical range");
  g["gravity"] = {0, -9.81 * 50};  // 50 g is a shot, not an error
  EXPECT_NO_THROW(parseScene<2>(g));
  json rho = base;
  rho["phases"] = json::array({{{"name", "water"}, {"rest_density", 1e30}}});
  rho["fluid_blocks"][0]["phase"] = "water";
  expectRejectedAt(rho, "phases[0].rest_density", "kg/m^3");
  json nu = rho;
  nu["phases"][0]["rest_density"] = 1000;
  nu["phases"][0]["viscosity"] = 1e12;
  expectRejectedAt(nu, "phases[0].viscosity", "physical range");
  json v = base;
  v["fluid_blocks"][0]["velocity"] = {1e6, 0};
  expectRejectedAt(v, "fluid_blocks[0].velocity", "m/s");
  json dom = base;
  dom["domain"]["max"] = {1e7, 1};
  expectRejectedAt(dom, "domain.max[0]", "physical range");
  // Every declared range is listed once, with a unit or a reason.
  for (const PhysicalRange& pr : physicalRanges()) {
    EXPECT_LT(pr.min, pr.max) << pr.name;
    EXPECT_TRUE(std::string(pr.help).size() > 5) << pr.name;
  }
}

TEST(HostileScene, InstanceTransformsOutsideTheirRangeAreRefusedByKey) {
  json scene = fc::test::smallTankScene();
  scene["instances"] = json::array({{{"template", "blob"},
                                     {"transform", json::array({{{"translation", {1e308, 0.5}}}})}}});
  const SimulationSetup<2> setup = parseScene<2>(scene);
  try {
    parseSceneControl<2>(scene, setup.phases);
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "instances[0].transform[0].translation[0]") << e.what();
  }
  scene["instances"][0]["transform"][0]["translation"] = {0.5, 0.5};
  scene["instances"][0]["speed"] = 1e9;
  try {
    parseSceneControl<2>(scene, setup.phases);
    FAIL();
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "instances[0].speed") << e.what();
  }
}

// ------------------------------------------------------------- watchdog ---

SimulationSetup<2> tank(json settings = json::object()) {
  json scene = fc::test::smallTankScene();
  scene["settings"] = std::move(settings);
  return parseScene<2>(scene);
}

TEST(Watchdog, ANonFiniteVelocityStopsTheFrameAtOnce) {
  Simulation<2> sim(tank());
  ASSERT_TRUE(sim.advanceFrame().finite);
  sim.fluid.v[7] = Vec<2>(std::numeric_limits<Real>::quiet_NaN(), 0);
  const FrameStats fs = sim.advanceFrame();
  EXPECT_FALSE(fs.finite);
  EXPECT_FALSE(fs.cancelled);
  EXPECT_NE(fs.failure.find("non-finite"), std::string::npos) << fs.failure;
  EXPECT_EQ(fs.substeps, 0);  // caught before the first substep moved anything
  EXPECT_EQ(fs.frame, 2);
  EXPECT_NE(failureText(fs).find("frame 2 (t = "), std::string::npos) << failureText(fs);
}

TEST(Watchdog, ParticlesPiledOntoEachOtherStopTheFrameWithAFailure) {
  json scene = fc::test::smallTankScene();
  scene["particle_radius"] = 0.002;  // 10,000 particles, more than a pile may hold
  Simulation<2> sim(parseScene<2>(scene));
  ASSERT_TRUE(sim.advanceFrame().finite);
  ASSERT_GT(sim.fluid.size(), 9000u);
  for (auto& x : sim.fluid.x) x = Vec<2>(0.2f, 0.2f);
  const FrameStats fs = sim.advanceFrame();
  EXPECT_FALSE(fs.finite);
  EXPECT_FALSE(fs.cancelled);
  EXPECT_NE(fs.failure.find("collapsed"), std::string::npos) << fs.failure;
  EXPECT_EQ(fs.frame, 2);
  EXPECT_EQ(fs.particles, sim.fluid.size());
}

TEST(Watchdog, AFrameNeedingMoreSubstepsThanTheLimitStops) {
  Simulation<2> sim(tank({{"frame_rate", 1}, {"dt_max", 0.001}, {"max_substeps_per_frame", 25}}));
  const FrameStats fs = sim.advanceFrame();
  EXPECT_FALSE(fs.finite);
  EXPECT_EQ(fs.substeps, 25);
  EXPECT_NE(fs.failure.find("more than 25 substeps"), std::string::npos) << fs.failure;
  EXPECT_NEAR(fs.time, 0.025, 1e-6);
}

TEST(Watchdog, DeadlineAndCancellationStopAFrameBetweenSubsteps) {
  const json endless = {{"frame_rate", 1}, {"dt_min", 1e-6}, {"dt_max", 1e-6}, {"max_substeps_per_frame", 1e7}};
  Simulation<2> late(tank(endless));
  late.setFrameLimits({std::chrono::steady_clock::now() + 50ms, nullptr});
  FrameStats fs = late.advanceFrame();
  EXPECT_FALSE(fs.finite);
  EXPECT_FALSE(fs.cancelled);
  EXPECT_NE(fs.failure.find("watchdog"), std::string::npos) << fs.failure;
  EXPECT_LT(fs.substeps, 1000000);

  Simulation<2> cancelled(tank(endless));
  std::atomic<bool> cancel = false;
  cancelled.setFrameLimits({std::chrono::steady_clock::time_point::max(), &cancel});
  std::thread stopper([&] {
    std::this_thread::sleep_for(20ms);
    cancel = true;
  });
  fs = cancelled.advanceFrame();
  stopper.join();
  EXPECT_TRUE(fs.cancelled);
  EXPECT_FALSE(fs.finite);
  EXPECT_LT(fs.substeps, 1000000);
}

// ------------------------------------------------------------------ REST ---

struct Hub {
  TempDir tmp;
  service::ServiceHub hub;
  Hub() : hub(options()) {
    fc::test::writeSmallTemplate<2>(tmp.file("templates"), "blob", 13, {0.05, 0.05}, {0.35, 0.35});
    std::filesystem::create_directories(tmp.file("scenes"));
    std::ofstream(tmp.file("scenes/box.json")) << fc::test::smallTankScene().dump(2);
    std::ofstream(tmp.file("scenes/deep.json")) << "{\"name\": " << nested(80000) << "}";
  }
  service::ServiceOptions options() {
    service::ServiceOptions o;
    o.templatesDir = tmp.file("templates");
    o.scenesDir = tmp.file("scenes");
    o.exportsDir = tmp.file("exports");
    o.presetsFile = tmp.file("presets.json");
    o.maxSessions = 4;
    o.maxThreads = 2;
    o.historyCapBytes = size_t(64) << 20;
    return o;
  }
  service::HttpResponse call(const std::string& method, const std::string& path, const std::string& body = "") {
    service::HttpRequest r;
    r.method = method;
    r.path = path;
    r.body = body;
    return hub.handle(r);
  }
};

// The body is JSON whose message is valid UTF-8; returns the error object.
json expectJsonError(const service::HttpResponse& r, int status) {
  EXPECT_EQ(r.status, status) << printable(r.body);
  EXPECT_TRUE(isValidUtf8(r.body)) << printable(r.body);
  const json j = json::parse(r.body);
  EXPECT_EQ(j["error"]["status"], status);
  return j["error"];
}

TEST(HostileRest, NonUtf8BytesInPathsAndBodiesAreEchoedPrintably) {
  Hub h;
  for (const char* path : {"/api/scenes/%ff", "/api/templates/%c0%ae", "/api/exports/%ff.h5", "/api/sessions/%ff",
                           "/api/sessions/%ff/instances/%fe", "/api/templates/%ff/preview"}) {
    const bool session = std::string(path).find("sessions") != std::string::npos;
    const json e = expectJsonError(h.call("GET", path), session ? 404 : 400);
    EXPECT_NE(e["message"].get<std::string>().find("\\x"), std::string::npos) << e.dump();
  }
  const json e = expectJsonError(h.call("POST", "/api/sessions", "{\"scene\":\"dr\xFFop\"}"), 400);
  EXPECT_NE(e["message"].get<std::string>().find("malformed JSON"), std::string::npos) << e.dump();
  EXPECT_EQ(h.hub.sessionCount(), 0u);
}

TEST(HostileRest, NumberOverflowInABodyIs400NamingTheKey) {
  Hub h;
  const json e = expectJsonError(h.call("POST", "/api/sessions", R"({"scene": "box", "playback_speed": 1e999})"), 400);
  EXPECT_EQ(e["path"], "playback_speed");
  EXPECT_NE(e["message"].get<std::string>().find("playback_speed"), std::string::npos);
}

TEST(HostileRest, DeeplyNestedSceneFileIs422AndTheServerGoesOn) {
  Hub h;
  const json e = expectJsonError(h.call("GET", "/api/scenes/deep"), 422);
  EXPECT_NE(e["message"].get<std::string>().find("deep.json"), std::string::npos) << e.dump();
  expectJsonError(h.call("POST", "/api/sessions", R"({"scene": "deep"})"), 422);
  const json list = json::parse(h.call("GET", "/api/scenes").body);
  bool listed = false;
  for (const json& s : list["scenes"])
    if (s["name"] == "deep") listed = s.contains("error");
  EXPECT_TRUE(listed) << list.dump();
  EXPECT_EQ(h.call("GET", "/api/health").status, 200);
}

TEST(HostileRest, ServerLimitsAreCeilingsARequestCannotRaise) {
  Hub h;
  json e = expectJsonError(h.call("POST", "/api/sessions", R"({"scene": "box", "history_cap_mb": 4096})"), 400);
  EXPECT_EQ(e["path"], "history_cap_mb");
  EXPECT_NE(e["message"].get<std::string>().find("ceiling"), std::string::npos) << e.dump();
  e = expectJsonError(h.call("POST", "/api/sessions", R"({"scene": "box", "threads": 1024})"), 400);
  EXPECT_EQ(e["path"], "threads");
  EXPECT_EQ(h.hub.sessionCount(), 0u);
  // Lower is fine.
  const service::HttpResponse ok = h.call("POST", "/api/sessions", R"({"scene": "box", "history_cap_mb": 8, "threads": 1})");
  ASSERT_EQ(ok.status, 201) << ok.body;
  EXPECT_EQ(json::parse(ok.body)["history"]["cap"], 8 * 1024 * 1024);
}

TEST(HostileRest, ATemplateInUseCannotBeDeleted) {
  Hub h;
  json scene = fc::test::smallTankScene();
  scene["instances"] = json::array({{{"name", "b"}, {"template", "blob"}, {"start", 5}}});
  const service::HttpResponse created = h.call("POST", "/api/sessions", json{{"scene", scene}}.dump());
  ASSERT_EQ(created.status, 201) << created.body;
  const std::string id = json::parse(created.body)["id"];
  const json e = expectJsonError(h.call("DELETE", "/api/templates/blob"), 409);
  EXPECT_NE(e["message"].get<std::string>().find(id), std::string::npos) << e.dump();
  EXPECT_TRUE(std::filesystem::exists(h.tmp.file("templates/blob.h5")));
  ASSERT_EQ(h.call("DELETE", "/api/sessions/" + id).status, 200);
  EXPECT_EQ(h.call("DELETE", "/api/templates/blob").status, 200);
}

TEST(HostileRest, ACaptureRegionOutsideTheCoordinateRangeIs400) {
  Hub h;
  const service::HttpResponse created = h.call("POST", "/api/sessions", R"({"scene": "box", "threads": 1})");
  ASSERT_EQ(created.status, 201);
  const std::string id = json::parse(created.body)["id"];
  const json e = expectJsonError(
      h.call("POST", "/api/sessions/" + id + "/templates",
             R"({"name": "huge", "region_min": [0, 0], "region_max": [1e308, 1], "first_frame": 0, "last_frame": 0})"),
      400);
  EXPECT_EQ(e["path"], "region_max[0]");
  EXPECT_NE(e["message"].get<std::string>().find("physical range"), std::string::npos) << e.dump();
  EXPECT_FALSE(std::filesystem::exists(h.tmp.file("templates/huge.h5")));
}

}  // namespace
}  // namespace fc
