#include "service/rest_api.h"

// Render jobs: POST /api/jobs runs a session's current scene again as a
// batch (final resolution, a wedge of one parameter, surface formats) on a
// Dask cluster through flowclip-batch (service/render_jobs.h); GET
// /api/jobs, /api/jobs/{id} follow them, DELETE cancels, and
// /api/jobs/{id}/files/{task}/{file} serves their results.
#include "export/surface_export.h"
#include "io/instance_binding.h"
#include "io/key_path.h"
#include "io/scene.h"
#include "service/render_jobs.h"
#include "service/rest_support.h"

#include <filesystem>
#include <fstream>
#include <iterator>

namespace fc::service {

using namespace rest;
namespace fs = std::filesystem;

namespace {

constexpr size_t kMaxWedgeValues = 64;

// What a task's scene must pass before anything is submitted: what a session
// checks when it opens (the simulation itself is built on the worker).
template <int D>
void validateScene(const json& scene, TemplateDatabase& database) {
  const SimulationSetup<D> setup = parseScene<D>(scene);
  const SceneControl<D> control = parseSceneControl<D>(scene, setup.phases);
  if (!control.instances.empty()) bindInstances<D>(control.instances, database);
}

// `where` names the request's key that made the scene: a scene error is 422 at it.
void checkTaskScene(const json& scene, TemplateDatabase& database, const std::string& where) {
  try {
    if (sceneDimension(scene) == 2) validateScene<2>(scene, database);
    else validateScene<3>(scene, database);
  } catch (const SceneError& e) {
    throw ApiError(422, where + ": " + e.what(), e.path.empty() ? where : where + " (" + e.path + ")");
  } catch (const std::exception& e) {
    throw ApiError(422, where + ": " + e.what(), where);
  }
}

void setOrRefuse(json& scene, const std::string& path, const json& value, const std::string& where) {
  try {
    setKeyPath(scene, path, value);
  } catch (const KeyPathError& e) {
    throw ApiError(422, where + ": " + e.what(), where);
  }
}

}  // namespace

HttpResponse ServiceHub::submitJob(const HttpRequest& req, const Params&) {
  const json body = requireObject(parseBody(req));
  onlyKeys(body, {"session", "name", "particle_radius", "frames", "seconds", "formats", "frames_export",
                  "overrides", "wedge", "threads"});
  auto s = requireSession(bodyString(body, "session"));
  if (!renderJobs_->available())
    throw ApiError(503,
                   "render jobs need flowclip-batch (pip install \"flowclip[batch]\" from clients/python, or "
                   "flowclip serve --batch-command PATH)");
  const std::string name = bodyString(body, "name", isValidTemplateName(s->name()) ? s->name() : "render");
  checkName(name, "name");
  json scene = s->sceneJson();
  json spec = json::object();
  if (body.contains("frames") && body.contains("seconds"))
    throw ApiError(400, "give frames or seconds, not both", "seconds");
  if (body.contains("frames")) spec["frames"] = bodyInteger(body, "frames", std::nullopt, Bounds(1, 1e6, "frames"));
  if (body.contains("seconds"))
    spec["seconds"] = bodyNumber(body, "seconds", std::nullopt, Bounds(1e-3, 36000, "s"));
  spec["threads"] = bodyInteger(body, "threads", 1, Bounds(1, options_.maxThreads, "threads", "per task"));
  std::vector<std::string> formats;
  if (const auto it = body.find("formats"); it != body.end()) {
    if (!it->is_array()) throw ApiError(422, "formats: expected an array of export format names", "formats");
    std::string list;
    for (size_t i = 0; i < it->size(); ++i) {
      if (!(*it)[i].is_string())
        throw ApiError(422, "formats[" + std::to_string(i) + "]: expected a format name", "formats[" + std::to_string(i) + "]");
      list += (i ? "," : "") + (*it)[i].get<std::string>();
    }
    try {
      if (!list.empty()) formats = parseFormats(list);
    } catch (const ExportSetupError& e) {
      throw ApiError(422, std::string("formats: ") + e.what(), "formats");
    }
  }
  const bool framesExport = bodyBool(body, "frames_export", true);
  spec["outputs"] = {{"stats", true}, {"frames", framesExport}, {"surface", formats}};
  // The changes every task shares, then the wedge's one key.
  if (body.contains("particle_radius"))
    setOrRefuse(scene, "particle_radius", bodyNumber(body, "particle_radius", std::nullopt, Bounds()), "particle_radius");
  if (const auto it = body.find("overrides"); it != body.end()) {
    if (!it->is_object()) throw ApiError(422, "overrides: expected an object of scene key path -> value", "overrides");
    for (const auto& [path, value] : it->items()) setOrRefuse(scene, path, value, "overrides." + path);
  }
  checkTaskScene(scene, database_, body.contains("overrides") ? "overrides" : "particle_radius");
  std::vector<json> variants;
  json wedge = nullptr;
  if (const auto it = body.find("wedge"); it != body.end() && !it->is_null()) {
    if (!it->is_object() || !it->contains("key") || !(*it)["key"].is_string() || !it->contains("values") ||
        !(*it)["values"].is_array())
      throw ApiError(422, "wedge: expected {\"key\": a scene key path, \"values\": [...]}", "wedge");
    for (const auto& [k, v] : it->items())
      if (k != "key" && k != "values") throw ApiError(422, "wedge." + k + ": not a key of a wedge (key, values)", "wedge." + k);
    const std::string key = (*it)["key"];
    const json& values = (*it)["values"];
    std::vector<json> scenes;
    if (values.empty() || values.size() > kMaxWedgeValues)
      throw ApiError(422, "wedge.values: from 1 to " + std::to_string(kMaxWedgeValues) + " values", "wedge.values");
    for (size_t i = 0; i < values.size(); ++i) {
      const std::string where = "wedge.values[" + std::to_string(i) + "]";
      json variant = scene;
      try {
        setKeyPath(variant, key, values[i]);
      } catch (const KeyPathError& e) {
        throw ApiError(422, std::string("wedge.key: ") + e.what(), "wedge.key");
      }
      // One task per scene: a value given twice (1 and 1.0 alike) would be one folder for two tasks.
      for (size_t k = 0; k < scenes.size(); ++k)
        if (scenes[k] == variant)
          throw ApiError(422, where + ": the same as wedge.values[" + std::to_string(k) + "]", where);
      checkTaskScene(variant, database_, where);
      variants.push_back({{key, values[i]}});
      scenes.push_back(std::move(variant));
    }
    wedge = *it;
  } else {
    variants.push_back(json::object());
  }
  json request = body;
  request["name"] = name;
  RenderJobRequest r;
  r.session = s->id();
  r.name = name;
  r.request = request;
  r.scene = std::move(scene);
  r.spec = std::move(spec);
  r.variants = std::move(variants);
  std::weak_ptr<Session> session = s;
  r.progress = [session](const RenderJobInfo& job) {
    if (auto live = session.lock()) live->setJobState(renderJobJson(job));
  };
  const RenderJobInfo job = renderJobs_->start(std::move(r));
  HttpResponse out = jsonResponse(renderJobJson(job), 202);
  out.headers.emplace_back("Location", "/api/jobs/" + job.id);
  return out;
}

HttpResponse ServiceHub::listJobs(const HttpRequest&, const Params&) {
  json list = json::array();
  for (const RenderJobInfo& j : renderJobs_->jobs()) list.push_back(renderJobJson(j));
  json out = {{"jobs", list}, {"available", renderJobs_->available()}, {"where", renderJobs_->where()}};
  return jsonResponse(out);
}

HttpResponse ServiceHub::getJob(const HttpRequest&, const Params& p) {
  return jsonResponse(renderJobJson(renderJobs_->job(p[0])));
}

HttpResponse ServiceHub::cancelJob(const HttpRequest&, const Params& p) {
  return jsonResponse(renderJobJson(renderJobs_->cancel(p[0])));
}

HttpResponse ServiceHub::getJobFile(const HttpRequest&, const Params& p) {
  // A RecipeJobError (400 bad id, 404 no job) is answered by the dispatch.
  const RenderJobInfo job = renderJobs_->job(p[0]);
  if (job.state != JobState::Done) throw ApiError(409, "render job " + p[0] + " is " + jobStateName(job.state) + ": its files come when it is done", "id");
  const std::string& task = p[1];
  const std::string& file = p[2];
  const auto known = std::find_if(job.tasks.begin(), job.tasks.end(), [&](const RenderTaskInfo& t) { return t.id == task; });
  if (known == job.tasks.end()) throw ApiError(404, "render job " + p[0] + " has no task \"" + task.substr(0, 40) + "\"", "task");
  // One of the files the job listed: nothing else of the disk can be named.
  if (std::find(known->files.begin(), known->files.end(), file) == known->files.end())
    throw ApiError(404, "task " + task + " of render job " + p[0] + " has no file \"" + file.substr(0, 120) + "\"", "file");
  const fs::path path = fs::path(renderJobs_->options().jobsDir) / job.id / task / file;
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ApiError(404, "the file \"" + file + "\" of task " + task + " is gone", "file");
  HttpResponse r;
  const std::string ext = path.extension().string();
  r.contentType = ext == ".json" ? "application/json" : ext == ".h5" ? "application/x-hdf5"
                  : ext == ".xdmf" ? "application/xml" : ext == ".obj" || ext == ".usda" ? "text/plain"
                                                                                         : "application/octet-stream";
  r.body.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  r.headers.emplace_back("Content-Disposition", "attachment; filename=\"" + path.filename().string() + "\"");
  return r;
}

}  // namespace fc::service
