#pragma once
// Every declared parameter (name, unit, range, default, help) as JSON: the
// answer of GET /api/parameters, of `flowclip params` and the source of the
// docs' parameter reference.
#include <nlohmann/json.hpp>

namespace fc {

// Instance parameters, control and simulation settings, the registered
// pressure solvers and effects with theirs, and the physical ranges.
template <int D>
nlohmann::json parameterReference();

}  // namespace fc
