#include "service/rest_api.h"

// /api/sessions: creating, listing and deleting sessions; their instances
// and settings (edits, applied by the session at a frame boundary); transport.
#include "io/scene.h"
#include "service/rest_support.h"

#include <filesystem>

namespace fc::service {

using namespace rest;
namespace fs = std::filesystem;

namespace {

// Frames per wall second while playing; 0: as fast as possible.
const Bounds kPlaybackSpeedBounds(0, 1e6, "frames/s");

json findInstance(const json& scene, const std::string& name) {
  for (const json& inst : instancesOf(scene))
    if (inst.value("name", "") == name) return inst;
  return nullptr;
}

}  // namespace

// ---- sessions ---------------------------------------------------------------------------

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
  std::string name = bodyString(body, "name", "");
  if (!name.empty()) checkName(name, "session");
  // The server's limits are ceilings: a request may lower them, never raise them.
  SessionOptions so;
  const double capMb = double(options_.historyCapBytes) / (1024.0 * 1024.0);
  const Bounds capBounds(1e-3, capMb, "MB", "the server's --history-cap-mb is the ceiling");
  so.historyCapBytes = body.contains("history_cap_mb")
                           ? size_t(bodyNumber(body, "history_cap_mb", kRequired, capBounds) * 1024 * 1024)
                           : options_.historyCapBytes;
  so.playbackSpeed = bodyNumber(body, "playback_speed", 0, kPlaybackSpeedBounds);
  so.threads = int(bodyInteger(body, "threads", 0,
                               {0, double(options_.maxThreads), "",
                                "the server's --max-threads is the ceiling; 0: all of them"}));
  if (so.threads == 0) so.threads = options_.maxThreads;
  so.frameTimeout = options_.frameTimeout;
  so.checkpointEvery = int(bodyInteger(body, "checkpoint_every", SessionOptions::kDefaultCheckpointEvery,
                                       {0, 100000, "", "frames between checkpoints; 0: none"}));
  so.denseCheckpoints = bodyBool(body, "checkpoint_dense", true);

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
  if (const auto kind = s->pendingEdit(id))
    return jsonResponse({{"id", id}, {"type", editKindName(*kind)}, {"pending", true}}, 202);
  throw ApiError(404, "session " + p[0] + " has no edit " + p[1] + " (results of the last 1024 edits are kept)", "edit");
}

// ---- transport ---------------------------------------------------------------------------

HttpResponse ServiceHub::transport(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  const json body = requireObject(parseBody(req));
  const std::string command = bodyString(body, "command");
  if (command == "play") {
    onlyKeys(body, {"command", "until"});
    s->play(int(bodyInteger(body, "until", -1, {0, INT32_MAX})));  // -1: no end
  } else if (command == "pause") {
    onlyKeys(body, {"command"});
    s->pause();
    // The answer shows the session stopped when the frame in progress ends
    // soon; a long frame answers at once with "computing": true.
    s->waitIdle(std::chrono::seconds(2));
  } else if (command == "step") {
    onlyKeys(body, {"command", "frames"});
    s->step(int(bodyInteger(body, "frames", 1, {1, 1000000})));
  } else if (command == "reset") {
    onlyKeys(body, {"command"});
    s->reset();
  } else if (command == "seek") {
    onlyKeys(body, {"command", "frame"});
    const int frame = int(bodyInteger(body, "frame", kRequired, {0, INT32_MAX}));
    try {
      s->seek(frame);
    } catch (const std::out_of_range& e) {
      throw ApiError(422, e.what(), "frame");
    }
  } else if (command == "speed") {
    onlyKeys(body, {"command", "speed"});
    s->setPlaybackSpeed(bodyNumber(body, "speed", kRequired, kPlaybackSpeedBounds));
  } else {
    throw ApiError(400, "\"command\" must be one of play, pause, step, reset, seek, speed; got \"" +
                            command.substr(0, 40) + "\"",
                   "command");
  }
  return jsonResponse(s->state());
}

}  // namespace fc::service
