// Surface reconstruction on an OpenVDB grid [Mus13], only where the surface
// is: the liquid's 8³-voxel blocks are classified from their neighbourhood's
// occupancy and samples at their corners and centre, and only the blocks the
// surface crosses are evaluated voxel by voxel, a row of 8 voxels per vector.
// The field is Zhu & Bridson's, the distance to the kernel-weighted mean of
// the neighbouring particles minus a radius; then a box filter, then a mesh:
// marching cubes over the blocks (surface/block_mesher.h) or OpenVDB's
// adaptive volume-to-mesh. Parameters and the trade-offs: docs/surfaces.md.
//
// References (docs/references.md):
//   [Mus13] K. Museth. VDB: High-resolution sparse volumes with dynamic
//           topology. ACM TOG 32(3), 2013. DOI 10.1145/2487228.2487235
//   [ZB05]  Y. Zhu, R. Bridson. Animating sand as a fluid. ACM TOG
//           (SIGGRAPH) 24(3), 2005. DOI 10.1145/1073204.1073298
#include "surface/surface.h"

#include "core/key_map.h"
#include "core/parallel_sort.h"
#include "core/parallel_failure.h"
#include "surface/block_field.h"
#include "surface/block_mesher.h"
#include "surface/particle_buckets.h"
#include "surface/planar_surface.h"
#include "surface/volumes.h"

#include <openvdb/tools/VolumeToMesh.h>

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <exception>
#include <limits>
#include <mutex>
#include <stdexcept>

namespace fc {

const ParamTable<SurfaceSettings>& surfaceSettingsTable() {
  static const ParamTable<SurfaceSettings> table{
      {.name = "voxel_size", .unit = "r", .min = 0.1, .max = 2, .def = 0.5,
       .help = "level-set voxel, in particle radii: smaller keeps finer detail at a quadratic cost in time (the "
               "surface's voxels) and memory",
       .member = &SurfaceSettings::voxelSize},
      {.name = "kernel_radius", .unit = "r", .min = 2, .max = 8, .def = 4,
       .help = "radius of the neighbourhood whose weighted mean position the surface wraps, in particle radii: "
               "larger is smoother and bridges small gaps",
       .member = &SurfaceSettings::kernelRadius},
      {.name = "surface_radius", .unit = "r", .min = 0.5, .max = 3, .def = 1.15,
       .help = "distance of the surface from the neighbourhood's mean position, in particle radii: a lone "
               "particle becomes a sphere of this radius, a one-particle sheet twice as thick",
       .member = &SurfaceSettings::surfaceRadius},
      {.name = "smoothing", .unit = "", .min = 0, .max = 20, .def = 1,
       .help = "box-filter passes over the field before meshing: each flattens the ripple between particles "
               "and shrinks a lone droplet a little",
       .member = &SurfaceSettings::smoothing},
      {.name = "trail", .unit = "s", .min = 0, .max = 0.1, .def = 0,
       .help = "velocity trails: each particle also forms the surface along its path of the last `trail` seconds, "
               "stretching fast liquid along its motion for renderers without motion blur (half a frame's shutter: "
               "0.01 s at 50 fps); 0 = none",
       .member = &SurfaceSettings::trail},
      {.name = "adaptivity", .unit = "", .min = 0, .max = 1, .def = 0,
       .help = "mesh adaptivity: 0 is a uniform mesh by marching cubes, the fastest, with the most triangles; "
               "above 0, OpenVDB's volume-to-mesh merges flat regions into larger polygons",
       .member = &SurfaceSettings::adaptivity},
      {.name = "thickness_2d", .unit = "r", .min = 0, .max = 20, .def = 2.3,
       .help = "a 2D liquid's mesh: a slab this thick, in particle radii, its faces the liquid's area at "
               "z = ±thickness/2 and its walls the outline; 0 = the flat area at z = 0 (the level set is then "
               "two voxels thick)",
       .member = &SurfaceSettings::thickness2d},
  };
  return table;
}

const ParamSpecs& surfaceSettingsSpecs() { return surfaceSettingsTable().specs(); }

std::string surfaceSettingsProblem(const SurfaceSettings& s) {
  if (!(s.surfaceRadius < s.kernelRadius))
    return "surface.surface_radius must be less than surface.kernel_radius: beyond the kernel no particle is seen";
  return {};
}

namespace {

using openvdb::Coord;
using LeafT = openvdb::FloatTree::LeafNodeType;
using VLeafT = openvdb::Vec3STree::LeafNodeType;
using namespace surface_detail;
constexpr int kVoxels = int(LeafT::SIZE);   // voxels per block
static_assert(kBlock == int(LeafT::DIM) && kVoxels == kBlockVoxels, "a block is an OpenVDB leaf");

void initialiseOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

// [ZB05] Sec. 6: phi(x) = |x - x̄| - r̄, x̄ the mean of the particles within
// R weighted by k(s), s = |x - x_i| / R. At one point (u in voxels from the
// block's first voxel); +inf where no particle is within R.
float phiAt(const Gathered& g, const float u[3], float rv, float rs) {
  const float inv = 1.0f / (rv * rv);
  float sum[2][4] = {};  // w, w dx, w dy, w dz: of the particles, of the trails
  for (int which = 0; which < 2; ++which) {
    const Points& points = which ? g.trail : g.real;
    float* a = sum[which];
    for (size_t n = 0; n < points.size(); ++n) {
      const float dx = points.x[n] - u[0], dy = points.y[n] - u[1], dz = points.z[n] - u[2];
      const float k = kernelWeight(dx * dx + dy * dy + dz * dz, inv);
      a[0] += k, a[1] += k * dx, a[2] += k * dy, a[3] += k * dz;
    }
  }
  const auto distance = [&](float w, float sx, float sy, float sz) {
    if (!(w > 0)) return std::numeric_limits<float>::infinity();
    return std::sqrt((sx / w) * (sx / w) + (sy / w) * (sy / w) + (sz / w) * (sz / w)) - rs;
  };
  const float liquid = distance(sum[0][0], sum[0][1], sum[0][2], sum[0][3]);
  if (g.trail.size() == 0) return liquid;
  // The union of the liquid and its trails, as fieldOfBlock.
  return std::min(liquid, distance(sum[0][0] + sum[1][0], sum[0][1] + sum[1][1], sum[0][2] + sum[1][2],
                                   sum[0][3] + sum[1][3]));
}

// A crossed block's field and velocity (x, y, z per voxel), when no
// OpenVDB leaf is made of them (only the grids need one).
struct BlockValues {
  float phi[kVoxels];
  float velocity[3 * kVoxels];
};

// One thread's blocks, a chunk at a time: an address handed out never moves.
class BlockArena {
 public:
  // The next free block; it stays free until keep().
  BlockValues* next() {
    if (chunks_.empty() || used_ == kChunk) chunks_.emplace_back(new BlockValues[kChunk]), used_ = 0;
    return &chunks_.back()[used_];
  }
  void keep() { ++used_; }

 private:
  static constexpr size_t kChunk = 64;
  std::vector<std::unique_ptr<BlockValues[]>> chunks_;
  size_t used_ = 0;
};

// One pass of the 3-wide box along x, then y, then z over block b, from the
// blocks' values `in` into `out`, clamped to [-band, band]. Each stage
// reads a neighbour's result of the stage before (its constant where it
// has no values), computed here from the values around the block.
void boxBlock(const MeshBlock& nb, const std::vector<float*>& in, float band, float* __restrict out) {
  constexpr int P = kBlock + 2;  // [-1, 8] along each axis
  constexpr float third = 1.0f / 3.0f;
  float v[P][P][P], x[kBlock][P][P], y[kBlock][kBlock][P];
  for (int i = -1; i <= kBlock; ++i)
    for (int j = -1; j <= kBlock; ++j) {
      const int di = blockOffset(i), dj = blockOffset(j), row = (withinBlock(i, di) << 6) | (withinBlock(j, dj) << 3);
      float* o = v[i + 1][j + 1];
      for (int dk = -1; dk <= 1; ++dk) {
        const int slot = neighbourSlot(di, dj, dk);
        const float* src = nb.neighbour[slot] >= 0 ? in[size_t(nb.neighbour[slot])] + row : nullptr;
        if (dk < 0) o[0] = src ? src[kBlock - 1] : nb.constant[slot];
        else if (dk > 0) o[kBlock + 1] = src ? src[0] : nb.constant[slot];
        else if (src) std::copy_n(src, kBlock, o + 1);
        else std::fill_n(o + 1, kBlock, nb.constant[slot]);
      }
    }
  // x over the block's columns, in every row around it; a row of a block
  // without values keeps that block's constant.
  for (int i = 0; i < kBlock; ++i)
    for (int j = 0; j < P; ++j) {
#pragma omp simd
      for (int k = 0; k < P; ++k) x[i][j][k] = (v[i][j][k] + v[i + 1][j][k] + v[i + 2][j][k]) * third;
      const int dj = blockOffset(j - 1);
      for (int dk = -1; dk <= 1; ++dk)
        if ((dj || dk) && nb.neighbour[neighbourSlot(0, dj, dk)] < 0) {
          const int k0 = dk < 0 ? 0 : dk > 0 ? P - 1 : 1, k1 = dk == 0 ? kBlock + 1 : k0 + 1;
          std::fill(x[i][j] + k0, x[i][j] + k1, nb.constant[neighbourSlot(0, dj, dk)]);
        }
    }
  // y over the block's rows, with the z ends around it.
  for (int i = 0; i < kBlock; ++i)
    for (int j = 0; j < kBlock; ++j) {
#pragma omp simd
      for (int k = 0; k < P; ++k) y[i][j][k] = (x[i][j][k] + x[i][j + 1][k] + x[i][j + 2][k]) * third;
      for (int dk = -1; dk <= 1; dk += 2)
        if (nb.neighbour[neighbourSlot(0, 0, dk)] < 0) y[i][j][dk < 0 ? 0 : P - 1] = nb.constant[neighbourSlot(0, 0, dk)];
    }
  // z, clamped to the band, outside which a grid's voxels are inactive (and
  // what is not a number, outside).
  for (int i = 0; i < kBlock; ++i)
    for (int j = 0; j < kBlock; ++j) {
      float* o = out + ((i << 6) | (j << 3));
#pragma omp simd
      for (int k = 0; k < kBlock; ++k) {
        const float f = (y[i][j][k] + y[i][j][k + 1] + y[i][j][k + 2]) * third;
        o[k] = f < -band ? -band : f < band ? f : band;
      }
    }
}

double msSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

Surface reconstructSurface(const ParticleFrame& frame, double particleRadius, const SurfaceSettings& s,
                           bool withMesh, int dimension, bool withGrids) {
  initialiseOpenVdb();
  const auto t0 = std::chrono::steady_clock::now();
  if (!(particleRadius > 0) || !std::isfinite(particleRadius))
    throw std::invalid_argument("surface: the particle radius must be positive and finite");
  if (const std::string problem = surfaceSettingsProblem(s); !problem.empty()) throw std::invalid_argument(problem);
  const double voxel = s.voxelSize * particleRadius;
  const double R = s.kernelRadius * particleRadius;
  const double rs = s.surfaceRadius * particleRadius;
  const float rv = float(R / voxel);
  const Buckets buckets(frame, R, s.trail, particleRadius, keyReach(R, kBlock * voxel));

  Surface out;
  out.particles = buckets.particles();
  if (buckets.size() == 0) return out;
  if (dimension == 2) {  // the particles lie in the plane z = 0 (surface/planar_surface.h)
    reconstructPlanar(buckets, particleRadius, s, withMesh, withGrids, out);
    out.ms = msSince(t0);
    return out;
  }

  // Narrow band: 3 voxels each side, no deeper than the inside's depth (the
  // field's floor), and never under 1.5 voxels (meshing needs neighbours).
  const float band = float(std::max(std::min(3.0 * voxel, rs), 1.5 * voxel));
  SurfaceVolumes grids = emptySurfaceVolumes(voxel, band);
  const auto sdf = grids.surface;
  const auto velocity = grids.velocity;

  // Particles per block (voxel centres at multiples of the voxel).
  const double blockSize = kBlock * voxel;
  const int ring = int(std::ceil(R / blockSize));
  const auto blockOf = [&](double x) { return int64_t(std::floor(x / blockSize + 0.5 / kBlock)); };
  KeyMap occupied(buckets.size() / 4 + 16);
  for (size_t n = 0; n < buckets.size(); ++n) {
    const float* p = buckets.pos(n);
    ++*occupied.insert(key(blockOf(p[0]), blockOf(p[1]), blockOf(p[2])), 0).first;
  }
  // A block whose neighbourhood is filled at half the rest density or more
  // is inside without evaluation: in a large pool, almost every block.
  const double full = 0.5 * std::pow(blockSize / (2 * particleRadius), 3);
  const auto filled = [&](const int64_t b[3]) {
    for (int i = -ring; i <= ring; ++i)
      for (int j = -ring; j <= ring; ++j)
        for (int l = -ring; l <= ring; ++l) {
          const uint32_t count = occupied.find(key(b[0] + i, b[1] + j, b[2] + l));
          if (count == KeyMap::kMissing || count < full) return false;
        }
    return true;
  };
  // Candidates: the blocks within R of a particle (the field is zero beyond):
  // the occupied ones and the empty ones in their rings, found on the
  // threads (each keeps its own finds once), then merged in key order (z
  // fastest, then y, then x): neighbouring blocks are evaluated and meshed
  // close together, in time and in memory.
  std::vector<uint64_t> candidates;
  candidates.reserve(occupied.size());
  occupied.forEach([&](uint64_t k, uint32_t) { candidates.push_back(k); });
  parallelSort(candidates);
  std::vector<std::vector<uint64_t>> ringFound(static_cast<size_t>(omp_get_max_threads()));
#pragma omp parallel
  {
    std::vector<uint64_t>& found = ringFound[size_t(omp_get_thread_num())];
    KeyMap seen(64);
#pragma omp for schedule(static)
    for (size_t c = 0; c < candidates.size(); ++c) {
      const int64_t b[3] = {unkey(candidates[c], 0), unkey(candidates[c], 1), unkey(candidates[c], 2)};
      for (int i = -ring; i <= ring; ++i)
        for (int j = -ring; j <= ring; ++j)
          for (int l = -ring; l <= ring; ++l) {
            const uint64_t k = key(b[0] + i, b[1] + j, b[2] + l);
            if (!occupied.contains(k) && seen.insert(k, 0).second) found.push_back(k);
          }
    }
  }
  std::vector<uint64_t> empty;
  for (const auto& found : ringFound) empty.insert(empty.end(), found.begin(), found.end());
  parallelSort(empty);
  empty.erase(std::unique(empty.begin(), empty.end()), empty.end());
  {
    std::vector<uint64_t> all(candidates.size() + empty.size());
    std::merge(candidates.begin(), candidates.end(), empty.begin(), empty.end(), all.begin());
    candidates.swap(all);
  }
  KeyMap candidateIndex(candidates.size() + 16);
  for (size_t c = 0; c < candidates.size(); ++c) candidateIndex.insert(candidates[c], uint32_t(c));
  out.classifyMs = msSince(t0);

  // Each candidate: skipped when far outside (its centre farther than its
  // half-diagonal and the band: the field grows about as fast as the
  // distance), a tile when filled or sampled deep inside at its corners and
  // centre, otherwise evaluated voxel by voxel and kept when crossed.
  const auto tFill = std::chrono::steady_clock::now();
  std::vector<uint8_t> kinds(candidates.size(), Outside);
  // Each crossed block's field and velocity: in the grids' leaves when a
  // format asks for the grids, else in the threads' arenas.
  const bool uniform = withMesh && s.adaptivity <= 0;
  const bool gridsWanted = withGrids || (withMesh && !uniform);
  std::vector<float*> phiOf(candidates.size(), nullptr), velocityOf(candidates.size(), nullptr);
  std::vector<std::unique_ptr<LeafT>> leaves(gridsWanted ? candidates.size() : 0);
  std::vector<std::unique_ptr<VLeafT>> velocityLeaves(gridsWanted ? candidates.size() : 0);
  std::vector<BlockArena> arenas(static_cast<size_t>(omp_get_max_threads()));
  const float halfDiagonal = float(0.5 * std::sqrt(3.0) * (kBlock - 1));  // voxels
  const float rsv = float(rs / voxel), bandv = float(band / voxel);
  ParallelFailure failure;  // an exception in the OpenMP regions, rethrown after them
#pragma omp parallel
  {
    Gathered g;
    std::unique_ptr<Sums> sums, trailSums;
    BlockArena& arena = arenas[size_t(omp_get_thread_num())];
    try {
      sums = std::make_unique<Sums>();
      if (s.trail > 0) trailSums = std::make_unique<Sums>();
    } catch (...) {
      failure.keep();
    }
#pragma omp for schedule(dynamic, 8)
    for (size_t c = 0; c < candidates.size(); ++c) try {
      if (!sums) continue;
      const int64_t b[3] = {unkey(candidates[c], 0), unkey(candidates[c], 1), unkey(candidates[c], 2)};
      if (filled(b)) {
        kinds[c] = Inside;
        continue;
      }
      const Coord o(int(b[0] * kBlock), int(b[1] * kBlock), int(b[2] * kBlock));
      const double origin[3] = {o.x() * voxel, o.y() * voxel, o.z() * voxel};
      g.from(buckets, origin, voxel, R);
      if (g.size() == 0) continue;
      const float mid[3] = {0.5f * (kBlock - 1), 0.5f * (kBlock - 1), 0.5f * (kBlock - 1)};
      const float phiMid = phiAt(g, mid, rv, rsv);
      if (phiMid > halfDiagonal + bandv) continue;
      bool deep = phiMid < -0.5f * rsv;
      for (int corner = 0; corner < 8 && deep; ++corner) {
        const float u[3] = {corner & 1 ? kBlock - 1.0f : 0.0f, corner & 2 ? kBlock - 1.0f : 0.0f,
                            corner & 4 ? kBlock - 1.0f : 0.0f};
        deep = phiAt(g, u, rv, rsv) < -0.5f * rsv;
      }
      if (deep) {
        kinds[c] = Inside;
        continue;
      }
      sumBlock(g.real, rv, *sums);
      const bool trails = g.trail.size() > 0;
      if (trails) sumBlock(g.trail, rv, *trailSums);
      BlockValues* block = arena.next();
      const Kind kind = fieldOfBlock(*sums, trails ? trailSums.get() : nullptr, float(voxel),
                                     float(rs), band, block->phi, block->velocity);
      kinds[c] = kind;
      if (kind != Crossed) continue;
      if (gridsWanted) {
        leaves[c] = std::make_unique<LeafT>(o, band, false);
        velocityLeaves[c] = std::make_unique<VLeafT>(o, openvdb::Vec3s(0.0f), false);
        std::copy_n(block->phi, kVoxels, leaves[c]->buffer().data());
        std::copy_n(block->velocity, 3 * kVoxels, &velocityLeaves[c]->buffer().data()[0][0]);
        phiOf[c] = leaves[c]->buffer().data(), velocityOf[c] = &velocityLeaves[c]->buffer().data()[0][0];
      } else {
        arena.keep();
        phiOf[c] = block->phi, velocityOf[c] = block->velocity;
      }
    } catch (...) {
      failure.keep();
    }
  }
  failure.rethrow();
  out.fillMs = msSince(tFill);

  // The box filter over the crossed blocks; a tile reads -band, the outside
  // +band, as OpenVDB's own filter reads its inactive values.
  const auto tSmooth = std::chrono::steady_clock::now();
  std::vector<size_t> crossed;
  for (size_t c = 0; c < candidates.size(); ++c)
    if (kinds[c] == Crossed) crossed.push_back(c);
  std::vector<uint32_t> crossedIndex(candidates.size(), KeyMap::kMissing);
  for (size_t n = 0; n < crossed.size(); ++n) crossedIndex[crossed[n]] = uint32_t(n);
  // A neighbour block: its index among the crossed ones, or -1 and its value.
  const auto neighbourOf = [&](const int64_t b[3], int di, int dj, int dk, float& value) {
    const uint32_t c = candidateIndex.find(key(b[0] + di, b[1] + dj, b[2] + dk));
    value = c != KeyMap::kMissing && kinds[c] == Inside ? -band : band;
    return c != KeyMap::kMissing && kinds[c] == Crossed ? int32_t(crossedIndex[c]) : -1;
  };
  // Each crossed block and its neighbours, for the filter and the mesher.
  std::vector<MeshBlock> blocks(crossed.size());
  std::vector<float*> data(crossed.size());
#pragma omp parallel for schedule(static)
  for (size_t n = 0; n < crossed.size(); ++n) {
    MeshBlock& m = blocks[n];
    const uint64_t k = candidates[crossed[n]];
    for (int d = 0; d < 3; ++d) m.block[d] = unkey(k, d);
    for (int di = -1; di <= 1; ++di)
      for (int dj = -1; dj <= 1; ++dj)
        for (int dk = -1; dk <= 1; ++dk) {
          const int slot = neighbourSlot(di, dj, dk);
          m.neighbour[slot] = neighbourOf(m.block, di, dj, dk, m.constant[slot]);
        }
    data[n] = phiOf[crossed[n]];
  }
  // The box filter, a pass at a time between the blocks' own values and a
  // scratch copy, each pass clamping what it writes to the band; the
  // result ends in the grids' leaves, or the arenas' blocks point at it.
  std::unique_ptr<float[]> scratchStore(s.smoothing > 0 ? new float[crossed.size() * kVoxels] : nullptr);
  if (s.smoothing > 0) {
    std::vector<float*> scratch(crossed.size());
    for (size_t n = 0; n < crossed.size(); ++n) scratch[n] = &scratchStore[n * kVoxels];
    for (int pass = 0; pass < s.smoothing; ++pass) {
#pragma omp parallel for schedule(static)
      for (size_t n = 0; n < crossed.size(); ++n) boxBlock(blocks[n], data, band, scratch[n]);
      std::swap(data, scratch);
    }
    if (s.smoothing % 2) {
      if (gridsWanted) {
#pragma omp parallel for schedule(static)
        for (size_t n = 0; n < crossed.size(); ++n) std::copy(data[n], data[n] + kVoxels, phiOf[crossed[n]]);
      } else {
        for (size_t n = 0; n < crossed.size(); ++n) phiOf[crossed[n]] = data[n];
      }
    }
  }
  // For the uniform mesh, which voxels are inside, a row of 8 along z per byte.
  constexpr int kRows = kVoxels / kBlock;
  std::unique_ptr<uint8_t[][kRows]> inside(uniform ? new uint8_t[crossed.size()][kRows] : nullptr);
  if (inside)
#pragma omp parallel for schedule(static)
    for (size_t n = 0; n < crossed.size(); ++n) {
      const float* phi = phiOf[crossed[n]];
      for (int r = 0; r < kRows; ++r) {
        uint32_t bits = 0;
        for (int k = 0; k < kBlock; ++k) bits |= uint32_t(phi[r * kBlock + k] < 0) << k;
        inside[n][r] = uint8_t(bits);
      }
    }
  out.smoothMs = msSince(tSmooth);

  // A uniform mesh from the blocks themselves, while they are at hand.
  const double adaptivity = s.adaptivity;
  auto tMesh = std::chrono::steady_clock::now();
  if (uniform) {
#pragma omp parallel for schedule(static)
    for (size_t n = 0; n < crossed.size(); ++n) {
      blocks[n].phi = phiOf[crossed[n]];
      blocks[n].velocity = velocityOf[crossed[n]];
      blocks[n].inside = inside[n];
    }
    meshBlocks(blocks, voxel, band, out.mesh);
  }
  out.meshMs = msSince(tMesh);
  // The grids, unless only a uniform mesh was asked for (a ply, obj or usd export).
  const auto tInsert = std::chrono::steady_clock::now();
  if (gridsWanted) {
    // Active where the field is inside the band; the velocity of a voxel
    // outside it is no one's.
#pragma omp parallel for schedule(static)
    for (size_t n = 0; n < crossed.size(); ++n) {
      LeafT& leaf = *leaves[crossed[n]];
      VLeafT& vleaf = *velocityLeaves[crossed[n]];
      const float* phi = leaf.buffer().data();
      openvdb::Vec3s* v = vleaf.buffer().data();
      for (int i = 0; i < kVoxels; ++i) {
        const bool on = std::abs(phi[i]) < band;
        if (!on) v[i] = openvdb::Vec3s(0.0f);
        leaf.setActiveState(openvdb::Index(i), on);
        vleaf.setActiveState(openvdb::Index(i), on);
      }
    }
    for (size_t c = 0; c < candidates.size(); ++c) {
      if (kinds[c] == Inside) {
        const Coord o(int(unkey(candidates[c], 0) * kBlock), int(unkey(candidates[c], 1) * kBlock),
                      int(unkey(candidates[c], 2) * kBlock));
        sdf->tree().addTile(1, o, -band, false);
      } else if (kinds[c] == Crossed) {
        sdf->tree().addLeaf(leaves[c].release());
        velocity->tree().addLeaf(velocityLeaves[c].release());
      }
    }
    out.volumes = prunedSurfaceVolumes(grids);
  }
  out.smoothMs += msSince(tInsert);

  // An adaptive mesh: OpenVDB's volume-to-mesh.
  tMesh = std::chrono::steady_clock::now();
  if (withMesh && !uniform) {
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(*sdf, points, triangles, quads, 0.0, adaptivity);
    SurfaceMesh& m = out.mesh;
    m.points.resize(points.size());
    m.velocities.resize(points.size());
    // Each vertex: the trilinear mean of the velocities of the active voxels
    // around it (an inactive voxel may have no particle near it).
#pragma omp parallel
    {
      const auto accessor = velocity->getConstAccessor();
#pragma omp for schedule(static)
      for (size_t i = 0; i < points.size(); ++i) {
        m.points[i] = {points[i][0], points[i][1], points[i][2]};
        const openvdb::Vec3d x = velocity->transform().worldToIndex(points[i]);
        const Coord base(int(std::floor(x[0])), int(std::floor(x[1])), int(std::floor(x[2])));
        const double f[3] = {x[0] - base.x(), x[1] - base.y(), x[2] - base.z()};
        openvdb::Vec3d sum(0.0);
        double weight = 0;
        for (int c = 0; c < 8; ++c) {
          openvdb::Vec3s v;
          if (!accessor.probeValue(base.offsetBy(c & 1, (c >> 1) & 1, (c >> 2) & 1), v)) continue;
          const double w = (c & 1 ? f[0] : 1 - f[0]) * (c & 2 ? f[1] : 1 - f[1]) * (c & 4 ? f[2] : 1 - f[2]);
          sum += w * openvdb::Vec3d(v), weight += w;
        }
        if (weight > 0) sum /= weight;
        m.velocities[i] = {float(sum[0]), float(sum[1]), float(sum[2])};
      }
    }
    // OpenVDB winds its polygons clockwise seen from outside; renderers and
    // the enclosed-volume sum expect counter-clockwise.
    m.triangles.resize(triangles.size() + 2 * quads.size());
#pragma omp parallel for schedule(static)
    for (size_t i = 0; i < triangles.size(); ++i) m.triangles[i] = {triangles[i][0], triangles[i][2], triangles[i][1]};
#pragma omp parallel for schedule(static)
    for (size_t i = 0; i < quads.size(); ++i) {
      const auto& q = quads[i];
      m.triangles[triangles.size() + 2 * i] = {q[0], q[2], q[1]};
      m.triangles[triangles.size() + 2 * i + 1] = {q[0], q[3], q[2]};
    }
  }
  out.meshMs += msSince(tMesh);
  out.ms = msSince(t0);
  return out;
}

}  // namespace fc
