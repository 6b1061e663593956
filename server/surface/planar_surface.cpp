// A 2D liquid's surface in its plane z = 0. The field is [ZB05]'s, as in
// 3D, on the nodes of 8 × 8 tiles within the kernel's reach of a particle;
// a 3-tap box filter per axis smooths it. Marching squares [LC87] gives the
// outline (closed loops, the liquid on their left) and the area: a cell
// the outline crosses is its inside polygon, a full cell two triangles,
// and a tile whose cells are all full one fan around its centre, with the
// nodes its non-full neighbours use on its edges, so that the area has no
// T-junction and its boundary is exactly the outline. The slab mesh is that
// area at z = ±thickness/2 joined by walls along the outline; the level set
// is the same prism, max(phi_2D, |z| - thickness/2).
//
// References (docs/references.md):
//   [ZB05] Y. Zhu, R. Bridson. Animating sand as a fluid. ACM TOG
//          (SIGGRAPH) 24(3), 2005. DOI 10.1145/1073204.1073298
//   [LC87] W. E. Lorensen, H. E. Cline. Marching cubes: a high resolution 3D
//          surface construction algorithm. ACM SIGGRAPH Computer
//          Graphics 21(4), 1987. DOI 10.1145/37402.37422
#include "surface/planar_surface.h"

#include "core/parallel_failure.h"
#include "surface/volumes.h"

#include <array>
#include <chrono>
#include <cstring>
#include <memory>
#include <stdexcept>

namespace fc::surface_detail {

namespace {

constexpr int kT = kBlock;       // nodes per tile side
constexpr int kNodes = kT * kT;  // a tile's nodes, index (i << 3) | j

double msSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

// Per-node sums of one tile: the weights, the weighted positions and
// velocities; a row of 8 nodes is one vector.
struct alignas(64) ColumnSums {
  float w[kNodes], x[kNodes], y[kNodes], vx[kNodes], vy[kNodes];
};

// [ZB05] Sec. 6, scattered: every particle adds k(s), k(s) x_i and k(s) v_i
// to the nodes of its kernel disc, a row of the tile at a time.
void sumTile(const Points& g, float rv, ColumnSums& s) {
  std::memset(&s, 0, sizeof s);
  const float rv2 = rv * rv, inv = 1.0f / rv2;
  for (size_t n = 0; n < g.size(); ++n) {
    const float ux = g.x[n], uy = g.y[n], ax = g.vx[n], ay = g.vy[n];
    const int i0 = std::max(0, int(std::ceil(ux - rv))), i1 = std::min(kT - 1, int(std::floor(ux + rv)));
    for (int i = i0; i <= i1; ++i) {
      const float dx = float(i) - ux, dx2 = dx * dx;
      if (dx2 >= rv2) continue;
      float* __restrict w = s.w + kT * i;
      float* __restrict x = s.x + kT * i;
      float* __restrict y = s.y + kT * i;
      float* __restrict vx = s.vx + kT * i;
      float* __restrict vy = s.vy + kT * i;
#pragma omp simd
      for (int j = 0; j < kT; ++j) {
        const float dy = float(j) - uy;
        const float c = kernelWeight(dx2 + dy * dy, inv);
        w[j] += c, x[j] += c * ux, y[j] += c * uy, vx[j] += c * ax, vy[j] += c * ay;
      }
    }
  }
}

// One tile's field (m, clamped to [-band, band]) and mean velocity (m/s).
struct TileField {
  float phi[kNodes], vx[kNodes], vy[kNodes];
  uint64_t empty = 0;  // bit n: no particle within the kernel's reach of node n
};

// The tiles that hold values, in key order, and where each is.
struct Tiles {
  std::vector<uint64_t> keys;
  std::vector<TileField> field;
  KeyMap index{16};
  std::vector<uint8_t> full;  // every cell of the tile inside (its nodes and the next tiles' first ones)
  float band = 0;

  std::vector<std::array<int32_t, 9>> ring;  // each tile's neighbours and itself, (di + 1) * 3 + (dj + 1)

  int32_t at(int64_t ti, int64_t tj) const {
    const uint32_t n = index.find(key(ti, tj, 0));
    return n == KeyMap::kMissing ? -1 : int32_t(n);
  }
  // Tile (qi, qj), seen from tile t: its ring when it is in it.
  int32_t near(size_t t, int64_t qi, int64_t qj) const {
    const int64_t di = qi - ti(t), dj = qj - tj(t);
    if (di >= -1 && di <= 1 && dj >= -1 && dj <= 1) return ring[t][size_t((di + 1) * 3 + (dj + 1))];
    return at(qi, qj);
  }
  void findRings() {
    ring.resize(keys.size());
#pragma omp parallel for schedule(static)
    for (size_t t = 0; t < keys.size(); ++t)
      for (int di = -1; di <= 1; ++di)
        for (int dj = -1; dj <= 1; ++dj) ring[t][size_t((di + 1) * 3 + (dj + 1))] = at(ti(t) + di, tj(t) + dj);
  }
  int64_t ti(size_t t) const { return unkey(keys[t], 0); }
  int64_t tj(size_t t) const { return unkey(keys[t], 1); }
  float value(int64_t gi, int64_t gj) const {
    const int32_t t = at(gi >> 3, gj >> 3);
    return t < 0 ? band : field[size_t(t)].phi[((gi & 7) << 3) | (gj & 7)];
  }
  bool isFull(size_t from, int64_t ti, int64_t tj) const {
    const int32_t t = near(from, ti, tj);
    return t >= 0 && full[size_t(t)];
  }
};

// A tile's view of the nodes around it, local coordinates in [-1, 8].
struct Neighbourhood {
  int32_t tile[3][3];  // (di + 1, dj + 1): the tile's index, -1 when it holds no values
  float phi[10][10];   // [i + 1][j + 1]
  Neighbourhood(const Tiles& tiles, size_t t) {
    for (int di = -1; di <= 1; ++di)
      for (int dj = -1; dj <= 1; ++dj) tile[di + 1][dj + 1] = tiles.ring[t][size_t((di + 1) * 3 + (dj + 1))];
    for (int i = -1; i <= kT; ++i)
      for (int j = -1; j <= kT; ++j) {
        const int di = i < 0 ? -1 : i >= kT ? 1 : 0, dj = j < 0 ? -1 : j >= kT ? 1 : 0;
        const int32_t n = tile[di + 1][dj + 1];
        phi[i + 1][j + 1] = n < 0 ? tiles.band : tiles.field[size_t(n)].phi[((i - kT * di) << 3) | (j - kT * dj)];
      }
  }
  float operator()(int i, int j) const { return phi[i + 1][j + 1]; }
  // Cell (ci, cj), ci and cj in [-1, 7], from node (ci, cj): all its corners inside.
  bool cellFull(int ci, int cj) const {
    return phi[ci + 1][cj + 1] < 0 && phi[ci + 2][cj + 1] < 0 && phi[ci + 1][cj + 2] < 0 && phi[ci + 2][cj + 2] < 0;
  }
  // Whether the cell is in a run: full, in a tile that is not.
  bool inRun(const Tiles& tiles, int ci, int cj) const {
    const int32_t n = tile[ci < 0 ? 0 : 1][cj < 0 ? 0 : 1];
    return n >= 0 && !tiles.full[size_t(n)] && cellFull(ci, cj);
  }
};

// One pass of the 3-tap box along an axis (0: i, stride 8; 1: j, stride 1);
// a node beyond the tiles with values reads +band, as the outside does.
void boxPass(int axis, const Tiles& tiles, const std::vector<int32_t>& low, const std::vector<int32_t>& high,
             const std::vector<float*>& in, const std::vector<float*>& out) {
  constexpr float third = 1.0f / 3.0f;
  const int stride = axis == 0 ? kT : 1;
#pragma omp parallel for schedule(static)
  for (size_t t = 0; t < in.size(); ++t) {
    const float* src = in[t];
    float* dst = out[t];
    const float* lo = low[t] >= 0 ? in[size_t(low[t])] : nullptr;
    const float* hi = high[t] >= 0 ? in[size_t(high[t])] : nullptr;
    for (int n = 0; n < kNodes; ++n) {
      const int c = axis == 0 ? n >> 3 : n & 7;
      const float a = c > 0 ? src[n - stride] : lo ? lo[n + (kT - 1) * stride] : tiles.band;
      const float b = c < kT - 1 ? src[n + stride] : hi ? hi[n - (kT - 1) * stride] : tiles.band;
      dst[n] = (a + src[n] + b) * third;
    }
  }
}

// A vertex in a tile's local coordinates (nodes, from its first node) and
// its velocity.
struct Vertex {
  float i, j, vx, vy;
};

// The vertices a tile owns: its used inside nodes, and the crossing edges
// whose lower node is its own or in a tile without values (an orphan).
struct OwnedVertices {
  int32_t node[kNodes];
  int32_t edge[2][9][9];  // axis, local lower node + 1
  std::vector<Vertex> vertices;
};

// Cell corners counter-clockwise: (0,0), (1,0), (1,1), (0,1); edge k joins
// corner k to corner k + 1: its lower node and axis.
constexpr int kCornerI[4] = {0, 1, 1, 0}, kCornerJ[4] = {0, 0, 1, 1};
constexpr int kEdgeI[4] = {0, 1, 0, 0}, kEdgeJ[4] = {0, 0, 1, 0}, kEdgeAxis[4] = {0, 1, 0, 1};

}  // namespace

void reconstructPlanar(const Buckets& buckets, double particleRadius, const SurfaceSettings& s, bool withMesh,
                       bool withGrids, Surface& out) {
  const auto t0 = std::chrono::steady_clock::now();
  const double voxel = s.voxelSize * particleRadius;
  const double R = s.kernelRadius * particleRadius;
  const float rs = float(s.surfaceRadius * particleRadius);
  const float rv = float(R / voxel);
  Tiles tiles;
  tiles.band = float(std::max(std::min(3.0 * voxel, double(rs)), 1.5 * voxel));
  const float band = tiles.band;

  // Candidates: the tiles within R of a particle.
  const double tileSize = kT * voxel;
  const int ring = int(std::ceil(R / tileSize));
  const auto tileOf = [&](double x) { return int64_t(std::floor(x / tileSize + 0.5 / kT)); };
  KeyMap occupied(buckets.size() / 8 + 16), candidateIndex(buckets.size() / 8 + 16);
  std::vector<uint64_t> candidates;
  for (size_t n = 0; n < buckets.size(); ++n) {
    const float* p = buckets.pos(n);
    const int64_t ti = tileOf(p[0]), tj = tileOf(p[1]);
    if (!occupied.insert(key(ti, tj, 0), 0).second) continue;  // its ring is in already
    for (int di = -ring; di <= ring; ++di)
      for (int dj = -ring; dj <= ring; ++dj)
        if (candidateIndex.insert(key(ti + di, tj + dj, 0), uint32_t(candidates.size())).second)
          candidates.push_back(key(ti + di, tj + dj, 0));
  }
  std::sort(candidates.begin(), candidates.end());  // the same mesh whatever the particles' order
  out.classifyMs = msSince(t0);

  // The field of every candidate; those with no node inside the band and
  // none inside are dropped (the outside).
  const auto tFill = std::chrono::steady_clock::now();
  std::vector<TileField> fields(candidates.size());
  std::vector<uint8_t> keep(candidates.size(), 0);
  ParallelFailure failure;
#pragma omp parallel
  {
    Gathered g;
    std::unique_ptr<ColumnSums> sums, trailSums;
    try {
      sums = std::make_unique<ColumnSums>();
      trailSums = std::make_unique<ColumnSums>();
    } catch (...) {
      failure.keep();
    }
#pragma omp for schedule(dynamic, 16)
    for (size_t c = 0; c < candidates.size(); ++c) try {
      if (!sums) continue;
      const int64_t ti = unkey(candidates[c], 0), tj = unkey(candidates[c], 1);
      const double origin[3] = {double(ti * kT) * voxel, double(tj * kT) * voxel, 0.0};
      g.from(buckets, origin, voxel, R);
      if (g.size() == 0) continue;
      sumTile(g.real, rv, *sums);
      const bool trails = g.trail.size() > 0;
      if (trails) sumTile(g.trail, rv, *trailSums);
      TileField& f = fields[c];
      bool any = false;
      for (int n = 0; n < kNodes; ++n) {
        const float i = float(n >> 3), j = float(n & 7);
        const auto distance = [&](float w, float x, float y) {
          const float mx = x / w - i, my = y / w - j;
          return float(voxel) * std::sqrt(mx * mx + my * my) - rs;
        };
        float w = sums->w[n], p = band, vx = sums->vx[n], vy = sums->vy[n];
        if (w > 0) p = distance(w, sums->x[n], sums->y[n]);
        if (trails && trailSums->w[n] > 0) {
          // The union of the liquid and its trails, as in 3D.
          w += trailSums->w[n], vx += trailSums->vx[n], vy += trailSums->vy[n];
          p = std::min(p, distance(w, sums->x[n] + trailSums->x[n], sums->y[n] + trailSums->y[n]));
        }
        f.phi[n] = std::min(band, std::max(-band, p));
        f.vx[n] = w > 0 ? vx / w : 0.0f, f.vy[n] = w > 0 ? vy / w : 0.0f;
        if (!(w > 0)) f.empty |= uint64_t(1) << n;
        any |= f.phi[n] < band;
      }
      keep[c] = any;
    } catch (...) {
      failure.keep();
    }
  }
  failure.rethrow();
  for (size_t c = 0; c < candidates.size(); ++c)
    if (keep[c]) {
      if (tiles.keys.size() != c) fields[tiles.keys.size()] = fields[c];
      tiles.index.insert(candidates[c], uint32_t(tiles.keys.size()));
      tiles.keys.push_back(candidates[c]);
    }
  fields.resize(tiles.keys.size());
  fields.shrink_to_fit();
  tiles.field = std::move(fields);
  tiles.findRings();
  const size_t nt = tiles.keys.size();
  out.fillMs = msSince(tFill);

  const auto tSmooth = std::chrono::steady_clock::now();
  if (s.smoothing > 0 && nt > 0) {
    std::vector<int32_t> low[2], high[2];
    for (int axis = 0; axis < 2; ++axis) low[axis].resize(nt), high[axis].resize(nt);
    std::vector<float*> data(nt), scratch(nt);
    std::unique_ptr<float[]> scratchStore(new float[nt * kNodes]);
    for (size_t t = 0; t < nt; ++t) {
      low[0][t] = tiles.ring[t][1], high[0][t] = tiles.ring[t][7];
      low[1][t] = tiles.ring[t][3], high[1][t] = tiles.ring[t][5];
      data[t] = tiles.field[t].phi, scratch[t] = &scratchStore[t * kNodes];
    }
    for (int pass = 0; pass < s.smoothing; ++pass) {
      boxPass(0, tiles, low[0], high[0], data, scratch);
      boxPass(1, tiles, low[1], high[1], scratch, data);
    }
    // A node no particle reaches stays outside: the filter would pull it
    // into the band without a velocity.
#pragma omp parallel for schedule(static)
    for (size_t t = 0; t < nt; ++t)
      for (int n = 0; n < kNodes; ++n)
        if (tiles.field[t].empty >> n & 1) tiles.field[t].phi[n] = band;
  }
  // Which tiles are full: all 81 nodes from their first to the next tiles' first inside.
  tiles.full.assign(nt, 0);
#pragma omp parallel for schedule(static)
  for (size_t t = 0; t < nt; ++t) {
    const Neighbourhood around(tiles, t);
    bool full = true;
    for (int i = 0; i <= kT && full; ++i)
      for (int j = 0; j <= kT && full; ++j) full = around(i, j) < 0;
    tiles.full[t] = full;
  }
  out.smoothMs = msSince(tSmooth);

  // The area: vertices, then each tile's triangles and outline segments.
  const auto tMesh = std::chrono::steady_clock::now();
  // A node is used when inside and a corner of a cell the outline crosses,
  // an end of a run of full cells (the full cells of a row of a tile that
  // is not full), or a corner of a full tile; and the centre of a full tile
  // with a used node inside one of its edges, its fan's hub. Runs and full
  // tiles take every used node on their edges: the area has no T-junction.
  std::vector<uint64_t> usedMask(nt, 0);
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t t = 0; t < nt; ++t) {
    const Neighbourhood around(tiles, t);
    const int64_t ti = tiles.ti(t), tj = tiles.tj(t);
    uint64_t mask = 0;
    for (int i = 0; i < kT; ++i)
      for (int j = 0; j < kT; ++j) {
        if (!(around(i, j) < 0)) continue;
        bool used = !around.cellFull(i - 1, j - 1) || !around.cellFull(i, j - 1) || !around.cellFull(i - 1, j) ||
                    !around.cellFull(i, j);
        for (int cj = j - 1; cj <= j && !used; ++cj) {
          const bool left = around.inRun(tiles, i - 1, cj), right = around.inRun(tiles, i, cj);
          used = left != right || (i == 0 && right);
        }
        if (!used && i == 0 && j == 0)
          used = tiles.isFull(t, ti, tj) || tiles.isFull(t, ti - 1, tj) || tiles.isFull(t, ti, tj - 1) ||
                 tiles.isFull(t, ti - 1, tj - 1);
        if (used) mask |= uint64_t(1) << ((i << 3) | j);
      }
    usedMask[t] = mask;
  }
  const auto usedNode = [&](size_t from, int64_t gi, int64_t gj) {
    const int32_t t = tiles.near(from, gi >> 3, gj >> 3);
    return t >= 0 && (usedMask[size_t(t)] >> (((gi & 7) << 3) | (gj & 7)) & 1);
  };
  // A full tile whose edges have no used node inside them is two triangles.
  std::vector<uint8_t> hub(nt, 0);
#pragma omp parallel for schedule(static)
  for (size_t t = 0; t < nt; ++t) {
    if (!tiles.full[t]) continue;
    const int64_t i0 = tiles.ti(t) * kT, j0 = tiles.tj(t) * kT;
    bool inner = false;
    for (int k = 1; k < kT && !inner; ++k)
      inner = usedNode(t, i0 + k, j0) || usedNode(t, i0 + k, j0 + kT) || usedNode(t, i0, j0 + k) ||
              usedNode(t, i0 + kT, j0 + k);
    hub[t] = inner;
  }

  std::vector<OwnedVertices> owned(nt);
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t t = 0; t < nt; ++t) try {
    const Neighbourhood around(tiles, t);
    const TileField& f = tiles.field[t];
    OwnedVertices& o = owned[t];
    std::fill(&o.node[0], &o.node[0] + kNodes, -1);
    std::fill(&o.edge[0][0][0], &o.edge[0][0][0] + 2 * 81, -1);
    for (int n = 0; n < kNodes; ++n) {
      if (!(usedMask[t] >> n & 1) && !(hub[t] && n == ((kT / 2) << 3 | kT / 2))) continue;
      o.node[n] = int32_t(o.vertices.size());
      o.vertices.push_back({float(n >> 3), float(n & 7), f.vx[n], f.vy[n]});
    }
    // The crossing edges, with the velocity interpolated along them from
    // the end inside the band (a node outside it may have no particle near).
    const auto velocityAt = [&](int i, int j, float& vx, float& vy) {
      const int di = i < 0 ? -1 : i >= kT ? 1 : 0, dj = j < 0 ? -1 : j >= kT ? 1 : 0;
      const int32_t n = around.tile[di + 1][dj + 1];
      if (n < 0) return false;
      const int k = ((i - kT * di) << 3) | (j - kT * dj);
      vx = tiles.field[size_t(n)].vx[k], vy = tiles.field[size_t(n)].vy[k];
      return true;
    };
    for (int axis = 0; axis < 2; ++axis)
      for (int i = -1; i < kT; ++i)
        for (int j = -1; j < kT; ++j) {
          if ((i < 0 && !(axis == 0 && j >= 0 && around.tile[0][1] < 0)) ||
              (j < 0 && !(axis == 1 && i >= 0 && around.tile[1][0] < 0)))
            continue;  // a neighbour's edge, unless an orphan of a tile without values
          const int ui = i + (axis == 0), uj = j + (axis == 1);
          const float a = around(i, j), b = around(ui, uj);
          if ((a < 0) == (b < 0)) continue;
          const float u = std::clamp(a / (a - b), 0.0f, 1.0f);
          float va[2] = {0, 0}, vb[2] = {0, 0};
          bool hasA = velocityAt(i, j, va[0], va[1]), hasB = velocityAt(ui, uj, vb[0], vb[1]);
          if (hasA && hasB && std::abs(a) >= band) hasA = false;
          else if (hasA && hasB && std::abs(b) >= band) hasB = false;
          Vertex v{float(i) + (axis == 0 ? u : 0.0f), float(j) + (axis == 1 ? u : 0.0f), 0.0f, 0.0f};
          for (int d = 0; d < 2; ++d)
            (d ? v.vy : v.vx) = hasA && hasB ? va[d] + u * (vb[d] - va[d]) : hasA ? va[d] : hasB ? vb[d] : 0.0f;
          o.edge[axis][i + 1][j + 1] = int32_t(o.vertices.size());
          o.vertices.push_back(v);
        }
  } catch (...) {
    failure.keep();
  }
  failure.rethrow();
  std::vector<size_t> first(nt + 1, 0);
  for (size_t t = 0; t < nt; ++t) first[t + 1] = first[t] + owned[t].vertices.size();
  const size_t areaVertices = first[nt];

  // The global index of a node's vertex, or of the vertex on the edge from
  // node (gi, gj) along an axis.
  const auto nodeVertex = [&](size_t from, int64_t gi, int64_t gj) -> uint32_t {
    const int32_t t = tiles.near(from, gi >> 3, gj >> 3);
    const int32_t v = t < 0 ? -1 : owned[size_t(t)].node[((gi & 7) << 3) | (gj & 7)];
    if (v < 0) throw std::logic_error("planar surface: a node the area uses has no vertex");
    return uint32_t(first[size_t(t)] + size_t(v));
  };
  const auto edgeVertex = [&](size_t from, int64_t gi, int64_t gj, int axis) -> uint32_t {
    int32_t t = tiles.near(from, gi >> 3, gj >> 3);
    int li = int(gi & 7), lj = int(gj & 7);
    if (t < 0) {  // an orphan of the upper node's tile
      const int64_t ui = gi + (axis == 0), uj = gj + (axis == 1);
      t = tiles.near(from, ui >> 3, uj >> 3);
      li = int(ui & 7) - (axis == 0), lj = int(uj & 7) - (axis == 1);
    }
    const int32_t v = t < 0 ? -1 : owned[size_t(t)].edge[axis][li + 1][lj + 1];
    if (v < 0) throw std::logic_error("planar surface: a crossing the area uses has no vertex");
    return uint32_t(first[size_t(t)] + size_t(v));
  };

  std::vector<std::vector<std::array<uint32_t, 3>>> triangles(nt);
  std::vector<std::vector<std::array<uint32_t, 2>>> segments(nt);  // the outline, the liquid on the left
#pragma omp parallel for schedule(dynamic, 16)
  for (size_t t = 0; t < nt; ++t) try {
    const Neighbourhood around(tiles, t);
    const int64_t ti = tiles.ti(t), tj = tiles.tj(t);
    auto& tris = triangles[t];
    auto& segs = segments[t];
    if (tiles.full[t]) {
      // One fan around the centre through every used node of its edges, or two triangles.
      const int64_t i0 = ti * kT, j0 = tj * kT;
      const int64_t corner[5][2] = {{i0, j0}, {i0 + kT, j0}, {i0 + kT, j0 + kT}, {i0, j0 + kT}, {i0, j0}};
      if (!hub[t]) {
        const uint32_t c[4] = {nodeVertex(t, i0, j0), nodeVertex(t, i0 + kT, j0), nodeVertex(t, i0 + kT, j0 + kT),
                               nodeVertex(t, i0, j0 + kT)};
        tris.push_back({c[0], c[1], c[2]});
        tris.push_back({c[0], c[2], c[3]});
      } else {
        std::vector<uint32_t> rim;
        for (int e = 0; e < 4; ++e) {
          const int64_t di = (corner[e + 1][0] - corner[e][0]) / kT, dj = (corner[e + 1][1] - corner[e][1]) / kT;
          for (int k = 0; k < kT; ++k) {
            const int64_t gi = corner[e][0] + di * k, gj = corner[e][1] + dj * k;
            if (k == 0 || usedNode(t, gi, gj)) rim.push_back(nodeVertex(t, gi, gj));
          }
        }
        const uint32_t centre = nodeVertex(t, i0 + kT / 2, j0 + kT / 2);
        for (size_t k = 0; k < rim.size(); ++k) tris.push_back({centre, rim[k], rim[(k + 1) % rim.size()]});
      }
    }
    for (int ci = -1; ci < kT; ++ci)
      for (int cj = -1; cj < kT; ++cj) {
        const int64_t gi = ti * kT + ci, gj = tj * kT + cj;
        if (ci >= 0 && cj >= 0) {
          if (tiles.full[t]) continue;
        } else {
          // Its first node is in another tile: this tile meshes it only when
          // that tile holds no values and this is the first corner's, in the
          // order (0,0), (1,0), (0,1), (1,1), whose tile does.
          const auto tileOfNode = [&](int i, int j) {
            return around.tile[i < 0 ? 0 : i < kT ? 1 : 2][j < 0 ? 0 : j < kT ? 1 : 2];
          };
          if (tileOfNode(ci, cj) >= 0) continue;
          int32_t owner = -1;
          for (const auto& c : {std::array<int, 2>{1, 0}, {0, 1}, {1, 1}})
            if ((owner = tileOfNode(ci + c[0], cj + c[1])) >= 0) break;
          if (owner != int32_t(t)) continue;
        }
        bool in[4];
        int inside = 0;
        for (int k = 0; k < 4; ++k) inside += in[k] = around(ci + kCornerI[k], cj + kCornerJ[k]) < 0;
        if (inside == 0) continue;
        if (inside == 4) {
          // A run of full cells along the row, from this one: a strip
          // zipped between the used nodes of its lower and upper edges.
          if (ci > 0 && around.inRun(tiles, ci - 1, cj)) continue;  // not its first cell
          int last = ci;
          while (last + 1 < kT && around.inRun(tiles, last + 1, cj)) ++last;
          const int64_t end = ti * kT + last + 1;
          std::vector<std::pair<int64_t, uint32_t>> lower, upper;  // x, vertex
          for (int64_t x = gi; x <= end; ++x) {
            if (x == gi || x == end || usedNode(t, x, gj)) lower.push_back({x, nodeVertex(t, x, gj)});
            if (x == gi || x == end || usedNode(t, x, gj + 1)) upper.push_back({x, nodeVertex(t, x, gj + 1)});
          }
          size_t a = 0, b = 0;
          while (a + 1 < lower.size() || b + 1 < upper.size()) {
            if (b + 1 >= upper.size() || (a + 1 < lower.size() && lower[a + 1].first <= upper[b + 1].first))
              tris.push_back({lower[a].second, lower[a + 1].second, upper[b].second}), ++a;
            else
              tris.push_back({lower[a].second, upper[b + 1].second, upper[b].second}), ++b;
          }
          continue;
        }
        const auto corner = [&](int k) { return nodeVertex(t, gi + kCornerI[k], gj + kCornerJ[k]); };
        const auto crossing = [&](int k) { return edgeVertex(t, gi + kEdgeI[k], gj + kEdgeJ[k], kEdgeAxis[k]); };
        if (inside == 2 && in[0] == in[2]) {
          // A saddle: its two inside corners are kept apart, as the outline's loops expect.
          const int a = in[0] ? 0 : 1, b = a + 2;
          tris.push_back({corner(a), crossing(a), crossing((a + 3) % 4)});
          tris.push_back({corner(b), crossing(b), crossing((b + 3) % 4)});
          segs.push_back({crossing(a), crossing((a + 3) % 4)});
          segs.push_back({crossing(b), crossing((b + 3) % 4)});
          continue;
        }
        // The inside polygon, counter-clockwise: convex, a fan from its first
        // vertex. Where it leaves the liquid, its next edge is the outline's.
        uint32_t poly[6];
        bool exits[6] = {};
        int np = 0;
        for (int k = 0; k < 4; ++k) {
          if (in[k]) poly[np++] = corner(k);
          if (in[k] != in[(k + 1) % 4]) exits[np] = in[k], poly[np++] = crossing(k);
        }
        for (int k = 0; k < np; ++k)
          if (exits[k]) segs.push_back({poly[k], poly[(k + 1) % np]});
        for (int k = 1; k + 1 < np; ++k) tris.push_back({poly[0], poly[k], poly[k + 1]});
      }
  } catch (...) {
    failure.keep();
  }
  failure.rethrow();

  // The vertices' positions (m) and velocities.
  std::vector<std::array<float, 2>> xy(areaVertices), vxy(areaVertices);
#pragma omp parallel for schedule(static)
  for (size_t t = 0; t < nt; ++t) {
    const double oi = double(tiles.ti(t) * kT), oj = double(tiles.tj(t) * kT);
    for (size_t v = 0; v < owned[t].vertices.size(); ++v) {
      const Vertex& p = owned[t].vertices[v];
      xy[first[t] + v] = {float((oi + p.i) * voxel), float((oj + p.j) * voxel)};
      vxy[first[t] + v] = {p.vx, p.vy};
    }
  }

  // The outline's loops, from the segments chained through their shared vertices.
  std::vector<uint32_t> next(areaVertices, UINT32_MAX);
  for (const auto& segs : segments)
    for (const auto& sg : segs) next[sg[0]] = sg[1];
  out.outline.clear();
  {
    std::vector<uint8_t> seen(areaVertices, 0);
    for (uint32_t start = 0; start < areaVertices; ++start) {
      if (next[start] == UINT32_MAX || seen[start]) continue;
      std::vector<std::array<float, 2>> loop;
      for (uint32_t v = start; v != UINT32_MAX && !seen[v]; v = next[v]) {
        seen[v] = 1;
        loop.push_back(xy[v]);
      }
      if (loop.size() >= 3) out.outline.push_back(std::move(loop));
    }
  }

  if (withMesh) {
    // Flat: the area at z = 0. A slab: the area at ±h, the bottom wound the
    // other way, and a wall along each outline segment.
    SurfaceMesh& m = out.mesh;
    const double h = 0.5 * s.thickness2d * particleRadius;
    const bool slab = h > 0;
    const size_t nv = areaVertices;
    m.points.resize(slab ? 2 * nv : nv);
    m.velocities.resize(m.points.size());
#pragma omp parallel for schedule(static)
    for (size_t v = 0; v < nv; ++v) {
      m.points[v] = {xy[v][0], xy[v][1], float(h)};
      m.velocities[v] = {vxy[v][0], vxy[v][1], 0.0f};
      if (slab) m.points[nv + v] = {xy[v][0], xy[v][1], float(-h)}, m.velocities[nv + v] = m.velocities[v];
    }
    // Each tile's triangles at its offset: the top faces, then (a slab) the
    // bottom faces, then the walls, two per outline segment.
    std::vector<size_t> top(nt + 1, 0), wall(nt + 1, 0);
    for (size_t t = 0; t < nt; ++t) top[t + 1] = top[t] + triangles[t].size(), wall[t + 1] = wall[t] + 2 * segments[t].size();
    const size_t areaTriangles = top[nt];
    m.triangles.resize(slab ? 2 * areaTriangles + wall[nt] : areaTriangles);
    const uint32_t b = uint32_t(nv);
#pragma omp parallel for schedule(static)
    for (size_t t = 0; t < nt; ++t) {
      std::copy(triangles[t].begin(), triangles[t].end(), m.triangles.begin() + std::ptrdiff_t(top[t]));
      if (!slab) continue;
      auto* bottom = m.triangles.data() + areaTriangles + top[t];
      for (const auto& tr : triangles[t]) *bottom++ = {tr[0] + b, tr[2] + b, tr[1] + b};
      auto* walls = m.triangles.data() + 2 * areaTriangles + wall[t];
      for (const auto& sg : segments[t]) {
        *walls++ = {sg[0] + b, sg[1] + b, sg[1]};
        *walls++ = {sg[0] + b, sg[1], sg[0]};
      }
    }
  }
  out.meshMs = msSince(tMesh);

  // The level set: the prism max(phi_2D, |z| - h), at least a voxel each
  // side of the plane, as 8³ blocks over the tiles.
  if (withGrids && nt > 0) {
    const auto tGrids = std::chrono::steady_clock::now();
    const double h = std::max(0.5 * s.thickness2d * particleRadius, voxel);
    SurfaceVolumes grids = emptySurfaceVolumes(voxel, band);
    using LeafT = openvdb::FloatTree::LeafNodeType;
    using VLeafT = openvdb::Vec3STree::LeafNodeType;
    const int64_t reach = int64_t(std::ceil((h + band) / voxel));
    const int64_t kz0 = (-reach) >> 3, kz1 = reach >> 3;
    const size_t layers = size_t(kz1 - kz0 + 1);
    enum : uint8_t { None, Inside, Leaf };
    std::vector<uint8_t> kinds(nt * layers, None);
    std::vector<std::unique_ptr<LeafT>> leaves(nt * layers);
    std::vector<std::unique_ptr<VLeafT>> vleaves(nt * layers);
#pragma omp parallel for schedule(dynamic, 16)
    for (size_t n = 0; n < nt * layers; ++n) try {
      const size_t t = n / layers;
      const int64_t kz = kz0 + int64_t(n % layers);
      const TileField& f = tiles.field[t];
      float phi[512];
      bool in = false, outside = false, near = false;
      for (int v = 0; v < 512; ++v) {
        const int i = v >> 6, j = (v >> 3) & 7, k = v & 7;
        const float z = float(std::abs(double(kz * kT + k) * voxel) - h);
        const float p = std::min(band, std::max(-band, std::max(f.phi[(i << 3) | j], z)));
        phi[v] = p;
        in |= p <= -band, outside |= p >= band, near |= std::abs(p) < band;
      }
      if (!near && !(in && outside)) {
        kinds[n] = in ? Inside : None;
        continue;
      }
      const openvdb::Coord o(int(tiles.ti(t) * kT), int(tiles.tj(t) * kT), int(kz * kT));
      auto leaf = std::make_unique<LeafT>(o, band, false);
      auto vleaf = std::make_unique<VLeafT>(o, openvdb::Vec3s(0.0f), false);
      float* dst = leaf->buffer().data();
      openvdb::Vec3s* vel = vleaf->buffer().data();
      for (int v = 0; v < 512; ++v) {
        const bool on = std::abs(phi[v]) < band;
        dst[v] = phi[v];
        leaf->setActiveState(openvdb::Index(v), on);
        vleaf->setActiveState(openvdb::Index(v), on);
        if (on) vel[v] = openvdb::Vec3s(f.vx[v >> 3], f.vy[v >> 3], 0.0f);
      }
      leaves[n] = std::move(leaf), vleaves[n] = std::move(vleaf);
      kinds[n] = Leaf;
    } catch (...) {
      failure.keep();
    }
    failure.rethrow();
    for (size_t n = 0; n < nt * layers; ++n) {
      if (kinds[n] == Inside) {
        const size_t t = n / layers;
        const openvdb::Coord o(int(tiles.ti(t) * kT), int(tiles.tj(t) * kT), int((kz0 + int64_t(n % layers)) * kT));
        grids.surface->tree().addTile(1, o, -band, false);
      } else if (kinds[n] == Leaf) {
        grids.surface->tree().addLeaf(leaves[n].release());
        grids.velocity->tree().addLeaf(vleaves[n].release());
      }
    }
    out.volumes = prunedSurfaceVolumes(std::move(grids));
    out.smoothMs += msSince(tGrids);
  }
}

}  // namespace fc::surface_detail
