#pragma once
#include "core/types.h"
#include <array>
#include <string>

namespace fc {

struct Phase {
  std::string name = "water";
  Real restDensity = 1000;          // kg/m^3
  Real viscosity = 0;               // kinematic, m^2/s (used by viscosity effects)
  std::array<float, 3> color = {0.45f, 0.7f, 1.0f};
};

enum class ParticleKind : uint8_t { Liquid = 0, Temporary = 1, Boundary = 2 };

}  // namespace fc
