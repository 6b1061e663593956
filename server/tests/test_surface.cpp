// Surface reconstruction (surface/surface.cpp): the mesh encloses the
// liquid's volume, stays near its particles, is closed and outward-facing,
// keeps droplets, and carries the particles' velocity; with both meshers,
// our marching cubes (adaptivity 0) and OpenVDB's adaptive volume-to-mesh.
#include "surface/surface.h"
#include "surface/volumes.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <tuple>

namespace fc {
namespace {

// A block of nx × ny × nz particles on the simulation's lattice (spacing 2r),
// its lowest corner particle at `origin`.
ParticleFrame lattice(int nx, int ny, int nz, double r, std::array<double, 3> origin = {0, 0, 0}) {
  ParticleFrame f;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j)
      for (int k = 0; k < nz; ++k) {
        f.position.insert(f.position.end(), {float(origin[0] + 2 * r * i), float(origin[1] + 2 * r * j),
                                             float(origin[2] + 2 * r * k)});
        f.velocity.insert(f.velocity.end(), {0.5f, -0.25f, 0.125f});
        f.kind.push_back(0);
        f.phase.push_back(0);
      }
  return f;
}

// Every edge of a closed, consistently oriented mesh is used once in each direction.
bool closedAndOriented(const SurfaceMesh& m) {
  std::map<std::pair<uint32_t, uint32_t>, int> edges;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e) ++edges[{t[e], t[(e + 1) % 3]}];
  for (const auto& [e, n] : edges) {
    if (n != 1) return false;
    auto back = edges.find({e.second, e.first});
    if (back == edges.end() || back->second != 1) return false;
  }
  return !m.triangles.empty();
}

// The default settings with one mesher: adaptivity 0 is our marching cubes.
SurfaceSettings meshedWith(double adaptivity) {
  SurfaceSettings s = surfaceSettingsTable().defaults();
  s.adaptivity = adaptivity;
  return s;
}
constexpr double kMeshers[] = {0.0, 0.1};

double farthestVertexFromParticles(const SurfaceMesh& m, const ParticleFrame& f) {
  double worst = 0;
  for (const auto& p : m.points) {
    double best = 1e30;
    for (size_t i = 0; i < f.count(); ++i) {
      const double dx = p[0] - f.position[3 * i], dy = p[1] - f.position[3 * i + 1], dz = p[2] - f.position[3 * i + 2];
      best = std::min(best, dx * dx + dy * dy + dz * dz);
    }
    worst = std::max(worst, std::sqrt(best));
  }
  return worst;
}

TEST(Surface, ABlockEnclosesItsParticlesVolume) {
  for (const double adaptivity : kMeshers) {
    SCOPED_TRACE("adaptivity " + std::to_string(adaptivity));
    const double r = 0.01;
    const ParticleFrame f = lattice(16, 12, 14, r);
    const Surface s = reconstructSurface(f, r, meshedWith(adaptivity));
    const double particles = double(f.count()) * std::pow(2 * r, 3);
    const double v = enclosedVolume(s.mesh);
    std::printf("block: %zu particles, mesh %zu points %zu triangles, volume ratio %.4f, %.1f ms\n", f.count(),
                s.mesh.points.size(), s.mesh.triangles.size(), v / particles, s.ms);
    EXPECT_NEAR(v / particles, 1.0, 0.02);
    EXPECT_TRUE(closedAndOriented(s.mesh));
    // The surface lies beyond the outer particles by about a radius: no vertex
    // is farther than one radius from some particle's sphere (2 r from its centre).
    const double far = farthestVertexFromParticles(s.mesh, f);
    std::printf("farthest vertex: %.3f r from a particle's centre\n", far / r);
    EXPECT_LE(far, 2 * r);
    EXPECT_GE(far, 0.9 * r);
    // Every particle moves at (0.5, -0.25, 0.125) m/s: so does every vertex.
    for (const auto& u : s.mesh.velocities) {
      ASSERT_NEAR(u[0], 0.5, 1e-4);
      ASSERT_NEAR(u[1], -0.25, 1e-4);
      ASSERT_NEAR(u[2], 0.125, 1e-4);
    }
    ASSERT_TRUE(s.volumes);
    EXPECT_EQ(s.volumes->surface->getGridClass(), openvdb::GRID_LEVEL_SET);
    EXPECT_EQ(s.volumes->surface->getName(), "surface");
    EXPECT_EQ(s.volumes->velocity->getName(), "v");
    // Inside the block the level set is negative, outside positive.
    auto acc = s.volumes->surface->getConstAccessor();
    const auto centre = s.volumes->surface->transform().worldToIndexCellCentered(openvdb::Vec3d(15 * r, 11 * r, 13 * r));
    const auto outside = s.volumes->surface->transform().worldToIndexCellCentered(openvdb::Vec3d(15 * r, 11 * r, 40 * r));
    EXPECT_LT(acc.getValue(centre), 0.0f);
    EXPECT_GT(acc.getValue(outside), 0.0f);
  }
}

TEST(Surface, OnlyLiquidAndTemporaryParticlesFormIt) {
  for (const double adaptivity : kMeshers) {
    SCOPED_TRACE("adaptivity " + std::to_string(adaptivity));
    const double r = 0.01;
    ParticleFrame f = lattice(6, 6, 6, r);
    const Surface liquid = reconstructSurface(f, r, meshedWith(adaptivity));
    // A wall of boundary samples beside it changes nothing.
    ParticleFrame wall = lattice(1, 6, 6, r, {-4 * r, 0, 0});
    for (size_t i = 0; i < wall.count(); ++i) {
      f.position.insert(f.position.end(), &wall.position[3 * i], &wall.position[3 * i + 3]);
      f.velocity.insert(f.velocity.end(), &wall.velocity[3 * i], &wall.velocity[3 * i + 3]);
      f.kind.push_back(2);
      f.phase.push_back(0);
    }
    const Surface withWall = reconstructSurface(f, r, meshedWith(adaptivity));
    EXPECT_EQ(withWall.particles, liquid.particles);
    EXPECT_EQ(withWall.mesh.triangles.size(), liquid.mesh.triangles.size());
    EXPECT_DOUBLE_EQ(enclosedVolume(withWall.mesh), enclosedVolume(liquid.mesh));
    // Without liquid there is no surface.
    for (auto& k : f.kind) k = 2;
    const Surface none = reconstructSurface(f, r, meshedWith(adaptivity));
    EXPECT_EQ(none.particles, 0u);
    EXPECT_FALSE(none.volumes);
    EXPECT_TRUE(none.mesh.triangles.empty());
  }
}

TEST(Surface, AOneParticleSheetStaysClosed) {
  for (const double adaptivity : kMeshers) {
    SCOPED_TRACE("adaptivity " + std::to_string(adaptivity));
    // A sheet one particle thick (a splash's crown) is a closed slab, not beads.
    const double r = 0.01;
    const ParticleFrame f = lattice(20, 20, 1, r);
    const Surface s = reconstructSurface(f, r, meshedWith(adaptivity));
    EXPECT_TRUE(closedAndOriented(s.mesh));
    auto acc = s.volumes->surface->getConstAccessor();
    // Between four particles of the sheet, in its plane: inside.
    const auto gap = s.volumes->surface->transform().worldToIndexCellCentered(openvdb::Vec3d(9 * r, 9 * r, 0));
    EXPECT_LT(acc.getValue(gap), 0.0f);
  }
}

TEST(Surface, ADropletOfFiftyParticlesIsMeshed) {
  for (const double adaptivity : kMeshers) {
    SCOPED_TRACE("adaptivity " + std::to_string(adaptivity));
    const double r = 0.01;
    ParticleFrame f;
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1, 1);
    while (f.count() < 50) {
      const double x = u(rng), y = u(rng), z = u(rng);
      if (x * x + y * y + z * z > 1) continue;
      f.position.insert(f.position.end(), {float(0.5 + 5 * r * x), float(0.5 + 5 * r * y), float(0.5 + 5 * r * z)});
      f.velocity.insert(f.velocity.end(), {0, 0, 0});
      f.kind.push_back(1);
      f.phase.push_back(0);
    }
    const Surface s = reconstructSurface(f, r, meshedWith(adaptivity));
    const double v = enclosedVolume(s.mesh);
    std::printf("droplet: %zu triangles, volume %.3g (particles %.3g)\n", s.mesh.triangles.size(), v,
                50 * std::pow(2 * r, 3));
    EXPECT_TRUE(closedAndOriented(s.mesh));
    EXPECT_GT(v, 0.5 * 50 * std::pow(2 * r, 3));
  }
}

TEST(Surface, ASingleParticleStaysASphere) {
  for (const double adaptivity : kMeshers) {
    SCOPED_TRACE("adaptivity " + std::to_string(adaptivity));
    const double r = 0.01;
    const ParticleFrame f = lattice(1, 1, 1, r, {0.3, 0.3, 0.3});
    const Surface s = reconstructSurface(f, r, meshedWith(adaptivity));
    EXPECT_TRUE(closedAndOriented(s.mesh));
    const double v = enclosedVolume(s.mesh);
    std::printf("single: volume %.3g, sphere of radius r %.3g\n", v, 4.0 / 3.0 * M_PI * r * r * r);
    EXPECT_GT(v, 0.5 * 4.0 / 3.0 * M_PI * r * r * r);
  }
}

// A splash: a jittered block, a sheet one particle thick with holes, and
// droplets of 1-30 particles, some touching: the cases where a cube's face
// has four crossings.
ParticleFrame splash(double r, unsigned seed) {
  ParticleFrame f = lattice(10, 10, 6, r);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  for (size_t i = 0; i < f.position.size(); ++i) f.position[i] += float(0.6 * r * (u(rng) - 0.5));
  for (size_t i = 0; i < f.count(); ++i)
    std::copy_n(std::array<float, 3>{f.position[3 * i], 0.0f, -1.0f}.begin(), 3, &f.velocity[3 * i]);
  const auto add = [&](double x, double y, double z) {
    f.position.insert(f.position.end(), {float(x), float(y), float(z)});
    f.velocity.insert(f.velocity.end(), {float(x), 0.0f, -1.0f});
    f.kind.push_back(0);
    f.phase.push_back(0);
  };
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 20; ++j)
      if (u(rng) > 0.15) add(2 * r * i + 0.4 * r * u(rng), 2 * r * j, 18 * r + 0.8 * r * u(rng));
  for (int d = 0; d < 60; ++d) {
    const double cx = 40 * r * u(rng), cy = 40 * r * u(rng), cz = 26 * r + 20 * r * u(rng);
    const int n = 1 + int(29 * u(rng));
    for (int p = 0; p < n; ++p) add(cx + 2.1 * r * (p % 3), cy + 2.1 * r * ((p / 3) % 3), cz + 2.1 * r * (p / 9));
  }
  return f;
}

TEST(Surface, VelocityTrailsStretchTheLiquidBehindItsMotion) {
  const double r = 0.01;
  ParticleFrame f = lattice(2, 2, 2, r, {0.3, 0.3, 0.3});
  for (size_t i = 0; i < f.count(); ++i) f.velocity[3 * i] = 2, f.velocity[3 * i + 1] = f.velocity[3 * i + 2] = 0;
  const auto extent = [](const SurfaceMesh& m, int d) {
    float lo = 1e30f, hi = -1e30f;
    for (const auto& p : m.points) lo = std::min(lo, p[d]), hi = std::max(hi, p[d]);
    return std::pair<double, double>(lo, hi);
  };
  for (const double adaptivity : kMeshers) {
    SCOPED_TRACE("adaptivity " + std::to_string(adaptivity));
    SurfaceSettings settings = meshedWith(adaptivity);
    const Surface still = reconstructSurface(f, r, settings);
    settings.trail = 0.01;  // 2 m/s: 2 cm, two radii, behind the particles
    const Surface trailed = reconstructSurface(f, r, settings);
    EXPECT_EQ(trailed.particles, still.particles);
    EXPECT_TRUE(closedAndOriented(trailed.mesh));
    const auto [x0, x1] = extent(still.mesh, 0);
    const auto [t0, t1] = extent(trailed.mesh, 0);
    EXPECT_NEAR(t1, x1, 0.25 * r);           // the front stays
    // The back reaches most of the 2 cm further: the field's mean position
    // at the trail's end lies a little ahead of its last sample.
    EXPECT_GT(x0 - t0, 0.6 * 0.02);
    EXPECT_LT(x0 - t0, 0.02 + 0.25 * r);
    for (int d = 1; d < 3; ++d) {
      const auto [a0, a1] = extent(still.mesh, d);
      const auto [b0, b1] = extent(trailed.mesh, d);
      EXPECT_NEAR(b1 - b0, a1 - a0, 0.5 * r);  // no wider across the motion
    }
    EXPECT_GT(enclosedVolume(trailed.mesh), 1.3 * enclosedVolume(still.mesh));
    for (const auto& u : trailed.mesh.velocities) ASSERT_NEAR(u[0], 2.0f, 1e-4);
  }
}

TEST(Surface, MarchingCubesIsClosedAndOrientedInASplash) {
  const double r = 0.01;
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const ParticleFrame f = splash(r, seed);
    for (const double voxel : {0.5, 0.37, 1.0}) {
      SCOPED_TRACE("voxel " + std::to_string(voxel));
      SurfaceSettings settings = meshedWith(0);
      settings.voxelSize = voxel;
      const Surface s = reconstructSurface(f, r, settings);
      EXPECT_TRUE(closedAndOriented(s.mesh));
      // A coarse voxel erodes the small droplets more (docs/surfaces.md).
      EXPECT_GT(enclosedVolume(s.mesh), (voxel < 1 ? 0.9 : 0.75) * double(f.count()) * std::pow(2 * r, 3));
      for (const auto& p : s.mesh.points) ASSERT_TRUE(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]));
    }
  }
}

TEST(Surface, BothMeshersEncloseTheSameVolume) {
  const double r = 0.01;
  const ParticleFrame f = splash(r, 4);
  const Surface uniform = reconstructSurface(f, r, meshedWith(0));
  const Surface adaptive = reconstructSurface(f, r, meshedWith(0.1));
  const double a = enclosedVolume(uniform.mesh), b = enclosedVolume(adaptive.mesh);
  std::printf("splash: uniform %zu triangles %.4g m3, adaptive %zu triangles %.4g m3\n", uniform.mesh.triangles.size(), a,
              adaptive.mesh.triangles.size(), b);
  // Merging flat regions into larger polygons cuts a little off the droplets.
  EXPECT_NEAR(a / b, 1.0, 0.02);
  EXPECT_GT(uniform.mesh.triangles.size(), adaptive.mesh.triangles.size());
  // Each vertex moves as the particles around it: -1 m/s along z, x m/s along x.
  for (const Surface* s : {&uniform, &adaptive}) {
    double worstZ = 0, worstX = 0;
    for (size_t i = 0; i < s->mesh.points.size(); ++i) {
      worstZ = std::max(worstZ, std::abs(double(s->mesh.velocities[i][2]) + 1.0));
      worstX = std::max(worstX, std::abs(double(s->mesh.velocities[i][0]) - s->mesh.points[i][0]));
    }
    EXPECT_LT(worstZ, 1e-5);
    EXPECT_LT(worstX, 3 * r);  // the mean of particles within the kernel's reach
  }
}

// The filter, voxel by voxel from the unfiltered grid: a 3-wide mean along
// x, then y, then z, clamped to the band, where a block without values (a
// tile inside, the outside) reads its constant at every stage.
TEST(Surface, TheFilterIsTheBoxOfTheUnfilteredFieldAcrossBlocks) {
  const double r = 0.01;
  const ParticleFrame f = splash(r, 6);
  SurfaceSettings raw = surfaceSettingsTable().defaults(), smoothed = raw;
  raw.smoothing = 0;
  smoothed.smoothing = 1;
  const Surface a = reconstructSurface(f, r, raw, false), b = reconstructSurface(f, r, smoothed, false);
  ASSERT_TRUE(a.volumes && b.volumes);
  const auto in = a.volumes->surface->getConstAccessor();
  const float band = a.volumes->surface->background(), third = 1.0f / 3.0f;
  using openvdb::Coord;
  const auto constant = [&](const Coord& c) { return in.probeConstLeaf(c) == nullptr; };
  const auto stage0 = [&](const Coord& c) { return in.getValue(c); };
  const auto stageX = [&](const Coord& c) {
    if (constant(c)) return in.getValue(c);
    return (stage0(c.offsetBy(-1, 0, 0)) + stage0(c) + stage0(c.offsetBy(1, 0, 0))) * third;
  };
  const auto stageY = [&](const Coord& c) {
    if (constant(c)) return in.getValue(c);
    return (stageX(c.offsetBy(0, -1, 0)) + stageX(c) + stageX(c.offsetBy(0, 1, 0))) * third;
  };
  size_t voxels = 0, changed = 0;
  for (auto leaf = b.volumes->surface->tree().cbeginLeaf(); leaf; ++leaf)
    for (auto v = leaf->cbeginValueAll(); v; ++v) {
      const Coord c = v.getCoord();
      ASSERT_FALSE(constant(c)) << "a filtered block the unfiltered field has no values in";
      const float box = (stageY(c.offsetBy(0, 0, -1)) + stageY(c) + stageY(c.offsetBy(0, 0, 1))) * third;
      ASSERT_NEAR(*v, std::clamp(box, -band, band), 1e-6f * band) << c;
      ++voxels;
      changed += std::abs(*v - in.getValue(c)) > 1e-3f * band;
    }
  EXPECT_GT(voxels, 100000u);
  EXPECT_GT(changed, voxels / 4);  // the filter did something
}

TEST(Surface, TheMeshDoesNotDependOnTheThreadCount) {
  const double r = 0.01;
  const ParticleFrame f = splash(r, 5);
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const Surface one = reconstructSurface(f, r, meshedWith(0));
  omp_set_num_threads(std::max(2, threads));
  const Surface many = reconstructSurface(f, r, meshedWith(0));
  omp_set_num_threads(threads);
  EXPECT_EQ(one.mesh.points, many.mesh.points);
  EXPECT_EQ(one.mesh.triangles, many.mesh.triangles);
  EXPECT_EQ(one.mesh.velocities, many.mesh.velocities);
}

}  // namespace
}  // namespace fc

namespace fc {
namespace {
// Prints the reconstruction's cost for cubes of 100k and 1M particles
// (the benchmark is `flowclip bench surface`).
TEST(Surface, DISABLED_Cost) {
  for (int n : {46, 100}) {
    const double r = 0.01;
    const ParticleFrame f = lattice(n, n, n, r);
    const Surface s = reconstructSurface(f, r, surfaceSettingsTable().defaults());
    std::printf("%d^3 = %zu particles: %.0f ms, %.3f us/particle, %zu triangles, volume ratio %.4f\n", n, f.count(),
                s.ms, s.ms * 1e3 / double(f.count()), s.mesh.triangles.size(),
                enclosedVolume(s.mesh) / (double(f.count()) * std::pow(2 * r, 3)));
  }
}
}  // namespace
}  // namespace fc
