#include "service/rest_api.h"

#include "core/text.h"
#include "io/json_text.h"
#include "io/scene.h"
#include "io/staged_files.h"
#include "io/stats_json.h"
#include "io/template_file.h"
#include "service/frame_encoding.h"
#include "service/recipe_jobs.h"
#include "control/instance.h"
#include "sph/pipeline.h"
#include "sph/limits.h"
#include "sph/settings.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>
#include <unistd.h>

namespace fc::service {

using json = nlohmann::json;
namespace fs = std::filesystem;

// ---- errors --------------------------------------------------------------------

ApiError::ApiError(int s, std::string message, std::string p)
    : std::runtime_error(std::move(message)), status(s), path(std::move(p)) {}

const char* errorCode(int status) {
  switch (status) {
    case 400: return "bad_request";
    case 401: return "unauthorized";
    case 403: return "forbidden";
    case 404: return "not_found";
    case 405: return "method_not_allowed";
    case 409: return "conflict";
    case 413: return "payload_too_large";
    case 415: return "unsupported_media_type";
    case 422: return "unprocessable";
    case 429: return "too_many_sessions";
    case 500: return "internal_error";
    case 503: return "unavailable";
    default: return status < 500 ? "bad_request" : "internal_error";
  }
}

// Messages echo client bytes (paths, names, headers): made printable here,
// so that no error can fail to serialise.
HttpResponse errorResponse(int status, const std::string& message, const std::string& path) noexcept {
  HttpResponse r;
  r.status = status;
  try {
    json e = {{"status", status}, {"code", errorCode(status)}, {"message", printable(message)}};
    if (!path.empty()) e["path"] = printable(path, 300);
    r.body = json{{"error", e}}.dump(-1, ' ', false, json::error_handler_t::replace);
  } catch (...) {
    r.body = R"({"error":{"status":500,"code":"internal_error","message":"the error could not be described"}})";
    r.status = 500;
  }
  return r;
}

namespace {

HttpResponse jsonResponse(const json& j, int status = 200) {
  HttpResponse r;
  r.status = status;
  // Replace rather than throw on invalid UTF-8 from file names or scene text.
  r.body = j.dump(-1, ' ', false, json::error_handler_t::replace);
  return r;
}

std::string percentDecode(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(uint8_t(s[i + 1])) && std::isxdigit(uint8_t(s[i + 2]))) {
      out.push_back(char(std::stoi(s.substr(i + 1, 2), nullptr, 16)));
      i += 2;
    } else {
      out.push_back(s[i]);
    }
  }
  return out;
}

std::vector<std::string> splitPath(const std::string& path) {
  std::vector<std::string> parts;
  size_t i = 0;
  while (i < path.size()) {
    if (path[i] == '/') {
      ++i;
      continue;
    }
    const size_t j = path.find('/', i);
    parts.push_back(percentDecode(path.substr(i, j == std::string::npos ? std::string::npos : j - i)));
    if (j == std::string::npos) break;
    i = j;
  }
  return parts;
}

std::string queryValue(const std::string& query, const std::string& key) {
  std::istringstream in(query);
  std::string kv;
  while (std::getline(in, kv, '&')) {
    const size_t eq = kv.find('=');
    if (percentDecode(kv.substr(0, eq)) == key) return eq == std::string::npos ? "" : percentDecode(kv.substr(eq + 1));
  }
  return {};
}

// Names in URLs and bodies share the template database's rule, so no name
// can reach outside its directory ("..", "/", "%2F" are all refused).
void checkName(const std::string& name, const std::string& what) {
  if (!isValidTemplateName(name))
    throw ApiError(400, what + " name \"" + name.substr(0, 80) +
                            "\" is invalid: names are 1 to 64 characters from A-Z a-z 0-9 _ -",
                   what);
}

json parseBody(const HttpRequest& req, bool required = true) {
  if (req.body.empty()) {
    if (required) throw ApiError(400, "the request needs a JSON body");
    return json::object();
  }
  return parseJsonLimited(req.body);
}

const json& requireObject(const json& body) {
  if (!body.is_object()) throw ApiError(400, std::string("the body must be a JSON object, not ") + body.type_name());
  return body;
}

void onlyKeys(const json& body, std::initializer_list<const char*> keys) {
  for (auto it = body.begin(); it != body.end(); ++it) {
    bool known = false;
    for (const char* k : keys) known = known || it.key() == k;
    if (!known) {
      std::string list;
      for (const char* k : keys) list += (list.empty() ? "" : ", ") + std::string(k);
      throw ApiError(400, "unknown key \"" + it.key() + "\" (expected: " + list + ")", it.key());
    }
  }
}

std::string getString(const json& body, const char* key, bool required, const std::string& fallback = {}) {
  if (!body.contains(key)) {
    if (required) throw ApiError(400, std::string("\"") + key + "\" is required", key);
    return fallback;
  }
  if (!body[key].is_string())
    throw ApiError(400, std::string("\"") + key + "\" must be a string, not " + body[key].type_name(), key);
  return body[key].get<std::string>();
}

int64_t getInt(const json& body, const char* key, bool required, int64_t fallback, int64_t min, int64_t max,
               const char* why = nullptr) {
  if (!body.contains(key)) {
    if (required) throw ApiError(400, std::string("\"") + key + "\" is required", key);
    return fallback;
  }
  const json& v = body[key];
  if (!v.is_number_integer())
    throw ApiError(400, std::string("\"") + key + "\" must be an integer, not " + v.type_name(), key);
  const int64_t x = v.get<int64_t>();
  if (x < min || x > max)
    throw ApiError(400, std::string("\"") + key + "\" must be in [" + std::to_string(min) + ", " + std::to_string(max) +
                            "], got " + std::to_string(x) + (why ? std::string(" (") + why + ")" : ""),
                   key);
  return x;
}

double getNumber(const json& body, const char* key, bool required, double fallback, double min, double max,
                 const char* why = nullptr) {
  if (!body.contains(key)) {
    if (required) throw ApiError(400, std::string("\"") + key + "\" is required", key);
    return fallback;
  }
  const json& v = body[key];
  if (!v.is_number()) throw ApiError(400, std::string("\"") + key + "\" must be a number, not " + v.type_name(), key);
  const double x = v.get<double>();
  if (!std::isfinite(x) || x < min || x > max) {
    char buf[160];
    std::snprintf(buf, sizeof buf, "\"%s\" must be in [%g, %g], got %g%s%s%s", key, min, max, x, why ? " (" : "",
                  why ? why : "", why ? ")" : "");
    throw ApiError(400, buf, key);
  }
  return x;
}

bool getBool(const json& body, const char* key, bool fallback) {
  if (!body.contains(key)) return fallback;
  if (!body[key].is_boolean())
    throw ApiError(400, std::string("\"") + key + "\" must be true or false, not " + body[key].type_name(), key);
  return body[key].get<bool>();
}

json templateEntryJson(const TemplateEntry& e) {
  json j = {{"name", e.name}};
  if (!e.error.empty()) {
    j["error"] = e.error;
    return j;
  }
  j.update({{"dimension", e.dimension},
            {"frames", e.frames},
            {"frame_rate", e.frameRate},
            {"duration", e.duration},
            {"avg_particles", e.avgParticles},
            {"region_min", e.regionMin},
            {"region_max", e.regionMax},
            {"bytes", e.bytesOnDisk}});
  return j;
}

json instancesOf(const json& scene) {
  return scene.contains("instances") && scene["instances"].is_array() ? scene["instances"] : json::array();
}

json findInstance(const json& scene, const std::string& name) {
  for (const json& inst : instancesOf(scene))
    if (inst.value("name", "") == name) return inst;
  return nullptr;
}

// Writes `text` to `path` through a temporary file in the same directory:
// readers see the old file or the new one, never a part. Without `replace`
// the final link fails if the name exists (even if it appeared meanwhile).
void writeFileAtomically(const fs::path& path, const std::string& text, bool replace) {
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  try {
    publishFile(path.string(), text, replace);  // io/staged_files.h: old or new file, also after a crash
  } catch (const PublishError& e) {
    if (e.exists) throw ApiError(409, path.filename().string() + " already exists (send \"force\": true to replace it)", "name");
    throw std::runtime_error("cannot write " + path.string() + ": " + e.what());
  }
}

json instanceSnapshotJson(const InstanceSnapshot& s) {
  return {{"name", s.name},
          {"template", s.templateName},
          {"phase", s.phase},
          {"active", s.active},
          {"template_frame", s.templateFrame},
          {"fidelity", s.fidelity},
          {"world_matrix", s.toWorld},
          {"region_min", s.regionMin},
          {"region_max", s.regionMax},
          {"falloff_width", s.falloffWidth}};
}

json frameStatsEntry(const FrameSnapshot& f) {
  json j = frameStatsToJson(f.stats, !f.instances.empty());
  j["frame"] = f.frame;
  j["time"] = f.time;
  return j;
}

}  // namespace

void encodeSnapshot(const FrameSnapshot& f, const std::string& sessionId, const wire::LayerFlags& layers,
                    flatbuffers::FlatBufferBuilder& fbb) {
  // Records are views into the snapshot, which outlives the call.
  std::vector<wire::InstanceRecord> records(f.instances.size());
  for (size_t i = 0; i < records.size(); ++i) {
    const InstanceSnapshot& src = f.instances[i];
    wire::InstanceRecord& r = records[i];
    r.name = src.name;
    r.templateName = src.templateName;
    r.active = src.active;
    r.templateFrame = src.templateFrame;
    r.phase = src.phase;
    r.setWorldFromColumnMajor4x4(src.toWorld, f.dimension);
    r.templateMin = src.regionMin;
    r.templateMax = src.regionMax;
    r.falloffWidth = src.falloffWidth;
    r.fidelity = src.fidelity;
    // The frame's stats hold what control did per instance (the editor tells an instance that steers nothing).
    if (f.stats.instances.size() == records.size() && f.stats.instances[i].name == src.name)
      r.controlled = f.stats.instances[i].controlled;
  }
  wire::QuantizedFrame q;
  q.sessionId = sessionId;
  q.dimension = f.dimension;
  q.domainMin = f.domainMin;
  q.domainMax = f.domainMax;
  q.positions = f.positions;
  q.kind = f.kind;
  q.phase = f.phase;
  q.velocities = f.velocities;
  q.velocityMax = f.velocityMax;
  q.stats = &f.stats;
  q.instances = records;
  wire::encodeQuantizedFrame(q, layers, fbb);
}

wire::StateChangeInfo stateChangeInfo(const json& state, uint32_t requestId) {
  static const std::map<std::string, wire::fb::SessionStatus> statuses = {
      {"paused", wire::fb::SessionStatus::Paused},
      {"playing", wire::fb::SessionStatus::Playing},
      {"stepping", wire::fb::SessionStatus::Stepping},
      {"error", wire::fb::SessionStatus::Error}};
  wire::StateChangeInfo info;
  info.sessionId = state.value("id", "");
  auto st = statuses.find(state.value("status", "paused"));
  info.status = st == statuses.end() ? wire::fb::SessionStatus::Paused : st->second;
  info.frame = state.value("frame", 0);
  info.time = state.value("time", 0.0);
  if (state.contains("shown")) {
    info.shownFrame = state["shown"].value("frame", 0);
    info.live = state["shown"].value("live", true);
  }
  info.playbackSpeed = state.value("playback_speed", 0.0);
  if (state.contains("history")) {
    const json& h = state["history"];
    info.historyFirstFrame = h["first"].is_number() ? h["first"].get<int>() : 0;
    info.historyLastFrame = h["last"].is_number() ? h["last"].get<int>() : 0;
    info.historyDroppedFrames = h.value("dropped", 0u);
  }
  if (state.contains("error")) info.message = state["error"].value("message", "");
  info.requestId = requestId;
  info.stateJson = state.dump(-1, ' ', false, json::error_handler_t::replace);
  return info;
}

json parseJsonLimited(const std::string& text) {
  JsonTextOptions options;
  options.maxDepth = kMaxJsonDepth;
  try {
    return parseJsonText(text, options);
  } catch (const JsonTextError& e) {
    switch (e.kind) {
      case JsonTextError::Kind::Syntax:
        throw ApiError(400, "malformed JSON" + (e.where.empty() ? "" : " at " + e.where) + ": " + e.detail, e.path);
      case JsonTextError::Kind::TooDeep:
        throw ApiError(400, e.detail + (e.path.empty() ? "" : " (at " + e.path + ")"), e.path);
      default:
        throw ApiError(400, e.detail, e.path);
    }
  }
}

double currentRssMb() {
  std::ifstream f("/proc/self/statm");
  long pages = 0, resident = 0;
  f >> pages >> resident;
  return double(resident) * double(::sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

// ---- the hub -------------------------------------------------------------------

ServiceHub::ServiceHub(ServiceOptions options)
    : options_(std::move(options)), database_(options_.templatesDir), started_(std::chrono::steady_clock::now()) {
  if (options_.maxThreads <= 0) options_.maxThreads = std::max(1, int(std::thread::hardware_concurrency()));
  if (options_.recordThreads <= 0) options_.recordThreads = std::max(1, int(std::thread::hardware_concurrency()) / 2);
  recipeJobs_ = std::make_unique<RecipeJobs>(
      RecipeJobsOptions{options_.recipesDir, options_.templatesDir, options_.recordThreads});
}

ServiceHub::~ServiceHub() {
  std::map<std::string, std::shared_ptr<Session>> sessions;
  {
    std::lock_guard lk(mutex_);
    sessions.swap(sessions_);
  }
  for (auto& [id, s] : sessions) s->pause();
}

const std::vector<ServiceHub::Route>& ServiceHub::routes() {
  static const std::vector<Route> table = {
      {"GET", "/api/health", &ServiceHub::health},
      {"GET", "/api/parameters", &ServiceHub::parameters},
      {"GET", "/api/presets", &ServiceHub::presets},
      {"GET", "/api/templates", &ServiceHub::listTemplates},
      {"GET", "/api/templates/{name}", &ServiceHub::getTemplate},
      {"DELETE", "/api/templates/{name}", &ServiceHub::deleteTemplate},
      {"GET", "/api/templates/{name}/preview", &ServiceHub::templatePreview},
      {"GET", "/api/scenes", &ServiceHub::listScenes},
      {"POST", "/api/scenes", &ServiceHub::saveScene},
      {"GET", "/api/scenes/{name}", &ServiceHub::getScene},
      {"GET", "/api/sessions", &ServiceHub::listSessions},
      {"POST", "/api/sessions", &ServiceHub::createSession},
      {"GET", "/api/sessions/{id}", &ServiceHub::getSession},
      {"DELETE", "/api/sessions/{id}", &ServiceHub::deleteSession},
      {"GET", "/api/sessions/{id}/stats", &ServiceHub::sessionStats},
      {"GET", "/api/sessions/{id}/scene", &ServiceHub::sessionScene},
      {"POST", "/api/sessions/{id}/templates", &ServiceHub::recordTemplate},
      {"GET", "/api/sessions/{id}/instances", &ServiceHub::listInstances},
      {"POST", "/api/sessions/{id}/instances", &ServiceHub::addInstance},
      {"GET", "/api/sessions/{id}/instances/{name}", &ServiceHub::getInstance},
      {"PATCH", "/api/sessions/{id}/instances/{name}", &ServiceHub::patchInstance},
      {"DELETE", "/api/sessions/{id}/instances/{name}", &ServiceHub::removeInstance},
      {"PATCH", "/api/sessions/{id}/settings", &ServiceHub::patchSettings},
      {"GET", "/api/sessions/{id}/edits/{edit}", &ServiceHub::getEdit},
      {"POST", "/api/sessions/{id}/transport", &ServiceHub::transport},
      {"GET", "/api/sessions/{id}/frames/{frame}", &ServiceHub::getFrame},
      {"POST", "/api/sessions/{id}/export", &ServiceHub::exportFrames},
      {"GET", "/api/exports/{file}", &ServiceHub::getExport},
      {"GET", "/api/recipes", &ServiceHub::listRecipes},
      {"POST", "/api/recipes/{name}/record", &ServiceHub::startRecipeJob},
      {"GET", "/api/recipes/jobs/{id}", &ServiceHub::getRecipeJob},
      {"DELETE", "/api/recipes/jobs/{id}", &ServiceHub::cancelRecipeJob},
  };
  return table;
}

HttpResponse ServiceHub::handle(const HttpRequest& req) {
  const std::vector<std::string> parts = splitPath(req.path);
  std::vector<std::string> allowed;
  for (const Route& route : routes()) {
    const std::vector<std::string> pattern = splitPath(route.pattern);
    if (pattern.size() != parts.size()) continue;
    Params params;
    bool match = true;
    for (size_t i = 0; i < parts.size() && match; ++i) {
      if (pattern[i].front() == '{') params.push_back(parts[i]);
      else match = pattern[i] == parts[i];
    }
    if (!match) continue;
    if (req.method != route.method && !(req.method == "HEAD" && std::string(route.method) == "GET")) {
      allowed.push_back(route.method);
      continue;
    }
    try {
      return (this->*route.handler)(req, params);
    } catch (const ApiError& e) {
      return errorResponse(e.status, e.what(), e.path);
    } catch (const RecipeJobError& e) {
      return errorResponse(e.status, e.what(), e.path);
    } catch (const SceneError& e) {
      return errorResponse(422, e.what(), e.path);
    } catch (const SessionOverloaded& e) {
      HttpResponse r = errorResponse(503, e.what());
      r.headers.emplace_back("Retry-After", "1");
      return r;
    } catch (const SessionError& e) {
      return errorResponse(409, e.what());
    } catch (const DatabaseError& e) {
      return errorResponse(404, e.what());
    } catch (const TemplateError& e) {
      return errorResponse(422, e.what());
    } catch (const std::out_of_range& e) {
      return errorResponse(422, e.what());
    } catch (const std::invalid_argument& e) {
      return errorResponse(422, e.what());
    } catch (const std::exception& e) {
      return errorResponse(500, std::string("internal error: ") + e.what());
    }
  }
  if (!allowed.empty()) {
    std::string allow;
    for (const auto& m : allowed) allow += (allow.empty() ? "" : ", ") + m;
    HttpResponse r = errorResponse(405, req.method + " is not allowed on " + req.path + " (allowed: " + allow + ")");
    r.headers.emplace_back("Allow", allow);
    return r;
  }
  return errorResponse(404, "no such endpoint: " + req.method + " " + req.path);
}

std::shared_ptr<Session> ServiceHub::session(const std::string& id) const {
  std::lock_guard lk(mutex_);
  auto it = sessions_.find(id);
  return it == sessions_.end() ? nullptr : it->second;
}

std::shared_ptr<Session> ServiceHub::requireSession(const std::string& id) const {
  auto s = session(id);
  if (!s) throw ApiError(404, "no session \"" + id.substr(0, 80) + "\"", "id");
  return s;
}

std::vector<std::shared_ptr<Session>> ServiceHub::allSessions() const {
  std::vector<std::shared_ptr<Session>> all;
  std::lock_guard lk(mutex_);
  for (const auto& [id, s] : sessions_) all.push_back(s);
  return all;
}

size_t ServiceHub::sessionCount() const {
  std::lock_guard lk(mutex_);
  return sessions_.size();
}

void ServiceHub::adoptSession(std::shared_ptr<Session> session) {
  std::lock_guard lk(mutex_);
  if (sessions_.count(session->id())) throw ApiError(409, "session id " + session->id() + " is taken");
  sessions_[session->id()] = std::move(session);
}

uint64_t ServiceHub::onSessionDeleted(const std::string& id, std::function<void()> callback) {
  {
    std::lock_guard lk(mutex_);
    if (sessions_.count(id)) {
      const uint64_t hook = nextHook_++;
      deletionHooks_.emplace(id, std::make_pair(hook, std::move(callback)));
      return hook;
    }
  }
  callback();
  return 0;
}

void ServiceHub::cancelOnSessionDeleted(uint64_t hook) {
  std::lock_guard lk(mutex_);
  for (auto it = deletionHooks_.begin(); it != deletionHooks_.end(); ++it)
    if (it->second.first == hook) {
      deletionHooks_.erase(it);
      return;
    }
}

// ---- health, templates, scenes ----------------------------------------------------

HttpResponse ServiceHub::health(const HttpRequest&, const Params&) {
  const double uptime = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
  return jsonResponse({{"status", "ok"},
                       {"version", FLOWCLIP_VERSION},
                       {"sessions", sessionCount()},
                       {"max_sessions", options_.maxSessions},
                       {"uptime_s", uptime},
                       {"rss_mb", currentRssMb()}});
}

namespace {

json specsJson(const ParamSpecs& specs) {
  json list = json::array();
  for (const ParamSpec& s : specs) {
    const char* type = s.type == ParamType::Boolean ? "boolean" : s.type == ParamType::Integer ? "integer" : "number";
    json j = {{"name", s.name}, {"unit", s.unit}, {"min", s.min}, {"max", s.max}, {"type", type}, {"help", s.help}};
    if (s.type == ParamType::Boolean) j["default"] = s.def != 0;
    else j["default"] = s.def;
    list.push_back(j);
  }
  return list;
}

template <class R>
json registryJson(const R& registry) {
  json out = json::object();
  for (const std::string& name : registry.names()) {
    const auto* e = registry.find(name);
    out[name] = {{"help", e->help}, {"params", specsJson(e->params)}};
  }
  return out;
}

json limitsJson() {
  json list = json::array();
  for (const PhysicalRange& r : physicalRanges())
    list.push_back({{"name", r.name}, {"unit", r.unit}, {"min", r.min}, {"max", r.max}, {"help", r.help}});
  return list;
}

template <int D>
json parametersJson() {
  registerBuiltinSolversAndEffects();
  return {{"dimension", D},
          {"instance", specsJson(instanceParamSpecs(D))},
          {"control", specsJson(controlSettingsSpecs())},
          {"settings", specsJson(simulationSettingsSpecs())},
          {"solvers", registryJson(PressureSolverRegistry<D>::instance())},
          {"effects", registryJson(EffectRegistry<D>::instance())},
          {"limits", limitsJson()}};
}

}  // namespace

// The one declaration of every parameter (name, unit, range, default, help):
// the editor's inspector builds its fields from it.
HttpResponse ServiceHub::parameters(const HttpRequest& req, const Params&) {
  const std::string d = queryValue(req.query, "dimension");
  if (d.empty() || d == "2") return jsonResponse(parametersJson<2>());
  if (d == "3") return jsonResponse(parametersJson<3>());
  throw ApiError(400, "query \"dimension\" must be 2 or 3, got \"" + d.substr(0, 40) + "\"", "dimension");
}

// The presets file as the study wrote it, checked against what a session's
// settings PATCH accepts: every solver and settings key must be declared
// (a preset the editor could not apply is refused here, naming the key).
// Without the file: no presets, and why.
HttpResponse ServiceHub::presets(const HttpRequest&, const Params&) {
  const std::string file = options_.presetsFile;
  std::ifstream in(file);
  if (!in) return jsonResponse({{"presets", json::array()}, {"source", nullptr}, {"missing", file}});
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {
    throw ApiError(500, file + ": not JSON: " + std::string(e.what()), "presets");
  }
  auto bad = [&](const std::string& where, const std::string& what) -> ApiError {
    return ApiError(500, file + ": " + where + ": " + what, "presets");
  };
  if (!j.is_object() || !j.contains("presets") || !j["presets"].is_array()) throw bad("presets", "expected an array");
  registerBuiltinSolversAndEffects();
  for (size_t i = 0; i < j["presets"].size(); ++i) {
    const json& p = j["presets"][i];
    const std::string at = "presets[" + std::to_string(i) + "]";
    if (!p.is_object() || !p.value("name", json()).is_string()) throw bad(at + ".name", "expected a string");
    for (const char* group : {"solver", "settings", "cost", "error"})
      if (!p.contains(group) || !p[group].is_object()) throw bad(at + "." + group, "expected an object");
    const std::string method = p["solver"].value("method", std::string("dfsph"));
    const auto* entry = PressureSolverRegistry<2>::instance().find(method);
    if (!entry) throw bad(at + ".solver.method", "unknown solver method '" + method + "'");
    for (auto it = p["solver"].begin(); it != p["solver"].end(); ++it)
      if (it.key() != "method" && !findSpec(entry->params, it.key()))
        throw bad(at + ".solver." + it.key(), "not a parameter of solver '" + method + "'");
    for (auto it = p["settings"].begin(); it != p["settings"].end(); ++it)
      if (!findSpec(simulationSettingsSpecs(), it.key())) throw bad(at + ".settings." + it.key(), "not a scene setting");
    for (const char* group : {"cost", "error"})
      for (auto it = p[group].begin(); it != p[group].end(); ++it)
        if (!it.value().is_number()) throw bad(at + "." + group + "." + it.key(), "expected a number");
  }
  return jsonResponse(j);
}

HttpResponse ServiceHub::listTemplates(const HttpRequest&, const Params&) {
  json list = json::array();
  for (const TemplateEntry& e : database_.list()) list.push_back(templateEntryJson(e));
  return jsonResponse({{"templates", list}});
}

HttpResponse ServiceHub::getTemplate(const HttpRequest&, const Params& p) {
  checkName(p[0], "template");
  if (!database_.contains(p[0])) throw ApiError(404, "no template \"" + p[0] + "\" in " + database_.directory(), "name");
  return jsonResponse(templateEntryJson(database_.entry(p[0])));
}

HttpResponse ServiceHub::deleteTemplate(const HttpRequest&, const Params& p) {
  checkName(p[0], "template");
  if (!database_.contains(p[0])) throw ApiError(404, "no template \"" + p[0] + "\" in " + database_.directory(), "name");
  // A session's scene that instances it could not be reset or saved and re-opened.
  for (const auto& s : allSessions())
    for (const json& inst : instancesOf(s->sceneJson()))
      if (inst.value("template", "") == p[0])
        throw ApiError(409, "template \"" + p[0] + "\" is in use by session " + s->id() + " (instance \"" +
                                inst.value("name", "") + "\"); remove the instance or delete the session first",
                       "name");
  database_.remove(p[0]);
  {
    std::lock_guard<std::mutex> lock(previewMutex_);
    previews_.erase(p[0]);
  }
  return jsonResponse({{"deleted", p[0]}});
}

namespace {

// Positions of one template frame for a library thumbnail: every k-th
// particle so that at most maxPoints remain, rounded to 0.1 mm.
template <int D>
json previewJson(const Template<D>& tpl, long frame, long maxPoints) {
  const TemplateFrame<D>& f = tpl.frames[size_t(frame)];
  const size_t n = f.size();
  const size_t stride = std::max<size_t>(1, (n + size_t(maxPoints) - 1) / size_t(maxPoints));
  json pos = json::array();
  for (size_t i = 0; i < n; i += stride)
    for (int d = 0; d < D; ++d) pos.push_back(std::round(double(f.x[i][d]) * 1e4) / 1e4);
  return {{"name", tpl.header.name},
          {"dimension", D},
          {"frame", frame},
          {"frames", tpl.frameCount()},
          {"time", double(frame) / tpl.header.frameRate},
          {"particles", n},
          {"stride", stride},
          {"region_min", tpl.header.regionMin},
          {"region_max", tpl.header.regionMax},
          {"positions", pos}};
}

long queryInteger(const std::string& query, const std::string& key, long fallback, long lo, long hi) {
  const std::string text = queryValue(query, key);
  if (text.empty()) return fallback;
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (errno != 0 || end == text.c_str() || *end != '\0' || v < lo || v > hi)
    throw ApiError(400, "query \"" + key + "\" must be an integer in [" + std::to_string(lo) + ", " +
                            std::to_string(hi) + "], got \"" + text.substr(0, 40) + "\"",
                   key);
  return v;
}

}  // namespace

HttpResponse ServiceHub::templatePreview(const HttpRequest& req, const Params& p) {
  checkName(p[0], "template");
  if (!database_.contains(p[0])) throw ApiError(404, "no template \"" + p[0] + "\" in " + database_.directory(), "name");
  const std::string path = database_.pathFor(p[0]);
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  const int64_t mtime = ec ? 0 : int64_t(std::filesystem::last_write_time(path, ec).time_since_epoch().count());
  PreviewSource src;
  {
    std::lock_guard<std::mutex> lock(previewMutex_);
    auto it = previews_.find(p[0]);
    if (it != previews_.end() && it->second.size == size && it->second.mtime == mtime) src = it->second;
  }
  if (!src.tpl) {
    try {
      const TemplateHeader header = readTemplateHeader(path);
      src.dimension = header.dimension;
      if (header.dimension == 2)
        src.tpl = std::make_shared<const Template<2>>(readTemplate<2>(path));
      else
        src.tpl = std::make_shared<const Template<3>>(readTemplate<3>(path));
    } catch (const TemplateError& e) {
      throw ApiError(422, e.what(), "name");
    }
    src.size = size;
    src.mtime = mtime;
    std::lock_guard<std::mutex> lock(previewMutex_);
    // A few decoded templates at most (a large 3D one holds tens of MB).
    if (previews_.size() >= kPreviewCacheSize && !previews_.count(p[0])) previews_.erase(previews_.begin());
    previews_[p[0]] = src;
  }
  const size_t frames = src.dimension == 2 ? static_cast<const Template<2>*>(src.tpl.get())->frameCount()
                                           : static_cast<const Template<3>*>(src.tpl.get())->frameCount();
  if (frames == 0) throw ApiError(422, "template \"" + p[0] + "\" has no frames", "name");
  const long frame = queryInteger(req.query, "frame", long(frames / 2), 0, long(frames) - 1);
  const long maxPoints = queryInteger(req.query, "max", 2000, 1, 100000);
  const json out = src.dimension == 2
                       ? previewJson(*static_cast<const Template<2>*>(src.tpl.get()), frame, maxPoints)
                       : previewJson(*static_cast<const Template<3>*>(src.tpl.get()), frame, maxPoints);
  return jsonResponse(out);
}

HttpResponse ServiceHub::recordTemplate(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"name", "region_min", "region_max", "first_frame", "last_frame", "force"});
  const std::string name = getString(body, "name", true);
  checkName(name, "template");
  auto box = [&](const char* key) {
    if (!body.contains(key)) throw ApiError(400, std::string("\"") + key + "\" is required", key);
    const json& v = body[key];
    if (!v.is_array() || v.size() != size_t(s->dimension()))
      throw ApiError(400, std::string("\"") + key + "\" must be an array of " + std::to_string(s->dimension()) + " numbers",
                     key);
    std::vector<double> out;
    for (const json& x : v) {
      if (!x.is_number() || !limits::kCoordinate.contains(x.get<double>()))
        throw ApiError(400, std::string("\"") + key + "\" must hold numbers in [" +
                                std::to_string(int64_t(limits::kCoordinate.min)) + ", " +
                                std::to_string(int64_t(limits::kCoordinate.max)) + "] m",
                       key);
      out.push_back(x.get<double>());
    }
    return out;
  };
  const std::vector<double> lo = box("region_min"), hi = box("region_max");
  const int first = int(getInt(body, "first_frame", true, 0, 0, INT32_MAX));
  const int last = int(getInt(body, "last_frame", true, 0, 0, INT32_MAX));
  const bool force = getBool(body, "force", false);
  if (!force && database_.contains(name))
    throw ApiError(409, "template \"" + name + "\" already exists (send \"force\": true to replace it)", "name");
  try {
    const TemplateEntry e = s->recordTemplate(database_, name, lo, hi, first, last, force);
    return jsonResponse(templateEntryJson(e), 201);
  } catch (const DatabaseError& e) {
    throw ApiError(409, e.what(), "name");
  } catch (const StaleFramesError& e) {
    throw ApiError(409, e.what(), "first_frame");
  }
}

HttpResponse ServiceHub::listScenes(const HttpRequest&, const Params&) {
  json list = json::array();
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(options_.scenesDir, ec))
    if (entry.is_regular_file() && entry.path().extension() == ".json" &&
        isValidTemplateName(entry.path().stem().string()))
      files.push_back(entry.path());
  std::sort(files.begin(), files.end());
  for (const fs::path& f : files) {
    json e = {{"name", f.stem().string()}};
    try {
      const json scene = loadSceneJson(f.string());
      e["dimension"] = sceneDimension(scene);
      e["instances"] = instancesOf(scene).size();
      // Templates its instances name that the database lacks (the scene then cannot be opened).
      json missing = json::array();
      for (const json& inst : instancesOf(scene)) {
        const std::string t = inst.is_object() && inst.contains("template") && inst["template"].is_string()
                                  ? inst["template"].get<std::string>()
                                  : std::string();
        if (!t.empty() && !database_.contains(t) &&
            std::find(missing.begin(), missing.end(), json(t)) == missing.end())
          missing.push_back(t);
      }
      if (!missing.empty()) e["missing_templates"] = missing;
    } catch (const std::exception& err) {
      e["dimension"] = nullptr;
      e["instances"] = 0;
      e["error"] = err.what();
    }
    list.push_back(e);
  }
  return jsonResponse({{"scenes", list}});
}

HttpResponse ServiceHub::getScene(const HttpRequest&, const Params& p) {
  checkName(p[0], "scene");
  const fs::path file = fs::path(options_.scenesDir) / (p[0] + ".json");
  if (!fs::is_regular_file(file)) throw ApiError(404, "no scene \"" + p[0] + "\" in " + options_.scenesDir, "name");
  return jsonResponse(loadSceneJson(file.string()));
}

HttpResponse ServiceHub::saveScene(const HttpRequest& req, const Params&) {
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"name", "session", "force"});
  const std::string name = getString(body, "name", true);
  checkName(name, "scene");
  auto s = requireSession(getString(body, "session", true));
  const bool force = getBool(body, "force", false);
  const fs::path file = fs::path(options_.scenesDir) / (name + ".json");
  std::lock_guard lk(fileMutex_);
  writeFileAtomically(file, s->sceneJson().dump(2) + "\n", force);
  return jsonResponse({{"name", name}, {"path", file.string()}}, 201);
}

// ---- sessions -----------------------------------------------------------------------

HttpResponse ServiceHub::listSessions(const HttpRequest&, const Params&) {
  json list = json::array();
  for (auto& s : allSessions()) list.push_back(s->state());
  return jsonResponse({{"sessions", list}});
}

HttpResponse ServiceHub::createSession(const HttpRequest& req, const Params&) {
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"scene", "name", "history_cap_mb", "playback_speed", "threads", "checkpoint_every",
                  "checkpoint_dense"});
  if (!body.contains("scene")) throw ApiError(400, "\"scene\" is required: a scene name or an inline scene object", "scene");
  json scene;
  std::string sceneName;
  if (body["scene"].is_string()) {
    sceneName = body["scene"].get<std::string>();
    checkName(sceneName, "scene");
    const fs::path file = fs::path(options_.scenesDir) / (sceneName + ".json");
    if (!fs::is_regular_file(file)) throw ApiError(404, "no scene \"" + sceneName + "\" in " + options_.scenesDir, "scene");
    scene = loadSceneJson(file.string());
  } else if (body["scene"].is_object()) {
    scene = body["scene"];
  } else {
    throw ApiError(400, std::string("\"scene\" must be a scene name or a scene object, not ") + body["scene"].type_name(),
                   "scene");
  }
  std::string name = getString(body, "name", false);
  if (!name.empty()) checkName(name, "session");
  // The server's limits are ceilings: a request may lower them, never raise them.
  SessionOptions so;
  const double capMb = double(options_.historyCapBytes) / (1024.0 * 1024.0);
  so.historyCapBytes = body.contains("history_cap_mb")
                           ? size_t(getNumber(body, "history_cap_mb", false, 0, 1e-3, capMb,
                                              "the server's --history-cap-mb is the ceiling") *
                                    1024 * 1024)
                           : options_.historyCapBytes;
  so.playbackSpeed = getNumber(body, "playback_speed", false, 0, 0, 1e6);
  so.threads = int(getInt(body, "threads", false, 0, 0, options_.maxThreads,
                          "the server's --max-threads is the ceiling; 0: all of them"));
  if (so.threads == 0) so.threads = options_.maxThreads;
  so.frameTimeout = options_.frameTimeout;
  so.checkpointEvery = int(getInt(body, "checkpoint_every", false, SessionOptions::kDefaultCheckpointEvery, 0, 100000,
                                  "frames between checkpoints; 0: none"));
  so.denseCheckpoints = getBool(body, "checkpoint_dense", true);

  std::string id;
  {
    std::lock_guard lk(mutex_);
    if (int(sessions_.size()) + creating_ >= options_.maxSessions)
      throw ApiError(429, "the server runs at most " + std::to_string(options_.maxSessions) +
                              " sessions (--max-sessions); delete one first");
    ++creating_;
    id = "s" + std::to_string(nextSession_++);
  }
  std::shared_ptr<Session> s;
  try {
    s = fc::service::createSession(id, name, scene, database_, so);
  } catch (const SceneError& e) {
    std::lock_guard lk(mutex_);
    --creating_;
    // Scene file errors name the file; inline ones the key inside "scene".
    const std::string path = e.path.empty() ? "scene" : "scene." + e.path;
    throw ApiError(422, sceneName.empty() ? std::string(e.what()) : sceneName + ".json: " + e.what(), path);
  } catch (...) {
    std::lock_guard lk(mutex_);
    --creating_;
    throw;
  }
  {
    std::lock_guard lk(mutex_);
    --creating_;
    sessions_[id] = s;
  }
  return jsonResponse(s->state(), 201);
}

HttpResponse ServiceHub::getSession(const HttpRequest&, const Params& p) {
  return jsonResponse(requireSession(p[0])->state());
}

HttpResponse ServiceHub::deleteSession(const HttpRequest&, const Params& p) {
  std::shared_ptr<Session> s;
  std::vector<std::function<void()>> hooks;
  {
    std::lock_guard lk(mutex_);
    auto it = sessions_.find(p[0]);
    if (it == sessions_.end()) throw ApiError(404, "no session \"" + p[0].substr(0, 80) + "\"", "id");
    s = it->second;
    sessions_.erase(it);
    auto range = deletionHooks_.equal_range(p[0]);
    for (auto h = range.first; h != range.second; ++h) hooks.push_back(std::move(h->second.second));
    deletionHooks_.erase(range.first, range.second);
  }
  s->pause();
  for (auto& h : hooks) h();
  s.reset();  // the last owner (once streams let go) stops the thread and frees the history
  return jsonResponse({{"deleted", p[0]}});
}

HttpResponse ServiceHub::sessionStats(const HttpRequest&, const Params& p) {
  auto s = requireSession(p[0]);
  json frames = json::array();
  for (const FramePtr& f : s->history()) frames.push_back(frameStatsEntry(*f));
  return jsonResponse({{"frames", frames}});
}

HttpResponse ServiceHub::sessionScene(const HttpRequest&, const Params& p) {
  return jsonResponse(requireSession(p[0])->sceneJson());
}

// ---- instances and edits ----------------------------------------------------------------

HttpResponse ServiceHub::runEdit(Session& s, Edit edit, int okStatus) {
  const EditKind kind = edit.kind;
  const EditTicket ticket = s.submit(std::move(edit));
  if (ticket.result.wait_for(options_.editWait) != std::future_status::ready) {
    return jsonResponse({{"edit", {{"id", ticket.id}, {"type", editKindName(kind)}, {"pending", true}}}}, 202);
  }
  const EditResult r = ticket.result.get();
  if (!r.accepted) throw ApiError(422, r.message, r.path);
  json out = {{"edit", r.toJson()}};
  if (r.kind == EditKind::AddInstance || r.kind == EditKind::UpdateInstance) {
    json inst = findInstance(s.sceneJson(), r.instance);
    if (!inst.is_null()) out["instance"] = inst;
  }
  return jsonResponse(out, okStatus);
}

HttpResponse ServiceHub::listInstances(const HttpRequest&, const Params& p) {
  return jsonResponse({{"instances", instancesOf(requireSession(p[0])->sceneJson())}});
}

HttpResponse ServiceHub::getInstance(const HttpRequest&, const Params& p) {
  auto s = requireSession(p[0]);
  checkName(p[1], "instance");
  json inst = findInstance(s->sceneJson(), p[1]);
  if (inst.is_null()) throw ApiError(404, "session " + p[0] + " has no instance \"" + p[1] + "\"", "name");
  return jsonResponse(inst);
}

HttpResponse ServiceHub::addInstance(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  json body = parseBody(req);
  if (!body.is_object()) throw ApiError(400, std::string("the body must be an instance object, not ") + body.type_name());
  Edit e;
  e.kind = EditKind::AddInstance;
  e.payload = std::move(body);
  return runEdit(*s, std::move(e), 201);
}

HttpResponse ServiceHub::patchInstance(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  checkName(p[1], "instance");
  json body = parseBody(req);
  if (!body.is_object()) throw ApiError(400, std::string("the body must be a JSON merge patch object, not ") + body.type_name());
  if (findInstance(s->sceneJson(), p[1]).is_null())
    throw ApiError(404, "session " + p[0] + " has no instance \"" + p[1] + "\"", "name");
  Edit e;
  e.kind = EditKind::UpdateInstance;
  e.instance = p[1];
  e.payload = std::move(body);
  return runEdit(*s, std::move(e), 200);
}

HttpResponse ServiceHub::removeInstance(const HttpRequest&, const Params& p) {
  auto s = requireSession(p[0]);
  checkName(p[1], "instance");
  if (findInstance(s->sceneJson(), p[1]).is_null())
    throw ApiError(404, "session " + p[0] + " has no instance \"" + p[1] + "\"", "name");
  Edit e;
  e.kind = EditKind::RemoveInstance;
  e.instance = p[1];
  return runEdit(*s, std::move(e), 200);
}

HttpResponse ServiceHub::patchSettings(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  json body = requireObject(parseBody(req));
  onlyKeys(body, {"settings", "solver", "control"});
  if (body.empty()) throw ApiError(400, "the body must name at least one of \"settings\", \"solver\", \"control\"");
  body["type"] = "settings";
  return runEdit(*s, Edit::fromJson(body), 200);
}

HttpResponse ServiceHub::getEdit(const HttpRequest&, const Params& p) {
  auto s = requireSession(p[0]);
  uint64_t id = 0;
  try {
    size_t used = 0;
    id = std::stoull(p[1], &used);
    if (used != p[1].size()) throw std::invalid_argument("trailing characters");
  } catch (const std::exception&) {
    throw ApiError(400, "edit id \"" + p[1].substr(0, 40) + "\" is not a number", "edit");
  }
  const auto r = s->editResult(id);
  if (r) return jsonResponse(r->toJson());
  // Ids are handed out in order; a known id without a result is still queued.
  const json state = s->state();
  if (state.value("pending_edits", 0) > 0)
    return jsonResponse({{"id", id}, {"pending", true}}, 202);
  throw ApiError(404, "session " + p[0] + " has no edit " + p[1] + " (results of the last 1024 edits are kept)", "edit");
}

// ---- transport, frames, export ----------------------------------------------------------

HttpResponse ServiceHub::transport(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  const std::string command = getString(body, "command", true);
  if (command == "play") {
    onlyKeys(body, {"command", "until"});
    s->play(int(getInt(body, "until", false, -1, 0, INT32_MAX)));
  } else if (command == "pause") {
    onlyKeys(body, {"command"});
    s->pause();
    // The answer shows the session stopped when the frame in progress ends
    // soon; a long frame answers at once with "computing": true.
    s->waitIdle(std::chrono::seconds(2));
  } else if (command == "step") {
    onlyKeys(body, {"command", "frames"});
    s->step(int(getInt(body, "frames", false, 1, 1, 1000000)));
  } else if (command == "reset") {
    onlyKeys(body, {"command"});
    s->reset();
  } else if (command == "seek") {
    onlyKeys(body, {"command", "frame"});
    const int frame = int(getInt(body, "frame", true, 0, 0, INT32_MAX));
    try {
      s->seek(frame);
    } catch (const std::out_of_range& e) {
      throw ApiError(422, e.what(), "frame");
    }
  } else if (command == "speed") {
    onlyKeys(body, {"command", "speed"});
    s->setPlaybackSpeed(getNumber(body, "speed", true, 0, 0, 1e6));
  } else {
    throw ApiError(400, "\"command\" must be one of play, pause, step, reset, seek, speed; got \"" +
                            command.substr(0, 40) + "\"",
                   "command");
  }
  return jsonResponse(s->state());
}

HttpResponse ServiceHub::getFrame(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  FramePtr f;
  if (p[1] == "latest") {
    f = s->latestFrame();
  } else {
    int n = -1;
    try {
      size_t used = 0;
      n = std::stoi(p[1], &used);
      if (used != p[1].size() || n < 0) throw std::invalid_argument("");
    } catch (const std::exception&) {
      throw ApiError(400, "frame \"" + p[1].substr(0, 40) + "\" must be a frame number >= 0 or \"latest\"", "frame");
    }
    f = s->frame(n);
    if (!f) {
      const json h = s->state()["history"];
      throw ApiError(404, "frame " + p[1] + " is not in session " + p[0] + "'s history (frames " + h["first"].dump() +
                              " to " + h["last"].dump() + " are kept)",
                     "frame");
    }
  }
  std::string format = queryValue(req.query, "format");
  if (format.empty()) format = req.header("accept").find("application/x-flowclip-frame") != std::string::npos ? "binary" : "json";
  if (format == "binary") {
    flatbuffers::FlatBufferBuilder fbb(f->positions.size() * 2 + f->kind.size() * 2 + 1024);
    encodeSnapshot(*f, s->id(), wire::LayerFlags{}, fbb);
    HttpResponse r;
    r.contentType = "application/x-flowclip-frame";
    r.body.assign(reinterpret_cast<const char*>(fbb.GetBufferPointer()), fbb.GetSize());
    return r;
  }
  if (format != "json") throw ApiError(400, "format must be json or binary, got \"" + format.substr(0, 40) + "\"", "format");
  const size_t n = f->particles();
  const int D = f->dimension;
  json positions = json::array(), velocities = json::array(), kind = json::array(), phase = json::array();
  for (size_t i = 0; i < n; ++i) {
    for (int d = 0; d < D; ++d) {
      positions.push_back(f->position(i, d));
      velocities.push_back(f->velocity(i, d));
    }
    kind.push_back(f->kind[i]);
    phase.push_back(f->phase[i]);
  }
  json instances = json::array();
  for (const InstanceSnapshot& inst : f->instances) instances.push_back(instanceSnapshotJson(inst));
  return jsonResponse({{"frame", f->frame},
                       {"time", f->time},
                       {"dimension", D},
                       {"domain_min", f->domainMin},
                       {"domain_max", f->domainMax},
                       {"count", n},
                       {"positions", std::move(positions)},
                       {"velocities", std::move(velocities)},
                       {"kind", std::move(kind)},
                       {"phase", std::move(phase)},
                       {"instances", std::move(instances)},
                       {"stats", frameStatsEntry(*f)}});
}

HttpResponse ServiceHub::exportFrames(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"name", "first_frame", "last_frame", "force"});
  const std::string name = getString(body, "name", true);
  checkName(name, "export");
  const int first = int(getInt(body, "first_frame", false, -1, 0, INT32_MAX));
  const int last = int(getInt(body, "last_frame", false, -1, 0, INT32_MAX));
  const bool force = getBool(body, "force", false);
  const fs::path h5 = fs::path(options_.exportsDir) / (name + ".h5");
  std::lock_guard lk(fileMutex_);
  if (!force) {
    const fs::path xdmf = fs::path(options_.exportsDir) / (name + ".xdmf");
    const bool haveH5 = fs::exists(h5), haveXdmf = fs::exists(xdmf);
    if (haveH5 || haveXdmf)
      throw ApiError(409, "export \"" + name + "\" already exists in " + options_.exportsDir + " (" +
                              (haveH5 && haveXdmf ? name + ".h5 and " + name + ".xdmf"
                                                  : (haveH5 ? name + ".h5" : name + ".xdmf") + " alone") +
                              "; send \"force\": true to replace it)",
                     "name");
  }
  std::error_code ec;
  fs::create_directories(options_.exportsDir, ec);
  HistoryExport e;
  try {
    e = s->exportHistory(h5.string(), first, last);
  } catch (const StaleFramesError& err) {
    throw ApiError(409, err.what(), "first_frame");
  } catch (const std::invalid_argument& err) {
    throw ApiError(422, err.what(), "first_frame");
  }
  return jsonResponse({{"name", name},
                       {"h5", name + ".h5"},
                       {"xdmf", name + ".xdmf"},
                       {"frames", e.frames},
                       {"particle_rows", e.particleRows},
                       {"bytes", e.bytes}},
                      201);
}

HttpResponse ServiceHub::getExport(const HttpRequest&, const Params& p) {
  const std::string& file = p[0];
  const size_t dot = file.rfind('.');
  const std::string stem = dot == std::string::npos ? file : file.substr(0, dot);
  const std::string ext = dot == std::string::npos ? "" : file.substr(dot);
  if (ext != ".h5" && ext != ".xdmf")
    throw ApiError(400, "export file \"" + file.substr(0, 80) + "\" must be NAME.h5 or NAME.xdmf", "file");
  checkName(stem, "export");
  const fs::path path = fs::path(options_.exportsDir) / file;
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ApiError(404, "no export file \"" + file + "\" in " + options_.exportsDir, "file");
  HttpResponse r;
  r.contentType = ext == ".h5" ? "application/x-hdf5" : "application/xml";
  r.body.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  r.headers.emplace_back("Content-Disposition", "attachment; filename=\"" + file + "\"");
  return r;
}

// ---- recipes: recording jobs (service/recipe_jobs.h) -----------------------------

HttpResponse ServiceHub::listRecipes(const HttpRequest&, const Params&) {
  return jsonResponse(recipeJobs_->list([this](const std::string& name) { return database_.contains(name); }));
}

HttpResponse ServiceHub::startRecipeJob(const HttpRequest& req, const Params& p) {
  const json body = requireObject(parseBody(req, false));
  onlyKeys(body, {"force"});
  bool created = false;
  const JobInfo job = recipeJobs_->start(p[0], getBool(body, "force", false), created);
  HttpResponse r = jsonResponse(jobJson(job), created ? 202 : 200);
  r.headers.emplace_back("Location", "/api/recipes/jobs/" + job.id);
  return r;
}

HttpResponse ServiceHub::getRecipeJob(const HttpRequest&, const Params& p) {
  return jsonResponse(jobJson(recipeJobs_->job(p[0])));
}

HttpResponse ServiceHub::cancelRecipeJob(const HttpRequest&, const Params& p) {
  return jsonResponse(jobJson(recipeJobs_->cancel(p[0])));
}

}  // namespace fc::service
