#include "control/instance.h"
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

namespace fc {

namespace {
constexpr double kDegree = std::numbers::pi / 180;

template <int D>
using VecD = Eigen::Matrix<double, D, 1>;
template <int D>
using MatD = Eigen::Matrix<double, D, D>;

Eigen::Quaterniond eulerXYZ(const std::array<double, 3>& deg) {
  return Eigen::AngleAxisd(deg[0] * kDegree, Eigen::Vector3d::UnitX()) *
         Eigen::AngleAxisd(deg[1] * kDegree, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(deg[2] * kDegree, Eigen::Vector3d::UnitZ());
}

template <int D>
MatD<D> scaleReflect(const VecD<D>& scale, const std::array<bool, D>& reflect) {
  VecD<D> s = scale;
  for (int d = 0; d < D; ++d)
    if (reflect[d]) s[d] = -s[d];
  return s.asDiagonal();
}

template <int D>
bool finite(const VecD<D>& v) {
  return v.allFinite();
}

// The transform at fraction u of the segment from key a to key b, with the
// reflection of key `reflectKey`.
template <int D>
void compose(const TransformKey<D>& ka, const TransformKey<D>& kb, double u, const TransformKey<D>& reflectKey,
             MatD<D>& linear, VecD<D>& translation) {
  // a + u (b − a): equal keys give exactly the key, so a key repeating a
  // pose changes nothing (sessions keep the frames it cannot change).
  translation = ka.translation + u * (kb.translation - ka.translation);
  const VecD<D> scale = ka.scale + u * (kb.scale - ka.scale);
  MatD<D> rotation;
  if constexpr (D == 2) {
    const double angle = (ka.rotationDeg[0] + u * (kb.rotationDeg[0] - ka.rotationDeg[0])) * kDegree;
    rotation << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
  } else if (ka.rotationDeg == kb.rotationDeg) {
    rotation = eulerXYZ(ka.rotationDeg).toRotationMatrix();
  } else {
    rotation = eulerXYZ(ka.rotationDeg).slerp(u, eulerXYZ(kb.rotationDeg)).toRotationMatrix();
  }
  linear = rotation * scaleReflect<D>(scale, reflectKey.reflect);
}

// Keys a <= b around `time` and the fraction u in [0, 1] between them; at a
// key time, the segment that starts there.
template <int D>
void locate(const std::vector<TransformKey<D>>& keys, double time, size_t& a, size_t& b, double& u) {
  b = 0;
  while (b < keys.size() && keys[b].time <= time) ++b;
  a = b == 0 ? 0 : b - 1;
  if (b >= keys.size()) b = keys.size() - 1;
  if (b < a) b = a;
  u = 0;
  if (b != a && keys[b].time > keys[a].time)
    u = std::clamp((time - keys[a].time) / (keys[b].time - keys[a].time), 0.0, 1.0);
}
}  // namespace

template <int D>
void TransformTrack<D>::evaluate(double time, MatD<D>& linear, VecD<D>& translation) const {
  if (keys.empty()) {
    linear.setIdentity();
    translation.setZero();
    return;
  }
  size_t a, b;
  double u;
  locate(keys, time, a, b, u);
  // Reflection is discrete: the earlier key's until the later key is reached.
  compose(keys[a], keys[b], u, u >= 1 ? keys[b] : keys[a], linear, translation);
}

template <int D>
void TransformTrack<D>::velocityMap(double time, MatD<D>& gradient, VecD<D>& offset) const {
  gradient.setZero();
  offset.setZero();
  if (keys.size() < 2 || time < keys.front().time || time >= keys.back().time) return;
  size_t a, b;
  double u;
  locate(keys, time, a, b, u);
  if (a == b) return;
  // Differentiate inside the segment (one-sided at its start), with its
  // reflection held: the switch at the next key is not a motion.
  const double span = keys[b].time - keys[a].time;
  const double du = std::min(1e-4 / span, 0.5);
  const double u0 = std::min(u, 1 - du);
  MatD<D> m0, m1;
  VecD<D> t0, t1;
  compose(keys[a], keys[b], u0, keys[a], m0, t0);
  compose(keys[a], keys[b], u0 + du, keys[a], m1, t1);
  const double dt = du * span;
  // x(τ) = M(τ) y + t(τ) with y = M⁻¹ (x − t): v = Ṁ M⁻¹ (x − t) + ṫ.
  gradient = (m1 - m0) / dt * m0.inverse();
  offset = (t1 - t0) / dt - gradient * t0;
}
template <int D>
Affine<D> TransformTrack<D>::templateToWorld(double time, const Vec<D>& centre) const {
  MatD<D> m;
  VecD<D> t;
  evaluate(time, m, t);
  Affine<D> a;
  a.linear = m.template cast<Real>();
  a.translation = (t - m * centre.template cast<double>()).template cast<Real>();
  return a;
}

template <int D>
Vec<D> TransformTrack<D>::pointVelocity(double time, const Vec<D>& centre, const Vec<D>& xWorld) const {
  (void)centre;  // the velocity of a carried point depends on where it is, not on c
  MatD<D> g;
  VecD<D> o;
  velocityMap(time, g, o);
  return (g * xWorld.template cast<double>() + o).template cast<Real>();
}

template <int D>
std::string TransformTrack<D>::validate() const {
  for (size_t k = 0; k < keys.size(); ++k) {
    const auto& key = keys[k];
    const std::string at = "[" + std::to_string(k) + "].";
    if (!std::isfinite(key.time)) return at + "time: must be a finite number";
    if (k > 0 && !(key.time > keys[k - 1].time))
      return at + "time: keys must be in strictly increasing time (" + std::to_string(key.time) +
             " s does not follow " + std::to_string(keys[k - 1].time) + " s)";
    if (!finite<D>(key.translation)) return at + "translation: must be finite";
    for (double r : key.rotationDeg)
      if (!std::isfinite(r)) return at + "rotation: must be finite";
    for (int d = 0; d < D; ++d)
      if (!(key.scale[d] > 0) || !std::isfinite(key.scale[d]))
        return at + "scale[" + std::to_string(d) + "]: must be a positive finite number (use reflect to mirror)";
  }
  return {};
}

bool TimeMap::active(double sceneTime, double templateDuration) const {
  const double eps = 1e-9;
  return sceneTime >= start - eps && sceneTime <= start + sceneDuration(templateDuration) + eps;
}

double TimeMap::templateTime(double sceneTime, double templateDuration) const {
  const double e = end(templateDuration);
  const double u = std::clamp((sceneTime - start) * speed, 0.0, e - cropBegin);
  return reverse ? e - u : cropBegin + u;
}

size_t TimeMap::frameAt(double sceneTime, double frameRate, size_t frameCount) const {
  if (frameCount == 0) return 0;
  const double duration = double(frameCount - 1) / frameRate;
  const double eps = 1e-6;
  const double first = std::ceil(cropBegin * frameRate - eps);
  const double last = std::floor(end(duration) * frameRate + eps);
  double f = std::round(templateTime(sceneTime, duration) * frameRate);
  f = std::clamp(f, first, std::max(first, last));
  return size_t(std::clamp(f, 0.0, double(frameCount - 1)));
}

std::string TimeMap::validate(double templateDuration) const {
  if (!std::isfinite(start)) return "start: must be a finite number";
  if (!(speed > 0) || !std::isfinite(speed)) return "speed: must be a positive finite number";
  if (!std::isfinite(cropBegin) || cropBegin < 0) return "crop_begin: must be a finite number >= 0";
  if (!std::isfinite(cropEnd)) return "crop_end: must be a finite number";
  const double e = end(templateDuration);
  const double eps = 1e-9;
  if (templateDuration >= 0 && cropBegin > templateDuration + eps)
    return "crop_begin: " + std::to_string(cropBegin) + " s is past the template's end (" +
           std::to_string(templateDuration) + " s)";
  if (cropEnd >= 0 && templateDuration >= 0 && cropEnd > templateDuration + eps)
    return "crop_end: " + std::to_string(cropEnd) + " s is past the template's end (" +
           std::to_string(templateDuration) + " s)";
  if (!(e > cropBegin)) return "crop_end: must be greater than crop_begin";
  return {};
}

const ParamTable<InstanceParams>& instanceParamTable(int dimension) {
  // Weights: paper §4 defaults. Units: see control/control.h (the forces'
  // normalisation makes them independent of the liquid's resolution).
  using P = InstanceParams;
  static const ParamTable<P> table2 = {
      {.name = "attraction_weight", .min = 0, .max = 100, .def = 0.2,
       .help = "w_a: attraction towards uncovered control particles (eq. 2)", .member = &P::attractionWeight},
      {.name = "velocity_weight", .min = 0, .max = 100, .def = 0.03,
       .help = "w_v: pull towards the control particles' velocity (eq. 4)", .member = &P::velocityWeight},
      {.name = "repulsion_weight", .min = 0, .max = 100, .def = 0.1,
       .help = "w_r: push back from the repulsion layer (eq. 5)", .member = &P::repulsionWeight},
      {.name = "repulsion", .min = 0, .max = 1, .def = 1, .help = "use the template's repulsion layer",
       .member = &P::repulsion},
      {.name = "temporary_particles", .min = 0, .max = 1, .def = 1,
       .help = "seed and remove temporary particles (Algorithms 1, 2)", .member = &P::temporaryParticles},
      {.name = "seed_threshold", .unit = "rho0", .min = 0, .max = 10, .def = 0.35,
       .help = "eta: seed where the control density exceeds the liquid density by this many rest densities",
       .member = &P::seedThreshold},
      {.name = "removal_threshold", .unit = "rho0", .min = 0, .max = 10, .def = 0.35,
       .help = "tau: remove temporary particles where the non-temporary density exceeds this many rest densities",
       .member = &P::removalThreshold},
      {.name = "seed_distance", .unit = "h", .min = 0.1, .max = 2, .def = 0.5,
       .help = "l: seed candidates at d_tp = l h from their particle", .member = &P::seedDistance},
      {.name = "falloff_width", .unit = "m", .min = 0, .max = 100, .def = 0.05,
       .help = "band around the instance's box across which control fades out", .member = &P::falloffWidth},
      {.name = "falloff_decay", .min = 0, .max = 10, .def = 1,
       .help = "gamma: the weights fade as t^gamma across the band", .member = &P::falloffDecay},
  };
  static const ParamTable<P> table3 =
      table2.withDefaults({{"attraction_weight", 0.06}, {"velocity_weight", 0.01}, {"repulsion_weight", 0.04}});
  return dimension == 3 ? table3 : table2;
}

const ParamTable<ControlSettings>& controlSettingsTable() {
  using C = ControlSettings;
  static const ParamTable<C> table = {
      {.name = "forces_every_substep", .min = 0, .max = 1, .def = 0,
       .help = "recompute the control forces at every substep instead of once per frame (the paper's choice)",
       .member = &C::forcesEverySubstep},
      {.name = "temporary_grace_frames", .unit = "frames", .min = 0, .max = 1e6, .def = 60,
       .help = "frames a temporary particle may stay outside every instance before it is removed regardless of "
               "density",
       .member = &C::temporaryGraceFrames},
      {.name = "temporary_fade_share", .min = 1e-4, .max = 1, .def = 0.02,
       .help = "at most this share of the liquid's mass leaves per frame as temporary particles past their grace "
               "period (the rest go in the next frames), so that the liquid does not visibly lose a layer in one "
               "frame",
       .member = &C::temporaryFadeShare},
      {.name = "fidelity_cell", .unit = "r", .min = 0.5, .max = 10, .def = 4,
       .help = "cell size of the fidelity occupancy grid, in template particle radii (4: two particle spacings)",
       .member = &C::fidelityCell},
  };
  return table;
}

template struct TransformTrack<2>;
template struct TransformTrack<3>;

}  // namespace fc
