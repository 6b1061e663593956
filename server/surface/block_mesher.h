#pragma once
// A uniform triangle mesh of the zero level of a level set stored in 8³
// blocks (surface/surface.cpp's crossed blocks): marching cubes [LC87] with
// a case table generated here, whose faces are all resolved by one rule
// (the inside corners of a face with four crossings are kept apart), so
// that two cubes always agree on the face they share and the mesh is closed
// and consistently oriented. OpenVDB's volume-to-mesh stays for adaptive
// meshes; this one is the fast path for adaptivity 0.
//
// References (docs/references.md):
//   [LC87] W. E. Lorensen, H. E. Cline. Marching cubes: a high resolution 3D
//          surface construction algorithm. ACM SIGGRAPH Computer
//          Graphics 21(4), 1987, 163-169.
//          DOI 10.1145/37402.37422
#include "surface/surface.h"
#include <cstdint>
#include <vector>

namespace fc {

// Neighbour (di, dj, dk) ∈ {-1, 0, 1}³ of a block: its slot in MeshBlock's arrays.
inline int neighbourSlot(int di, int dj, int dk) { return (di + 1) * 9 + (dj + 1) * 3 + (dk + 1); }
// Which block along an axis a local voxel coordinate in [-1, 8] is in (a
// block is 8 voxels wide): -1, 0 or 1.
inline int blockOffset(int local) { return local < 0 ? -1 : local >= 8 ? 1 : 0; }
// That coordinate within the block `offset` names: in [0, 8).
inline int withinBlock(int local, int offset) { return local - offset * 8; }

// One block of the level set that holds values, and its 26 neighbours.
struct MeshBlock {
  int64_t block[3] = {0, 0, 0};    // block coordinates: voxel = 8 × block + local
  const float* phi = nullptr;      // 512 values, index (i << 6) | (j << 3) | k
  const float* velocity = nullptr; // 3 × 512, the same order
  const uint8_t* inside = nullptr; // 64 rows along z, bit k of row (i << 3) | j: phi < 0 at (i, j, k)
  // Neighbour (dx, dy, dz) ∈ {-1, 0, 1}³ at (dx + 1) * 9 + (dy + 1) * 3 + (dz + 1):
  // its index in the block list, or -1 and the value it holds everywhere.
  int32_t neighbour[27];
  float constant[27];
};

// The zero level of the blocks' field, voxel centres at voxel × index (m),
// each vertex with the velocity interpolated along its grid edge (from the
// voxels inside the narrow band |phi| < band, where particles are); triangles
// counter-clockwise seen from outside (the positive side). Parallel over
// blocks; the result does not depend on the thread count.
void meshBlocks(const std::vector<MeshBlock>& blocks, double voxel, float band, SurfaceMesh& mesh);

}  // namespace fc
