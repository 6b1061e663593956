#pragma once
// Physical ranges of the values a scene or a request gives outside the
// ParamSpec tables (those carry their own): declared once here, checked by
// the scene parser and the REST layer, listed by GET /api/parameters and the
// docs. Inside them every accepted scene finishes its frames: the limits
// keep speeds, accelerations and densities where float arithmetic and the
// CFL step stay meaningful (ρ² and |g|·dt² must not overflow), well beyond
// anything a liquid shot needs.
#include <vector>

namespace fc {

struct PhysicalRange {
  const char* name;  // the scene key (or the family of keys) it applies to
  const char* unit;
  double min, max;
  const char* help;
  bool contains(double v) const { return v >= min && v <= max; }
};

namespace limits {
inline constexpr PhysicalRange kGravity{"gravity", "m/s^2", 0, 1000,
                                        "magnitude of the gravity vector (1000 m/s^2 is about 100 g)"};
inline constexpr PhysicalRange kRestDensity{"phases[].rest_density", "kg/m^3", 1, 1e5,
                                            "rest density of a liquid phase (water 1000, mercury 13 546)"};
inline constexpr PhysicalRange kViscosity{"phases[].viscosity", "m^2/s", 0, 1e3, "kinematic viscosity of a phase"};
inline constexpr PhysicalRange kSpeed{"velocity, speed", "m/s", 0, 1e3,
                                      "a block's, emitter's or body's speed (magnitude); an emitter's at most 100 m/s"};
inline constexpr PhysicalRange kAngularSpeed{"angular_velocity", "deg/s", 0, 1e5, "a body's spin, per axis"};
inline constexpr PhysicalRange kBodyDensity{"bodies[].density", "kg/m^3", 1, 1e6, "a dynamic body's density"};
inline constexpr PhysicalRange kCoordinate{"positions, sizes", "m", -1e5, 1e5,
                                           "any coordinate or extent in a scene (domain, blocks, obstacles, bodies, "
                                           "emitters, instance translations, capture regions)"};
inline constexpr PhysicalRange kTime{"times", "s", -1e6, 1e6,
                                     "any time in a scene (duration, instance start and keys, emitter start/end)"};
inline constexpr PhysicalRange kScale{"transform[].scale", "", 1e-3, 1e3, "an instance's scale, per axis"};
inline constexpr PhysicalRange kRotation{"rotation", "deg", -1e6, 1e6, "a rotation angle"};
inline constexpr PhysicalRange kPlaybackSpeed{"speed", "", 1e-3, 1e3, "an instance's playback speed"};
}  // namespace limits

inline const std::vector<PhysicalRange>& physicalRanges() {
  static const std::vector<PhysicalRange> all = {
      limits::kGravity,     limits::kRestDensity,    limits::kViscosity,  limits::kSpeed,
      limits::kAngularSpeed, limits::kBodyDensity,   limits::kCoordinate,
      limits::kTime,        limits::kScale,          limits::kRotation,   limits::kPlaybackSpeed};
  return all;
}

}  // namespace fc
