// Edits of a running scene: see edit.h.
#include "service/edit.h"

#include "io/scene.h"

#include <algorithm>

namespace fc::service {

using nlohmann::json;

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

std::string joinedNames(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
  return s;
}

namespace {

void onlyKeys(const json& j, const std::vector<std::string>& allowed, const std::string& type) {
  for (const auto& [k, v] : j.items())
    if (std::find(allowed.begin(), allowed.end(), k) == allowed.end())
      throw SceneError(k, "unknown key for a " + type + " edit (accepted: " + joinedNames(allowed) + ")");
}

const json& requiredMember(const json& j, const std::string& key, json::value_t type, const std::string& what) {
  auto it = j.find(key);
  if (it == j.end()) throw SceneError(key, "required: " + what);
  if (it->type() != type)
    throw SceneError(key, std::string("must be ") + (type == json::value_t::object ? "an object" : "a string") +
                              ", got " + it->type_name());
  return *it;
}
}  // namespace

Edit Edit::fromJson(const json& j) {
  if (!j.is_object()) throw SceneError("", std::string("an edit must be a JSON object, got ") + j.type_name());
  const std::string kinds = "add_instance, update_instance, remove_instance or settings";
  const std::string type = requiredMember(j, "type", json::value_t::string, kinds).get<std::string>();
  Edit e;
  if (type == "add_instance") {
    onlyKeys(j, {"type", "instance"}, type);
    e.kind = EditKind::AddInstance;
    e.payload = requiredMember(j, "instance", json::value_t::object, "the instance object");
  } else if (type == "update_instance") {
    onlyKeys(j, {"type", "name", "patch"}, type);
    e.kind = EditKind::UpdateInstance;
    e.instance = requiredMember(j, "name", json::value_t::string, "the instance's name").get<std::string>();
    e.payload = requiredMember(j, "patch", json::value_t::object, "a JSON merge patch of the instance");
  } else if (type == "remove_instance") {
    onlyKeys(j, {"type", "name"}, type);
    e.kind = EditKind::RemoveInstance;
    e.instance = requiredMember(j, "name", json::value_t::string, "the instance's name").get<std::string>();
  } else if (type == "settings") {
    onlyKeys(j, {"type", "settings", "solver", "control"}, type);
    e.kind = EditKind::Settings;
    e.payload = json::object();
    for (const auto& k : settingsEditKeys())
      if (j.contains(k)) e.payload[k] = requiredMember(j, k, json::value_t::object, "");
    if (e.payload.empty()) throw SceneError("", "a settings edit needs at least one of " + joinedNames(settingsEditKeys()));
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
