#pragma once
// Everything a simulation is built from: what a scene file describes, in
// plain C++ (io/scene.cpp parses and validates JSON into this).
#include "core/aabb.h"
#include "core/mesh_sdf.h"
#include "sph/parameters.h"
#include "sph/phase.h"
#include "sph/settings.h"
#include <algorithm>
#include <array>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace fc {

template <int D>
struct FluidBlock {
  AABB<D> box;
  int phase = 0;
  Vec<D> velocity = Vec<D>::Zero();
};

enum class ObstacleShape { Box, Sphere, Mesh };

// Where a mesh obstacle's file puts its solid: x_world = R (s ∘ x_file) + t,
// R = Rx·Ry·Rz from the Euler angles (as bodies). `file` is the path as
// resolved (io/scene.h: relative to the scene file's directory).
struct MeshPlacement {
  std::string file;
  std::array<double, 3> scale{1, 1, 1};
  std::array<double, 3> translation{};
  std::array<double, 3> rotationDeg{};
};

template <int D>
struct Obstacle {
  ObstacleShape shape = ObstacleShape::Box;
  AABB<D> box;                          // Box; for a sphere and a mesh their bounds
  Vec<D> center = Vec<D>::Zero();       // Sphere / disk
  Real radius = 0;
  // Mesh (3D only): the placed solid's signed-distance grid, shared by every
  // copy of the setup.
  MeshPlacement placement;
  std::shared_ptr<const MeshSdf> mesh;
  // Signed distance to the surface, negative inside the solid.
  Real signedDistance(const Vec<D>& p) const {
    if (shape == ObstacleShape::Sphere) return (p - center).norm() - radius;
    if (shape == ObstacleShape::Mesh) {
      if constexpr (D == 3) return mesh->signedDistance(p);
      else return std::numeric_limits<Real>::max();
    }
    const Vec<D> q = (p - box.center()).cwiseAbs() - Real(0.5) * box.size();
    const Real outside = q.cwiseMax(Vec<D>::Zero()).norm();
    const Real inside = std::min(q.maxCoeff(), Real(0));
    return outside + inside;
  }
};

// Φ, the signed distance to the static solids, positive in the liquid: the
// domain's walls alone (the nearest face of the box the liquid is in), and
// with the obstacles.
template <int D>
Real wallDistance(const AABB<D>& domain, const Vec<D>& x) {
  Real phi = std::numeric_limits<Real>::max();
  for (int d = 0; d < D; ++d) phi = std::min({phi, x[d] - domain.min[d], domain.max[d] - x[d]});
  return phi;
}

template <int D>
Real solidDistance(const AABB<D>& domain, const std::vector<Obstacle<D>>& obstacles, const Vec<D>& x) {
  Real phi = wallDistance(domain, x);
  for (const auto& o : obstacles) phi = std::min(phi, o.signedDistance(x));
  return phi;
}

// ∇Φ by central differences over ±eps, not normalised: smooth across the
// kinks of Φ at edges and corners.
template <int D>
Vec<D> solidDistanceGradient(const AABB<D>& domain, const std::vector<Obstacle<D>>& obstacles, const Vec<D>& x,
                             Real eps) {
  Vec<D> n;
  for (int d = 0; d < D; ++d) {
    Vec<D> a = x, b = x;
    a[d] += eps;
    b[d] -= eps;
    n[d] = (solidDistance(domain, obstacles, a) - solidDistance(domain, obstacles, b)) / (2 * eps);
  }
  return n;
}

// A rigid body (Akinci et al. 2012 [AIA*12] boundary particles on its surface):
// kinematic (its motion is given) or dynamic (two-way coupled: the liquid's
// pressure moves it, it moves the liquid). Its shape is described in its own
// frame, centred on the origin; `position` and `rotationDeg` place it.
enum class BodyMotion { Kinematic, Dynamic };

template <int D>
struct BodyKey {
  double time = 0;                        // s
  Vec<D> position = Vec<D>::Zero();       // m, the body centre
  std::array<double, D == 2 ? 1 : 3> rotationDeg{};  // 2D angle; 3D Euler XYZ (R = Rx·Ry·Rz)
};

template <int D>
struct Body {
  std::string name;
  ObstacleShape shape = ObstacleShape::Box;
  Vec<D> halfSize = Vec<D>::Zero();       // Box: half extents, m
  Real radius = 0;                        // Sphere / disk, m
  Vec<D> position = Vec<D>::Zero();       // initial centre, m
  std::array<double, D == 2 ? 1 : 3> rotationDeg{};  // initial orientation
  BodyMotion motion = BodyMotion::Kinematic;
  // Kinematic: keys (piecewise linear; slerp in 3D), repeated every
  // `period` s when > 0; without keys, constant velocity and angular
  // velocity (deg/s: 2D counter-clockwise, 3D about the world axes).
  std::vector<BodyKey<D>> keys;
  double period = 0;
  Vec<D> velocity = Vec<D>::Zero();
  std::array<double, D == 2 ? 1 : 3> angularVelocityDeg{};
  // Dynamic:
  Real density = 500;                     // kg/m^3 (2D: kg/m^3 per metre of depth)
  // Liquid of the fluid blocks that would start inside the body is left out
  // (otherwise a block overlapping a body is an error).
  bool carveFluid = false;

  // Signed distance in the body's own frame, negative inside.
  Real localSignedDistance(const Vec<D>& p) const {
    if (shape == ObstacleShape::Sphere) return p.norm() - radius;
    const Vec<D> q = p.cwiseAbs() - halfSize;
    return q.cwiseMax(Vec<D>::Zero()).norm() + std::min(q.maxCoeff(), Real(0));
  }
  // Radius of the sphere about the centre that holds the body.
  Real boundingRadius() const { return shape == ObstacleShape::Sphere ? radius : halfSize.norm(); }
};

// An inflow: a nozzle that emits liquid of one phase at a fixed speed while
// its window is open (a falling jet, a water jet). Layers of particles are
// added at frame starts, a particle spacing apart along the jet, so that the
// jet is as dense as a fluid block; a layer's points that would land on
// liquid already there (a jet piled back up to its nozzle) are left out.
template <int D>
struct Emitter {
  std::string name;
  Vec<D> center = Vec<D>::Zero();     // m, the nozzle's centre
  Vec<D> direction = Vec<D>::Zero();  // unit, the jet's direction
  Real radius = 0;                    // m, the nozzle's radius (2D: half width)
  Real speed = 0;                     // m/s
  int phase = 0;
  double start = 0;                   // s
  double end = std::numeric_limits<double>::infinity();  // s
};

struct NamedParams {
  std::string name;
  ParamValues values;
};

// The boundary model of a scene that names none (docs/physics/boundaries.md).
inline constexpr const char* kDefaultBoundaryModel = "akinci2012";

// Where a renderer looks at the scene from (the gallery, docs/surfaces.md):
// in 3D also for 2D scenes, whose liquid lies in the plane z = 0. Not used
// by the simulation.
struct SceneCamera {
  bool set = false;
  std::array<double, 3> position{};  // m
  std::array<double, 3> target{};    // m, what the camera looks at
  double lensMm = 40;                // focal length of a 36 mm wide sensor
};

// A named resolution of the scene ("scales": {"paper": {...}}): what
// `--scale NAME` puts in place of particle_radius and max_particles.
struct SceneScale {
  double particleRadius = 0;  // m
  size_t maxParticles = 0;    // 0: the scene's own
  std::string templates;      // the folder of templates it plays; empty: the scale's name
};

template <int D>
struct SimulationSetup {
  std::string name = "scene";
  Real particleRadius = Real(0.01);     // m; the resolution knob
  AABB<D> domain;                       // tank interior; walls on all sides
  Vec<D> gravity = Vec<D>::Zero();
  std::vector<Phase> phases{Phase{}};
  std::vector<FluidBlock<D>> fluidBlocks;
  std::vector<Obstacle<D>> obstacles;
  std::vector<Body<D>> bodies;          // moving solids (none: no stage, no cost)
  std::vector<Emitter<D>> emitters;     // inflows (none: no stage, no cost)
  NamedParams solver;                   // pressure solver name and its parameters
  NamedParams boundary{kDefaultBoundaryModel, {}};  // boundary model name and its parameters
  SimulationSettings settings = simulationSettingsTable().defaults();  // the scene's "settings"
  std::vector<NamedParams> effects;     // in the order the scene lists them
  double duration = 2;                  // s, default run length
  size_t maxParticles = 2000000;
  SceneCamera camera;
  std::map<std::string, SceneScale> scales;  // by name, e.g. "paper"
};

}  // namespace fc
