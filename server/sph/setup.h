#pragma once
// Everything a simulation is built from: what a scene file describes, in
// plain C++ (io/scene.cpp parses and validates JSON into this).
#include "core/aabb.h"
#include "sph/parameters.h"
#include "sph/phase.h"
#include <string>
#include <vector>

namespace fc {

template <int D>
struct FluidBlock {
  AABB<D> box;
  int phase = 0;
  Vec<D> velocity = Vec<D>::Zero();
};

enum class ObstacleShape { Box, Sphere };

template <int D>
struct Obstacle {
  ObstacleShape shape = ObstacleShape::Box;
  AABB<D> box;                          // Box
  Vec<D> center = Vec<D>::Zero();       // Sphere / disk
  Real radius = 0;
  // Signed distance to the surface, negative inside the solid.
  Real signedDistance(const Vec<D>& p) const {
    if (shape == ObstacleShape::Sphere) return (p - center).norm() - radius;
    const Vec<D> q = (p - box.center()).cwiseAbs() - Real(0.5) * box.size();
    const Real outside = q.cwiseMax(Vec<D>::Zero()).norm();
    const Real inside = std::min(q.maxCoeff(), Real(0));
    return outside + inside;
  }
};

struct NamedParams {
  std::string name;
  ParamValues values;
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
  NamedParams solver;                   // pressure solver name and its parameters
  ParamValues settings;                 // scene-level solver settings (simulationSettingsSpecs)
  std::vector<NamedParams> effects;     // in the order the scene lists them
  double duration = 2;                  // s, default run length
  size_t maxParticles = 2000000;
};

}  // namespace fc
