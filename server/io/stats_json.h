#pragma once
// One frame's statistics as JSON: the `frames[]` objects of `flowclip run
// --stats` and the `stats` of a session's state (docs/headless.md).
#include "sph/simulation.h"
#include <nlohmann/json.hpp>

namespace fc {

// `controlled`: the scene has template instances. Without them the control
// keys are left out (a scene that names no instance pays nothing, in the
// stats too).
nlohmann::json frameStatsToJson(const FrameStats& stats, bool controlled);

}  // namespace fc
