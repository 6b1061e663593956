// Marching cubes [LC87] over the crossed blocks of a level set: the case
// table, the owner of every cell and grid edge, and the mesh.
#include "surface/block_mesher.h"

#include "core/parallel_failure.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <vector>

namespace fc {

namespace {

constexpr int kB = 8;

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
int padded(int i, int j, int k) { return ((i + 1) * 10 + (j + 1)) * 10 + (k + 1); }
constexpr int kPadded = 1000;  // [-1, 8]³

// A block's view of the voxels around it, local coordinates in [-1, 8]:
// each neighbour's values (or the constant it holds) and velocities.
struct Around {
  const float* phi[27];
  const float* velocity[27];
  float constant[27];
  bool crossed[27];
  Around(const std::vector<MeshBlock>& blocks, const MeshBlock& b) {
    for (int n = 0; n < 27; ++n) {
      const int32_t other = b.neighbour[n];
      crossed[n] = other >= 0;
      phi[n] = other >= 0 ? blocks[size_t(other)].phi : nullptr;
      velocity[n] = other >= 0 ? blocks[size_t(other)].velocity : nullptr;
      constant[n] = b.constant[n];
    }
  }
  static int local(int i, int d) { return i - d * kB; }
  const float* velocityAt(int i, int j, int k) const {
    const int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
    const float* v = velocity[neighbourOf(di, dj, dk)];
    return v ? v + 3 * ((local(i, di) << 6) | (local(j, dj) << 3) | local(k, dk)) : nullptr;
  }
  // Every value in [-1, 8]³, at padded(i, j, k): a row along k at a time.
  void pad(float* out) const {
    for (int i = -1; i <= kB; ++i)
      for (int j = -1; j <= kB; ++j) {
        const int di = blockOffset(i), dj = blockOffset(j);
        const int li = local(i, di), lj = local(j, dj), row = (li << 6) | (lj << 3);
        float* o = out + padded(i, j, -1);
        const int below = neighbourOf(di, dj, -1), middle = neighbourOf(di, dj, 0), above = neighbourOf(di, dj, 1);
        o[0] = phi[below] ? phi[below][row + kB - 1] : constant[below];
        if (phi[middle]) std::copy_n(phi[middle] + row, kB, o + 1);
        else std::fill_n(o + 1, kB, constant[middle]);
        o[kB + 1] = phi[above] ? phi[above][row] : constant[above];
      }
  }
};

// The crossing grid edges a block owns, as a bit set over (axis, lower
// voxel in [-1, 7]³) whose rank is the vertex's index in the block.
struct EdgeBits {
  static constexpr int kBits = 3 * 729, kWords = (kBits + 63) / 64;
  uint64_t bits[kWords];
  uint16_t before[kWords];  // set bits in the words before
  void clear() { std::fill_n(bits, kWords, uint64_t(0)); }
  static int index(int axis, int i, int j, int k) { return ((axis * 9 + i + 1) * 9 + j + 1) * 9 + k + 1; }
  // The 9 edges of a row along z from bit b (z = -1) on.
  void setRow(int b, uint32_t nine) {
    if (!nine) return;
    const int w = b >> 6, o = b & 63;
    bits[w] |= uint64_t(nine) << o;
    if (o > 64 - 9) bits[w + 1] |= uint64_t(nine) >> (64 - o);
  }
  void rank() {
    uint16_t n = 0;
    for (int w = 0; w < kWords; ++w) before[w] = n, n = uint16_t(n + __builtin_popcountll(bits[w]));
  }
  int32_t vertex(int b) const {
    const uint64_t word = bits[b >> 6], bit = uint64_t(1) << (b & 63);
    if (!(word & bit)) return -1;
    return int32_t(before[b >> 6]) + __builtin_popcountll(word & (bit - 1));
  }
};

// One block's inside bits over [-1, 8]³ (1: phi < 0), a row along z per
// mask (bit t: z = t - 1), and the edges it owns. Filled by the threads:
// nothing to zero on one.
struct BlockState {
  uint16_t row[kB + 2][kB + 2];
  EdgeBits edges;
};

}  // namespace

void meshBlocks(const std::vector<MeshBlock>& blocks, double voxel, float band, SurfaceMesh& mesh) {
  const CubeTable& table = cubeTable();
  const size_t nb = blocks.size();
  std::unique_ptr<BlockState[]> state(new BlockState[nb]);
  std::vector<std::vector<std::array<float, 6>>> vertices(nb);  // position (voxels), velocity

  ParallelFailure failure;  // an exception in the OpenMP regions, rethrown after them

  // The crossing edges each block owns: those whose lower voxel is in it,
  // and the orphans whose lower voxel is in a neighbour without values
  // (along that axis only). Their vertices, in the order of their bits.
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t n = 0; n < nb; ++n) try {
    const Around around(blocks, blocks[n]);
    float P[kPadded];
    around.pad(P);
    BlockState& st = state[n];
    st.edges.clear();
    auto& verts = vertices[n];
    verts.reserve(128);
    // An edge crosses where its two ends' inside bits differ: 9 edges of a
    // row at a time.
    uint16_t(&row)[kB + 2][kB + 2] = st.row;
    for (int i = 0; i < kB + 2; ++i)
      for (int j = 0; j < kB + 2; ++j) {
        const float* r = P + (i * 10 + j) * 10;
        uint32_t m = 0;
        for (int t = 0; t < kB + 2; ++t) m |= uint32_t(r[t] < 0) << t;
        row[i][j] = uint16_t(m);
      }
    const auto orphansAlong = [&](int axis) {
      int dir[3] = {0, 0, 0};
      dir[axis] = -1;
      return !around.crossed[neighbourOf(dir[0], dir[1], dir[2])];
    };
    const int from[3] = {orphansAlong(0) ? -1 : 0, orphansAlong(1) ? -1 : 0, orphansAlong(2) ? -1 : 0};
    constexpr uint32_t inBlock = 0x1FE, withOrphan = 0x1FF;  // z = 0..7; z = -1..7
    for (int i = from[0]; i < kB; ++i)
      for (int j = 0; j < kB; ++j)
        st.edges.setRow(EdgeBits::index(0, i, j, -1), uint32_t(row[i + 1][j + 1] ^ row[i + 2][j + 1]) & inBlock);
    for (int i = 0; i < kB; ++i)
      for (int j = from[1]; j < kB; ++j)
        st.edges.setRow(EdgeBits::index(1, i, j, -1), uint32_t(row[i + 1][j + 1] ^ row[i + 1][j + 2]) & inBlock);
    for (int i = 0; i < kB; ++i)
      for (int j = 0; j < kB; ++j)
        st.edges.setRow(EdgeBits::index(2, i, j, -1),
                        uint32_t(row[i + 1][j + 1] ^ (row[i + 1][j + 1] >> 1)) & (from[2] < 0 ? withOrphan : inBlock));
    st.edges.rank();
    // The vertices, in bit order: the rank is the index.
    for (int w = 0; w < EdgeBits::kWords; ++w)
      for (uint64_t word = st.edges.bits[w]; word; word &= word - 1) {
        const int bit = w * 64 + __builtin_ctzll(word);
        const int axis = bit / 729, rest = bit % 729;
        const int i = rest / 81 - 1, j = (rest / 9) % 9 - 1, k = rest % 9 - 1;
        const int ui = i + (axis == 0), uj = j + (axis == 1), uk = k + (axis == 2);
        const float a = P[padded(i, j, k)], b = P[padded(ui, uj, uk)];
        const float t = std::clamp(a / (a - b), 0.0f, 1.0f);
        std::array<float, 6> vx{float(i), float(j), float(k), 0, 0, 0};
        vx[size_t(axis)] += t;
        // A voxel outside the band may have no particle near it: its velocity is no one's.
        const float* va = around.velocityAt(i, j, k);
        const float* vb = around.velocityAt(ui, uj, uk);
        if (va && vb && std::abs(a) >= band) va = nullptr;
        else if (va && vb && std::abs(b) >= band) vb = nullptr;
        for (int d = 0; d < 3; ++d)
          vx[size_t(3 + d)] = va && vb ? va[d] + t * (vb[d] - va[d]) : va ? va[d] : vb ? vb[d] : 0.0f;
        verts.push_back(vx);
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
  for (size_t n = 0; n < nb; ++n) {
    for (size_t v = 0; v < vertices[n].size(); ++v) {
      const auto& p = vertices[n][v];
      const int64_t* o = blocks[n].block;
      mesh.points[first[n] + v] = {float((double(o[0] * kB) + p[0]) * voxel), float((double(o[1] * kB) + p[1]) * voxel),
                                   float((double(o[2] * kB) + p[2]) * voxel)};
      mesh.velocities[first[n] + v] = {p[3], p[4], p[5]};
    }
    std::vector<std::array<float, 6>>().swap(vertices[n]);
  }

  // The cells each block owns: those whose first corner in a block with
  // values (corner 0 first) is in it.
  std::vector<std::vector<std::array<uint32_t, 3>>> triangles(nb);
  const int unit[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t n = 0; n < nb; ++n) try {
    const MeshBlock& b = blocks[n];
    const uint16_t(&row)[kB + 2][kB + 2] = state[n].row;
    auto& tris = triangles[n];
    tris.reserve(2 * (first[n + 1] - first[n]) + 16);
    // The global index of the vertex on the edge from local voxel (i, j, k) along axis.
    const auto vertexOf = [&](int i, int j, int k, int axis) -> int64_t {
      int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
      int32_t owner = di || dj || dk ? b.neighbour[neighbourOf(di, dj, dk)] : int32_t(n);
      if (owner < 0) {  // the lower voxel's block has no values: an orphan of the upper voxel's block
        const int u[3] = {i + unit[axis][0], j + unit[axis][1], k + unit[axis][2]};
        di = blockOffset(u[0]), dj = blockOffset(u[1]), dk = blockOffset(u[2]);
        owner = di || dj || dk ? b.neighbour[neighbourOf(di, dj, dk)] : int32_t(n);
        if (owner < 0) return -1;
        i = u[0] - di * kB - unit[axis][0], j = u[1] - dj * kB - unit[axis][1], k = u[2] - dk * kB - unit[axis][2];
      } else {
        i -= di * kB, j -= dj * kB, k -= dk * kB;
      }
      const int32_t v = state[size_t(owner)].edges.vertex(EdgeBits::index(axis, i, j, k));
      return v < 0 ? -1 : int64_t(first[size_t(owner)]) + v;
    };
    for (int i = -1; i < kB; ++i)
      for (int j = -1; j < kB; ++j) {
        // The row's configurations, one cell per k.
        const uint32_t r00 = row[i + 1][j + 1], r10 = row[i + 2][j + 1], r01 = row[i + 1][j + 2],
                       r11 = row[i + 2][j + 2];
        const auto at = [](uint32_t r, int t) { return (r >> t) & 1u; };
        uint8_t config[kB + 1];
        for (int k = 0; k <= kB; ++k)
          config[k] = uint8_t(at(r00, k) | at(r10, k) << 1 | at(r01, k) << 2 | at(r11, k) << 3 | at(r00, k + 1) << 4 |
                              at(r10, k + 1) << 5 | at(r01, k + 1) << 6 | at(r11, k + 1) << 7);
        for (int k = -1; k < kB; ++k) {
          const int c = config[k + 1];
          if (c == 0 || c == 255) continue;
          if (i < 0 || j < 0 || k < 0) {
            // The first corner, in corner order, whose block has values owns the cell.
            bool mine = false;
            for (int corner = 0; corner < 8; ++corner) {
              const int di = blockOffset(i + (corner & 1)), dj = blockOffset(j + ((corner >> 1) & 1)),
                        dk = blockOffset(k + ((corner >> 2) & 1));
              if (!di && !dj && !dk) {
                mine = true;
                break;
              }
              if (b.neighbour[neighbourOf(di, dj, dk)] >= 0) break;
            }
            if (!mine) continue;
          }
          const std::vector<uint8_t>& cases = table.tri[c];
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
