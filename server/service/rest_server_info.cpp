#include "service/rest_api.h"

// GET /api/health, /api/parameters, /api/presets: what the server is and
// what it accepts.
#include "service/rest_support.h"
#include "sph/limits.h"
#include "sph/pipeline.h"
#include "sph/settings.h"
#include "control/instance.h"

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

}  // namespace fc::service
