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
  int edgeOf[8][3];  // the edge from corner c along an axis (c's bit clear)
  // Configuration c's triangles, 3 edges each, at edge[start[c]] on.
  uint16_t start[257];
  std::vector<uint8_t> edge;
  uint32_t triangles(int c) const { return uint32_t(start[c + 1] - start[c]) / 3; }
  const uint8_t* edges(int c) const { return edge.data() + start[c]; }
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
      t.start[config] = uint16_t(t.edge.size());
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
          t.edge.insert(t.edge.end(), {uint8_t(loop[0]), uint8_t(loop[k]), uint8_t(loop[k + 1])});
      }
    }
    t.start[256] = uint16_t(t.edge.size());
    return t;
  }();
  return table;
}


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
  const float* velocityAt(int i, int j, int k) const {
    const int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
    const float* v = velocity[neighbourSlot(di, dj, dk)];
    return v ? v + 3 * ((withinBlock(i, di) << 6) | (withinBlock(j, dj) << 3) | withinBlock(k, dk)) : nullptr;
  }
  float phiAt(int i, int j, int k) const {
    const int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
    const int n = neighbourSlot(di, dj, dk);
    return phi[n] ? phi[n][(withinBlock(i, di) << 6) | (withinBlock(j, dj) << 3) | withinBlock(k, dk)] : constant[n];
  }
  // The inside bits of every row along z over [-1, 8]³ (bit t: z = t - 1),
  // from the blocks' own rows (inside[n]: 8 bits per row, bit k: z = k).
  void rows(const uint8_t* const* inside, uint16_t (&out)[kB + 2][kB + 2]) const {
    const auto rowOf = [&](int n, int row) -> uint32_t {
      return inside[n] ? inside[n][row] : constant[n] < 0 ? 0xFFu : 0u;
    };
    for (int i = -1; i <= kB; ++i)
      for (int j = -1; j <= kB; ++j) {
        const int di = blockOffset(i), dj = blockOffset(j);
        const int row = (withinBlock(i, di) << 3) | withinBlock(j, dj);
        const uint32_t below = rowOf(neighbourSlot(di, dj, -1), row) >> (kB - 1);
        const uint32_t middle = rowOf(neighbourSlot(di, dj, 0), row), above = rowOf(neighbourSlot(di, dj, 1), row) & 1u;
        out[i + 1][j + 1] = uint16_t(below | middle << 1 | above << (kB + 1));
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
  // Each word's count of the set bits before it; returns them all.
  uint32_t rank() {
    uint16_t n = 0;
    for (int w = 0; w < kWords; ++w) before[w] = n, n = uint16_t(n + __builtin_popcountll(bits[w]));
    return n;
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
  std::vector<uint32_t> vertexCount(nb), triangleCount(nb);
  ParallelFailure failure;  // an exception in the OpenMP regions, rethrown after them

  // Whether block b owns cell (i, j, k) of its padded range: the first
  // corner, in corner order, whose block has values.
  const auto owns = [](const MeshBlock& b, int i, int j, int k) {
    if (i >= 0 && j >= 0 && k >= 0) return true;
    for (int corner = 0; corner < 8; ++corner) {
      const int di = blockOffset(i + (corner & 1)), dj = blockOffset(j + ((corner >> 1) & 1)),
                dk = blockOffset(k + ((corner >> 2) & 1));
      if (!di && !dj && !dk) return true;
      if (b.neighbour[neighbourSlot(di, dj, dk)] >= 0) return false;
    }
    return false;
  };
  // Each cell of the block's padded range with a configuration other than
  // all inside or all outside: f(i, j, k, configuration). A row of 9 cells
  // along z at a time: the corners' bits at z and z + 1 of the four rows.
  const auto forEachCell = [](const uint16_t (&row)[kB + 2][kB + 2], auto&& f) {
    for (int i = -1; i < kB; ++i)
      for (int j = -1; j < kB; ++j) {
        const uint32_t r00 = row[i + 1][j + 1], r10 = row[i + 2][j + 1], r01 = row[i + 1][j + 2],
                       r11 = row[i + 2][j + 2];
        const uint32_t any = r00 | r10 | r01 | r11, all = r00 & r10 & r01 & r11;
        // Bit t: the cell at z = t - 1, whose corners are bits t and t + 1.
        uint32_t mixed = ((any | any >> 1) & ~(all & all >> 1)) & 0x1FFu;
        for (; mixed; mixed &= mixed - 1) {
          const int t = __builtin_ctz(mixed);
          const uint32_t c = ((r00 >> t) & 1u) | ((r10 >> t) & 1u) << 1 | ((r01 >> t) & 1u) << 2 |
                             ((r11 >> t) & 1u) << 3 | ((r00 >> (t + 1)) & 1u) << 4 | ((r10 >> (t + 1)) & 1u) << 5 |
                             ((r01 >> (t + 1)) & 1u) << 6 | ((r11 >> (t + 1)) & 1u) << 7;
          f(i, j, t - 1, int(c));
        }
      }
  };

  const auto insideOf = [&](const MeshBlock& b, const uint8_t* (&inside)[27]) {
    for (int q = 0; q < 27; ++q) inside[q] = b.neighbour[q] >= 0 ? blocks[size_t(b.neighbour[q])].inside : nullptr;
  };

  // Pass 1: each block's inside bits and the crossing edges it owns (those
  // whose lower voxel is in it, and the orphans whose lower voxel is in a
  // neighbour without values, along that axis only); how many vertices and
  // triangles it makes.
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t n = 0; n < nb; ++n) try {
    const MeshBlock& b = blocks[n];
    const Around around(blocks, b);
    BlockState& st = state[n];
    st.edges.clear();
    const uint8_t* inside[27];
    insideOf(b, inside);
    around.rows(inside, st.row);
    // An edge crosses where its two ends' inside bits differ: 9 edges of a
    // row at a time.
    uint16_t(&row)[kB + 2][kB + 2] = st.row;
    const auto orphansAlong = [&](int axis) {
      int dir[3] = {0, 0, 0};
      dir[axis] = -1;
      return !around.crossed[neighbourSlot(dir[0], dir[1], dir[2])];
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
    vertexCount[n] = st.edges.rank();
    uint32_t triangles = 0;
    forEachCell(row, [&](int i, int j, int k, int c) {
      if (owns(b, i, j, k)) triangles += table.triangles(c);
    });
    triangleCount[n] = triangles;
  } catch (...) {
    failure.keep();
  }
  failure.rethrow();

  // Where each block's vertices and triangles go; the mesh's arrays are
  // first touched by the threads that fill them.
  std::vector<size_t> first(nb + 1, 0), firstTriangle(nb + 1, 0);
  for (size_t n = 0; n < nb; ++n) {
    first[n + 1] = first[n] + vertexCount[n];
    firstTriangle[n + 1] = firstTriangle[n] + triangleCount[n];
  }
  mesh.points.resize(first[nb]);
  mesh.velocities.resize(first[nb]);
  mesh.triangles.resize(firstTriangle[nb]);
  constexpr uint32_t kNone = ~uint32_t(0);  // a triangle with a vertex no block owns, removed below
  size_t dropped = 0;

  // Pass 2: the vertices, in the order of their bits (the rank is the
  // index), and the triangles of the cells each block owns.
  const int unit[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : dropped)
  for (size_t n = 0; n < nb; ++n) try {
    const MeshBlock& b = blocks[n];
    const Around around(blocks, b);
    const BlockState& st = state[n];
    const int64_t* o = b.block;
    size_t v = first[n];
    for (int w = 0; w < EdgeBits::kWords; ++w)
      for (uint64_t word = st.edges.bits[w]; word; word &= word - 1, ++v) {
        const int bit = w * 64 + __builtin_ctzll(word);
        const int axis = bit / 729, rest = bit % 729;
        const int i = rest / 81 - 1, j = (rest / 9) % 9 - 1, k = rest % 9 - 1;
        const int ui = i + (axis == 0), uj = j + (axis == 1), uk = k + (axis == 2);
        const float a = around.phiAt(i, j, k), c = around.phiAt(ui, uj, uk);
        const float t = std::clamp(a / (a - c), 0.0f, 1.0f);
        float p[3] = {float(i), float(j), float(k)};
        p[axis] += t;
        mesh.points[v] = {float((double(o[0] * kB) + p[0]) * voxel), float((double(o[1] * kB) + p[1]) * voxel),
                          float((double(o[2] * kB) + p[2]) * voxel)};
        // A voxel outside the band may have no particle near it: its velocity is no one's.
        const float* va = around.velocityAt(i, j, k);
        const float* vb = around.velocityAt(ui, uj, uk);
        if (va && vb && std::abs(a) >= band) va = nullptr;
        else if (va && vb && std::abs(c) >= band) vb = nullptr;
        auto& out = mesh.velocities[v];
        for (int d = 0; d < 3; ++d) out[size_t(d)] = va && vb ? va[d] + t * (vb[d] - va[d]) : va ? va[d] : vb ? vb[d] : 0.0f;
      }
    // The global index of the vertex on the edge from local voxel (i, j, k) along axis.
    const auto vertexOf = [&](int i, int j, int k, int axis) -> uint32_t {
      int di = blockOffset(i), dj = blockOffset(j), dk = blockOffset(k);
      int32_t owner = di || dj || dk ? b.neighbour[neighbourSlot(di, dj, dk)] : int32_t(n);
      if (owner < 0) {  // the lower voxel's block has no values: an orphan of the upper voxel's block
        const int u[3] = {i + unit[axis][0], j + unit[axis][1], k + unit[axis][2]};
        di = blockOffset(u[0]), dj = blockOffset(u[1]), dk = blockOffset(u[2]);
        owner = di || dj || dk ? b.neighbour[neighbourSlot(di, dj, dk)] : int32_t(n);
        if (owner < 0) return kNone;
        i = u[0] - di * kB - unit[axis][0], j = u[1] - dj * kB - unit[axis][1], k = u[2] - dk * kB - unit[axis][2];
      } else {
        i -= di * kB, j -= dj * kB, k -= dk * kB;
      }
      const int32_t index = state[size_t(owner)].edges.vertex(EdgeBits::index(axis, i, j, k));
      return index < 0 ? kNone : uint32_t(first[size_t(owner)] + size_t(index));
    };
    auto* tri = mesh.triangles.data() + firstTriangle[n];
    forEachCell(st.row, [&](int i, int j, int k, int c) {
      if (!owns(b, i, j, k)) return;
      const uint8_t* edges = table.edges(c);
      for (uint32_t t = 0; t < table.triangles(c); ++t, ++tri) {
        for (int q = 0; q < 3; ++q) {
          const int e = edges[3 * t + uint32_t(q)], low = table.edgeLow[e];
          (*tri)[size_t(q)] = vertexOf(i + (low & 1), j + ((low >> 1) & 1), k + ((low >> 2) & 1), table.edgeAxis[e]);
        }
        dropped += (*tri)[0] == kNone || (*tri)[1] == kNone || (*tri)[2] == kNone;
      }
    });
  } catch (...) {
    failure.keep();
  }
  failure.rethrow();
  if (dropped) {
    const auto whole = [](const std::array<uint32_t, 3>& t) { return t[0] != kNone && t[1] != kNone && t[2] != kNone; };
    mesh.triangles.erase(std::stable_partition(mesh.triangles.begin(), mesh.triangles.end(), whole),
                         mesh.triangles.end());
  }
}

}  // namespace fc
