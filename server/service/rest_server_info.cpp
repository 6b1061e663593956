#include "service/rest_api.h"

// GET /api/health, /api/parameters, /api/presets: what the server is and
// what it accepts.
#include "io/parameter_reference.h"
#include "service/rest_support.h"
#include "sph/pipeline.h"
#include "sph/settings.h"

#include <fstream>
#include <unistd.h>

namespace fc::service {

using namespace rest;

double currentRssMb() {
  std::ifstream f("/proc/self/statm");
  long pages = 0, resident = 0;
  f >> pages >> resident;
  return double(resident) * double(::sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

HttpResponse ServiceHub::health(const HttpRequest&, const Params&) {
  const double uptime = std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
  return jsonResponse({{"status", "ok"},
                       {"version", FLOWCLIP_VERSION},
                       {"sessions", sessionCount()},
                       {"max_sessions", options_.maxSessions},
                       {"uptime_s", uptime},
                       {"rss_mb", currentRssMb()}});
}

// The one declaration of every parameter (name, unit, range, default, help):
// the editor's inspector builds its fields from it.
HttpResponse ServiceHub::parameters(const HttpRequest& req, const Params&) {
  const std::string d = queryValue(req.query, "dimension");
  if (d.empty() || d == "2") return jsonResponse(parameterReference<2>());
  if (d == "3") return jsonResponse(parameterReference<3>());
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

}  // namespace fc::service
