#include "cli/param_override.h"

#include "io/scene.h"

#include <cmath>
#include <cstdio>

namespace fc::cli {

ParamOverride parseParamOverride(const ParamSpecs& specs, const std::string& kv, const std::string& option,
                                 const std::string& prefix) {
  const size_t eq = kv.find('=');
  const std::string key = kv.substr(0, eq);
  const ParamSpec* spec = findSpec(specs, key);
  if (eq == std::string::npos || !spec) {
    std::string known;
    for (const auto& s : specs) known += (known.empty() ? "" : ", ") + s.name;
    throw SceneError(prefix, option + " '" + kv + "': expected KEY=VALUE with KEY one of: " +
                                 (known.empty() ? std::string("(none)") : known));
  }
  const std::string text = kv.substr(eq + 1);
  const auto bad = [&](const std::string& why) {
    return SceneError(prefix + "." + key, "'" + text + "' given by " + option + ": " + why);
  };
  double value = 0;
  if (spec->type == ParamType::Boolean && (text == "true" || text == "false")) {
    value = text == "true" ? 1 : 0;
  } else {
    size_t used = 0;
    try {
      value = std::stod(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != text.size()) throw bad("not a number");
  }
  if (spec->type == ParamType::Boolean && value != 0 && value != 1) throw bad("must be 0, 1, true or false");
  if (spec->type == ParamType::Integer && value != std::floor(value)) throw bad("must be an integer");
  if (!(value >= spec->min && value <= spec->max)) {
    char range[64];
    std::snprintf(range, sizeof(range), "must be in [%g, %g]", spec->min, spec->max);
    throw bad(range);
  }
  return {spec, value};
}

}  // namespace fc::cli
