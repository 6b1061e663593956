#include "service/rest_api.h"

// Exports of a session's history: POST /api/sessions/{id}/export writes
// NAME.h5 + NAME.xdmf to the exports directory (service/history_export.h)
// and, with "formats", starts a job that meshes them into EXPORTS/NAME/
// (service/surface_jobs.h); GET /api/exports/{file} and
// /api/exports/{name}/{file} serve them, /api/exports/jobs/{id} the jobs.
#include "service/rest_support.h"
#include "service/surface_jobs.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <fstream>
#include <iterator>

namespace fc::service {

using namespace rest;
namespace fs = std::filesystem;

namespace {

// The body's "formats", "surface" and "format_settings", checked before
// anything is written (422 naming the key).
struct SurfaceRequest {
  std::vector<std::string> formats;
  SurfaceSettings surface = surfaceSettingsTable().defaults();
  std::map<std::string, ParamValues> params;
};

double declaredValue(const json& v, const ParamSpec& spec, const std::string& path) {
  double value = 0;
  if (spec.type == ParamType::Boolean && v.is_boolean()) value = v.get<bool>() ? 1 : 0;
  else if (v.is_number()) value = v.get<double>();
  else throw ApiError(422, path + ": expected a " + (spec.type == ParamType::Boolean ? "boolean" : "number"), path);
  if (spec.type == ParamType::Integer && value != std::floor(value)) throw ApiError(422, path + ": must be an integer", path);
  if (!(value >= spec.min && value <= spec.max)) {
    char range[64];
    std::snprintf(range, sizeof range, "[%g, %g]", spec.min, spec.max);
    throw ApiError(422, path + ": " + v.dump() + " is outside " + range, path);
  }
  return value;
}

SurfaceRequest surfaceRequest(const json& body) {
  SurfaceRequest r;
  const json& formats = body.at("formats");
  if (!formats.is_array() || formats.empty())
    throw ApiError(422, "formats: expected a non-empty array of export format names", "formats");
  std::string list;
  for (size_t i = 0; i < formats.size(); ++i) {
    if (!formats[i].is_string())
      throw ApiError(422, "formats[" + std::to_string(i) + "]: expected a format name", "formats[" + std::to_string(i) + "]");
    list += (i ? "," : "") + formats[i].get<std::string>();
  }
  try {
    r.formats = parseFormats(list);
  } catch (const ExportSetupError& e) {
    throw ApiError(422, std::string("formats: ") + e.what(), "formats");
  }
  if (const auto it = body.find("surface"); it != body.end()) {
    if (!it->is_object()) throw ApiError(422, "surface: expected an object of surface settings", "surface");
    for (const auto& [key, value] : it->items()) {
      const ParamSpec* spec = findSpec(surfaceSettingsSpecs(), key);
      if (!spec) throw ApiError(422, "surface." + key + ": not a surface setting (GET /api/parameters lists them)", "surface." + key);
      surfaceSettingsTable().assign(r.surface, key, declaredValue(value, *spec, "surface." + key));
    }
  }
  if (const std::string problem = surfaceSettingsProblem(r.surface); !problem.empty())
    throw ApiError(422, problem, "surface.surface_radius");
  if (const auto it = body.find("format_settings"); it != body.end()) {
    if (!it->is_object()) throw ApiError(422, "format_settings: expected {FORMAT: {KEY: value}}", "format_settings");
    for (const auto& [format, settings] : it->items()) {
      const std::string path = "format_settings." + format;
      const auto* entry = ExporterRegistry::instance().find(format);
      if (!entry || std::find(r.formats.begin(), r.formats.end(), format) == r.formats.end())
        throw ApiError(422, path + ": not one of the formats asked", path);
      if (!settings.is_object()) throw ApiError(422, path + ": expected an object", path);
      ParamValues values(entry->params);
      for (const auto& [key, value] : settings.items()) {
        const ParamSpec* spec = findSpec(entry->params, key);
        if (!spec) throw ApiError(422, path + "." + key + ": not a setting of " + format, path + "." + key);
        values.set(key, declaredValue(value, *spec, path + "." + key));
      }
      r.params[format] = values;
    }
  }
  return r;
}

}  // namespace

HttpResponse ServiceHub::exportFrames(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"name", "first_frame", "last_frame", "force", "formats", "surface", "format_settings"});
  const std::string name = bodyString(body, "name");
  checkName(name, "export");
  // -1: the oldest / the newest frame kept.
  const int first = int(bodyInteger(body, "first_frame", -1, {0, INT32_MAX}));
  const int last = int(bodyInteger(body, "last_frame", -1, {0, INT32_MAX}));
  const bool force = bodyBool(body, "force", false);
  std::optional<SurfaceRequest> surface;
  if (body.contains("formats")) surface = surfaceRequest(body);
  else if (body.contains("surface") || body.contains("format_settings"))
    throw ApiError(422, "surface and format_settings need formats", body.contains("surface") ? "surface" : "format_settings");
  if (surface && name == "jobs") throw ApiError(422, "name: \"jobs\" is reserved for /api/exports/jobs/", "name");
  const fs::path h5 = fs::path(options_.exportsDir) / (name + ".h5");
  const fs::path dir = fs::path(options_.exportsDir) / name;
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
    if (surface && fs::exists(dir))
      throw ApiError(409, "export \"" + name + "\" already has surfaces in " + options_.exportsDir + "/" + name +
                              "/; send \"force\": true to replace them",
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
  json out = {{"name", name},
              {"h5", name + ".h5"},
              {"xdmf", name + ".xdmf"},
              {"frames", e.frames},
              {"particle_rows", e.particleRows},
              {"bytes", e.bytes}};
  if (!surface) return jsonResponse(out, 201);
  std::weak_ptr<Session> session = s;
  SurfaceJobRequest request{s->id(), name, h5.string(), dir.string(), surface->formats, surface->surface,
                            surface->params, [session](const SurfaceJobInfo& job) {
                              if (auto live = session.lock()) live->setExportState(surfaceJobJson(job));
                            }};
  const SurfaceJobInfo job = surfaceJobs_->start(std::move(request));
  out["surface_job"] = surfaceJobJson(job);
  HttpResponse r = jsonResponse(out, 202);
  r.headers.emplace_back("Location", "/api/exports/jobs/" + job.id);
  return r;
}

HttpResponse ServiceHub::getSurfaceJob(const HttpRequest&, const Params& p) {
  return jsonResponse(surfaceJobJson(surfaceJobs_->job(p[0])));
}

HttpResponse ServiceHub::cancelSurfaceJob(const HttpRequest&, const Params& p) {
  return jsonResponse(surfaceJobJson(surfaceJobs_->cancel(p[0])));
}

HttpResponse ServiceHub::getSurfaceFile(const HttpRequest&, const Params& p) {
  const std::string& name = p[0];
  const std::string& file = p[1];
  checkName(name, "export");
  // A file of the directory: a plain name, no path.
  if (file.empty() || file.size() > 255 || file.front() == '.' || file.find('/') != std::string::npos ||
      file.find('\\') != std::string::npos)
    throw ApiError(400, "export file \"" + file.substr(0, 80) + "\" must be a file name of the export's directory", "file");
  const fs::path path = fs::path(options_.exportsDir) / name / file;
  std::ifstream in(path, std::ios::binary);
  if (!in || !fs::is_regular_file(path))
    throw ApiError(404, "no file \"" + file + "\" in export \"" + name + "\"", "file");
  static const std::map<std::string, std::string> types = {
      {".vdb", "application/octet-stream"}, {".ply", "application/octet-stream"}, {".obj", "text/plain"},
      {".usda", "text/plain"},              {".json", "application/json"}};
  const auto t = types.find(path.extension().string());
  HttpResponse r;
  r.contentType = t == types.end() ? "application/octet-stream" : t->second;
  r.body.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  r.headers.emplace_back("Content-Disposition", "attachment; filename=\"" + file + "\"");
  return r;
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

}  // namespace fc::service
