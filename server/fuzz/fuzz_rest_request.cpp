// Fuzz target: REST request handling (service/rest_api.h) without the
// network: the bytes are one request in a small HTTP-like text form,
//
//   METHOD SP TARGET LF          TARGET = path [ "?" query ], path percent-encoded
//   name ":" value LF ...        headers (names lower-cased), until an empty line
//   LF body...                   everything after the empty line, raw bytes
//
// handed to ServiceHub::handle on one hub whose template, scene and export
// directories are fresh temporary ones, holding a tiny 2D scene `tiny`
// (about 50 particles, one instance), the template `tiny` recorded from it
// at start-up, and one live session with the fixed id `fuzz` (paused).
//
// Checked for every request (proto/openapi.yaml, rest_api.h):
//   - the status is in 200..599, and not 500: an internal error means an
//     exception no handler expected (FLOWCLIP_FUZZ_ALLOW_500=1 turns this off);
//   - a JSON response (Content-Type application/json) is valid JSON, UTF-8
//     included (nlohmann's strict parser), and an error status carries
//     {"error": {"status", "code", "message", ...}} with the same status.
// Plus every sanitizer check, and no exception may escape handle().
//
// State. Requests may change the directories and sessions; after any
// request other than GET/HEAD the fixture is put back (extra sessions
// deleted, session `fuzz` rebuilt if a successful request addressed a
// session, scenes, templates and exports restored), so each input starts
// from the same state.
//
// Sessions. Creating one from a scene name (`tiny`, `blank`) is exercised,
// at most 3 sessions at once. Creating one from a VALID inline scene object
// whose domain holds more than 20 000 particle-sized cells is skipped (the
// input is ignored): such a scene is bounded only by max_particles (50 M),
// so the fuzzer would measure allocation speed and hit its memory limit;
// io/scene.cpp's validation of any scene is fuzzed by fuzz_scene_parser.
// Invalid and small inline scenes go to the server.
#include "fuzz_support.h"
#include "io/scene.h"
#include "service/rest_api.h"

#include <nlohmann/json.hpp>
#include <omp.h>

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

namespace {

namespace fs = std::filesystem;
namespace svc = fc::service;
using nlohmann::json;

// About 50 liquid particles in a 0.2 m tank: a frame takes a few ms.
const char* const kBlankScene = R"({
  "name": "blank", "dimension": 2, "particle_radius": 0.005,
  "domain": {"min": [0, 0], "max": [0.2, 0.2]}, "duration": 1,
  "fluid_blocks": [{"min": [0.05, 0], "max": [0.15, 0.05]}],
  "settings": {"frame_rate": 60}
})";

json tinyScene() {
  json j = json::parse(kBlankScene);
  j["name"] = "tiny";
  j["instances"] = json::array({{{"name", "drop"}, {"template", "tiny"}, {"start", 0}}});
  return j;
}

struct Fixture {
  fs::path root, templates, scenes, exports, templateBackup;
  std::unique_ptr<svc::ServiceHub> hub;
  bool allow500 = false;
};
Fixture* fixture = nullptr;

[[noreturn]] void setupFailed(const std::string& what) {
  std::fprintf(stderr, "fuzz_rest_request: setting up the fixture failed: %s\n", what.c_str());
  std::exit(2);
}

svc::HttpResponse call(const std::string& method, const std::string& path, const std::string& body = {}) {
  svc::HttpRequest r;
  r.method = method;
  r.path = path;
  r.body = body;
  if (!body.empty()) r.headers["content-type"] = "application/json";
  return fixture->hub->handle(r);
}

void writeFile(const fs::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary);
  f << text;
  if (!f) setupFailed("cannot write " + p.string());
}

svc::SessionOptions sessionOptions() {
  svc::SessionOptions so;
  so.historyCapBytes = size_t(4) << 20;
  so.threads = 1;
  return so;
}

void createFuzzSession() {
  std::shared_ptr<svc::Session> s =
      svc::createSession("fuzz", "", tinyScene(), fixture->hub->templates(), sessionOptions());
  fixture->hub->adoptSession(std::move(s));
}

void setUp() {
  omp_set_num_threads(1);
  fixture = new Fixture;
  Fixture& f = *fixture;
  f.allow500 = !fc::fuzz::env("FLOWCLIP_FUZZ_ALLOW_500", "").empty();
  std::string tmpl = (fs::temp_directory_path() / "flowclip-fuzz-rest-XXXXXX").string();
  if (!mkdtemp(tmpl.data())) setupFailed("mkdtemp");
  f.root = tmpl;
  f.templates = f.root / "templates";
  f.scenes = f.root / "scenes";
  f.exports = f.root / "exports";
  for (const fs::path& d : {f.templates, f.scenes, f.exports, f.root / "backup"}) fs::create_directories(d);
  writeFile(f.scenes / "blank.json", kBlankScene);

  svc::ServiceOptions o;
  o.templatesDir = f.templates.string();
  o.scenesDir = f.scenes.string();
  o.exportsDir = f.exports.string();
  o.presetsFile = std::string(FLOWCLIP_SOURCE_DIR) + "/bench/accuracy/presets.json";
  o.maxSessions = 3;
  o.historyCapBytes = size_t(4) << 20;
  o.editWait = std::chrono::milliseconds(2000);
  f.hub = std::make_unique<svc::ServiceHub>(o);

  // The template `tiny`: 6 frames of the blank scene's liquid, recorded
  // through the API itself.
  svc::HttpResponse r = call("POST", "/api/sessions", R"({"scene": "blank", "name": "recorder", "threads": 1})");
  if (r.status != 201) setupFailed("creating the recording session: " + r.body);
  const std::string id = json::parse(r.body)["id"].get<std::string>();
  r = call("POST", "/api/sessions/" + id + "/transport", R"({"command": "step", "frames": 6})");
  if (r.status != 200) setupFailed("stepping: " + r.body);
  if (!f.hub->session(id)->waitIdle(std::chrono::seconds(60))) setupFailed("the recording session did not pause");
  r = call("POST", "/api/sessions/" + id + "/templates",
           R"({"name": "tiny", "region_min": [0.04, 0], "region_max": [0.16, 0.08], "first_frame": 0, "last_frame": 6})");
  if (r.status != 201) setupFailed("recording the template: " + r.body);
  call("DELETE", "/api/sessions/" + id);
  f.templateBackup = f.root / "backup" / "tiny.h5";
  fs::copy_file(f.templates / "tiny.h5", f.templateBackup);
  writeFile(f.scenes / "tiny.json", tinyScene().dump(1));
  createFuzzSession();
  std::atexit([] {
    if (!fixture) return;
    fixture->hub.reset();  // stops every session
    std::error_code ec;
    fs::remove_all(fixture->root, ec);
  });
}

// ---- the input -----------------------------------------------------------------

svc::HttpRequest parseRequest(const std::string& in) {
  svc::HttpRequest r;
  size_t eol = in.find('\n');
  const std::string first = in.substr(0, eol);
  const size_t sp = first.find(' ');
  r.method = first.substr(0, sp);
  const std::string target = sp == std::string::npos ? std::string("/") : first.substr(sp + 1);
  const size_t q = target.find('?');
  r.path = target.substr(0, q);
  if (q != std::string::npos) r.query = target.substr(q + 1);
  size_t pos = eol == std::string::npos ? in.size() : eol + 1;
  while (pos < in.size()) {
    eol = in.find('\n', pos);
    const std::string line = in.substr(pos, eol == std::string::npos ? std::string::npos : eol - pos);
    pos = eol == std::string::npos ? in.size() : eol + 1;
    if (line.empty()) break;  // the body follows
    const size_t colon = line.find(':');
    std::string name = line.substr(0, colon);
    std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    std::string value = colon == std::string::npos ? std::string() : line.substr(colon + 1);
    value.erase(0, value.find_first_not_of(' '));
    r.headers[name] = value;
  }
  if (pos < in.size()) r.body = in.substr(pos);
  return r;
}

// The path's segments, percent-decoded as the route matcher decodes them.
std::vector<std::string> segments(const std::string& path) {
  std::vector<std::string> out;
  std::string cur;
  auto hex = [](char c) { return std::isxdigit(static_cast<unsigned char>(c)) != 0; };
  for (size_t i = 0; i <= path.size(); ++i) {
    if (i == path.size() || path[i] == '/') {
      if (!cur.empty()) out.push_back(cur);
      cur.clear();
    } else if (path[i] == '%' && i + 2 < path.size() && hex(path[i + 1]) && hex(path[i + 2])) {
      cur.push_back(char(std::stoi(path.substr(i + 1, 2), nullptr, 16)));
      i += 2;
    } else {
      cur.push_back(path[i]);
    }
  }
  return out;
}

// An inline scene whose domain holds at most this many particle-sized cells
// (2r on a side) may create a session: at most that many liquid particles.
constexpr double kMaxInlineCells = 20000;

template <int D>
bool smallScene(const json& scene) {
  const fc::SimulationSetup<D> s = fc::parseScene<D>(scene);
  double cells = 1;
  for (int d = 0; d < D; ++d) cells *= double(s.domain.max[d] - s.domain.min[d]) / (2 * double(s.particleRadius));
  return cells <= kMaxInlineCells;
}

// POST /api/sessions with an inline scene object that is valid and larger
// than kMaxInlineCells: skipped (see the top of this file). An invalid one is
// let through: the server must reject it (any exception that reaches
// ServiceHub::handle unexpected is a 500, a finding).
bool createsLargeInlineSession(const svc::HttpRequest& r, const std::vector<std::string>& seg) {
  if (r.method != "POST" || seg != std::vector<std::string>{"api", "sessions"}) return false;
  const json body = json::parse(r.body, nullptr, /*allow_exceptions=*/false);
  if (!body.is_object() || !body.contains("scene") || !body["scene"].is_object()) return false;
  try {
    const json& scene = body["scene"];
    return fc::sceneDimension(scene) == 2 ? !smallScene<2>(scene) : !smallScene<3>(scene);
  } catch (...) {
    return false;
  }
}

// ---- checks and restoring the fixture -----------------------------------------

std::string describe(const svc::HttpRequest& req, const svc::HttpResponse& resp) {
  return req.method + " " + req.path + (req.query.empty() ? "" : "?" + req.query) + " -> " +
         std::to_string(resp.status) + " " + resp.contentType + "\n" + resp.body.substr(0, 2000);
}

void checkResponse(const svc::HttpRequest& req, const svc::HttpResponse& resp) {
  FUZZ_CHECK(resp.status >= 200 && resp.status <= 599, describe(req, resp));
  FUZZ_CHECK(resp.status != 500 || fixture->allow500, "internal error: " + describe(req, resp));
  if (resp.contentType != "application/json") return;
  json body;
  try {
    body = json::parse(resp.body);
  } catch (const json::exception& e) {
    fc::fuzz::fail(__FILE__, __LINE__, "the response body is not valid JSON", std::string(e.what()) + "\n" + describe(req, resp));
  }
  if (resp.status >= 400) {
    const bool shaped = body.is_object() && body.contains("error") && body["error"].is_object() &&
                        body["error"].value("status", 0) == resp.status && body["error"].contains("code") &&
                        body["error"]["code"].is_string() && body["error"].contains("message") &&
                        body["error"]["message"].is_string();
    FUZZ_CHECK(shaped, "an error without {\"error\": {status, code, message}}: " + describe(req, resp));
  }
}

void removeAllBut(const fs::path& dir, const std::vector<std::string>& keep) {
  std::error_code ec;
  std::vector<fs::path> extra;
  for (const auto& e : fs::directory_iterator(dir, ec))
    if (std::find(keep.begin(), keep.end(), e.path().filename().string()) == keep.end()) extra.push_back(e.path());
  for (const fs::path& p : extra) fs::remove_all(p, ec);
}

void restore(const std::vector<std::string>& seg, int status) {
  Fixture& f = *fixture;
  if (f.hub->sessionCount() != 1 || !f.hub->session("fuzz")) {
    const json list = json::parse(call("GET", "/api/sessions").body);
    for (const json& s : list["sessions"]) {
      const std::string id = s["id"].get<std::string>();
      if (id != "fuzz") call("DELETE", "/api/sessions/" + id);
    }
  }
  // A request that failed changed no session (rest_api.h: a rejected edit
  // changes nothing); one that succeeded may have stepped, edited or reset
  // one, so `fuzz` is rebuilt (some 10 ms).
  const bool changedSession = status < 300 && seg.size() >= 2 && seg[1] == "sessions";
  if (changedSession || !f.hub->session("fuzz")) {
    if (f.hub->session("fuzz")) call("DELETE", "/api/sessions/fuzz");
    createFuzzSession();
  }
  removeAllBut(f.scenes, {"blank.json", "tiny.json"});
  removeAllBut(f.exports, {});
  removeAllBut(f.templates, {"tiny.h5"});
  std::error_code ec;
  if (!fs::exists(f.templates / "tiny.h5", ec)) fs::copy_file(f.templateBackup, f.templates / "tiny.h5", ec);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const svc::HttpRequest req = parseRequest(std::string(reinterpret_cast<const char*>(data), size));
  const std::vector<std::string> seg = segments(req.path);
  if (createsLargeInlineSession(req, seg)) return -1;  // not added to the corpus
  const svc::HttpResponse resp = fixture->hub->handle(req);
  checkResponse(req, resp);
  if (req.method != "GET" && req.method != "HEAD") restore(seg, resp.status);
  return 0;
}
