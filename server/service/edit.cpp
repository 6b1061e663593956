// Edits of a running scene: see edit.h.
#include "service/edit.h"

#include "io/scene.h"

#include <algorithm>

namespace fc::service {

using nlohmann::json;
using namespace json_access;

const char* editKindName(EditKind kind) {
  switch (kind) {
    case EditKind::AddInstance: return "add_instance";
    case EditKind::UpdateInstance: return "update_instance";
    case EditKind::RemoveInstance: return "remove_instance";
    case EditKind::Settings: return "settings";
  }
  return "?";
}

const std::vector<std::string>& settingsEditKeys() {
  static const std::vector<std::string> keys = {"settings", "solver", "control"};
  return keys;
}

namespace {
// The member `key` of an edit, checked for its JSON type (json_access.h's messages).
const json& objectMember(const json& j, const std::string& key, const std::string& what) {
  return expectObject(required(j, "", key, what), key);
}
std::string stringMember(const json& j, const std::string& key, const std::string& what) {
  return getString(required(j, "", key, what), key);
}
}  // namespace

Edit Edit::fromJson(const json& j) {
  if (!j.is_object()) throw SceneError("", std::string("an edit must be a JSON object, got ") + j.type_name());
  const std::string kinds = "add_instance, update_instance, remove_instance or settings";
  const std::string type = stringMember(j, "type", kinds);
  Edit e;
  if (type == "add_instance") {
    checkKeys(j, "", {"type", "instance"}, "a " + type + " edit");
    e.kind = EditKind::AddInstance;
    e.payload = objectMember(j, "instance", "the instance object");
  } else if (type == "update_instance") {
    checkKeys(j, "", {"type", "name", "patch"}, "a " + type + " edit");
    e.kind = EditKind::UpdateInstance;
    e.instance = stringMember(j, "name", "the instance's name");
    e.payload = objectMember(j, "patch", "a JSON merge patch of the instance");
  } else if (type == "remove_instance") {
    checkKeys(j, "", {"type", "name"}, "a " + type + " edit");
    e.kind = EditKind::RemoveInstance;
    e.instance = stringMember(j, "name", "the instance's name");
  } else if (type == "settings") {
    checkKeys(j, "", {"type", "settings", "solver", "control"}, "a " + type + " edit");
    e.kind = EditKind::Settings;
    e.payload = json::object();
    for (const auto& k : settingsEditKeys())
      if (j.contains(k)) e.payload[k] = objectMember(j, k, "");
    if (e.payload.empty()) throw SceneError("", "a settings edit needs at least one of " + joinNames(settingsEditKeys()));
  } else {
    throw SceneError("type", "unknown edit type '" + type + "' (expected " + kinds + ")");
  }
  return e;
}

json EditResult::toJson() const {
  json j = {{"id", id}, {"type", editKindName(kind)}, {"accepted", accepted}};
  if (!instance.empty()) j["instance"] = instance;
  if (accepted)
    j["frame"] = frame;
  else
    j["error"] = {{"path", path}, {"message", message}};
  return j;
}

}  // namespace fc::service
