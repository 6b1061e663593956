// The REST API (service/rest_api.h) without networking: routing, the JSON
// error contract (status, code, message, path) for bad input, sessions,
// instances and edits, transport, frames as JSON and flatbuffers, scene
// saving, history export and templates recorded from the history.
#include "service/rest_api.h"

#include "service/frame_encoding.h"
#include "control/instance.h"
#include "tests/hdf5_test_util.h"
#include "tests/support/frame_decoding.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

namespace fc::service {
namespace {

using nlohmann::json;
using fc::test::TempDir;
using namespace std::chrono_literals;

using fc::test::smallTankScene;

struct Api {
  TempDir tmp;
  ServiceHub hub;
  explicit Api(int maxSessions = 4) : hub(options(maxSessions)) {
    fc::test::writeSmallTemplate<2>(tmp.file("templates"), "blob", 13, {0.05, 0.05}, {0.35, 0.35});
    std::filesystem::create_directories(tmp.file("scenes"));
    std::ofstream(tmp.file("scenes/box.json")) << smallTankScene().dump(2);
  }
  ServiceOptions options(int maxSessions) {
    ServiceOptions o;
    o.templatesDir = tmp.file("templates");
    o.scenesDir = tmp.file("scenes");
    o.exportsDir = tmp.file("exports");
    o.presetsFile = tmp.file("presets.json");
    o.maxSessions = maxSessions;
    return o;
  }
  HttpResponse call(const std::string& method, const std::string& target, const std::string& body = "") {
    HttpRequest r;
    r.method = method;
    const size_t q = target.find('?');
    r.path = target.substr(0, q);
    if (q != std::string::npos) r.query = target.substr(q + 1);
    r.body = body;
    return hub.handle(r);
  }
  json callJson(const std::string& method, const std::string& target, const json& body, int expectStatus) {
    const HttpResponse r = call(method, target, body.is_null() ? "" : body.dump());
    EXPECT_EQ(r.status, expectStatus) << method << " " << target << ": " << r.body;
    return json::parse(r.body);
  }
  std::string createSession() {
    const json s = callJson("POST", "/api/sessions", {{"scene", "box"}}, 201);
    return s.at("id").get<std::string>();
  }
  void settle(const std::string& id) { ASSERT_TRUE(hub.session(id)->waitIdle(10s)); }
};

// Every error is {"error": {"status", "code", "message"[, "path"]}}.
void expectError(const HttpResponse& r, int status, const std::string& code, const std::string& path = "") {
  EXPECT_EQ(r.status, status) << r.body;
  const json j = json::parse(r.body);
  ASSERT_TRUE(j.contains("error")) << r.body;
  EXPECT_EQ(j["error"]["status"], status);
  EXPECT_EQ(j["error"]["code"], code);
  EXPECT_FALSE(j["error"]["message"].get<std::string>().empty());
  if (!path.empty()) {
    EXPECT_EQ(j["error"].value("path", ""), path) << r.body;
  }
}

TEST(RestApi, RoutesAnswerUnknownPathsAndMethodsWithJsonErrors) {
  Api api;
  const json health = api.callJson("GET", "/api/health", nullptr, 200);
  EXPECT_EQ(health["status"], "ok");
  EXPECT_EQ(health["sessions"], 0);
  EXPECT_GT(health["rss_mb"].get<double>(), 0.0);
  expectError(api.call("GET", "/api/nothing"), 404, "not_found");
  const HttpResponse r = api.call("PUT", "/api/sessions");
  expectError(r, 405, "method_not_allowed");
  ASSERT_EQ(r.headers.size(), 1u);
  EXPECT_EQ(r.headers[0].second, "GET, POST");
}

TEST(RestApi, BadInputGetsTheRightStatusAndNamesWhatWasWrong) {
  Api api;
  expectError(api.call("POST", "/api/sessions", "{\"scene\": "), 400, "bad_request");
  expectError(api.call("POST", "/api/sessions", "[1, 2]"), 400, "bad_request");
  expectError(api.call("POST", "/api/sessions", R"({"scene": 5})"), 400, "bad_request", "scene");
  expectError(api.call("POST", "/api/sessions", R"({"scene": "box", "history_cap_mb": "big"})"), 400, "bad_request",
              "history_cap_mb");
  expectError(api.call("POST", "/api/sessions", R"({"scene": "box", "colour": 1})"), 400, "bad_request", "colour");
  expectError(api.call("POST", "/api/sessions", R"({"scene": "nowhere"})"), 404, "not_found", "scene");
  // Traversal never reaches the filesystem: the name rule refuses it.
  expectError(api.call("GET", "/api/templates/..%2F..%2Fetc%2Fpasswd"), 400, "bad_request");
  expectError(api.call("GET", "/api/scenes/.."), 400, "bad_request");
  expectError(api.call("POST", "/api/sessions", R"({"scene": "../scenes/box"})"), 400, "bad_request", "scene");
  expectError(api.call("GET", "/api/exports/..%2Fbox.h5"), 400, "bad_request");
  expectError(api.call("GET", "/api/templates/missing"), 404, "not_found");
  // Deep nesting is refused before anything copies it (copies recurse).
  expectError(api.call("POST", "/api/scenes",
                       R"({"name": "x", "session": "s1", "force": )" + std::string(100000, '[') +
                           std::string(100000, ']') + "}"),
              400, "bad_request");
  expectError(api.call("GET", "/api/sessions/s99"), 404, "not_found");
  // An invalid inline scene is understood but cannot be simulated: 422 with the key.
  json scene = smallTankScene();
  scene["particle_radius"] = -1;
  expectError(api.call("POST", "/api/sessions", json{{"scene", scene}}.dump()), 422, "unprocessable",
              "scene.particle_radius");
  EXPECT_EQ(api.hub.sessionCount(), 0u);
}

TEST(RestApi, SessionsAreCreatedListedCappedAndDeleted) {
  Api api(2);
  const std::string a = api.createSession();
  const json b = api.callJson("POST", "/api/sessions", {{"scene", smallTankScene()}, {"name", "inline"}}, 201);
  EXPECT_NE(a, b["id"]);
  EXPECT_EQ(b["name"], "inline");
  EXPECT_EQ(b["status"], "paused");
  EXPECT_EQ(b["particles"]["liquid"], 100);
  expectError(api.call("POST", "/api/sessions", R"({"scene": "box"})"), 429, "too_many_sessions");
  EXPECT_EQ(api.callJson("GET", "/api/sessions", nullptr, 200)["sessions"].size(), 2u);
  std::weak_ptr<Session> weak = api.hub.session(a);
  api.callJson("DELETE", "/api/sessions/" + a, nullptr, 200);
  EXPECT_TRUE(weak.expired()) << "a deleted session with no stream must be freed";
  expectError(api.call("GET", "/api/sessions/" + a), 404, "not_found");
  api.createSession();  // room again
}

TEST(RestApi, InstanceEditsAreAcknowledgedWithTheirFrameAndInvalidOnesChangeNothing) {
  Api api;
  const std::string id = api.createSession();
  const std::string base = "/api/sessions/" + id;
  api.callJson("POST", base + "/transport", {{"command", "step"}, {"frames", 2}}, 200);
  api.settle(id);
  const json added = api.callJson(
      "POST", base + "/instances", {{"name", "drop"}, {"template", "blob"}, {"transform", json::array({{{"time", 0}, {"translation", {0.5, 0.5}}}})}},
      201);
  EXPECT_TRUE(added["edit"]["accepted"]);
  EXPECT_EQ(added["edit"]["frame"], 1) << "an instance starting at 0 changes every frame after frame 0";
  EXPECT_EQ(added["instance"]["name"], "drop");
  EXPECT_EQ(api.callJson("GET", base + "/instances", nullptr, 200)["instances"].size(), 1u);

  const json before = api.callJson("GET", base + "/instances/drop", nullptr, 200);
  expectError(api.call("PATCH", base + "/instances/drop", R"({"speed": -2})"), 422, "unprocessable");
  EXPECT_EQ(api.callJson("GET", base + "/instances/drop", nullptr, 200), before);
  const json patched = api.callJson("PATCH", base + "/instances/drop", {{"speed", 2.0}}, 200);
  EXPECT_EQ(patched["instance"]["speed"], 2.0);
  expectError(api.call("POST", base + "/instances", R"({"name": "x", "template": "missing"})"), 422, "unprocessable");
  expectError(api.call("PATCH", base + "/instances/ghost", "{}"), 404, "not_found");
  const json edit = api.callJson("GET", base + "/edits/" + std::to_string(patched["edit"]["id"].get<int>()), nullptr, 200);
  EXPECT_EQ(edit["accepted"], true);
  api.callJson("DELETE", base + "/instances/drop", nullptr, 200);
  EXPECT_TRUE(api.callJson("GET", base + "/instances", nullptr, 200)["instances"].empty());
  const json settings = api.callJson("PATCH", base + "/settings", {{"settings", {{"cfl_factor", 0.5}}}}, 200);
  EXPECT_TRUE(settings["edit"]["accepted"]);
}

TEST(RestApi, TransportFramesAndSeekAgreeInJsonAndBinary) {
  Api api;
  const std::string id = api.createSession();
  const std::string base = "/api/sessions/" + id;
  const json stepped = api.callJson("POST", base + "/transport", {{"command", "step"}, {"frames", 3}}, 200);
  EXPECT_NE(stepped["status"], "error");
  api.settle(id);
  const json f = api.callJson("GET", base + "/frames/3", nullptr, 200);
  ASSERT_EQ(f["frame"], 3);
  ASSERT_EQ(f["count"], 100);
  ASSERT_EQ(f["positions"].size(), 200u);
  ASSERT_EQ(f["velocities"].size(), 200u);
  for (const json& x : f["positions"]) EXPECT_TRUE(x.get<double>() >= 0 && x.get<double>() <= 1);
  const HttpResponse bin = api.call("GET", base + "/frames/3?format=binary");
  ASSERT_EQ(bin.status, 200);
  EXPECT_EQ(bin.contentType, "application/x-flowclip-frame");
  const wire::DecodedFrame d = wire::decodeFrame(reinterpret_cast<const uint8_t*>(bin.body.data()), bin.body.size());
  EXPECT_EQ(d.frame, 3);
  ASSERT_EQ(d.particles.x.size(), 100u);
  for (size_t i = 0; i < 100; ++i)
    for (int k = 0; k < 2; ++k)
      EXPECT_NEAR(d.particles.x[i][size_t(k)], f["positions"][2 * i + size_t(k)].get<double>(), 1e-5);
  expectError(api.call("GET", base + "/frames/9"), 404, "not_found", "frame");
  expectError(api.call("GET", base + "/frames/abc"), 400, "bad_request", "frame");
  expectError(api.call("GET", base + "/frames/3?format=xml"), 400, "bad_request", "format");

  const json sought = api.callJson("POST", base + "/transport", {{"command", "seek"}, {"frame", 1}}, 200);
  EXPECT_EQ(sought["shown"]["frame"], 1);
  EXPECT_EQ(sought["shown"]["live"], false);
  EXPECT_EQ(api.callJson("GET", base + "/frames/latest", nullptr, 200)["frame"], 1);
  expectError(api.call("POST", base + "/transport", R"({"command": "seek", "frame": 40})"), 422, "unprocessable", "frame");
  expectError(api.call("POST", base + "/transport", R"({"command": "jump"})"), 400, "bad_request", "command");
  expectError(api.call("POST", base + "/transport", R"({"command": "step", "frames": 0})"), 400, "bad_request",
              "frames");
  const json stats = api.callJson("GET", base + "/stats", nullptr, 200);
  ASSERT_EQ(stats["frames"].size(), 4u);
  EXPECT_EQ(stats["frames"][3]["frame"], 3);
  EXPECT_GT(stats["frames"][3]["substeps"].get<int>(), 0);
}

// The pause answer is the state after the frame in progress: the frame it
// names is the one the session stays at.
TEST(RestApi, PauseAnswersWithTheFrameTheSessionStopsAt) {
  Api api;
  const std::string id = api.createSession();
  const std::string base = "/api/sessions/" + id;
  api.callJson("POST", base + "/transport", {{"command", "play"}}, 200);
  ASSERT_TRUE(api.hub.session(id)->waitForFrame(3, 10s));
  const json paused = api.callJson("POST", base + "/transport", {{"command", "pause"}}, 200);
  EXPECT_EQ(paused["status"], "paused");
  EXPECT_EQ(paused["computing"], false);
  std::this_thread::sleep_for(200ms);
  EXPECT_EQ(api.callJson("GET", base, nullptr, 200)["frame"], paused["frame"]);
}

TEST(RestApi, SavedScenesReloadAndAreNotOverwrittenWithoutForce) {
  Api api;
  const std::string id = api.createSession();
  api.callJson("POST", "/api/sessions/" + id + "/instances", {{"name", "drop"}, {"template", "blob"}}, 201);
  const json saved = api.callJson("POST", "/api/scenes", {{"name", "mine"}, {"session", id}}, 201);
  EXPECT_EQ(saved["name"], "mine");
  const json scene = api.callJson("GET", "/api/scenes/mine", nullptr, 200);
  EXPECT_EQ(scene["instances"][0]["name"], "drop");
  expectError(api.call("POST", "/api/scenes", json{{"name", "mine"}, {"session", id}}.dump()), 409, "conflict");
  api.callJson("POST", "/api/scenes", {{"name", "mine"}, {"session", id}, {"force", true}}, 201);
  const json list = api.callJson("GET", "/api/scenes", nullptr, 200);
  ASSERT_EQ(list["scenes"].size(), 2u);
  EXPECT_EQ(list["scenes"][1]["name"], "mine");
  EXPECT_EQ(list["scenes"][1]["instances"], 1);
  // The saved scene starts a session with its instance.
  const json s = api.callJson("POST", "/api/sessions", {{"scene", "mine"}}, 201);
  EXPECT_EQ(s["instances"], 1);
  EXPECT_EQ(api.tmp.entries().size(), 2u);  // templates, scenes: nothing else written
  for (auto& e : std::filesystem::directory_iterator(api.tmp.file("scenes")))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos);
}

// The parameter declarations the inspector is built from: the same specs the
// scene parser validates with (names, ranges, defaults per dimension).
TEST(RestApi, ParametersAreTheDeclarations) {
  Api api;
  const json p2 = api.callJson("GET", "/api/parameters", nullptr, 200);
  const json p3 = api.callJson("GET", "/api/parameters?dimension=3", nullptr, 200);
  EXPECT_EQ(p2["dimension"], 2);
  EXPECT_EQ(p3["dimension"], 3);
  auto find = [](const json& list, const std::string& name) {
    for (const json& s : list)
      if (s["name"] == name) return s;
    return json();
  };
  ASSERT_EQ(p2["instance"].size(), instanceParamSpecs(2).size());
  for (const ParamSpec& spec : instanceParamSpecs(2)) {
    const json j = find(p2["instance"], spec.name);
    ASSERT_FALSE(j.is_null()) << spec.name;
    EXPECT_EQ(j["min"].get<double>(), spec.min) << spec.name;
    EXPECT_EQ(j["max"].get<double>(), spec.max) << spec.name;
    EXPECT_EQ(j["unit"], spec.unit) << spec.name;
  }
  // Paper §4 defaults differ by dimension.
  EXPECT_DOUBLE_EQ(find(p2["instance"], "attraction_weight")["default"].get<double>(), 0.2);
  EXPECT_DOUBLE_EQ(find(p3["instance"], "attraction_weight")["default"].get<double>(), 0.06);
  const json rep = find(p2["instance"], "repulsion");
  EXPECT_EQ(rep["type"], "boolean");
  EXPECT_EQ(rep["default"], true);
  EXPECT_EQ(find(p2["control"], "temporary_grace_frames")["type"], "integer");
  EXPECT_DOUBLE_EQ(find(p2["settings"], "cfl_factor")["default"].get<double>(), 1.0);
  ASSERT_TRUE(p2["solvers"].contains("dfsph"));
  ASSERT_TRUE(p2["solvers"].contains("wcsph"));
  EXPECT_DOUBLE_EQ(find(p2["solvers"]["dfsph"]["params"], "density_tolerance_pct")["default"].get<double>(), 0.01);
  EXPECT_TRUE(p2["effects"].contains("viscosity_standard"));
  expectError(api.call("GET", "/api/parameters?dimension=4"), 400, "bad_request", "dimension");
}

// The accuracy presets: the study's file as written, checked against the
// declarations a settings PATCH accepts; without the file, none and why.
TEST(RestApi, PresetsAreTheStudysFileCheckedAgainstTheDeclarations) {
  Api api;
  const json none = api.callJson("GET", "/api/presets", nullptr, 200);
  EXPECT_TRUE(none["presets"].empty());
  EXPECT_EQ(none["missing"], api.tmp.file("presets.json"));
  json file = json::parse(R"({"source": "flowclip bench accuracy", "presets": [
    {"name": "draft", "description": "blocking out",
     "solver": {"method": "dfsph", "density_tolerance_pct": 1.0, "divergence_tolerance_pct": 1.0},
     "settings": {"cfl_factor": 1.0},
     "cost": {"us_per_particle_step": 1.5, "ms_per_frame": 4.0, "wall_s_per_sim_s": 0.24},
     "error": {"avg_density_error_pct": 0.8, "max_density_error_pct": 5.0, "volume_drift_pct": 0.9, "surge_front_rms": 0.05}}]})");
  std::ofstream(api.tmp.file("presets.json")) << file.dump();
  EXPECT_EQ(api.callJson("GET", "/api/presets", nullptr, 200), file);
  // A preset the editor could not apply is refused, naming the key.
  json bad = file;
  bad["presets"][0]["settings"]["cfl"] = 0.5;
  std::ofstream(api.tmp.file("presets.json")) << bad.dump();
  HttpResponse r = api.call("GET", "/api/presets");
  EXPECT_EQ(r.status, 500);
  EXPECT_NE(r.body.find("presets[0].settings.cfl: not a scene setting"), std::string::npos) << r.body;
  bad = file;
  bad["presets"][0]["solver"]["method"] = "pcisph";
  std::ofstream(api.tmp.file("presets.json")) << bad.dump();
  r = api.call("GET", "/api/presets");
  EXPECT_NE(r.body.find("presets[0].solver.method: unknown solver method 'pcisph'"), std::string::npos) << r.body;
  std::ofstream(api.tmp.file("presets.json")) << "{\"presets\": [";
  r = api.call("GET", "/api/presets");
  EXPECT_EQ(r.status, 500);
  EXPECT_NE(r.body.find("not JSON"), std::string::npos) << r.body;
}

// The library's thumbnail: one frame's positions, thinned to at most `max`.
TEST(RestApi, TemplatePreviewIsOneFrameThinnedToMax) {
  Api api;
  const json mid = api.callJson("GET", "/api/templates/blob/preview", nullptr, 200);
  EXPECT_EQ(mid["dimension"], 2);
  EXPECT_EQ(mid["frames"], 13);
  EXPECT_EQ(mid["frame"], 6);  // the middle frame by default
  EXPECT_EQ(mid["particles"], 16);
  EXPECT_EQ(mid["positions"].size(), 32u);
  // Frame 12 is frame 0 moved up by 12 mm (writeSmallTemplate): the same x, y + 0.012.
  const json first = api.callJson("GET", "/api/templates/blob/preview?frame=0", nullptr, 200);
  const json last = api.callJson("GET", "/api/templates/blob/preview?frame=12", nullptr, 200);
  double ySum0 = 0, ySum12 = 0;
  for (size_t i = 1; i < 32; i += 2) {
    ySum0 += first["positions"][i].get<double>();
    ySum12 += last["positions"][i].get<double>();
  }
  EXPECT_NEAR((ySum12 - ySum0) / 16, 0.012, 2e-4);
  const json thin = api.callJson("GET", "/api/templates/blob/preview?max=5", nullptr, 200);
  EXPECT_LE(thin["positions"].size() / 2, 5u);
  EXPECT_EQ(thin["stride"], 4);
  for (const json& v : thin["positions"]) EXPECT_TRUE(v.get<double>() >= 0.0 && v.get<double>() <= 0.4);
  expectError(api.call("GET", "/api/templates/blob/preview?frame=13"), 400, "bad_request", "frame");
  expectError(api.call("GET", "/api/templates/blob/preview?max=0"), 400, "bad_request", "max");
  expectError(api.call("GET", "/api/templates/blob/preview?frame=x"), 400, "bad_request", "frame");
  expectError(api.call("GET", "/api/templates/nothing/preview"), 404, "not_found", "name");
  // Not a template file: 422 naming the file, and the server goes on.
  std::ofstream(api.tmp.file("templates/junk.h5")) << "not hdf5";
  expectError(api.call("GET", "/api/templates/junk/preview"), 422, "unprocessable", "name");
  api.callJson("GET", "/api/templates/blob/preview", nullptr, 200);
}

TEST(RestApi, ExportAndTemplateRecordingFromTheHistory) {
  Api api;
  const std::string id = api.createSession();
  const std::string base = "/api/sessions/" + id;
  api.callJson("POST", base + "/transport", {{"command", "step"}, {"frames", 4}}, 200);
  api.settle(id);
  const json e = api.callJson("POST", base + "/export", {{"name", "run1"}}, 201);
  EXPECT_EQ(e["frames"], 5);
  EXPECT_EQ(e["particle_rows"], 500);
  EXPECT_TRUE(std::filesystem::exists(api.tmp.file("exports/run1.h5")));
  EXPECT_TRUE(std::filesystem::exists(api.tmp.file("exports/run1.xdmf")));
  expectError(api.call("POST", base + "/export", json{{"name", "run1"}}.dump()), 409, "conflict", "name");
  const HttpResponse xdmf = api.call("GET", "/api/exports/run1.xdmf");
  EXPECT_EQ(xdmf.status, 200);
  EXPECT_NE(xdmf.body.find("run1.h5"), std::string::npos);
  expectError(api.call("GET", "/api/exports/run2.h5"), 404, "not_found");

  const json t = api.callJson("POST", base + "/templates",
                              {{"name", "pool"}, {"region_min", {0.0, 0.0}}, {"region_max", {0.5, 0.5}},
                               {"first_frame", 1}, {"last_frame", 4}},
                              201);
  EXPECT_EQ(t["frames"], 4);
  EXPECT_EQ(t["dimension"], 2);
  EXPECT_NEAR(t["avg_particles"].get<double>(), 100, 1e-9);
  EXPECT_EQ(api.callJson("GET", "/api/templates/pool", nullptr, 200)["frames"], 4);
  expectError(api.call("POST", base + "/templates",
                       json{{"name", "pool"}, {"region_min", {0.0, 0.0}}, {"region_max", {0.5, 0.5}},
                            {"first_frame", 1}, {"last_frame", 4}}
                           .dump()),
              409, "conflict", "name");
  expectError(api.call("POST", base + "/templates",
                       json{{"name", "late"}, {"region_min", {0.0, 0.0}}, {"region_max", {0.5, 0.5}},
                            {"first_frame", 2}, {"last_frame", 40}}
                           .dump()),
              422, "unprocessable");
  expectError(api.call("POST", base + "/templates",
                       json{{"name", "flat"}, {"region_min", {0.0}}, {"region_max", {0.5, 0.5}},
                            {"first_frame", 0}, {"last_frame", 1}}
                           .dump()),
              400, "bad_request", "region_min");
  api.callJson("DELETE", "/api/templates/pool", nullptr, 200);
  expectError(api.call("GET", "/api/templates/pool"), 404, "not_found");
}

}  // namespace
}  // namespace fc::service
