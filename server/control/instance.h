#pragma once
// A template instance (paper §3.5): which template, where it is (a keyframed
// transform track), when and how it plays (a time map), which phase it
// controls and how strongly (its parameters). This is the model every layer
// above shares: scene files, REST, the editor.
//
// Spaces. Template space is the recording's world space (the coordinates of
// the template's particles and capture region). The instance transform maps
// the region's CENTRE to the key's translation, then rotates, scales and
// reflects about it:
//   x_world = R · S · F · (x_template − c) + t
// with c the region centre, F = diag(±1) (reflect), S = diag(scale), R the
// rotation, t the translation. An instance whose single key is
// {translation: c} therefore plays the template where it was recorded.
#include "control/template_grids.h"
#include "core/aabb.h"
#include "core/transform.h"
#include "sph/parameters.h"
#include <array>
#include <memory>
#include <string>
#include <vector>

namespace fc {

template <int D>
struct TransformKey {
  double time = 0;                        // scene time, s
  Eigen::Matrix<double, D, 1> translation = Eigen::Matrix<double, D, 1>::Zero();  // m
  // Degrees. 2D: [angle] counter-clockwise. 3D: [x, y, z] Euler angles,
  // intrinsic order XYZ (three.js's default): R = Rx · Ry · Rz.
  std::array<double, D == 2 ? 1 : 3> rotationDeg{};
  Eigen::Matrix<double, D, 1> scale = Eigen::Matrix<double, D, 1>::Ones();  // per axis, > 0
  std::array<bool, D> reflect{};          // mirror template axis d before scaling
};

// Keys in strictly increasing time; between keys translation and scale are
// linear, rotation is slerp (3D) or angle interpolation (2D); reflection
// switches at the later key (it cannot be interpolated). Outside the first and
// last key the nearest key holds.
template <int D>
struct TransformTrack {
  std::vector<TransformKey<D>> keys;

  // Linear part M and translation t at scene time `time`, in double, of
  // x_world = M (x_template − c) + t (the centre c is the instance's).
  void evaluate(double time, Eigen::Matrix<double, D, D>& linear, Eigen::Matrix<double, D, 1>& translation) const;
  // The template-space → world map at `time`, for template region centre c.
  Affine<D> templateToWorld(double time, const Vec<D>& centre) const;
  // World velocity of the points the instance carries: v(x) = G x + g at
  // world position x (zero outside the keys and for a single key). Taken
  // inside the segment holding `time` (the one starting there at a key), so
  // a reflection switching at a key is not mistaken for motion.
  void velocityMap(double time, Eigen::Matrix<double, D, D>& gradient, Eigen::Matrix<double, D, 1>& offset) const;
  // World velocity at scene time `time` of the point that the instance
  // carries through world position x (velocityMap applied to x).
  Vec<D> pointVelocity(double time, const Vec<D>& centre, const Vec<D>& xWorld) const;
  bool animated() const { return keys.size() > 1; }
  // Empty string when valid, otherwise what is wrong, starting with the key
  // index and field: "[2].scale[0]: must be ...".
  std::string validate() const;
};

// Scene time → template time. The instance plays template time
// [cropBegin, cropEnd] starting at scene time `start`, `speed` template
// seconds per scene second, backwards when `reverse`.
struct TimeMap {
  double start = 0;        // scene time the instance starts, s
  double cropBegin = 0;    // template time, s
  double cropEnd = -1;     // template time, s; < 0: the template's end
  double speed = 1;        // > 0
  bool reverse = false;

  // cropEnd with the template's duration filled in.
  double end(double templateDuration) const { return cropEnd < 0 ? templateDuration : cropEnd; }
  // Scene seconds the instance is active.
  double sceneDuration(double templateDuration) const { return (end(templateDuration) - cropBegin) / speed; }
  // Active on the closed interval [start, start + sceneDuration].
  bool active(double sceneTime, double templateDuration) const;
  // Template time at sceneTime (clamped to the crop window).
  double templateTime(double sceneTime, double templateDuration) const;
  // The template frame played at sceneTime: the nearest recorded frame to
  // templateTime, within the crop window's frames.
  size_t frameAt(double sceneTime, double frameRate, size_t frameCount) const;
  // Factor on template velocities: speed, negated when reversed.
  double velocityFactor() const { return reverse ? -speed : speed; }
  // Empty when valid for a template of that duration, else what is wrong.
  std::string validate(double templateDuration) const;
};

// Per-instance parameters (paper §3.3–§3.5, defaults of §4).
struct InstanceParams {
  double attractionWeight;  // w_a, eq. (2)
  double velocityWeight;    // w_v, eq. (4)
  double repulsionWeight;   // w_r, eq. (5)
  bool repulsion;
  bool temporaryParticles;  // Algorithms 1 and 2
  double seedThreshold;     // eta, rest densities
  double removalThreshold;  // tau, rest densities
  double seedDistance;      // l, smoothing lengths
  double falloffWidth;      // m
  double falloffDecay;      // gamma
  bool operator==(const InstanceParams&) const = default;
};
// Declared once; the weights' defaults depend on the dimension (paper §4).
const ParamTable<InstanceParams>& instanceParamTable(int dimension);
inline const ParamSpecs& instanceParamSpecs(int dimension) { return instanceParamTable(dimension).specs(); }

// Scene-level control settings (the "control" object of a scene).
struct ControlSettings {
  bool forcesEverySubstep;
  int temporaryGraceFrames;
  double temporaryFadeShare;
  double fidelityCell;  // template particle radii
  bool operator==(const ControlSettings&) const = default;
};
const ParamTable<ControlSettings>& controlSettingsTable();
inline const ParamSpecs& controlSettingsSpecs() { return controlSettingsTable().specs(); }

template <int D>
struct InstanceSpec {
  std::string name;             // label shown in the editor; unique in a scene
  std::string templateName;
  TransformTrack<D> transform;  // empty: one key at the recording place (filled in at bind time)
  TimeMap time;
  int phase = 0;                // index of the scene phase it controls
  InstanceParams params = instanceParamTable(D).defaults();
};

// An instance with its template loaded (shared between instances of the same
// template) and its transform track filled in.
template <int D>
struct BoundInstance {
  InstanceSpec<D> spec;
  std::shared_ptr<const TemplateAccel<D>> accel;  // accel->source is the template
  const Template<D>& templ() const { return *accel->source; }
  Vec<D> centre() const { return templ().region().center(); }
};

}  // namespace fc
