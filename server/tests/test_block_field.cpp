// The surface's field over one block (surface/block_field.h): Zhu &
// Bridson's distance to the particles' weighted mean, against a plain sum,
// the sphere of a lone particle, and the same field with trails that add
// nothing.
#include "surface/block_field.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

namespace fc::surface_detail {
namespace {

void add(Points& p, float x, float y, float z, float vx, float vy, float vz) {
  p.x.push_back(x), p.y.push_back(y), p.z.push_back(z), p.vx.push_back(vx), p.vy.push_back(vy), p.vz.push_back(vz);
}

struct Field {
  std::vector<float> phi = std::vector<float>(kBlockVoxels), vel = std::vector<float>(3 * kBlockVoxels);
  Kind kind = Outside;
};

// The default settings in voxels: kernel 8, surface 2.3, band 2.3 (voxel 0.5 r).
constexpr float kVoxel = 1, kRv = 8, kRs = 2.3f, kBand = 2.3f;

Field fieldOf(const Sums& sums, const Sums* trail) {
  Field f;
  f.kind = fieldOfBlock(sums, trail, kVoxel, kRs, kBand, f.phi.data(), f.vel.data());
  return f;
}

TEST(BlockField, ALoneParticleIsASphereMovingAsIt) {
  Points p;
  add(p, 3.3f, 4.6f, 2.2f, 0.5f, -1.0f, 2.0f);
  auto sums = std::make_unique<Sums>();
  sumBlock(p, kRv, *sums);
  const Field f = fieldOf(*sums, nullptr);
  EXPECT_EQ(f.kind, Crossed);
  for (int n = 0; n < kBlockVoxels; ++n) {
    const float dx = float(n >> 6) - 3.3f, dy = float((n >> 3) & 7) - 4.6f, dz = float(n & 7) - 2.2f;
    const float sphere = std::min(kBand, std::sqrt(dx * dx + dy * dy + dz * dz) - kRs);
    ASSERT_NEAR(f.phi[size_t(n)], sphere, 1e-4f) << "voxel " << n;
    ASSERT_NEAR(f.vel[3 * size_t(n)], 0.5f, 1e-5f);
    ASSERT_NEAR(f.vel[3 * size_t(n) + 1], -1.0f, 1e-5f);
    ASSERT_NEAR(f.vel[3 * size_t(n) + 2], 2.0f, 1e-5f);
  }
}

TEST(BlockField, FarParticlesLeaveTheBlockOutsideAndABulkPutsItAtTheFloor) {
  auto sums = std::make_unique<Sums>();
  Points far;
  add(far, 3.5f, 3.5f, 3.5f + 7.9f + kRv, 0, 0, 0);  // beyond every voxel's kernel
  sumBlock(far, kRv, *sums);
  EXPECT_EQ(fieldOf(*sums, nullptr).kind, Outside);
  Points bulk;  // a lattice 2 voxels apart, symmetric about every voxel within the kernel
  for (int i = -10; i <= 18; i += 2)
    for (int j = -10; j <= 18; j += 2)
      for (int k = -10; k <= 18; k += 2) add(bulk, float(i), float(j), float(k), 0, 0, 0);
  sumBlock(bulk, kRv, *sums);
  // Inside a uniform bulk the weighted mean is the point itself: the field
  // is its floor, minus the surface radius, with no velocity.
  const Field inside = fieldOf(*sums, nullptr);
  for (int n = 0; n < kBlockVoxels; ++n) {
    ASSERT_NEAR(inside.phi[size_t(n)], -kRs, 1e-4f) << "voxel " << n;
    for (int d = 0; d < 3; ++d) ASSERT_EQ(inside.vel[3 * size_t(n) + d], 0.0f);
  }
}

// The rows a particle visits are all those its kernel reaches: the sums
// equal a plain sum of every particle at every voxel, particles inside,
// beside and beyond the block, some just at the kernel's reach.
TEST(BlockField, TheSumsAreEveryParticleAtEveryVoxel) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> at(-9, 16), u(-1, 1);
  Points p;
  for (int n = 0; n < 400; ++n) add(p, at(rng), at(rng), at(rng), u(rng), u(rng), u(rng));
  for (int n = 0; n < 8; ++n) add(p, 3.0f, 4.0f, 7.0f + kRv * (1.0f - 1e-6f * float(n)), 0, 0, 1);  // grazing the block
  add(p, 2.5f, 6.5f, 0.5f, 0.25f, 0, -2);  // an odd count: the last is summed alone, the others two at a time
  auto sums = std::make_unique<Sums>();
  sumBlock(p, kRv, *sums);
  const float inv = 1.0f / (kRv * kRv);
  for (int v = 0; v < kBlockVoxels; ++v) {
    double w = 0, x = 0, vz = 0;
    for (size_t n = 0; n < p.size(); ++n) {
      const float dx = p.x[n] - float(v >> 6), dy = p.y[n] - float((v >> 3) & 7), dz = p.z[n] - float(v & 7);
      const double c = kernelWeight(dx * dx + dy * dy + dz * dz, inv);
      w += c, x += c * p.x[n], vz += c * p.vz[n];
    }
    ASSERT_NEAR(sums->w[v], w, 1e-5 * std::max(1.0, w)) << "voxel " << v;
    ASSERT_NEAR(sums->x[v], x, 1e-4 * std::max(1.0, std::abs(x))) << "voxel " << v;
    ASSERT_NEAR(sums->vz[v], vz, 1e-5 * std::max(1.0, std::abs(vz))) << "voxel " << v;
  }
}

// The field without trails is the field with trails that add nothing (its
// own instance), on a random surface with droplets.
TEST(BlockField, AnEmptyTrailChangesNothing) {
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-0.5f, 0.5f), at(-8, 16);
    Points p;
    for (int i = -12; i < 4; i += 4)
      for (int j = -12; j <= 20; j += 4)
        for (int k = -12; k <= 20; k += 4) add(p, float(i) + u(rng), float(j) + u(rng), float(k) + u(rng), 1, u(rng), 0);
    for (int d = 0; d < 6; ++d) add(p, at(rng) + 12, at(rng), at(rng), 0, 1, u(rng));
    auto sums = std::make_unique<Sums>();
    auto none = std::make_unique<Sums>();
    sumBlock(p, kRv, *sums);
    sumBlock(Points{}, kRv, *none);
    const Field a = fieldOf(*sums, nullptr), b = fieldOf(*sums, none.get());
    EXPECT_EQ(a.kind, Crossed);
    EXPECT_EQ(a.kind, b.kind);
    int near = 0;
    for (int n = 0; n < kBlockVoxels; ++n) {
      near += std::abs(a.phi[size_t(n)]) < kBand;
      ASSERT_NEAR(a.phi[size_t(n)], b.phi[size_t(n)], 1e-5f) << "voxel " << n;
      for (int d = 0; d < 3; ++d) ASSERT_NEAR(a.vel[3 * size_t(n) + d], b.vel[3 * size_t(n) + d], 1e-6f);
    }
    EXPECT_GT(near, 32);  // the surface crosses the block
  }
}

}  // namespace
}  // namespace fc::surface_detail
