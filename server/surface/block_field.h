#pragma once
// Zhu & Bridson's field over one 8³ block of the surface's grid
// (surface/surface.cpp): the kernel-weighted sums of the particles around
// it, the distance to their weighted mean, and what the block is.
//
// References (docs/references.md):
//   [ZB05]  Y. Zhu, R. Bridson. Animating sand as a fluid. ACM TOG
//           (SIGGRAPH) 24(3), 2005. DOI 10.1145/1073204.1073298
#include "surface/particle_buckets.h"

#include <cstdint>

namespace fc::surface_detail {

constexpr int kBlockVoxels = kBlock * kBlock * kBlock;

// Per-voxel sums of the weights and the weighted positions and velocities
// of one block, one array per quantity: a row of 8 voxels is one vector.
struct alignas(64) Sums {
  float w[kBlockVoxels], x[kBlockVoxels], y[kBlockVoxels], z[kBlockVoxels], vx[kBlockVoxels], vy[kBlockVoxels],
      vz[kBlockVoxels];
};

// The same sums at every second voxel of a block and on its far faces,
// (0, 2, 4, 6, 8)³ in voxels: rows along z of 5 samples, padded to 8 lanes.
constexpr float kCoarseFrom = 5;  // kernel radius (voxels) from which the sums are sampled every second voxel
constexpr int kCoarse = kBlock / 2 + 1, kCoarseRows = kCoarse * kCoarse, kCoarseSize = kCoarseRows * kBlock;
struct alignas(64) CoarseSums {
  float w[kCoarseSize], x[kCoarseSize], y[kCoarseSize], z[kCoarseSize], vx[kCoarseSize], vy[kCoarseSize],
      vz[kCoarseSize];
};

enum Kind : uint8_t { Outside, Inside, Crossed };

// [ZB05]'s sums at every voxel of a block, from samples at every second
// voxel: the kernel changes little over two voxels (a quarter of its
// radius at the default voxel), and 5³ samples cost 25 rows where 8³ voxels
// cost 64. Interpolating the weights and the weighted positions alike keeps
// x̄ a weighted mean of the particles: a lone particle is still a sphere.
void sumBlock(const Points& g, float rv, CoarseSums& coarse, Sums& s);

// One block's field clamped to [-band, band] and its mean velocity, and
// what the block is: crossed when some voxel is inside the band or the
// sign changes.
Kind fieldOfBlock(const Sums& s, const Sums* trail, float voxel, float rs, float band, float* phi, float* vel);

}  // namespace fc::surface_detail
