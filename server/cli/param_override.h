#pragma once
// KEY=VALUE on the command line against declared parameters (sph/parameters.h):
// --control-setting, --surface, --format-setting.
#include "sph/parameters.h"
#include <string>

namespace fc::cli {

struct ParamOverride {
  const ParamSpec* spec = nullptr;
  double value = 0;
};

// Parses `kv` as KEY=VALUE with KEY one of `specs`, checked as a scene
// file's value would be (booleans as 0/1/true/false, integers whole, the
// declared range). Throws SceneError with key path `prefix.KEY` (or `prefix`
// when KEY is unknown) saying that `option` gave it.
ParamOverride parseParamOverride(const ParamSpecs& specs, const std::string& kv, const std::string& option,
                                 const std::string& prefix);

}  // namespace fc::cli
