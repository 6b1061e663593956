#pragma once
// The liquid's surface from its particles, frame by frame: a level set on
// an OpenVDB grid (Zhu & Bridson's distance to the neighbourhood's mean
// position, evaluated only in the blocks the surface crosses), a box filter,
// and a triangle mesh (marching cubes, or OpenVDB's adaptive volume-to-mesh).
// docs/surfaces.md says how the parameters trade thin sheets and droplets
// against smoothness, and what each costs.
//
// Only surface.cpp and the exporters that write grids include OpenVDB
// (surface/volumes.h): everything else sees the mesh and an opaque handle.
#include "core/default_init.h"
#include "io/particle_frame.h"
#include "sph/parameters.h"
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace fc {

// Parameters in multiples of the particle radius r, so that one set suits
// every resolution.
struct SurfaceSettings {
  double voxelSize = 0.5;      // × r: the level set's voxel
  double kernelRadius = 4.0;   // × r: the neighbourhood averaged
  double surfaceRadius = 1.15; // × r: the surface's distance from the neighbourhood's mean
  int smoothing = 1;           // box-filter passes
  double trail = 0;            // s: velocity trails, the path of the last `trail` seconds
  double adaptivity = 0;       // 0: uniform marching cubes; above: OpenVDB's adaptive volume-to-mesh
  double thickness2d = 2.3;    // × r: a 2D liquid's slab; 0: its flat area
};
const ParamTable<SurfaceSettings>& surfaceSettingsTable();
const ParamSpecs& surfaceSettingsSpecs();
// What is wrong with settings whose values are each in range but not
// together ("" when nothing): surface_radius must stay under kernel_radius.
std::string surfaceSettingsProblem(const SurfaceSettings& settings);

// The reconstruction fills these on its threads (FillVector: not zeroed first).
struct SurfaceMesh {
  FillVector<std::array<float, 3>> points;      // m
  FillVector<std::array<float, 3>> velocities;  // m/s, one per point
  FillVector<std::array<uint32_t, 3>> triangles;
};

// The volume a closed mesh encloses (m³): positive when its triangles face
// outwards (the divergence theorem over its triangles).
inline double enclosedVolume(const SurfaceMesh& m) {
  double v = 0;
  for (const auto& t : m.triangles) {
    const auto& a = m.points[t[0]];
    const auto& b = m.points[t[1]];
    const auto& c = m.points[t[2]];
    v += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) -
          double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
          double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) / 6.0;
  }
  return v;
}

struct SurfaceVolumes;  // the level set and velocity grids (surface/volumes.h)

struct Surface {
  std::shared_ptr<SurfaceVolumes> volumes;  // null when the frame has no liquid
  SurfaceMesh mesh;
  // A 2D liquid's outline in the plane z = 0 (m): closed loops with the
  // liquid on their left, counter-clockwise around it, clockwise around a hole.
  std::vector<std::vector<std::array<float, 2>>> outline;
  size_t particles = 0;  // how many particles formed it
  double ms = 0;         // wall time of the reconstruction, and of its stages:
  double classifyMs = 0, fillMs = 0, smoothMs = 0, meshMs = 0;
};

// The surface of the frame's liquid and temporary particles of radius
// `particleRadius` (m). `withMesh` false: no mesh; `withGrids` false: no
// grids (a uniform 3D mesh is made without them). `dimension` 2: the
// particles lie at z = 0; the outline and a flat area mesh are made in the
// plane, the mesh is that area as a slab `thickness_2d` thick (or flat),
// the grids the same prism. Throws std::invalid_argument for a radius that
// is not positive.
Surface reconstructSurface(const ParticleFrame& frame, double particleRadius, const SurfaceSettings& settings,
                           bool withMesh = true, int dimension = 3, bool withGrids = true);

}  // namespace fc
