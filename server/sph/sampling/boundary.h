#pragma once
// Boundary sampling of solid surfaces (walls, obstacles, bodies).
#include "core/aabb.h"
#include "core/mesh_sdf.h"
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <vector>

namespace fc {

// Per-axis coordinates of a box shell lattice: the two faces, evenly spaced
// points between them (spacing close to `spacing`, faces hit exactly), and
// `extra` further layers beyond each face.
inline std::vector<Real> axisCoords(Real lo, Real hi, Real spacing, int extra) {
  const int n = std::max(1, int(std::lround((hi - lo) / spacing)));
  std::vector<Real> c;
  for (int l = extra; l >= 1; --l) c.push_back(lo - l * spacing);
  for (int k = 0; k <= n; ++k) c.push_back(lo + (hi - lo) * Real(k) / Real(n));
  for (int l = 1; l <= extra; ++l) c.push_back(hi + l * spacing);
  return c;
}

// Boundary samples of a box surface, `layers` deep: outward for the tank
// walls (the fluid is inside), inward for a solid box obstacle.
template <int D>
void sampleBoxShell(const AABB<D>& box, Real spacing, int layers, bool outward, std::vector<Vec<D>>& out) {
  std::array<std::vector<Real>, D> coords;
  for (int d = 0; d < D; ++d) coords[d] = axisCoords(box.min[d], box.max[d], spacing, outward ? layers - 1 : 0);
  const Real depth = (layers - Real(0.5)) * spacing;
  std::array<size_t, D> i{};
  while (true) {
    Vec<D> p;
    for (int d = 0; d < D; ++d) p[d] = coords[d][i[d]];
    bool keep;
    if (outward) {
      keep = !((p.array() > box.min.array() + spacing * Real(0.01)).all() &&
               (p.array() < box.max.array() - spacing * Real(0.01)).all());
    } else {
      const Real inside = std::min((p - box.min).minCoeff(), (box.max - p).minCoeff());
      keep = inside < depth;
    }
    if (keep) out.push_back(p);
    int d = 0;
    while (d < D && ++i[d] == coords[d].size()) i[d++] = 0;
    if (d == D) break;
  }
}

template <int D>
void sampleSphereShell(const Vec<D>& c, Real radius, Real spacing, int layers, std::vector<Vec<D>>& out) {
  for (int l = 0; l < layers; ++l) {
    const Real rr = radius - l * spacing;
    if (rr <= Real(0.25) * spacing) {
      if (rr > -Real(0.5) * spacing) out.push_back(c);
      break;
    }
    if constexpr (D == 2) {
      const int n = std::max(3, int(std::lround(2 * std::numbers::pi * rr / spacing)));
      for (int k = 0; k < n; ++k) {
        const double t = 2 * std::numbers::pi * k / n;
        out.push_back(c + rr * Vec<D>(Real(std::cos(t)), Real(std::sin(t))));
      }
    } else {
      // Fibonacci sphere: near-uniform area per point.
      const int n = std::max(4, int(std::lround(4 * std::numbers::pi * rr * rr / (spacing * spacing))));
      const double golden = std::numbers::pi * (3 - std::sqrt(5.0));
      for (int k = 0; k < n; ++k) {
        const double y = 1 - 2 * (k + 0.5) / n;
        const double rxy = std::sqrt(std::max(0.0, 1 - y * y));
        const double t = golden * k;
        out.push_back(c + rr * Vec<D>(Real(rxy * std::cos(t)), Real(y), Real(rxy * std::sin(t))));
      }
    }
  }
}

// Boundary samples of a closed triangle mesh, `layers` deep, as a box is
// sampled: layer l on the surface offset `radius + l·spacing` into the solid
// (one particle radius behind the surface, where the fluid lattice would
// continue, then a spacing deeper per layer). sph/sampling/mesh_boundary.cpp says how.
// Returns the lattice points examined.
size_t sampleMeshShell(const MeshSdf& mesh, Real radius, Real spacing, int layers, std::vector<Vec3>& out);

}  // namespace fc
