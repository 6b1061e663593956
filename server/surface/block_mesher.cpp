// Marching cubes [LC87] over the crossed blocks of a level set: the case
// table, the owner of every cell and grid edge, and the mesh.
#include "surface/block_mesher.h"

#include "core/parallel_failure.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace fc {

namespace {

constexpr int kB = 8, kVoxels = 512;

// Corner c of a cube is at (c & 1, c >> 1 & 1, c >> 2 & 1); edge e joins
// corner kEdgeLow[e] to kEdgeLow[e] + (1 << kEdgeAxis[e]).
struct CubeTable {
  int edgeLow[12], edgeAxis[12];
  int edgeOf[8][3];               // the edge from corner c along an axis (c's bit clear)
  std::vector<uint8_t> tri[256];  // 3 edges per triangle
};

const CubeTable& cubeTable() {
  static const CubeTable table = [] {
    CubeTable t{};
    int e = 0;
    for (int axis = 0; axis < 3; ++axis)
      for (int c = 0; c < 8; ++c)
        if (!(c & (1 << axis))) t.edgeLow[e] = c, t.edgeAxis[e] = axis, t.edgeOf[c][axis] = e++;
    const auto edgeBetween = [&](int a, int b) {
      const int low = std::min(a, b), bit = a ^ b;
      return t.edgeOf[low][bit == 1 ? 0 : bit == 2 ? 1 : 2];
    };
    for (int config = 0; config < 256; ++config) {
      const auto inside = [&](int c) { return (config >> c) & 1; };
      // Each face's crossing edges, paired into segments: a face with four
      // crossings keeps its two inside corners apart, on both of its cubes.
      std::vector<int> partners[12];
      for (int axis = 0; axis < 3; ++axis)
        for (int side = 0; side < 2; ++side) {
          const int u = (axis + 1) % 3, v = (axis + 2) % 3;
          const int uv[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
          int q[4];
          for (int k = 0; k < 4; ++k) q[k] = (side << axis) | (uv[k][0] << u) | (uv[k][1] << v);
          int crossing[4], n = 0;
          for (int k = 0; k < 4; ++k)
            if (inside(q[k]) != inside(q[(k + 1) % 4])) crossing[n++] = edgeBetween(q[k], q[(k + 1) % 4]);
          const auto pair = [&](int a, int b) { partners[a].push_back(b), partners[b].push_back(a); };
          if (n == 2) pair(crossing[0], crossing[1]);
          if (n == 4)
            for (int k = 0; k < 4; ++k)
              if (inside(q[k])) pair(edgeBetween(q[(k + 3) % 4], q[k]), edgeBetween(q[k], q[(k + 1) % 4]));
        }
      // Every crossing edge lies on two faces: the segments close into loops.
      bool seen[12] = {};
      for (int start = 0; start < 12; ++start) {
        if (partners[start].empty() || seen[start]) continue;
        std::vector<int> loop;
        int previous = -1, current = start;
        do {
          loop.push_back(current);
          seen[current] = true;
          const int next = partners[current][0] != previous ? partners[current][0] : partners[current][1];
          previous = current, current = next;
        } while (current != start);
        // Outward: the loop's normal (Newell) points from its inside corners to its outside ones.
        const auto mid = [&](int edge, int d) {
          return double((t.edgeLow[edge] >> d) & 1) + (t.edgeAxis[edge] == d ? 0.5 : 0.0);
        };
        double normal[3] = {0, 0, 0}, away[3] = {0, 0, 0};
        for (size_t k = 0; k < loop.size(); ++k) {
          const int a = loop[k], b = loop[(k + 1) % loop.size()];
          for (int d = 0; d < 3; ++d) {
            const int d1 = (d + 1) % 3, d2 = (d + 2) % 3;
            normal[d] += (mid(a, d1) - mid(b, d1)) * (mid(a, d2) + mid(b, d2));
          }
          const int low = t.edgeLow[a], high = low | (1 << t.edgeAxis[a]);
          const int in = inside(low) ? low : high, out = in == low ? high : low;
          for (int d = 0; d < 3; ++d) away[d] += double((out >> d) & 1) - double((in >> d) & 1);
        }
        if (normal[0] * away[0] + normal[1] * away[1] + normal[2] * away[2] < 0) std::reverse(loop.begin(), loop.end());
        for (size_t k = 1; k + 1 < loop.size(); ++k)
          t.tri[config].insert(t.tri[config].end(),
                                {uint8_t(loop[0]), uint8_t(loop[k]), uint8_t(loop[k + 1])});
      }
    }
    return t;
  }();
  return table;
}

int neighbourOf(int di, int dj, int dk) { return (di + 1) * 9 + (dj + 1) * 3 + (dk + 1); }
int blockOffset(int local) { return local < 0 ? -1 : local >= kB ? 1 : 0; }

// A block's view of the voxels around it, local coordinates in [-1, 8].
struct Around {
  const std::vector<MeshBlock>& blocks;
  const MeshBlock& b;
  float value(int i, int j, int k) const {
    const int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k), n = neighbourOf(di, dj, dk);
    const int32_t other = b.neighbour[n];
    if (other < 0) return b.constant[n];
    return blocks[size_t(other)].phi[((i - di * kB) << 6) | ((j - dj * kB) << 3) | (k - dk * kB)];
  }
  const float* velocity(int i, int j, int k) const {
    const int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
    const int32_t other = b.neighbour[neighbourOf(di, dj, dk)];
    if (other < 0) return nullptr;
    return blocks[size_t(other)].velocity + 3 * (((i - di * kB) << 6) | ((j - dj * kB) << 3) | (k - dk * kB));
  }
  bool crossed(int di, int dj, int dk) const { return b.neighbour[neighbourOf(di, dj, dk)] >= 0; }
  // Every value in [-1, 8]³, at padded(i, j, k).
  void pad(float* out) const {
    for (int i = -1; i <= kB; ++i)
      for (int j = -1; j <= kB; ++j) {
        float* row = out + padded(i, j, -1);
        if (i >= 0 && i < kB && j >= 0 && j < kB) {
          row[0] = value(i, j, -1);
          std::copy_n(b.phi + ((i << 6) | (j << 3)), kB, row + 1);
          row[kB + 1] = value(i, j, kB);
        } else {
          for (int k = -1; k <= kB; ++k) row[k + 1] = value(i, j, k);
        }
      }
  }
  static int padded(int i, int j, int k) { return ((i + 1) * 10 + (j + 1)) * 10 + (k + 1); }
};

// The vertices a block owns: one per crossing grid edge whose lower voxel is
// in the block, and per crossing edge whose lower voxel is in a neighbour
// without values (an orphan). Local lower voxel in [-1, 7] per axis.
struct EdgeTable {
  std::vector<int32_t> vertex;  // 3 axes × 9³, -1: no vertex
  int32_t& at(int axis, int i, int j, int k) { return vertex[size_t(((axis * 9 + i + 1) * 9 + j + 1) * 9 + k + 1)]; }
  int32_t at(int axis, int i, int j, int k) const {
    return vertex[size_t(((axis * 9 + i + 1) * 9 + j + 1) * 9 + k + 1)];
  }
};

}  // namespace

void meshBlocks(const std::vector<MeshBlock>& blocks, double voxel, float band, SurfaceMesh& mesh) {
  const CubeTable& table = cubeTable();
  const size_t nb = blocks.size();
  std::vector<EdgeTable> edges(nb);
  std::vector<std::vector<std::array<float, 6>>> vertices(nb);  // position (voxels), velocity
  const int unit[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};

  ParallelFailure failure;  // an exception in the OpenMP regions, rethrown after them

  // The crossing edges each block owns, and their vertices.
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t n = 0; n < nb; ++n) try {
    const Around around{blocks, blocks[n]};
    float P[1000];
    around.pad(P);
    EdgeTable& owned = edges[n];
    owned.vertex.assign(3 * 9 * 9 * 9, -1);
    auto& verts = vertices[n];
    verts.reserve(256);
    for (int axis = 0; axis < 3; ++axis)
      for (int i = -1; i < kB; ++i)
        for (int j = -1; j < kB; ++j)
          for (int k = -1; k < kB; ++k) {
            const int u[3] = {i + unit[axis][0], j + unit[axis][1], k + unit[axis][2]};
            const float a = P[Around::padded(i, j, k)], b = P[Around::padded(u[0], u[1], u[2])];
            if ((a < 0) == (b < 0)) continue;
            const int lower[3] = {i, j, k};
            bool own = true;
            for (int d = 0; d < 3 && own; ++d)
              if (lower[d] < 0)  // an orphan: along this axis only, from a neighbour without values
                own = d == axis && !around.crossed(-unit[d][0], -unit[d][1], -unit[d][2]);
            if (!own) continue;
            const float t = std::clamp(a / (a - b), 0.0f, 1.0f);
            std::array<float, 6> v{float(i), float(j), float(k), 0, 0, 0};
            v[size_t(axis)] += t;
            // A voxel outside the band may have no particle near it: its velocity is no one's.
            const float* va = around.velocity(i, j, k);
            const float* vb = around.velocity(u[0], u[1], u[2]);
            if (va && vb && std::abs(a) >= band) va = nullptr;
            else if (va && vb && std::abs(b) >= band) vb = nullptr;
            for (int d = 0; d < 3; ++d)
              v[size_t(3 + d)] = va && vb ? va[d] + t * (vb[d] - va[d]) : va ? va[d] : vb ? vb[d] : 0.0f;
            owned.at(axis, i, j, k) = int32_t(verts.size());
            verts.push_back(v);
          }
  } catch (...) {
    failure.keep();
  }
  failure.rethrow();
  std::vector<size_t> first(nb + 1, 0);
  for (size_t n = 0; n < nb; ++n) first[n + 1] = first[n] + vertices[n].size();
  mesh.points.resize(first[nb]);
  mesh.velocities.resize(first[nb]);
#pragma omp parallel for schedule(static)
  for (size_t n = 0; n < nb; ++n)
    for (size_t v = 0; v < vertices[n].size(); ++v) {
      const auto& p = vertices[n][v];
      const int64_t* o = blocks[n].block;
      mesh.points[first[n] + v] = {float((double(o[0] * kB) + p[0]) * voxel), float((double(o[1] * kB) + p[1]) * voxel),
                                   float((double(o[2] * kB) + p[2]) * voxel)};
      mesh.velocities[first[n] + v] = {p[3], p[4], p[5]};
    }

  // The cells each block owns: those whose first corner in a block with
  // values (corner 0 first) is in it.
  std::vector<std::vector<std::array<uint32_t, 3>>> triangles(nb);
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t n = 0; n < nb; ++n) try {
    const Around around{blocks, blocks[n]};
    float P[1000];
    around.pad(P);
    auto& tris = triangles[n];
    tris.reserve(2 * vertices[n].size() + 16);
    // The global index of the vertex on the edge from local voxel (i, j, k) along axis.
    const auto vertexOf = [&](int i, int j, int k, int axis) -> int64_t {
      int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
      int32_t owner = di || dj || dk ? blocks[n].neighbour[neighbourOf(di, dj, dk)] : int32_t(n);
      if (owner < 0) {  // the lower voxel's block has no values: an orphan of the upper voxel's block
        const int u[3] = {i + unit[axis][0], j + unit[axis][1], k + unit[axis][2]};
        di = blockOffset(u[0]), dj = blockOffset(u[1]), dk = blockOffset(u[2]);
        owner = di || dj || dk ? blocks[n].neighbour[neighbourOf(di, dj, dk)] : int32_t(n);
        if (owner < 0) return -1;
        i = u[0] - di * kB - unit[axis][0], j = u[1] - dj * kB - unit[axis][1], k = u[2] - dk * kB - unit[axis][2];
      } else {
        i -= di * kB, j -= dj * kB, k -= dk * kB;
      }
      const int32_t v = edges[size_t(owner)].at(axis, i, j, k);
      return v < 0 ? -1 : int64_t(first[size_t(owner)]) + v;
    };
    for (int i = -1; i < kB; ++i)
      for (int j = -1; j < kB; ++j)
        for (int k = -1; k < kB; ++k) {
          int config = 0;
          const int base = Around::padded(i, j, k);
          for (int c = 0; c < 8; ++c) config |= (P[base + (c & 1) * 100 + ((c >> 1) & 1) * 10 + ((c >> 2) & 1)] < 0) << c;
          if (config == 0 || config == 255) continue;
          if (i < 0 || j < 0 || k < 0) {
            // The first corner, in corner order, whose block has values owns the cell.
            bool mine = false;
            for (int c = 0; c < 8; ++c) {
              const int di = blockOffset(i + (c & 1)), dj = blockOffset(j + ((c >> 1) & 1)),
                        dk = blockOffset(k + ((c >> 2) & 1));
              if (!di && !dj && !dk) {
                mine = true;
                break;
              }
              if (around.crossed(di, dj, dk)) break;
            }
            if (!mine) continue;
          }
          const std::vector<uint8_t>& cases = table.tri[config];
          for (size_t t = 0; t < cases.size(); t += 3) {
            std::array<uint32_t, 3> tri{};
            bool whole = true;
            for (int v = 0; v < 3 && whole; ++v) {
              const int e = cases[t + size_t(v)], low = table.edgeLow[e];
              const int64_t index = vertexOf(i + (low & 1), j + ((low >> 1) & 1), k + ((low >> 2) & 1), table.edgeAxis[e]);
              whole = index >= 0;
              tri[size_t(v)] = uint32_t(index);
            }
            if (whole) tris.push_back(tri);
          }
        }
  } catch (...) {
    failure.keep();
  }
  failure.rethrow();
  std::vector<size_t> firstTriangle(nb + 1, 0);
  for (size_t n = 0; n < nb; ++n) firstTriangle[n + 1] = firstTriangle[n] + triangles[n].size();
  mesh.triangles.resize(firstTriangle[nb]);
#pragma omp parallel for schedule(static)
  for (size_t n = 0; n < nb; ++n) {
    std::copy(triangles[n].begin(), triangles[n].end(), mesh.triangles.begin() + std::ptrdiff_t(firstTriangle[n]));
    std::vector<std::array<uint32_t, 3>>().swap(triangles[n]);
  }
}

}  // namespace fc
