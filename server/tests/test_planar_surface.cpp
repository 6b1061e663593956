// A 2D liquid's surface (surface/planar_surface.cpp): the outline wraps the
// liquid, holes and droplets; the flat area has no T-junction, its boundary
// is the outline and its interior is merged; the slab is a closed prism of
// that area; the level set is the same prism; the velocities are the
// particles'; nothing depends on the thread count.
#include "surface/surface.h"
#include "surface/volumes.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <cmath>
#include <map>
#include <random>

namespace fc {
namespace {

void add(ParticleFrame& f, double x, double y, float vx = 0.5f, float vy = -0.25f) {
  f.position.insert(f.position.end(), {float(x), float(y), 0.0f});
  f.velocity.insert(f.velocity.end(), {vx, vy, 0.0f});
  f.kind.push_back(0);
  f.phase.push_back(0);
}

// An nx × ny block on the simulation's lattice with an hx × hy hole in its middle.
ParticleFrame blockWithHole(int nx, int ny, int hx, int hy, double r) {
  ParticleFrame f;
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j) {
      const bool hole = std::abs(2 * i - nx) < hx && std::abs(2 * j - ny) < hy;
      if (!hole) add(f, 2 * r * i, 2 * r * j);
    }
  return f;
}

// A 2D splash: a block, a line one particle thick, jittered droplets of 1-30 particles.
ParticleFrame splash2d(double r, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  ParticleFrame f;
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 15; ++j) add(f, 2 * r * i + 0.3 * r * u(rng), 2 * r * j + 0.3 * r * u(rng));
  for (int i = 0; i < 60; ++i) add(f, 2 * r * i, 40 * r + 0.6 * r * u(rng));
  for (int d = 0; d < 80; ++d) {
    const double cx = 80 * r * u(rng), cy = 50 * r + 60 * r * u(rng);
    const int n = 1 + int(29 * u(rng));
    for (int p = 0; p < n; ++p) add(f, cx + 2.1 * r * (p % 5) + 0.5 * r * u(rng), cy + 2.1 * r * (p / 5));
  }
  return f;
}

SurfaceSettings withThickness(double thickness) {
  SurfaceSettings s = surfaceSettingsTable().defaults();
  s.thickness2d = thickness;
  return s;
}

// Edges used by the triangles: (from, to) → count.
std::map<std::pair<uint32_t, uint32_t>, int> directedEdges(const SurfaceMesh& m) {
  std::map<std::pair<uint32_t, uint32_t>, int> edges;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e) ++edges[{t[e], t[(e + 1) % 3]}];
  return edges;
}

bool closedAndOriented(const SurfaceMesh& m) {
  const auto edges = directedEdges(m);
  for (const auto& [e, n] : edges) {
    if (n != 1) return false;
    const auto back = edges.find({e.second, e.first});
    if (back == edges.end() || back->second != 1) return false;
  }
  return !m.triangles.empty();
}

double signedArea(const std::vector<std::array<float, 2>>& loop) {
  double a = 0;
  for (size_t k = 0; k < loop.size(); ++k) {
    const auto& p = loop[k];
    const auto& q = loop[(k + 1) % loop.size()];
    a += 0.5 * (double(p[0]) * q[1] - double(q[0]) * p[1]);
  }
  return a;
}

double outlineArea(const Surface& s) {
  double a = 0;
  for (const auto& l : s.outline) a += signedArea(l);
  return a;
}

size_t outlineSegments(const Surface& s) {
  size_t n = 0;
  for (const auto& l : s.outline) n += l.size();
  return n;
}

// The triangle's area seen from +z (positive when counter-clockwise).
double zArea(const SurfaceMesh& m, const std::array<uint32_t, 3>& t) {
  const auto& a = m.points[t[0]];
  const auto& b = m.points[t[1]];
  const auto& c = m.points[t[2]];
  return 0.5 * ((double(b[0]) - a[0]) * (double(c[1]) - a[1]) - (double(c[0]) - a[0]) * (double(b[1]) - a[1]));
}

TEST(PlanarSurface, TheOutlineWrapsTheLiquidItsHoleAndALoneParticle) {
  const double r = 0.01;
  ParticleFrame f = blockWithHole(40, 30, 12, 10, r);
  const size_t block = f.count();
  add(f, 2.0, 2.0);  // a lone particle far away
  const Surface s = reconstructSurface(f, r, surfaceSettingsTable().defaults(), true, 2);
  ASSERT_EQ(s.outline.size(), 3u);
  int outer = 0, holes = 0;
  for (const auto& l : s.outline) (signedArea(l) > 0 ? outer : holes) += 1;
  EXPECT_EQ(outer, 2);
  EXPECT_EQ(holes, 1);
  // The block's area within a few percent: the outline lies about a radius beyond its outer particles.
  const double liquid = double(block) * 4 * r * r + M_PI * std::pow(1.15 * r, 2);
  EXPECT_NEAR(outlineArea(s) / liquid, 1.0, 0.08);
  // The lone particle: a circle of surface_radius around it (within a voxel's interpolation error).
  for (const auto& l : s.outline) {
    if (std::abs(double(l[0][0]) - 2.0) > 0.1) continue;
    for (const auto& p : l)
      EXPECT_NEAR(std::hypot(double(p[0]) - 2.0, double(p[1]) - 2.0), 1.15 * r, 0.25 * r);
  }
}

TEST(PlanarSurface, LoneParticlesAreWholeCirclesWhereverTheTilesFall) {
  // Particles 7.5 r apart (beyond each other's kernel), at every offset
  // across a tile: each outline is a circle of surface_radius around its
  // particle, none cut where a tile was missed; and the mesh does not depend
  // on the particles' order.
  const double r = 0.01;
  ParticleFrame f;
  for (int k = 0; k < 24; ++k) add(f, 0.075 * k + 0.0013 * k, 0.3 + 0.0007 * k);
  const Surface s = reconstructSurface(f, r, withThickness(0), true, 2);
  ASSERT_EQ(s.outline.size(), f.count());
  for (const auto& l : s.outline)
    for (const auto& p : l) {
      double nearest = 1e30;
      for (size_t i = 0; i < f.count(); ++i)
        nearest = std::min(nearest, std::hypot(double(p[0]) - f.position[3 * i], double(p[1]) - f.position[3 * i + 1]));
      ASSERT_NEAR(nearest, 1.15 * r, 0.25 * r) << "an outline point off its particle's circle: cut by a missing tile";
    }
  ParticleFrame reversed;
  for (size_t i = f.count(); i-- > 0;) add(reversed, f.position[3 * i], f.position[3 * i + 1]);
  const Surface t = reconstructSurface(reversed, r, withThickness(0), true, 2);
  EXPECT_EQ(t.mesh.points, s.mesh.points);
  EXPECT_EQ(t.mesh.triangles, s.mesh.triangles);
}

TEST(PlanarSurface, TheFlatAreaIsTheOutlinesInteriorWithoutTJunctions) {
  const double r = 0.01;
  for (const double voxel : {0.5, 0.37, 1.0}) {
    SCOPED_TRACE("voxel " + std::to_string(voxel));
    SurfaceSettings settings = withThickness(0);
    settings.voxelSize = voxel;
    const ParticleFrame f = blockWithHole(60, 40, 16, 12, r);
    const Surface s = reconstructSurface(f, r, settings, true, 2);
    const SurfaceMesh& m = s.mesh;
    ASSERT_FALSE(m.triangles.empty());
    for (const auto& p : m.points) ASSERT_EQ(p[2], 0.0f);
    // Every triangle faces +z and the area they cover is the outline's.
    double area = 0;
    for (const auto& t : m.triangles) {
      const double a = zArea(m, t);
      ASSERT_GE(a, -1e-12);
      area += a;
    }
    EXPECT_NEAR(area / outlineArea(s), 1.0, 1e-5);
    // An edge is shared by two triangles, once each way, or lies on the
    // outline: a T-junction would leave an edge used once inside.
    const auto edges = directedEdges(m);
    size_t boundary = 0;
    for (const auto& [e, n] : edges) {
      ASSERT_EQ(n, 1);
      if (!edges.count({e.second, e.first})) ++boundary;
    }
    EXPECT_EQ(boundary, outlineSegments(s));
    // The interior is merged: far fewer triangles than two per grid cell.
    const double cells = area / std::pow(voxel * r, 2);
    std::printf("voxel %.2f r: %zu triangles for %.0f cells, %zu outline segments\n", voxel, m.triangles.size(), cells,
                outlineSegments(s));
    EXPECT_LT(double(m.triangles.size()), 0.15 * 2 * cells);
    // No vertex is unused.
    std::vector<bool> used(m.points.size(), false);
    for (const auto& t : m.triangles) used[t[0]] = used[t[1]] = used[t[2]] = true;
    EXPECT_EQ(std::count(used.begin(), used.end(), false), 0);
  }
}

TEST(PlanarSurface, TheSlabIsAClosedPrismOfTheArea) {
  const double r = 0.01;
  const ParticleFrame f = blockWithHole(60, 40, 16, 12, r);
  for (const double thickness : {2.3, 5.0}) {
    SCOPED_TRACE("thickness " + std::to_string(thickness));
    const Surface s = reconstructSurface(f, r, withThickness(thickness), true, 2);
    EXPECT_TRUE(closedAndOriented(s.mesh));
    const double h = 0.5 * thickness * r;
    EXPECT_NEAR(enclosedVolume(s.mesh) / (outlineArea(s) * 2 * h), 1.0, 1e-4);
    for (const auto& p : s.mesh.points) ASSERT_NEAR(std::abs(double(p[2])), h, 1e-7);
    // Every vertex moves as the particles: (0.5, -0.25) m/s in the plane.
    for (const auto& v : s.mesh.velocities) {
      ASSERT_NEAR(v[0], 0.5, 1e-5);
      ASSERT_NEAR(v[1], -0.25, 1e-5);
      ASSERT_EQ(v[2], 0.0f);
    }
  }
}

TEST(PlanarSurface, ASplashStaysClosedWithItsDropletsAndSaddles) {
  const double r = 0.01;
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const ParticleFrame f = splash2d(r, seed);
    for (const double voxel : {0.5, 0.37, 1.0})
      for (const int smoothing : {0, 1, 3}) {
        SCOPED_TRACE("voxel " + std::to_string(voxel) + " smoothing " + std::to_string(smoothing));
        SurfaceSettings settings = withThickness(2.3);
        settings.voxelSize = voxel, settings.smoothing = smoothing;
        const Surface s = reconstructSurface(f, r, settings, true, 2);
        ASSERT_TRUE(closedAndOriented(s.mesh));
        EXPECT_NEAR(enclosedVolume(s.mesh) / (outlineArea(s) * 2.3 * r), 1.0, 1e-4);
        // Each loop: at least three segments, each no longer than a cell's diagonal.
        for (const auto& l : s.outline) {
          ASSERT_GE(l.size(), 3u);
          for (size_t k = 0; k < l.size(); ++k) {
            const auto& p = l[k];
            const auto& q = l[(k + 1) % l.size()];
            ASSERT_LE(std::hypot(double(q[0]) - p[0], double(q[1]) - p[1]), std::sqrt(2.0) * voxel * r * 1.0001);
          }
        }
      }
  }
}

TEST(PlanarSurface, TheLevelSetIsTheSamePrism) {
  const double r = 0.01;
  const ParticleFrame f = blockWithHole(40, 30, 12, 10, r);
  const SurfaceSettings settings = withThickness(4.0);
  const Surface s = reconstructSurface(f, r, settings, true, 2);
  ASSERT_TRUE(s.volumes);
  const auto& grid = *s.volumes->surface;
  auto acc = grid.getConstAccessor();
  const auto at = [&](double x, double y, double z) {
    return acc.getValue(grid.transform().worldToIndexCellCentered(openvdb::Vec3d(x, y, z)));
  };
  const double voxel = settings.voxelSize * r, h = 2.0 * r;
  // Inside the liquid's area: negative at z = 0, zero at the faces z = ±h, positive beyond.
  EXPECT_LT(at(10 * r, 10 * r, 0), 0.0f);
  for (const double z : {h, -h}) EXPECT_NEAR(at(10 * r, 10 * r, z), 0.0, 0.5 * voxel);
  EXPECT_GT(at(10 * r, 10 * r, h + 2 * voxel), 0.0f);
  // In the hole and beyond the block: outside.
  EXPECT_GT(at(40 * r, 30 * r, 0), 0.0f);
  EXPECT_GT(at(-4 * r, 10 * r, 0), 0.0f);
  // The velocity grid carries the particles' velocity where the band is.
  auto vacc = s.volumes->velocity->getConstAccessor();
  size_t active = 0;
  for (auto v = s.volumes->velocity->cbeginValueOn(); v; ++v, ++active) {
    SCOPED_TRACE(v.getCoord().asVec3d().str() + " phi " + std::to_string(acc.getValue(v.getCoord())));
    ASSERT_NEAR((*v)[0], 0.5, 1e-5);
    ASSERT_NEAR((*v)[1], -0.25, 1e-5);
  }
  EXPECT_GT(active, 0u);
  // Only the outline: no grids, no mesh.
  const Surface bare = reconstructSurface(f, r, settings, false, 2, false);
  EXPECT_FALSE(bare.volumes);
  EXPECT_TRUE(bare.mesh.triangles.empty());
  EXPECT_EQ(bare.outline.size(), s.outline.size());
}

TEST(PlanarSurface, TrailsStretchTheOutlineBehindTheMotion) {
  const double r = 0.01;
  ParticleFrame f;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) add(f, 0.3 + 2 * r * i, 0.3 + 2 * r * j, 2.0f, 0.0f);
  SurfaceSettings settings = surfaceSettingsTable().defaults();
  const auto extent = [&](const Surface& s) {
    double lo = 1e30, hi = -1e30;
    for (const auto& l : s.outline)
      for (const auto& p : l) lo = std::min(lo, double(p[0])), hi = std::max(hi, double(p[0]));
    return std::pair<double, double>{lo, hi};
  };
  const auto still = extent(reconstructSurface(f, r, settings, true, 2));
  settings.trail = 0.01;  // 2 m/s × 0.01 s = 2 cm behind
  const auto trailed = extent(reconstructSurface(f, r, settings, true, 2));
  EXPECT_NEAR(trailed.second, still.second, 0.25 * r);  // the front stays
  // The back reaches most of the 2 cm further: the field's mean position at
  // the trail's end lies a little ahead of its last sample.
  EXPECT_GT(still.first - trailed.first, 0.6 * 0.02);
  EXPECT_LT(still.first - trailed.first, 0.02 + 0.25 * r);
}

TEST(PlanarSurface, TheMeshDoesNotDependOnTheThreadCount) {
  const double r = 0.01;
  const ParticleFrame f = splash2d(r, 7);
  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  const Surface one = reconstructSurface(f, r, surfaceSettingsTable().defaults(), true, 2);
  omp_set_num_threads(std::max(2, threads));
  const Surface many = reconstructSurface(f, r, surfaceSettingsTable().defaults(), true, 2);
  omp_set_num_threads(threads);
  EXPECT_EQ(one.mesh.points, many.mesh.points);
  EXPECT_EQ(one.mesh.triangles, many.mesh.triangles);
  EXPECT_EQ(one.mesh.velocities, many.mesh.velocities);
  EXPECT_EQ(one.outline, many.outline);
}

TEST(PlanarSurface, PointsOffTheGridAreLeftOutAndVelocitiesStayFinite) {
  // A particle kilometres away, one at NaN, one whose velocity is not finite
  // or huge: the surface is the one of the others, every velocity finite.
  const double r = 0.01;
  const ParticleFrame clean = blockWithHole(20, 12, 0, 0, r);
  for (const int dim : {2, 3}) {
    SCOPED_TRACE("dimension " + std::to_string(dim));
    ParticleFrame f = clean;
    add(f, 1e30, 0.1);
    add(f, std::nan(""), 0.1);
    add(f, 0.1, -3e9);
    add(f, 0.1, 0.1, std::numeric_limits<float>::infinity(), 0.0f);
    add(f, 0.12, 0.1, 3e38f, 3e38f);
    add(f, 0.14, 0.1, 3e38f, -3e38f);
    SurfaceSettings settings = surfaceSettingsTable().defaults();
    settings.trail = 0.01;
    const Surface s = reconstructSurface(f, r, settings, true, dim);
    ParticleFrame reference = clean;
    add(reference, 0.1, 0.1, 0.0f, 0.0f);
    add(reference, 0.12, 0.1, 0.0f, 0.0f);
    add(reference, 0.14, 0.1, 0.0f, 0.0f);
    const Surface want = reconstructSurface(reference, r, settings, true, dim);
    EXPECT_EQ(s.particles, want.particles);
    EXPECT_EQ(s.mesh.triangles.size(), want.mesh.triangles.size());
    EXPECT_NEAR(enclosedVolume(s.mesh), enclosedVolume(want.mesh), 1e-12);
    for (const auto& v : s.mesh.velocities)
      ASSERT_TRUE(std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]));
  }
}

}  // namespace
}  // namespace fc
