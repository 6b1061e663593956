#pragma once
// Key paths into a scene's JSON, as job specs and render jobs name what they
// change: `a.b`, `list[NAME]` (the element whose "name" is NAME) or
// `list[3]`; the grammar of flowclip-batch's specs (docs/batch.md).
#include <nlohmann/json.hpp>

#include <stdexcept>
#include <string>

namespace fc {

// A key path that is malformed or names nothing in the scene; the message
// says which part.
struct KeyPathError : std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

// Sets `path` of `scene` to `value`. Every container on the way must exist;
// the last key of an object may be new. Throws KeyPathError.
void setKeyPath(nlohmann::json& scene, const std::string& path, const nlohmann::json& value);

}  // namespace fc
