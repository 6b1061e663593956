#include "service/rest_api.h"

// /api/scenes: the scene files of the scenes directory, and saving a
// session's scene as one.
#include "io/scene.h"
#include "io/staged_files.h"
#include "service/rest_support.h"

#include <algorithm>
#include <filesystem>

namespace fc::service {

using namespace rest;
namespace fs = std::filesystem;

namespace {

// Publishes `text` as `path` (io/staged_files.h): readers, and the directory
// after a crash, see the old file or the new one. Without `replace`, a file
// of that name (even one that appeared meanwhile) is a 409.
void publishSceneFile(const fs::path& path, const std::string& text, bool replace) {
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  try {
    publishFile(path.string(), text, replace);
  } catch (const PublishError& e) {
    if (e.exists)
      throw ApiError(409, path.filename().string() + " already exists (send \"force\": true to replace it)", "name");
    throw std::runtime_error("cannot write " + path.string() + ": " + e.what());
  }
}

}  // namespace

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
  const std::string name = bodyString(body, "name");
  checkName(name, "scene");
  auto s = requireSession(bodyString(body, "session"));
  const bool force = bodyBool(body, "force", false);
  const fs::path file = fs::path(options_.scenesDir) / (name + ".json");
  std::lock_guard lk(fileMutex_);
  publishSceneFile(file, s->sceneJson().dump(2) + "\n", force);
  return jsonResponse({{"name", name}, {"path", file.string()}}, 201);
}

}  // namespace fc::service
