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

enum Kind : uint8_t { Outside, Inside, Crossed };

// [ZB05] Sec. 6, scattered: every particle within `rv` voxels adds k(s),
// k(s) x_i and k(s) v_i to the block's voxels, a row of 8 per vector.
void sumBlock(const Points& g, float rv, Sums& s);

// One block's field clamped to [-band, band] and its mean velocity, and
// what the block is: crossed when some voxel is inside the band or the
// sign changes.
Kind fieldOfBlock(const Sums& s, const Sums* trail, float voxel, float rs, float band, float* phi, float* vel);

}  // namespace fc::surface_detail
