// The scene format parsed in one place: every key's check and error path
// (with its key path) side by side, as the scene reference documents them.
#include "io/scene.h"

#include "core/text.h"
#include "core/transform.h"
#include "io/json_access.h"
#include "io/json_text.h"
#include "io/obj_mesh.h"
#include "io/template_database.h"

#include "sph/emitters/nozzle.h"
#include "sph/pipeline.h"
#include "sph/sampling/lattice.h"
#include "sph/limits.h"
#include "sph/settings.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>
#include <type_traits>

namespace fc {

using nlohmann::json;
using namespace json_access;

namespace {

// ---------------------------------------------------------------- limits ---
// Documented in scenes/README.md; keep the two in sync.
constexpr double kMaxParticlesLimit = 50'000'000;
constexpr double kDefaultMaxParticles = 2'000'000;
// The neighbour grid is dense over the domain, so a radius tiny relative to
// the domain costs memory even where there is no liquid.
constexpr double kMaxDomainCells = 1e9;       // domain volume in particle-sized cells
constexpr double kMinDomainDiameters = 2;     // narrowest domain side, in particle diameters
constexpr double kMaxDuration = 1e6;          // s
constexpr double kContainTolerance = 1e-6;    // m, fluid block inside domain
constexpr size_t kMaxPhases = 256;            // phase index is stored as uint8_t
const char* const kDefaultSolver = "dfsph";

// ----------------------------------------------------------- formatting ---
// The shortest decimal that reads back as the same float, so that messages
// and saved scenes say 0.01 rather than 0.009999999776482582.
double shortest(float v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::strtod(std::string(buf, r.ptr).c_str(), nullptr);
}

double toJsonNumber(Real v) {
  if constexpr (std::is_same_v<Real, float>)
    return shortest(v);
  else
    return v;
}

std::string fmt(double v) { return formatNumber(v); }
std::string fmt(float v) { return fmt(shortest(v)); }

std::string interval(Real lo, Real hi) {
  std::string s = "[";
  s += fmt(lo);
  s += ", ";
  s += fmt(hi);
  s += "]";
  return s;
}

template <int D>
std::string fmtVec(const Vec<D>& v) {
  std::string s = "(";
  for (int d = 0; d < D; ++d) s += (d ? ", " : "") + fmt(v[d]);
  return s + ")";
}

const char* axisName(int d) { return d == 0 ? "x" : d == 1 ? "y" : "z"; }

// ------------------------------------------------------- typed accessors ---
// A number stored as Real must also be finite once narrowed to it.
Real getReal(const json& j, const std::string& path) {
  const double v = getNumber(j, path);
  if (std::abs(v) > double(std::numeric_limits<Real>::max()))
    fail(path, fmt(v) + " does not fit in a " + realName());
  return Real(v);
}

template <int D>
Vec<D> getVec(const json& j, const std::string& path) {
  expectType(j.is_array(), j, path, D == 2 ? "an array of 2 numbers" : "an array of 3 numbers");
  if (j.size() != size_t(D))
    fail(path, "expected " + std::to_string(D) + " components (the scene is " + std::to_string(D) + "D), got " +
                   std::to_string(j.size()));
  Vec<D> v;
  for (int d = 0; d < D; ++d) v[d] = getReal(j[size_t(d)], indexPath(path, size_t(d)));
  return v;
}

// Physical ranges (sph/limits.h): the message gives the range and what it is for.
double inRange(double v, const std::string& path, const PhysicalRange& r) {
  return checkBounds(v, path, boundsOf(r, "physical"));
}
template <int D>
void normInRange(const Vec<D>& v, const std::string& path, const PhysicalRange& r) {
  const double n = double(v.template cast<double>().norm());
  if (!r.contains(n))
    fail(path, "magnitude " + fmt(n) + " is outside the physical range " + rangeText(boundsOf(r)) + " (" + r.help + ")");
}
template <int D>
void componentsInRange(const Vec<D>& v, const std::string& path, const PhysicalRange& r) {
  for (int d = 0; d < D; ++d) inRange(double(v[d]), indexPath(path, size_t(d)), r);
}

// Reads one declared parameter into values, checking its JSON type and range.
void readParam(const json& j, const std::string& path, const ParamSpec& spec, ParamValues& values) {
  double v = 0;
  switch (spec.type) {
    case ParamType::Boolean:
      values.set(spec.name, getBool(j, path) ? 1 : 0);
      return;
    case ParamType::Integer: v = getInteger(j, path); break;
    case ParamType::Number: v = getNumber(j, path); break;
  }
  values.set(spec.name, checkBounds(v, path, boundsOf(spec)));
}

// Params of a solver, effect or the settings block: every key other than the
// `reserved` ones must be a declared ParamSpec; absent ones keep defaults.
ParamValues parseParams(const json& obj, const std::string& path, const ParamSpecs& specs,
                        const std::vector<std::string>& reserved, const std::string& owner) {
  ParamValues values(specs);
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    if (std::find(reserved.begin(), reserved.end(), it.key()) != reserved.end()) continue;
    const ParamSpec* spec = findSpec(specs, it.key());
    if (!spec) {
      std::vector<std::string> names = reserved;
      for (const auto& s : specs) names.push_back(s.name);
      fail(keyPath(path, it.key()), "unknown parameter of " + owner + "; expected one of: " + joinNames(names));
    }
    readParam(it.value(), keyPath(path, it.key()), *spec, values);
  }
  return values;
}

json paramsToJson(const ParamValues& values, const ParamSpecs* specs) {
  json out = json::object();
  for (const auto& [name, v] : values.all()) {
    const ParamSpec* s = specs ? findSpec(*specs, name) : nullptr;
    if (s && s->type == ParamType::Boolean)
      out[name] = v != 0;
    else if (s && s->type == ParamType::Integer)
      out[name] = static_cast<long long>(std::llround(v));
    else
      out[name] = v;
  }
  return out;
}

template <int D>
json vecToJson(const Vec<D>& v) {
  json a = json::array();
  for (int d = 0; d < D; ++d) a.push_back(toJsonNumber(v[d]));
  return a;
}

// ------------------------------------------------------------ sections ---
template <int D>
AABB<D> parseBox(const json& obj, const std::string& path) {
  AABB<D> box(getVec<D>(required(obj, path, "min", "lower corner, m"), keyPath(path, "min")),
              getVec<D>(required(obj, path, "max", "upper corner, m"), keyPath(path, "max")));
  componentsInRange<D>(box.min, keyPath(path, "min"), limits::kCoordinate);
  componentsInRange<D>(box.max, keyPath(path, "max"), limits::kCoordinate);
  for (int d = 0; d < D; ++d)
    if (!(box.min[d] < box.max[d]))
      fail(path, std::string("min must be less than max on every axis, but along ") + axisName(d) + " min[" +
                     std::to_string(d) + "] = " + fmt(box.min[d]) + " >= max[" + std::to_string(d) +
                     "] = " + fmt(box.max[d]));
  return box;
}

std::vector<Phase> parsePhases(const json* j) {
  if (!j) return {Phase{}};
  const std::string path = "phases";
  expectArray(*j, path);
  if (j->empty()) fail(path, "must list at least one phase (omit the key for the default water phase)");
  if (j->size() > kMaxPhases) fail(path, "at most " + std::to_string(kMaxPhases) + " phases are supported");
  std::vector<Phase> phases;
  for (size_t i = 0; i < j->size(); ++i) {
    const std::string p = indexPath(path, i);
    const json& o = expectObject((*j)[i], p);
    checkKeys(o, p, {"name", "rest_density", "viscosity", "color"});
    Phase ph;
    ph.name = getString(required(o, p, "name", "string referenced by fluid_blocks[].phase"), keyPath(p, "name"));
    if (ph.name.empty()) fail(keyPath(p, "name"), "must not be empty");
    for (size_t k = 0; k < i; ++k)
      if (phases[k].name == ph.name) fail(keyPath(p, "name"), "duplicate phase name '" + ph.name + "' (also " + indexPath(path, k) + ")");
    if (const json* m = member(o, "rest_density")) {
      ph.restDensity = getReal(*m, keyPath(p, "rest_density"));
      if (ph.restDensity <= 0) fail(keyPath(p, "rest_density"), fmt(ph.restDensity) + " kg/m^3 must be > 0");
      inRange(ph.restDensity, keyPath(p, "rest_density"), limits::kRestDensity);
    }
    if (const json* m = member(o, "viscosity")) {
      ph.viscosity = getReal(*m, keyPath(p, "viscosity"));
      if (ph.viscosity < 0) fail(keyPath(p, "viscosity"), fmt(ph.viscosity) + " m^2/s must be >= 0");
      inRange(ph.viscosity, keyPath(p, "viscosity"), limits::kViscosity);
    }
    if (const json* m = member(o, "color")) {
      const std::string cp = keyPath(p, "color");
      expectType(m->is_array(), *m, cp, "an array of 3 numbers (RGB in [0, 1])");
      if (m->size() != 3) fail(cp, "expected 3 components (RGB), got " + std::to_string(m->size()));
      for (size_t c = 0; c < 3; ++c) {
        const double v = getNumber((*m)[c], indexPath(cp, c));
        if (v < 0 || v > 1) fail(indexPath(cp, c), fmt(v) + " is outside the allowed range [0, 1]");
        ph.color[c] = float(v);
      }
    }
    phases.push_back(ph);
  }
  return phases;
}

// The index of the phase a "phase" key names.
int findPhase(const json& j, const std::string& path, const std::vector<Phase>& phases) {
  const std::string name = getString(j, path);
  auto it = std::find_if(phases.begin(), phases.end(), [&](const Phase& ph) { return ph.name == name; });
  if (it == phases.end()) {
    std::vector<std::string> names;
    for (const auto& ph : phases) names.push_back(ph.name);
    fail(path, "unknown phase '" + name + "'; the scene's phases are: " + joinNames(names));
  }
  return int(it - phases.begin());
}

template <int D>
std::vector<FluidBlock<D>> parseFluidBlocks(const json& root, const std::vector<Phase>& phases) {
  const std::string path = "fluid_blocks";
  // A scene whose liquid all comes from emitters may start empty.
  const json* em = member(root, "emitters");
  const bool emits = em && em->is_array() && !em->empty();
  if (emits && !member(root, path)) return {};
  const json& j = expectArray(required(root, "", path, "array of liquid boxes"), path);
  if (j.empty() && !emits) fail(path, "the scene has no liquid: list at least one fluid block or an emitter");
  std::vector<FluidBlock<D>> blocks;
  for (size_t i = 0; i < j.size(); ++i) {
    const std::string p = indexPath(path, i);
    const json& o = expectObject(j[i], p);
    checkKeys(o, p, {"min", "max", "phase", "velocity"});
    FluidBlock<D> b;
    b.box = parseBox<D>(o, p);
    if (const json* m = member(o, "phase")) b.phase = findPhase(*m, keyPath(p, "phase"), phases);
    if (const json* m = member(o, "velocity")) {
      b.velocity = getVec<D>(*m, keyPath(p, "velocity"));
      normInRange<D>(b.velocity, keyPath(p, "velocity"), limits::kSpeed);
    }
    blocks.push_back(b);
  }
  return blocks;
}

template <int D>
std::array<double, D == 2 ? 1 : 3> parseRotationDeg(const json& j, const std::string& path);

// A mesh obstacle's placement: scale (a number or one per axis, > 0),
// translation, rotation (Euler XYZ, degrees).
MeshPlacement parseMeshPlacement(const json& o, const std::string& p) {
  MeshPlacement pl;
  const std::string fp = keyPath(p, "file");
  pl.file = getString(required(o, p, "file", "an OBJ file, relative to the scene file's directory"), fp);
  if (pl.file.empty()) fail(fp, "must name an OBJ file");
  std::string ext = std::filesystem::path(pl.file).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  if (ext != ".obj") fail(fp, "'" + pl.file + "' is not a Wavefront OBJ file (.obj), the only mesh format read");
  if (const json* m = member(o, "scale")) {
    const std::string sp = keyPath(p, "scale");
    if (m->is_number()) {
      const double v = getNumber(*m, sp);
      if (!(v > 0)) fail(sp, fmt(v) + " must be > 0");
      inRange(v, sp, limits::kScale);
      pl.scale = {v, v, v};
    } else {
      expectType(m->is_array() && m->size() == 3, *m, sp, "a number (uniform scale) or an array of 3 numbers");
      for (size_t d = 0; d < 3; ++d) {
        pl.scale[d] = getNumber((*m)[d], indexPath(sp, d));
        if (!(pl.scale[d] > 0)) fail(indexPath(sp, d), fmt(pl.scale[d]) + " must be > 0");
        inRange(pl.scale[d], indexPath(sp, d), limits::kScale);
      }
    }
  }
  if (const json* m = member(o, "translation")) {
    const std::string tp = keyPath(p, "translation");
    expectType(m->is_array(), *m, tp, "an array of 3 numbers");
    if (m->size() != 3) fail(tp, "expected 3 components (the scene is 3D), got " + std::to_string(m->size()));
    for (size_t d = 0; d < 3; ++d) pl.translation[d] = inRange(getNumber((*m)[d], indexPath(tp, d)), indexPath(tp, d), limits::kCoordinate);
  }
  if (const json* m = member(o, "rotation")) pl.rotationDeg = parseRotationDeg<3>(*m, keyPath(p, "rotation"));
  return pl;
}

// Reads, validates and places the mesh, then builds its signed-distance grid
// at the particle radius over its bounds plus the kernel support and a cell.
std::shared_ptr<const MeshSdf> buildMeshObstacle(const MeshPlacement& pl, Real particleRadius, Real contactDistance,
                                                 const std::string& path) {
  ObjSolid solid;
  try {
    solid = readObjSolid(pl.file);
  } catch (const MeshFileError& e) {
    fail(path, e.what());
  }
  const Eigen::Matrix3d R = eulerXYZDegrees(pl.rotationDeg).toRotationMatrix();
  const Vec3d scale(pl.scale[0], pl.scale[1], pl.scale[2]);
  const Vec3d t(pl.translation[0], pl.translation[1], pl.translation[2]);
  for (Vec3d& v : solid.mesh.vertices) {
    v = R * scale.cwiseProduct(v) + t;
    if (!v.allFinite() || (v.cwiseAbs().array() > double(std::numeric_limits<Real>::max())).any())
      fail(path, "'" + pl.file + "': a vertex placed by scale, rotation and translation is not finite in " + realName());
  }
  MeshSdf::Options opt;
  opt.spacing = double(particleRadius);
  opt.band = 5 * double(particleRadius);
  // Exact where the grid says the surface is nearer than the contact
  // distance plus 0.6 r: the contact model then decides on the exact surface
  // (the grid errs by at most half a cell, measured), while particles resting
  // on the obstacle (about r off it) stay on the grid.
  opt.exactBand = (double(contactDistance) + 0.6) * double(particleRadius);
  try {
    return std::make_shared<const MeshSdf>(std::move(solid.mesh), opt);
  } catch (const MeshGridTooLarge& e) {
    fail(path, "'" + pl.file + "': " + e.what());
  } catch (const std::invalid_argument& e) {
    fail(path, "'" + pl.file + "': " + e.what());
  }
}

template <int D>
std::vector<Obstacle<D>> parseObstacles(const json* j, Real particleRadius, Real contactDistance) {
  std::vector<Obstacle<D>> obstacles;
  if (!j) return obstacles;
  const std::string path = "obstacles";
  expectArray(*j, path);
  for (size_t i = 0; i < j->size(); ++i) {
    const std::string p = indexPath(path, i);
    const json& o = expectObject((*j)[i], p);
    const std::string type = getString(required(o, p, "type", D == 2 ? "\"box\", \"sphere\" or \"disk\"" : "\"box\", \"sphere\" or \"mesh\""),
                                       keyPath(p, "type"));
    Obstacle<D> ob;
    if (type == "box") {
      checkKeys(o, p, {"type", "min", "max"});
      ob.shape = ObstacleShape::Box;
      ob.box = parseBox<D>(o, p);
    } else if (type == "sphere" || (D == 2 && type == "disk")) {
      checkKeys(o, p, {"type", "center", "radius"});
      ob.shape = ObstacleShape::Sphere;
      ob.center = getVec<D>(required(o, p, "center", "m"), keyPath(p, "center"));
      ob.radius = getReal(required(o, p, "radius", "m"), keyPath(p, "radius"));
      if (ob.radius <= 0) fail(keyPath(p, "radius"), fmt(ob.radius) + " m must be > 0");
      componentsInRange<D>(ob.center, keyPath(p, "center"), limits::kCoordinate);
      inRange(ob.radius, keyPath(p, "radius"), limits::kCoordinate);
      ob.box = AABB<D>(ob.center.array() - ob.radius, ob.center.array() + ob.radius);
    } else if (type == "mesh") {
      if constexpr (D == 2) {
        fail(keyPath(p, "type"), "mesh obstacles (OBJ files) are 3D only; a 2D scene takes box and disk obstacles");
      } else {
        checkKeys(o, p, {"type", "file", "scale", "translation", "rotation"});
        ob.shape = ObstacleShape::Mesh;
        ob.placement = parseMeshPlacement(o, p);
        ob.mesh = buildMeshObstacle(ob.placement, particleRadius, contactDistance, keyPath(p, "file"));
        ob.box = ob.mesh->bounds();
      }
    } else {
      fail(keyPath(p, "type"), "unknown obstacle type '" + type + "'; expected " +
                               (D == 2 ? "box, sphere or disk (mesh is 3D only)" : "box, sphere or mesh (disk is 2D only)"));
    }
    obstacles.push_back(ob);
  }
  return obstacles;
}

// Rotation in degrees: 2D a number (counter-clockwise), 3D [x, y, z] Euler
// angles, intrinsic XYZ.
template <int D>
std::array<double, D == 2 ? 1 : 3> parseRotationDeg(const json& j, const std::string& path) {
  std::array<double, D == 2 ? 1 : 3> r{};
  if constexpr (D == 2) {
    r[0] = inRange(getNumber(j, path), path, limits::kRotation);
  } else {
    expectType(j.is_array() && j.size() == 3, j, path, "[x, y, z] Euler angles in degrees");
    for (size_t a = 0; a < 3; ++a) r[a] = inRange(getNumber(j[a], indexPath(path, a)), indexPath(path, a), limits::kRotation);
  }
  return r;
}

template <int D>
json rotationToJson(const std::array<double, D == 2 ? 1 : 3>& r) {
  if constexpr (D == 2) return r[0];
  else return json::array({r[0], r[1], r[2]});
}

// Fails at `where` if the body, placed at `pose`, reaches outside the domain.
template <int D>
void checkBodyInDomain(const Body<D>& b, const BodyKey<D>& pose, const AABB<D>& domain, const std::string& where) {
  const Eigen::Matrix<double, D, D> R = rotationFromDegrees<D>(pose.rotationDeg);
  for (int d = 0; d < D; ++d) {
    double e = double(b.radius);
    if (b.shape == ObstacleShape::Box) {
      e = 0;
      for (int c = 0; c < D; ++c) e += std::abs(R(d, c)) * double(b.halfSize[c]);
    }
    const double lo = double(pose.position[d]) - e, hi = double(pose.position[d]) + e;
    if (lo < double(domain.min[d]) - kContainTolerance || hi > double(domain.max[d]) + kContainTolerance)
      fail(where, "the body reaches " + fmt(Real(lo)) + ".." + fmt(Real(hi)) + " m along " + axisName(d) +
                      ", outside the domain " + fmt(domain.min[d]) + ".." + fmt(domain.max[d]) + " m");
  }
}

// The "name" of an object in a list of named ones (bodies, emitters): a
// valid name, unique among those read before it.
template <class Named>
std::string uniqueName(const json& o, const std::string& p, const std::vector<Named>& before, const char* one,
                       const char* many) {
  const std::string name = getString(required(o, p, "name", std::string("a name unique among the ") + many), keyPath(p, "name"));
  if (!isValidTemplateName(name)) fail(keyPath(p, "name"), "\"" + name.substr(0, 40) + "\" is not a name ([A-Za-z0-9_-]{1,64})");
  for (const Named& other : before)
    if (other.name == name) fail(keyPath(p, "name"), std::string("duplicate ") + one + " name \"" + name + "\"");
  return name;
}

// Moving solids: "bodies": [{name, type: box|sphere|disk, size | radius,
// position, rotation, motion: kinematic|dynamic, ...}].
template <int D>
std::vector<Body<D>> parseBodies(const json* j, const AABB<D>& domain) {
  std::vector<Body<D>> bodies;
  if (!j) return bodies;
  const std::string path = "bodies";
  expectArray(*j, path);
  for (size_t i = 0; i < j->size(); ++i) {
    const std::string p = indexPath(path, i);
    const json& o = expectObject((*j)[i], p);
    checkKeys(o, p, {"name", "type", "size", "radius", "position", "rotation", "motion", "velocity",
                     "angular_velocity", "keys", "period", "density", "carve_fluid"});
    Body<D> b;
    b.name = uniqueName(o, p, bodies, "body", "bodies");
    const std::string type = getString(required(o, p, "type", D == 2 ? "\"box\" or \"disk\"" : "\"box\" or \"sphere\""), keyPath(p, "type"));
    if (type == "box") {
      b.shape = ObstacleShape::Box;
      if (member(o, "radius")) fail(keyPath(p, "radius"), "a box has a size, not a radius");
      const Vec<D> size = getVec<D>(required(o, p, "size", "edge lengths, m"), keyPath(p, "size"));
      for (int d = 0; d < D; ++d)
        if (!(size[d] > 0)) fail(indexPath(keyPath(p, "size"), size_t(d)), fmt(size[d]) + " m must be > 0");
      b.halfSize = Real(0.5) * size;
    } else if (type == "sphere" || (D == 2 && type == "disk")) {
      b.shape = ObstacleShape::Sphere;
      if (member(o, "size")) fail(keyPath(p, "size"), "a " + type + " has a radius, not a size");
      b.radius = getReal(required(o, p, "radius", "m"), keyPath(p, "radius"));
      if (!(b.radius > 0)) fail(keyPath(p, "radius"), fmt(b.radius) + " m must be > 0");
    } else {
      fail(keyPath(p, "type"), "unknown body type '" + type + "'; expected " + (D == 2 ? "box or disk" : "box or sphere"));
    }
    if (member(o, "keys") && member(o, "motion") && (*member(o, "motion")) == "dynamic")
      fail(keyPath(p, "keys"), "a dynamic body moves by the liquid's forces; it has no keys");
    // Keyed bodies start at their first key.
    if (!member(o, "keys")) b.position = getVec<D>(required(o, p, "position", "the body centre, m"), keyPath(p, "position"));
    else if (member(o, "position")) fail(keyPath(p, "position"), "a keyed body starts at its first key; give no position");
    if (member(o, "keys") && member(o, "rotation")) fail(keyPath(p, "rotation"), "a keyed body starts at its first key; give no rotation");
    if (const json* m = member(o, "rotation")) b.rotationDeg = parseRotationDeg<D>(*m, keyPath(p, "rotation"));
    const std::string motion = getString(required(o, p, "motion", "\"kinematic\" or \"dynamic\""), keyPath(p, "motion"));
    if (motion == "kinematic") {
      b.motion = BodyMotion::Kinematic;
      if (member(o, "density")) fail(keyPath(p, "density"), "only a dynamic body has a density");
      if (const json* m = member(o, "velocity")) {
        b.velocity = getVec<D>(*m, keyPath(p, "velocity"));
        normInRange<D>(b.velocity, keyPath(p, "velocity"), limits::kSpeed);
      }
      if (const json* m = member(o, "angular_velocity")) {
        b.angularVelocityDeg = parseRotationDeg<D>(*m, keyPath(p, "angular_velocity"));
        for (size_t a = 0; a < b.angularVelocityDeg.size(); ++a)
          inRange(std::abs(b.angularVelocityDeg[a]), indexPath(keyPath(p, "angular_velocity"), a), limits::kAngularSpeed);
      }
      if (const json* m = member(o, "keys")) {
        const std::string kp = keyPath(p, "keys");
        expectArray(*m, kp);
        if (m->empty()) fail(kp, "needs at least one key");
        if (member(o, "velocity") || member(o, "angular_velocity"))
          fail(kp, "give either keys or velocity/angular_velocity, not both");
        for (size_t k = 0; k < m->size(); ++k) {
          const std::string q = indexPath(kp, k);
          const json& ko = expectObject((*m)[k], q);
          checkKeys(ko, q, {"time", "position", "rotation"});
          BodyKey<D> key0;
          key0.time = inRange(getNumber(required(ko, q, "time", "s"), keyPath(q, "time")), keyPath(q, "time"), limits::kTime);
          key0.position = getVec<D>(required(ko, q, "position", "m"), keyPath(q, "position"));
          if (const json* r = member(ko, "rotation")) key0.rotationDeg = parseRotationDeg<D>(*r, keyPath(q, "rotation"));
          if (!b.keys.empty() && !(key0.time > b.keys.back().time))
            fail(keyPath(q, "time"), fmt(key0.time) + " s must be after the previous key's " + fmt(b.keys.back().time) + " s");
          b.keys.push_back(key0);
        }
        b.position = b.keys.front().position;
        b.rotationDeg = b.keys.front().rotationDeg;
      }
      if (const json* m = member(o, "period")) {
        b.period = inRange(getNumber(*m, keyPath(p, "period")), keyPath(p, "period"), limits::kTime);
        if (b.keys.empty()) fail(keyPath(p, "period"), "a period repeats keys; this body has none");
        if (!(b.period >= b.keys.back().time) || !(b.period > 0))
          fail(keyPath(p, "period"), fmt(b.period) + " s must be > 0 and at least the last key's time");
      }
    } else if (motion == "dynamic") {
      b.motion = BodyMotion::Dynamic;
      for (const char* k : {"velocity", "angular_velocity", "keys", "period"})
        if (const json* m = member(o, k); m && std::string(k) != "velocity")
          fail(keyPath(p, k), "a dynamic body moves by the liquid's forces; it has no " + std::string(k));
      if (const json* m = member(o, "velocity")) {
        b.velocity = getVec<D>(*m, keyPath(p, "velocity"));
        normInRange<D>(b.velocity, keyPath(p, "velocity"), limits::kSpeed);
      }
      b.density = getReal(required(o, p, "density", "kg/m^3"), keyPath(p, "density"));
      if (!(b.density > 0)) fail(keyPath(p, "density"), fmt(b.density) + " kg/m^3 must be > 0");
      inRange(b.density, keyPath(p, "density"), limits::kBodyDensity);
    } else {
      fail(keyPath(p, "motion"), "unknown motion '" + motion + "'; expected kinematic or dynamic");
    }
    if (const json* m = member(o, "carve_fluid")) b.carveFluid = getBool(*m, keyPath(p, "carve_fluid"));
    // The body stays inside the tank: at its start and at every key.
    std::vector<std::pair<std::string, BodyKey<D>>> poses;
    if (b.keys.empty()) {
      BodyKey<D> k;
      k.position = b.position;
      k.rotationDeg = b.rotationDeg;
      poses.push_back({keyPath(p, "position"), k});
    } else {
      for (size_t k = 0; k < b.keys.size(); ++k) poses.push_back({keyPath(indexPath(keyPath(p, "keys"), k), "position"), b.keys[k]});
    }
    for (const auto& [where, pose] : poses) checkBodyInDomain<D>(b, pose, domain, where);
    bodies.push_back(b);
  }
  return bodies;
}

// Inflows: "emitters": [{name, center, direction, radius, speed, phase,
// start, end}].
constexpr double kMaxEmitterSpeed = 100;  // m/s
template <int D>
std::vector<Emitter<D>> parseEmitters(const json* j, const std::vector<Phase>& phases) {
  std::vector<Emitter<D>> emitters;
  if (!j) return emitters;
  const std::string path = "emitters";
  expectArray(*j, path);
  for (size_t i = 0; i < j->size(); ++i) {
    const std::string p = indexPath(path, i);
    const json& o = expectObject((*j)[i], p);
    checkKeys(o, p, {"name", "center", "direction", "radius", "speed", "phase", "start", "end"});
    Emitter<D> e;
    e.name = uniqueName(o, p, emitters, "emitter", "emitters");
    e.center = getVec<D>(required(o, p, "center", "the nozzle's centre, m"), keyPath(p, "center"));
    const Vec<D> dir = getVec<D>(required(o, p, "direction", "the jet's direction (normalised when read)"), keyPath(p, "direction"));
    if (!(dir.norm() > Real(1e-6))) fail(keyPath(p, "direction"), "must not be zero");
    e.direction = dir.normalized();
    e.radius = getReal(required(o, p, "radius", D == 2 ? "the nozzle's half width, m" : "the nozzle's radius, m"), keyPath(p, "radius"));
    if (!(e.radius > 0)) fail(keyPath(p, "radius"), fmt(e.radius) + " m must be > 0");
    e.speed = getReal(required(o, p, "speed", "m/s"), keyPath(p, "speed"));
    if (!(e.speed > 0) || e.speed > kMaxEmitterSpeed)
      fail(keyPath(p, "speed"), fmt(e.speed) + " m/s is outside the allowed range (0, " + fmt(kMaxEmitterSpeed) + "]");
    if (const json* m = member(o, "phase")) e.phase = findPhase(*m, keyPath(p, "phase"), phases);
    if (const json* m = member(o, "start")) e.start = getNumber(*m, keyPath(p, "start"));
    if (!(e.start >= 0) || e.start > kMaxDuration) fail(keyPath(p, "start"), fmt(e.start) + " s must be in [0, " + fmt(kMaxDuration) + "]");
    if (const json* m = member(o, "end")) {
      e.end = inRange(getNumber(*m, keyPath(p, "end")), keyPath(p, "end"), limits::kTime);
      if (!(e.end > e.start)) fail(keyPath(p, "end"), fmt(e.end) + " s must be after start (" + fmt(e.start) + " s)");
    }
    emitters.push_back(e);
  }
  return emitters;
}

// Every point of a nozzle's layer lies in the tank and outside the solids at
// least a particle radius (a particle emitted there would start inside a
// wall), and the liquid emitted over the scene's duration fits max_particles.
template <int D>
void checkEmitters(const SimulationSetup<D>& s) {
  const Real r = s.particleRadius;
  const Real spacing = 2 * r;
  const Real slack = Real(1e-3) * r + Real(kContainTolerance);
  double total = 0;
  for (const FluidBlock<D>& b : s.fluidBlocks) total += double(latticeCount(b.box, spacing));
  for (size_t i = 0; i < s.emitters.size(); ++i) {
    const Emitter<D>& e = s.emitters[i];
    const std::string p = indexPath("emitters", i);
    const std::vector<Vec<D>> layer = nozzleLayer(e, spacing);
    for (const Vec<D>& x : layer) {
      for (int d = 0; d < D; ++d)
        if (x[d] < s.domain.min[d] + r - slack || x[d] > s.domain.max[d] - r + slack)
          fail(keyPath(p, "center"), "the nozzle's point " + fmtVec<D>(x) + " is closer than a particle radius (" + fmt(r) +
                                     " m) to the tank's " + axisName(d) + " walls " +
                                     interval(s.domain.min[d], s.domain.max[d]));
      for (size_t k = 0; k < s.obstacles.size(); ++k)
        if (s.obstacles[k].signedDistance(x) < r - slack)
          fail(keyPath(p, "center"), "the nozzle's point " + fmtVec<D>(x) + " lies inside or within a particle radius of " +
                                     indexPath("obstacles", k));
    }
    const double open = std::max(0.0, std::min(e.end, s.duration) - e.start);
    total += double(layer.size()) * (double(e.speed) * open / double(spacing) + 1);
  }
  if (total > double(s.maxParticles))
    fail("emitters", "the fluid blocks and the emitters over the scene's " + fmt(s.duration) + " s make about " +
                         std::to_string(size_t(total)) + " particles at particle_radius " + fmt(r) +
                         " m, more than max_particles = " + std::to_string(s.maxParticles));
}

// "solver" or "boundary": {"method": NAME, ...its parameters}; absent, the
// registry's default method `fallback` with its defaults.
template <class Registry>
NamedParams parseMethod(const json* j, const std::string& path, const char* fallback) {
  const auto& reg = Registry::instance();
  NamedParams method{fallback, {}};
  const json empty = json::object();
  const json& o = j ? expectObject(*j, path) : empty;
  if (const json* m = member(o, "method")) method.name = getString(*m, keyPath(path, "method"));
  const auto* entry = reg.find(method.name);
  if (!entry)
    fail(j && member(o, "method") ? keyPath(path, "method") : path,
         "unknown " + path + " method '" + method.name + "'; known methods: " + joinNames(reg.names(), "(none registered)"));
  method.values = parseParams(o, path, entry->params, {"method"}, path + " '" + method.name + "'");
  return method;
}

// The inverse of parseMethod: the method's name and every parameter.
template <class Registry>
json methodToJson(const NamedParams& method) {
  const auto* entry = Registry::instance().find(method.name);
  json o = paramsToJson(method.values, entry ? &entry->params : nullptr);
  o["method"] = method.name;
  return o;
}

SimulationSettings parseSettings(const json* j) {
  const std::string path = "settings";
  if (!j) return simulationSettingsTable().defaults();
  const SimulationSettings s =
      simulationSettingsTable().bind(parseParams(expectObject(*j, path), path, simulationSettingsSpecs(), {}, "settings"));
  if (s.dtMin > s.dtMax)
    fail(keyPath(path, member(*j, "dt_min") ? "dt_min" : "dt_max"),
         "dt_min = " + fmt(s.dtMin) + " s is larger than dt_max = " + fmt(s.dtMax) + " s");
  return s;
}

template <int D>
std::vector<NamedParams> parseEffects(const json* j) {
  std::vector<NamedParams> effects;
  if (!j) return effects;
  const std::string path = "effects";
  expectArray(*j, path);
  const auto& reg = EffectRegistry<D>::instance();
  std::vector<std::string> namePaths;  // where each effect's name was written, for duplicate messages
  for (size_t i = 0; i < j->size(); ++i) {
    const std::string p = indexPath(path, i);
    const json& item = (*j)[i];
    const json empty = json::object();
    const json* params = &empty;
    std::string namePath = p;
    NamedParams e;
    if (item.is_string()) {
      e.name = item.get<std::string>();
    } else if (item.is_object()) {
      namePath = keyPath(p, "name");
      e.name = getString(required(item, p, "name", "effect name"), namePath);
      params = &item;
    } else {
      expectType(false, item, p, "an effect name or an object with \"name\" and parameters");
    }
    const auto* entry = reg.find(e.name);
    if (!entry) fail(namePath, "unknown effect '" + e.name + "'; known effects: " + joinNames(reg.names(), "(none registered)"));
    for (size_t k = 0; k < effects.size(); ++k)
      if (effects[k].name == e.name) fail(namePath, "duplicate effect '" + e.name + "' (also " + namePaths[k] + ")");
    e.values = parseParams(*params, p, entry->params, {"name"}, "effect '" + e.name + "'");
    effects.push_back(std::move(e));
    namePaths.push_back(namePath);
  }
  return effects;
}

// ------------------------------------------------ control and instances ---
template <int D>
using VecDouble = Eigen::Matrix<double, D, 1>;

// Instance keys other than the instanceParamSpecs(D) parameters.
const std::vector<std::string> kInstanceKeys = {"name",       "template", "phase", "transform", "start",
                                                "crop_begin", "crop_end", "speed", "reverse"};

// A vector of doubles (transforms are stored in double, not Real).
template <int D>
VecDouble<D> getVecDouble(const json& j, const std::string& path) {
  expectType(j.is_array(), j, path, D == 2 ? "an array of 2 numbers" : "an array of 3 numbers");
  if (j.size() != size_t(D))
    fail(path, "expected " + std::to_string(D) + " components (the scene is " + std::to_string(D) + "D), got " +
                   std::to_string(j.size()));
  VecDouble<D> v;
  for (int d = 0; d < D; ++d) v[d] = getNumber(j[size_t(d)], indexPath(path, size_t(d)));
  return v;
}

template <int D>
TransformKey<D> parseTransformKey(const json& j, const std::string& p) {
  const json& o = expectObject(j, p);
  checkKeys(o, p, {"time", "translation", "rotation", "scale", "reflect"});
  TransformKey<D> k;
  if (const json* m = member(o, "time")) k.time = inRange(getNumber(*m, keyPath(p, "time")), keyPath(p, "time"), limits::kTime);
  k.translation = getVecDouble<D>(required(o, p, "translation", "m, where the template region's centre goes"),
                                  keyPath(p, "translation"));
  for (int d = 0; d < D; ++d) inRange(k.translation[d], indexPath(keyPath(p, "translation"), size_t(d)), limits::kCoordinate);
  if (const json* m = member(o, "rotation")) {
    const std::string rp = keyPath(p, "rotation");
    if constexpr (D == 2) {
      expectType(m->is_number(), *m, rp, "a number (degrees, counter-clockwise)");
      k.rotationDeg[0] = inRange(getNumber(*m, rp), rp, limits::kRotation);
    } else {
      const VecDouble<3> r = getVecDouble<3>(*m, rp);
      for (int d = 0; d < 3; ++d) k.rotationDeg[size_t(d)] = inRange(r[d], indexPath(rp, size_t(d)), limits::kRotation);
    }
  }
  if (const json* m = member(o, "scale")) {
    const std::string sp = keyPath(p, "scale");
    const char* rule = " must be > 0 (use reflect to mirror)";
    if (m->is_number()) {
      const double v = getNumber(*m, sp);
      if (!(v > 0)) fail(sp, fmt(v) + rule);
      inRange(v, sp, limits::kScale);
      k.scale.setConstant(v);
    } else {
      expectType(m->is_array(), *m, sp,
                 D == 2 ? "a number (uniform scale) or an array of 2 numbers"
                        : "a number (uniform scale) or an array of 3 numbers");
      k.scale = getVecDouble<D>(*m, sp);
      for (int d = 0; d < D; ++d)
        if (!(k.scale[d] > 0)) fail(indexPath(sp, size_t(d)), fmt(k.scale[d]) + rule);
        else inRange(k.scale[d], indexPath(sp, size_t(d)), limits::kScale);
    }
  }
  if (const json* m = member(o, "reflect")) {
    const std::string rp = keyPath(p, "reflect");
    expectType(m->is_array(), *m, rp, D == 2 ? "an array of 2 booleans" : "an array of 3 booleans");
    if (m->size() != size_t(D))
      fail(rp, "expected " + std::to_string(D) + " components (the scene is " + std::to_string(D) + "D), got " +
                   std::to_string(m->size()));
    for (int d = 0; d < D; ++d) k.reflect[size_t(d)] = getBool((*m)[size_t(d)], indexPath(rp, size_t(d)));
  }
  return k;
}

template <int D>
TransformTrack<D> parseTransform(const json& j, const std::string& path) {
  expectArray(j, path);
  TransformTrack<D> track;
  for (size_t k = 0; k < j.size(); ++k) track.keys.push_back(parseTransformKey<D>(j[k], indexPath(path, k)));
  // Ordering (and anything parsing let through): "[k].field: what".
  const std::string err = track.validate();
  if (!err.empty()) {
    const size_t sep = err.find(": ");
    if (sep == std::string::npos) fail(path, err);
    fail(path + err.substr(0, sep), err.substr(sep + 2));
  }
  return track;
}

// One instance; its name is left empty when the object has none (the caller
// assigns the default).
template <int D>
InstanceSpec<D> parseInstance(const json& j, const std::string& p, const std::vector<Phase>& phases) {
  const json& o = expectObject(j, p);
  InstanceSpec<D> s;
  // Parameters first: an unknown key fails here, listing every accepted one.
  s.params = instanceParamTable(D).bind(parseParams(o, p, instanceParamSpecs(D), kInstanceKeys, "an instance"));
  if (const json* m = member(o, "name")) {
    s.name = getString(*m, keyPath(p, "name"));
    if (s.name.empty()) fail(keyPath(p, "name"), "must not be empty (omit it for a name derived from the template)");
    // Instances are addressed by name in URLs (/api/sessions/{id}/instances/{name}).
    if (!isValidTemplateName(s.name))
      fail(keyPath(p, "name"), "'" + s.name.substr(0, 80) + "' must be 1 to 64 characters from A-Z a-z 0-9 _ -");
  }
  const std::string tp = keyPath(p, "template");
  s.templateName = getString(required(o, p, "template", "name of a template in the template database"), tp);
  try {
    checkTemplateName(s.templateName);
  } catch (const DatabaseError& e) {
    fail(tp, e.what());
  }
  if (const json* m = member(o, "phase")) s.phase = findPhase(*m, keyPath(p, "phase"), phases);
  if (const json* m = member(o, "transform")) s.transform = parseTransform<D>(*m, keyPath(p, "transform"));

  TimeMap& t = s.time;
  if (const json* m = member(o, "start")) t.start = inRange(getNumber(*m, keyPath(p, "start")), keyPath(p, "start"), limits::kTime);
  if (const json* m = member(o, "crop_begin")) {
    t.cropBegin = inRange(getNumber(*m, keyPath(p, "crop_begin")), keyPath(p, "crop_begin"), limits::kTime);
    if (t.cropBegin < 0) fail(keyPath(p, "crop_begin"), fmt(t.cropBegin) + " s must be >= 0 (template time)");
  }
  if (const json* m = member(o, "crop_end")) {
    const std::string ep = keyPath(p, "crop_end");
    t.cropEnd = inRange(getNumber(*m, ep), ep, limits::kTime);
    if (t.cropEnd < 0) fail(ep, fmt(t.cropEnd) + " s must be >= 0 (omit crop_end to play to the template's end)");
    if (!(t.cropEnd > t.cropBegin))
      fail(ep, fmt(t.cropEnd) + " s must be greater than crop_begin = " + fmt(t.cropBegin) + " s");
  }
  if (const json* m = member(o, "speed")) {
    t.speed = getNumber(*m, keyPath(p, "speed"));
    if (!(t.speed > 0)) fail(keyPath(p, "speed"), fmt(t.speed) + " must be > 0 (use reverse to play backwards)");
    inRange(t.speed, keyPath(p, "speed"), limits::kPlaybackSpeed);
  }
  if (const json* m = member(o, "reverse")) t.reverse = getBool(*m, keyPath(p, "reverse"));
  return s;
}

template <int D>
std::vector<InstanceSpec<D>> parseInstances(const json* j, const std::vector<Phase>& phases) {
  std::vector<InstanceSpec<D>> out;
  if (!j) return out;
  const std::string path = "instances";
  expectArray(*j, path);
  std::set<std::string> taken;
  for (size_t i = 0; i < j->size(); ++i) {
    const std::string p = indexPath(path, i);
    out.push_back(parseInstance<D>((*j)[i], p, phases));
    const std::string& name = out.back().name;
    if (name.empty()) continue;
    if (!taken.insert(name).second) {
      size_t k = 0;
      while (out[k].name != name) ++k;
      fail(keyPath(p, "name"), "duplicate instance name '" + name + "' (also " + keyPath(indexPath(path, k), "name") + ")");
    }
  }
  // Unnamed instances: the template's name, or "<template>-<k>" (k = 2, 3,
  // ...) when that is taken, never clashing with an explicit name.
  for (auto& s : out) {
    if (!s.name.empty()) continue;
    std::string name = s.templateName;
    for (int k = 2; taken.count(name); ++k) name = s.templateName + "-" + std::to_string(k);
    s.name = name;
    taken.insert(name);
  }
  return out;
}

template <int D>
json vecDoubleToJson(const VecDouble<D>& v) {
  json a = json::array();
  for (int d = 0; d < D; ++d) a.push_back(v[d]);
  return a;
}

template <int D>
json instanceToJson(const InstanceSpec<D>& s, const std::vector<Phase>& phases) {
  json o = paramsToJson(instanceParamTable(D).values(s.params), &instanceParamSpecs(D));
  o["name"] = s.name;
  o["template"] = s.templateName;
  o["phase"] = phases.at(size_t(s.phase)).name;
  json keys = json::array();
  for (const TransformKey<D>& k : s.transform.keys) {
    json reflect = json::array();
    for (bool r : k.reflect) reflect.push_back(r);
    json rotation;
    if constexpr (D == 2)
      rotation = k.rotationDeg[0];
    else
      rotation = json::array({k.rotationDeg[0], k.rotationDeg[1], k.rotationDeg[2]});
    keys.push_back({{"time", k.time},
                    {"translation", vecDoubleToJson<D>(k.translation)},
                    {"rotation", rotation},
                    {"scale", vecDoubleToJson<D>(k.scale)},
                    {"reflect", reflect}});
  }
  o["transform"] = keys;
  o["start"] = s.time.start;
  o["crop_begin"] = s.time.cropBegin;
  if (s.time.cropEnd >= 0) o["crop_end"] = s.time.cropEnd;
  o["speed"] = s.time.speed;
  o["reverse"] = s.time.reverse;
  return o;
}

// ---------------------------------------------------- cross-section checks ---
template <int D>
void checkRadiusAgainstDomain(const SimulationSetup<D>& s, bool overridden) {
  const std::string path = "particle_radius";
  const std::string what = fmt(s.particleRadius) + " m" + (overridden ? " (override)" : "");
  const Real diameter = 2 * s.particleRadius;
  double cells = 1;
  for (int d = 0; d < D; ++d) {
    const Real side = s.domain.size()[d];
    if (side < kMinDomainDiameters * diameter)
      fail(path, what + " is too large for the domain: its side along " + axisName(d) + " is " + fmt(side) +
                     " m, less than " + fmt(kMinDomainDiameters) + " particle diameters");
    cells *= side / diameter;
  }
  if (cells > kMaxDomainCells)
    fail(path, what + " is too small for the domain: it would hold " + fmt(cells) + " particle-sized cells, more than " +
                   fmt(kMaxDomainCells));
}

template <int D>
void checkFluidBlocks(const SimulationSetup<D>& s, bool overridden) {
  const Real r = s.particleRadius;
  const Real spacing = 2 * r;
  size_t total = 0;
  for (size_t i = 0; i < s.fluidBlocks.size(); ++i) {
    const std::string p = indexPath("fluid_blocks", i);
    const AABB<D>& b = s.fluidBlocks[i].box;
    for (int d = 0; d < D; ++d) {
      const bool below = b.min[d] < s.domain.min[d] - kContainTolerance;
      const bool above = b.max[d] > s.domain.max[d] + kContainTolerance;
      if (below || above)
        fail(indexPath(keyPath(p, below ? "min" : "max"), d), fmt(below ? b.min[d] : b.max[d]) +
                                                       " lies outside the domain, whose " + axisName(d) + " range is " +
                                                       interval(s.domain.min[d], s.domain.max[d]));
    }
    // Overlapping blocks would stack particles on top of each other.
    for (size_t k = 0; k < i; ++k) {
      const AABB<D>& o = s.fluidBlocks[k].box;
      bool overlap = true;
      for (int d = 0; d < D; ++d)
        overlap = overlap && std::min(b.max[d], o.max[d]) - std::max(b.min[d], o.min[d]) > kContainTolerance;
      if (overlap) fail(p, "overlaps " + indexPath("fluid_blocks", k) + "; fluid blocks may touch but not overlap");
    }
    const size_t n = latticeCount(b, spacing);
    if (n == 0)
      fail(p, "holds no particle: it is thinner than one particle diameter (" + fmt(spacing) + " m) along some axis");
    total += n;
  }
  if (total > s.maxParticles)
    fail("fluid_blocks", "the fluid blocks hold " + std::to_string(total) + " particles at particle_radius " + fmt(r) +
                             (overridden ? " m (override)" : " m") + ", more than max_particles = " + std::to_string(s.maxParticles));

  // Particles inside an obstacle, or closer to it than a particle radius,
  // start with huge pressure and explode the first step. The relative slack
  // lets a block touch an obstacle face exactly as it may touch a wall.
  const Real limit = r - (Real(1e-3) * r + Real(kContainTolerance));
  for (size_t i = 0; i < s.fluidBlocks.size(); ++i) {
    const AABB<D>& b = s.fluidBlocks[i].box;
    for (size_t k = 0; k < s.obstacles.size(); ++k) {
      const Obstacle<D>& ob = s.obstacles[k];
      if (!ob.box.grown(r).intersects(b)) continue;
      forEachLatticePoint(b, spacing, [&](const Vec<D>& x) {
        const Real dist = ob.signedDistance(x);
        if (dist < limit)
          fail(indexPath("fluid_blocks", i),
               "its particle at " + fmtVec<D>(x) + " is " +
                   (dist < 0 ? "inside " + indexPath("obstacles", k)
                             : fmt(dist) + " m from " + indexPath("obstacles", k) + ", closer than particle_radius " + fmt(r) + " m") +
                   "; move or shrink the block");
      });
    }
  }
}

// A body whose solid overlaps a fluid block would start with liquid inside
// it: an error, unless the body says carve_fluid (the liquid it overlaps is
// left out, as a boat placed on a pool displaces it).
template <int D>
void checkBodies(const SimulationSetup<D>& s) {
  const Real r = s.particleRadius;
  const Real spacing = 2 * r;
  for (size_t k = 0; k < s.bodies.size(); ++k) {
    const Body<D>& b = s.bodies[k];
    if (b.carveFluid) continue;
    const Eigen::Matrix<double, D, D> R = rotationFromDegrees<D>(b.rotationDeg);
    const Real reach = b.boundingRadius() + r;
    for (size_t i = 0; i < s.fluidBlocks.size(); ++i) {
      const AABB<D>& blk = s.fluidBlocks[i].box;
      if (!AABB<D>(Vec<D>(b.position.array() - reach), Vec<D>(b.position.array() + reach)).intersects(blk)) continue;
      forEachLatticePoint(blk, spacing, [&](const Vec<D>& x) {
        const Eigen::Matrix<double, D, 1> local = R.transpose() * (x - b.position).template cast<double>();
        const Real dist = b.localSignedDistance(local.template cast<Real>());
        if (dist < r)
          fail(indexPath("bodies", k),
               "body \"" + b.name + "\" overlaps " + indexPath("fluid_blocks", i) + " (its particle at " + fmtVec<D>(x) +
                   " would start " + (dist < 0 ? "inside the body" : "closer than particle_radius to it") +
                   "); move the body or the block, or set \"carve_fluid\": true to leave that liquid out");
      });
    }
  }
}

}  // namespace

// ================================================================ public ===

json parseSceneText(const std::string& text, const std::string& origin) {
  JsonTextOptions options;
  options.maxDepth = kMaxSceneDepth;
  try {
    return parseJsonText(text, options);
  } catch (const JsonTextError& e) {
    // File-level errors name the origin (and line:column when known); a
    // duplicate key is reported at its key path like any scene error.
    if (e.kind == JsonTextError::Kind::DuplicateKey) throw SceneError(e.path, e.detail);
    const std::string where = printable(origin, 300) + (e.where.empty() ? "" : ":" + e.where);
    std::string detail = e.detail;
    if (e.kind == JsonTextError::Kind::TooDeep && !e.path.empty()) detail += " (at " + e.path + ")";
    throw SceneError("", where + ": malformed JSON: " + detail);
  }
}

json loadSceneJson(const std::string& file) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(file, ec)) throw SceneError("", "scene file '" + file + "' does not exist");
  if (fs::is_directory(file, ec)) throw SceneError("", "scene file '" + file + "' is a directory");
  if (const auto size = fs::file_size(file, ec); !ec && size > kMaxSceneFileBytes)
    throw SceneError("", "scene file '" + file + "' holds " + std::to_string(size) + " bytes, more than the " +
                             std::to_string(kMaxSceneFileBytes >> 20) + " MB a scene may have");
  std::ifstream in(file, std::ios::binary);
  if (!in) throw SceneError("", "cannot open scene file '" + file + "'");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw SceneError("", "cannot read scene file '" + file + "'");
  json scene = parseSceneText(text.str(), file);
  if (!scene.is_object())
    throw SceneError("", printable(file, 300) + ": a scene must be a JSON object, got " + scene.type_name());
  resolveSceneFilePaths(scene, file);
  return scene;
}

void resolveSceneFilePaths(json& scene, const std::string& sceneFile) {
  namespace fs = std::filesystem;
  if (!scene.is_object()) return;
  const auto obstacles = scene.find("obstacles");
  if (obstacles == scene.end() || !obstacles->is_array()) return;
  const fs::path dir = fs::path(sceneFile).parent_path();
  for (json& o : *obstacles) {
    if (!o.is_object()) continue;
    const auto type = o.find("type");
    const auto file = o.find("file");
    if (type == o.end() || *type != "mesh" || file == o.end() || !file->is_string()) continue;
    const fs::path f = file->get<std::string>();
    if (f.empty() || f.is_absolute()) continue;
    std::error_code ec;
    fs::path resolved = fs::absolute(dir / f, ec);
    if (ec) resolved = dir / f;
    *file = resolved.lexically_normal().string();
  }
}

int sceneDimension(const json& scene) {
  if (!scene.is_object()) fail("", std::string("a scene must be a JSON object, got ") + scene.type_name());
  const json& j = required(scene, "", "dimension", "2 or 3");
  const double d = getInteger(j, "dimension");
  if (d != 2 && d != 3) fail("dimension", "must be 2 or 3, got " + j.dump());
  return int(d);
}

json applySceneScale(const json& scene, const std::string& scale) {
  if (!scene.is_object()) fail("", std::string("a scene must be a JSON object, got ") + scene.type_name());
  const json* scales = member(scene, "scales");
  std::string known;
  if (scales && scales->is_object())
    for (const auto& [name, v] : scales->items()) known += (known.empty() ? "" : ", ") + name;
  if (!scales || !scales->is_object() || !scales->contains(scale))
    fail("scales." + scale, "the scene has no scale '" + scale + "' (" +
                                (known.empty() ? std::string("it names none") : "it has: " + known) + ")");
  const json& sc = (*scales)[scale];
  json out = scene;
  if (sc.is_object() && sc.contains("particle_radius")) out["particle_radius"] = sc["particle_radius"];
  if (sc.is_object() && sc.contains("max_particles")) out["max_particles"] = sc["max_particles"];
  return out;  // parseScene checks the values like any scene's
}

// A scale's name, and the templates folder a scale names, are one folder name.
static void checkScaleFolderName(const std::string& name, const std::string& path, const char* what) {
  if (name.empty() || name.size() > 32 ||
      name.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789_-") != std::string::npos)
    fail(path, std::string(what) + " is 1-32 characters of a-z, 0-9, '_' and '-'");
}

// A scale's "templates" (the folder it plays), checked; empty where it names none.
static std::string scaleTemplatesFolder(const json& scale, const std::string& path) {
  const json* t = scale.is_object() ? member(scale, "templates") : nullptr;
  if (!t) return {};
  expectType(t->is_string(), *t, path + ".templates", "a folder name");
  const std::string folder = t->get<std::string>();
  checkScaleFolderName(folder, path + ".templates", "a scale's templates folder");
  return folder;
}

std::string scaledTemplatesDir(const std::string& dir, const json& scene, const std::string& scale) {
  std::string folder;
  if (const json* scales = member(scene, "scales"); scales && scales->is_object() && scales->contains(scale))
    folder = scaleTemplatesFolder((*scales)[scale], "scales." + scale);
  return (std::filesystem::path(dir) / (folder.empty() ? scale : folder)).string();
}

// "camera": {"position": [x, y, z], "target": [x, y, z], "lens_mm": 40}, 3D in every scene.
static SceneCamera parseCamera(const json& j) {
  expectObject(j, "camera");
  checkKeys(j, "camera", {"position", "target", "lens_mm"});
  SceneCamera c;
  c.set = true;
  const auto point = [&](const char* key, const char* what) {
    const std::string path = std::string("camera.") + key;
    const json& v = required(j, "camera", key, what);
    expectType(v.is_array(), v, path, "an array of 3 numbers");
    if (v.size() != 3)
      fail(path, "expected 3 components (a camera is placed in 3D, also in a 2D scene), got " + std::to_string(v.size()));
    std::array<double, 3> p{};
    for (size_t d = 0; d < 3; ++d) p[d] = getNumber(v[d], indexPath(path, d));
    return p;
  };
  c.position = point("position", "where the camera is, m");
  c.target = point("target", "what it looks at, m");
  const double gap = std::hypot(c.position[0] - c.target[0], c.position[1] - c.target[1], c.position[2] - c.target[2]);
  if (gap < 1e-6) fail("camera.target", "must differ from camera.position");
  if (const json* m = member(j, "lens_mm")) {
    c.lensMm = getNumber(*m, "camera.lens_mm");
    if (!(c.lensMm >= 5 && c.lensMm <= 500)) fail("camera.lens_mm", fmt(c.lensMm) + " mm is outside [5, 500]");
  }
  return c;
}

// A particle cap, the scene's own or a scale's.
static size_t parseMaxParticles(const json& j, const std::string& path) {
  const double n = getInteger(j, path);
  if (n < 1 || n > kMaxParticlesLimit)
    fail(path, fmt(n) + " is outside the allowed range [1, " + fmt(kMaxParticlesLimit) + "]");
  return size_t(n);
}

// "scales": {"paper": {"particle_radius": 0.0036, "max_particles": 3000000, "templates": "paper"}}:
// named resolutions, each a particle radius and optionally a particle cap
// and the folder of templates it plays (the scale's name by default).
static std::map<std::string, SceneScale> parseScales(const json& j) {
  expectObject(j, "scales");
  std::map<std::string, SceneScale> out;
  for (const auto& [name, v] : j.items()) {
    const std::string path = "scales." + name;
    checkScaleFolderName(name, path, "a scale's name");
    expectObject(v, path);
    checkKeys(v, path, {"particle_radius", "max_particles", "templates"});
    SceneScale sc;
    sc.particleRadius = getNumber(required(v, path, "particle_radius", "the scale's particle radius, m"),
                                  path + ".particle_radius");
    if (!(sc.particleRadius > 0) || !std::isfinite(sc.particleRadius))
      fail(path + ".particle_radius", fmt(sc.particleRadius) + " m must be a finite value > 0");
    if (const json* m = member(v, "max_particles")) sc.maxParticles = parseMaxParticles(*m, path + ".max_particles");
    sc.templates = scaleTemplatesFolder(v, path);
    out[name] = sc;
  }
  return out;
}

template <int D>
SimulationSetup<D> parseScene(const json& root, double particleRadiusOverride) {
  registerBuiltinSolversAndEffects();
  if (sceneDimension(root) != D)
    fail("dimension", "the scene is " + std::to_string(sceneDimension(root)) + "D but was loaded as " +
                          std::to_string(D) + "D");
  checkKeys(root, "", {"name", "dimension", "particle_radius", "domain", "gravity", "duration", "max_particles",
                       "phases", "fluid_blocks", "obstacles", "bodies", "emitters", "solver", "boundary", "settings",
                       "effects", "camera", "scales",
                       "control", "instances"});
  // "control" and "instances" are read by parseSceneControl.

  SimulationSetup<D> s;
  if (const json* m = member(root, "name")) {
    s.name = getString(*m, "name");
    if (s.name.empty()) fail("name", "must not be empty");
  }

  if (const json* m = member(root, "particle_radius")) {
    s.particleRadius = getReal(*m, "particle_radius");
    if (s.particleRadius <= 0) fail("particle_radius", fmt(s.particleRadius) + " m must be > 0");
  }
  const bool overridden = particleRadiusOverride != 0;
  if (overridden) {
    if (!(particleRadiusOverride > 0) || !std::isfinite(particleRadiusOverride))
      fail("particle_radius", "override " + fmt(particleRadiusOverride) + " m must be a finite value > 0");
    s.particleRadius = Real(particleRadiusOverride);
  }

  {
    const json& d = expectObject(required(root, "", "domain", "tank interior {\"min\", \"max\"}"), "domain");
    checkKeys(d, "domain", {"min", "max"});
    s.domain = parseBox<D>(d, "domain");
  }
  checkRadiusAgainstDomain(s, overridden);

  s.gravity = Vec<D>::Zero();
  s.gravity[1] = Real(-9.81);
  if (const json* m = member(root, "gravity")) {
    s.gravity = getVec<D>(*m, "gravity");
    normInRange<D>(s.gravity, "gravity", limits::kGravity);
  }

  if (const json* m = member(root, "duration")) {
    s.duration = getNumber(*m, "duration");
    if (s.duration <= 0 || s.duration > kMaxDuration)
      fail("duration", fmt(s.duration) + " is outside the allowed range (0, " + fmt(kMaxDuration) + "] s");
  }

  s.maxParticles = size_t(kDefaultMaxParticles);
  if (const json* m = member(root, "max_particles")) s.maxParticles = parseMaxParticles(*m, "max_particles");

  s.phases = parsePhases(member(root, "phases"));
  s.fluidBlocks = parseFluidBlocks<D>(root, s.phases);
  s.settings = parseSettings(member(root, "settings"));  // before the obstacles: mesh grids use contact_distance
  s.obstacles = parseObstacles<D>(member(root, "obstacles"), s.particleRadius, Real(s.settings.contactDistance));
  s.bodies = parseBodies<D>(member(root, "bodies"), s.domain);
  s.emitters = parseEmitters<D>(member(root, "emitters"), s.phases);
  s.solver = parseMethod<PressureSolverRegistry<D>>(member(root, "solver"), "solver", kDefaultSolver);
  s.boundary = parseMethod<BoundaryModelRegistry<D>>(member(root, "boundary"), "boundary", kDefaultBoundaryModel);
  s.effects = parseEffects<D>(member(root, "effects"));

  if (const json* m = member(root, "camera")) s.camera = parseCamera(*m);
  if (const json* m = member(root, "scales")) s.scales = parseScales(*m);

  checkFluidBlocks(s, overridden);
  checkBodies(s);
  checkEmitters(s);
  return s;
}

template <int D>
json sceneToJson(const SimulationSetup<D>& s) {
  registerBuiltinSolversAndEffects();
  json j;
  j["name"] = s.name;
  j["dimension"] = D;
  j["particle_radius"] = toJsonNumber(s.particleRadius);
  j["domain"] = {{"min", vecToJson<D>(s.domain.min)}, {"max", vecToJson<D>(s.domain.max)}};
  j["gravity"] = vecToJson<D>(s.gravity);
  j["duration"] = s.duration;
  j["max_particles"] = s.maxParticles;
  if (s.camera.set)
    j["camera"] = {{"position", s.camera.position}, {"target", s.camera.target}, {"lens_mm", s.camera.lensMm}};
  if (!s.scales.empty()) {
    json scales = json::object();
    for (const auto& [name, sc] : s.scales) {
      scales[name] = {{"particle_radius", sc.particleRadius}};
      if (sc.maxParticles) scales[name]["max_particles"] = sc.maxParticles;
      if (!sc.templates.empty()) scales[name]["templates"] = sc.templates;
    }
    j["scales"] = scales;
  }

  json phases = json::array();
  for (const Phase& ph : s.phases) {
    json c = json::array();
    for (float v : ph.color) c.push_back(toJsonNumber(Real(v)));
    phases.push_back({{"name", ph.name},
                      {"rest_density", toJsonNumber(ph.restDensity)},
                      {"viscosity", toJsonNumber(ph.viscosity)},
                      {"color", c}});
  }
  j["phases"] = phases;

  json blocks = json::array();
  for (const FluidBlock<D>& b : s.fluidBlocks) {
    blocks.push_back({{"min", vecToJson<D>(b.box.min)},
                      {"max", vecToJson<D>(b.box.max)},
                      {"phase", s.phases.at(size_t(b.phase)).name},
                      {"velocity", vecToJson<D>(b.velocity)}});
  }
  j["fluid_blocks"] = blocks;

  json obstacles = json::array();
  for (const Obstacle<D>& o : s.obstacles) {
    if (o.shape == ObstacleShape::Box)
      obstacles.push_back({{"type", "box"}, {"min", vecToJson<D>(o.box.min)}, {"max", vecToJson<D>(o.box.max)}});
    else if (o.shape == ObstacleShape::Sphere)
      obstacles.push_back({{"type", "sphere"}, {"center", vecToJson<D>(o.center)}, {"radius", toJsonNumber(o.radius)}});
    else
      obstacles.push_back({{"type", "mesh"},
                           {"file", o.placement.file},
                           {"scale", o.placement.scale},
                           {"translation", o.placement.translation},
                           {"rotation", o.placement.rotationDeg}});
  }
  j["obstacles"] = obstacles;
  if (!s.bodies.empty()) {
    json bodies = json::array();
    for (const Body<D>& b : s.bodies) {
      json o = {{"name", b.name}, {"position", vecToJson<D>(b.position)}, {"rotation", rotationToJson<D>(b.rotationDeg)}};
      if (b.shape == ObstacleShape::Box) {
        o["type"] = "box";
        o["size"] = vecToJson<D>(Vec<D>(2 * b.halfSize));
      } else {
        o["type"] = D == 2 ? "disk" : "sphere";
        o["radius"] = toJsonNumber(b.radius);
      }
      if (b.motion == BodyMotion::Dynamic) {
        o["motion"] = "dynamic";
        o["density"] = toJsonNumber(b.density);
        if (!b.velocity.isZero()) o["velocity"] = vecToJson<D>(b.velocity);
      } else {
        o["motion"] = "kinematic";
        if (!b.keys.empty()) {
          json keys = json::array();
          for (const BodyKey<D>& k : b.keys)
            keys.push_back({{"time", k.time}, {"position", vecToJson<D>(k.position)}, {"rotation", rotationToJson<D>(k.rotationDeg)}});
          o["keys"] = keys;
          if (b.period > 0) o["period"] = b.period;
          o.erase("position");
          o.erase("rotation");
        } else {
          o["velocity"] = vecToJson<D>(b.velocity);
          o["angular_velocity"] = rotationToJson<D>(b.angularVelocityDeg);
        }
      }
      if (b.carveFluid) o["carve_fluid"] = true;
      bodies.push_back(o);
    }
    j["bodies"] = bodies;
  }

  if (!s.emitters.empty()) {
    json emitters = json::array();
    for (const Emitter<D>& e : s.emitters) {
      json o = {{"name", e.name},
                {"center", vecToJson<D>(e.center)},
                {"direction", vecToJson<D>(e.direction)},
                {"radius", toJsonNumber(e.radius)},
                {"speed", toJsonNumber(e.speed)},
                {"phase", s.phases.at(size_t(e.phase)).name},
                {"start", e.start}};
      if (std::isfinite(e.end)) o["end"] = e.end;
      emitters.push_back(o);
    }
    j["emitters"] = emitters;
  }

  j["solver"] = methodToJson<PressureSolverRegistry<D>>(s.solver);
  j["boundary"] = methodToJson<BoundaryModelRegistry<D>>(s.boundary);

  j["settings"] = paramsToJson(simulationSettingsTable().values(s.settings), &simulationSettingsSpecs());

  json effects = json::array();
  for (const NamedParams& e : s.effects) {
    const auto* entry = EffectRegistry<D>::instance().find(e.name);
    json o = paramsToJson(e.values, entry ? &entry->params : nullptr);
    o["name"] = e.name;
    effects.push_back(o);
  }
  j["effects"] = effects;
  return j;
}

template <int D>
SceneControl<D> parseSceneControl(const json& root, const std::vector<Phase>& phases) {
  if (!root.is_object()) fail("", std::string("a scene must be a JSON object, got ") + root.type_name());
  if (member(root, "dimension") && sceneDimension(root) != D)
    fail("dimension", "the scene is " + std::to_string(sceneDimension(root)) + "D but was loaded as " +
                          std::to_string(D) + "D");
  if (phases.empty()) throw std::invalid_argument("parseSceneControl: the scene has no phases");
  SceneControl<D> c;
  if (const json* m = member(root, "control"))
    c.settings = controlSettingsTable().bind(
        parseParams(expectObject(*m, "control"), "control", controlSettingsSpecs(), {}, "control"));
  c.instances = parseInstances<D>(member(root, "instances"), phases);
  return c;
}

template <int D>
json sceneControlToJson(const SceneControl<D>& c, const std::vector<Phase>& phases) {
  json instances = json::array();
  for (const auto& s : c.instances) instances.push_back(instanceToJson<D>(s, phases));
  return {{"control", paramsToJson(controlSettingsTable().values(c.settings), &controlSettingsSpecs())}, {"instances", instances}};
}

template SimulationSetup<2> parseScene<2>(const json&, double);
template SimulationSetup<3> parseScene<3>(const json&, double);
template json sceneToJson<2>(const SimulationSetup<2>&);
template json sceneToJson<3>(const SimulationSetup<3>&);
template SceneControl<2> parseSceneControl<2>(const json&, const std::vector<Phase>&);
template SceneControl<3> parseSceneControl<3>(const json&, const std::vector<Phase>&);
template json sceneControlToJson<2>(const SceneControl<2>&, const std::vector<Phase>&);
template json sceneControlToJson<3>(const SceneControl<3>&, const std::vector<Phase>&);

}  // namespace fc
