#include "service/rest_api.h"

// The route table, the dispatch and the session registry. The handlers are
// in one file per resource: rest_server_info.cpp (health, parameters,
// presets), rest_templates.cpp, rest_scenes.cpp, rest_sessions.cpp (sessions,
// instances and edits, transport), rest_frames.cpp (frames and stats),
// rest_exports.cpp, rest_recipes.cpp, rest_jobs.cpp; what they share is rest_support.h.
#include "core/text.h"
#include "io/json_text.h"
#include "io/scene.h"
#include "io/template_file.h"
#include "service/recipe_jobs.h"
#include "service/render_jobs.h"
#include "service/surface_jobs.h"
#include "service/rest_support.h"

#include <algorithm>
#include <filesystem>
#include <thread>

namespace fc::service {

using json = nlohmann::json;
using rest::splitPath;

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

// ---- the hub -------------------------------------------------------------------

ServiceHub::ServiceHub(ServiceOptions options)
    : options_(std::move(options)), database_(options_.templatesDir, options_.templateMemoryBytes), started_(std::chrono::steady_clock::now()) {
  if (options_.maxThreads <= 0) options_.maxThreads = std::max(1, int(std::thread::hardware_concurrency()));
  if (options_.recordThreads <= 0) options_.recordThreads = std::max(1, int(std::thread::hardware_concurrency()) / 2);
  surfaceJobs_ = std::make_unique<SurfaceJobs>(options_.recordThreads);
  recipeJobs_ = std::make_unique<RecipeJobs>(
      RecipeJobsOptions{options_.recipesDir, options_.templatesDir, options_.recordThreads});
  if (options_.jobsDir.empty()) options_.jobsDir = (std::filesystem::path(options_.exportsDir) / "jobs").string();
  renderJobs_ = std::make_unique<RenderJobs>(RenderJobsOptions{options_.jobsDir, options_.batchCommand,
                                                               options_.batchBinary, options_.templatesDir,
                                                               options_.scheduler, std::max(1, options_.jobWorkers)});
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
      {"GET", "/api/exports/jobs/{id}", &ServiceHub::getSurfaceJob},
      {"DELETE", "/api/exports/jobs/{id}", &ServiceHub::cancelSurfaceJob},
      {"GET", "/api/exports/{name}/{file}", &ServiceHub::getSurfaceFile},
      {"GET", "/api/recipes", &ServiceHub::listRecipes},
      {"POST", "/api/recipes/{name}/record", &ServiceHub::startRecipeJob},
      {"GET", "/api/recipes/jobs/{id}", &ServiceHub::getRecipeJob},
      {"DELETE", "/api/recipes/jobs/{id}", &ServiceHub::cancelRecipeJob},
      {"GET", "/api/jobs", &ServiceHub::listJobs},
      {"POST", "/api/jobs", &ServiceHub::submitJob},
      {"GET", "/api/jobs/{id}", &ServiceHub::getJob},
      {"DELETE", "/api/jobs/{id}", &ServiceHub::cancelJob},
      {"GET", "/api/jobs/{id}/files/{task}/{file}", &ServiceHub::getJobFile},
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

}  // namespace fc::service
