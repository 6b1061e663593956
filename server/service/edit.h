#pragma once
// Edits of a running scene (what a session applies at a frame boundary):
// their JSON form, parsed and checked key by key, and their results.
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace fc::service {

// ---- edits -----------------------------------------------------------------

enum class EditKind { AddInstance, UpdateInstance, RemoveInstance, Settings };
const char* editKindName(EditKind kind);  // "add_instance", "update_instance", "remove_instance", "settings"

// An edit of the running scene. Payloads are the scene file's JSON:
//   AddInstance     payload: an instance object (scenes/README.md, instances[i]).
//   UpdateInstance  instance: its name; payload: a JSON merge patch (RFC 7396)
//                   applied to the instance's full scene JSON (as sceneJson()
//                   writes it; null removes a key, i.e. restores its default).
//   RemoveInstance  instance: its name; no payload.
//   Settings        payload: an object with any of "settings", "solver",
//                   "control", each a merge patch on the scene's object of
//                   that name. A "solver" patch naming another "method"
//                   replaces the solver object (the other method's
//                   parameters do not apply). The simulation is rebuilt
//                   from the scene at frame 0 and every recorded frame is
//                   re-simulated (docs/cache.md).
struct Edit {
  EditKind kind = EditKind::AddInstance;
  std::string instance;
  nlohmann::json payload;

  // {"type": "add_instance", "instance": {...}}
  // {"type": "update_instance", "name": "drop", "patch": {...}}
  // {"type": "remove_instance", "name": "drop"}
  // {"type": "settings", "settings": {...}, "solver": {...}, "control": {...}}
  // Throws SceneError naming the key ("type", "name", "instance", "patch").
  static Edit fromJson(const nlohmann::json& j);
};

struct EditResult {
  uint64_t id = 0;
  EditKind kind = EditKind::AddInstance;
  bool accepted = false;
  // Accepted: the first frame the edit changes (0: every frame; recorded
  // frames from there are re-simulated), or the next frame to simulate when
  // it changes none (a rename).
  int frame = -1;
  std::string instance;   // the instance concerned (an added one's resolved name)
  std::string path;       // rejected: key path of the offending value in the scene ("instances[2].speed")
  std::string message;    // rejected: what was wrong, starting with the path when there is one
  // {"id", "type", "accepted", "frame" | "error": {"path", "message"}, "instance"}
  nlohmann::json toJson() const;
};

// The scene objects a settings edit may patch: settings, solver, control.
const std::vector<std::string>& settingsEditKeys();

}  // namespace fc::service
