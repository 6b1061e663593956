// Surface reconstruction on an OpenVDB grid [Mus13], only where the surface
// is: the liquid's 8³-voxel blocks are classified from samples at their corners and centre,
// and only the blocks the surface crosses are evaluated voxel by voxel.
// The field is Zhu & Bridson's, the distance to the kernel-weighted mean of
// the neighbouring particles minus a radius; then a box filter, then
// volume-to-mesh. Parameters and the trade-offs: docs/surfaces.md.
//
// References (docs/references.md):
//   [Mus13] K. Museth. VDB: High-resolution sparse volumes with dynamic
//           topology. ACM TOG 32(3), 2013. DOI 10.1145/2487228.2487235
//   [ZB05]  Y. Zhu, R. Bridson. Animating sand as a fluid. ACM TOG
//           (SIGGRAPH) 24(3), 2005. DOI 10.1145/1073204.1073298
#include "surface/surface.h"

#include "surface/volumes.h"

#include <openvdb/tools/Filter.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <unordered_map>
#include <unordered_set>

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
      {.name = "adaptivity", .unit = "", .min = 0, .max = 1, .def = 0.1,
       .help = "volume-to-mesh adaptivity: 0 meshes every voxel, higher merges flat regions into larger polygons",
       .member = &SurfaceSettings::adaptivity},
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
constexpr int kBlock = int(LeafT::DIM);  // voxels per block side (8)

void initialiseOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

uint64_t key(int64_t i, int64_t j, int64_t k) {
  constexpr int64_t off = int64_t(1) << 20, mask = (int64_t(1) << 21) - 1;
  return (uint64_t((i + off) & mask) << 42) | (uint64_t((j + off) & mask) << 21) | uint64_t((k + off) & mask);
}

// The surface particles bucketed in cubic cells of the kernel's radius.
class Buckets {
 public:
  Buckets(const ParticleFrame& f, double cell) : inv_(1.0 / cell) {
    for (size_t i = 0; i < f.count(); ++i) {
      const float* x = &f.position[3 * i];
      // A non-finite position has no place on the grid.
      if (formsSurface(f.kind[i]) && std::isfinite(x[0]) && std::isfinite(x[1]) && std::isfinite(x[2]))
        rows_.push_back(uint32_t(i));
    }
    std::vector<uint64_t> keys(rows_.size());
    for (size_t n = 0; n < rows_.size(); ++n) {
      const float* x = &f.position[size_t(rows_[n]) * 3];
      keys[n] = key(cellOf(x[0]), cellOf(x[1]), cellOf(x[2]));
    }
    std::vector<uint32_t> order(rows_.size());
    for (size_t n = 0; n < order.size(); ++n) order[n] = uint32_t(n);
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return keys[a] < keys[b]; });
    pos_.resize(order.size() * 3);
    vel_.resize(order.size() * 3);
    cells_.reserve(order.size() / 4 + 1);
    for (size_t n = 0; n < order.size(); ++n) {
      const size_t row = rows_[order[n]];
      for (int d = 0; d < 3; ++d) {
        pos_[3 * n + d] = f.position[3 * row + d];
        vel_[3 * n + d] = f.velocity[3 * row + d];
      }
      auto [it, fresh] = cells_.try_emplace(keys[order[n]], uint32_t(n), uint32_t(n + 1));
      if (!fresh) it->second.second = uint32_t(n + 1);
    }
  }
  size_t size() const { return pos_.size() / 3; }
  int64_t cellOf(double x) const { return int64_t(std::floor(x * inv_)); }
  const float* pos(size_t n) const { return &pos_[3 * n]; }
  const float* vel(size_t n) const { return &vel_[3 * n]; }
  // Calls f(n) for the particles of every cell overlapping [lo, hi].
  template <class F>
  void forRange(const double lo[3], const double hi[3], F&& f) const {
    int64_t a[3], b[3];
    for (int d = 0; d < 3; ++d) a[d] = cellOf(lo[d]), b[d] = cellOf(hi[d]);
    for (int64_t i = a[0]; i <= b[0]; ++i)
      for (int64_t j = a[1]; j <= b[1]; ++j)
        for (int64_t k = a[2]; k <= b[2]; ++k) {
          auto it = cells_.find(key(i, j, k));
          if (it == cells_.end()) continue;
          for (uint32_t n = it->second.first; n < it->second.second; ++n) f(n);
        }
  }

 private:
  double inv_;
  std::vector<uint32_t> rows_;
  std::vector<float> pos_, vel_;
  std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> cells_;
};

// [ZB05] Sec. 6: phi(x) = |x - x̄| - r̄ with x̄ the mean of
// the neighbours within R weighted by k(s) = max(0, 1 - s²)³, s = |x - x_i| / R.
struct FieldSample {
  double phi = 0;
  bool reached = false;  // some particle within R
};

class Field {
 public:
  Field(double radius, double surfaceRadius) : R_(radius), invR2_(1.0 / (radius * radius)), rs_(surfaceRadius) {}

  // From a list of candidate particles (positions, SoA).
  FieldSample at(const double x[3], const std::vector<float>& px, const std::vector<float>& py,
                 const std::vector<float>& pz) const {
    double w = 0, sx = 0, sy = 0, sz = 0;
    const size_t n = px.size();
    for (size_t i = 0; i < n; ++i) {
      const double dx = px[i] - x[0], dy = py[i] - x[1], dz = pz[i] - x[2];
      const double s2 = (dx * dx + dy * dy + dz * dz) * invR2_;
      if (s2 >= 1) continue;
      const double t = 1 - s2, k = t * t * t;
      w += k;
      sx += k * px[i], sy += k * py[i], sz += k * pz[i];
    }
    FieldSample s;
    if (w <= 0) return s;
    s.reached = true;
    const double mx = sx / w - x[0], my = sy / w - x[1], mz = sz / w - x[2];
    s.phi = std::sqrt(mx * mx + my * my + mz * mz) - rs_;
    return s;
  }
  double radius() const { return R_; }
  double surfaceRadius() const { return rs_; }

 private:
  double R_, invR2_, rs_;
};

// The particles within R of the box [lo, hi], as SoA.
struct Gathered {
  std::vector<float> x, y, z, v;
  void from(const Buckets& b, const double lo[3], const double hi[3], double R) {
    x.clear(), y.clear(), z.clear(), v.clear();
    const double elo[3] = {lo[0] - R, lo[1] - R, lo[2] - R}, ehi[3] = {hi[0] + R, hi[1] + R, hi[2] + R};
    b.forRange(elo, ehi, [&](size_t n) {
      const float* p = b.pos(n);
      if (p[0] < elo[0] || p[0] > ehi[0] || p[1] < elo[1] || p[1] > ehi[1] || p[2] < elo[2] || p[2] > ehi[2]) return;
      x.push_back(p[0]), y.push_back(p[1]), z.push_back(p[2]);
      const float* u = b.vel(n);
      v.insert(v.end(), {u[0], u[1], u[2]});
    });
  }
};

}  // namespace

Surface reconstructSurface(const ParticleFrame& frame, double particleRadius, const SurfaceSettings& s,
                           bool withMesh, int dimension) {
  // A 2D scene's particles lie in the plane z = 0: the field is evaluated
  // there once per column and extruded into a slab.
  const bool planar = dimension == 2;
  initialiseOpenVdb();
  const auto t0 = std::chrono::steady_clock::now();
  if (!(particleRadius > 0) || !std::isfinite(particleRadius))
    throw std::invalid_argument("surface: the particle radius must be positive and finite");
  if (const std::string problem = surfaceSettingsProblem(s); !problem.empty()) throw std::invalid_argument(problem);
  const double voxel = s.voxelSize * particleRadius;
  const double R = s.kernelRadius * particleRadius;
  const Field field(R, s.surfaceRadius * particleRadius);
  const Buckets buckets(frame, R);

  Surface out;
  out.particles = buckets.size();
  if (buckets.size() == 0) return out;

  // Narrow band: 3 voxels each side, no deeper than the inside's depth (the
  // field's floor), and never under 1.5 voxels (meshing needs neighbours).
  const float band = float(std::max(std::min(3.0 * voxel, field.surfaceRadius()), 1.5 * voxel));
  auto sdf = openvdb::FloatGrid::create(band);
  sdf->setTransform(openvdb::math::Transform::createLinearTransform(voxel));
  sdf->setGridClass(openvdb::GRID_LEVEL_SET);
  sdf->setName("surface");
  auto velocity = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
  velocity->setTransform(sdf->transform().copy());
  velocity->setName("v");
  velocity->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);

  // Candidate blocks: those within R of a particle (the field is zero beyond).
  const double blockSize = kBlock * voxel;
  const int ring = int(std::ceil(R / blockSize));
  std::unordered_map<uint64_t, uint32_t> occupied;  // particles per block
  for (size_t n = 0; n < buckets.size(); ++n) {
    const float* p = buckets.pos(n);
    ++occupied[key(int64_t(std::floor(p[0] / blockSize + 0.5 / kBlock)), int64_t(std::floor(p[1] / blockSize + 0.5 / kBlock)),
                   int64_t(std::floor(p[2] / blockSize + 0.5 / kBlock)))];
  }
  std::unordered_set<uint64_t> candidateKeys;
  std::vector<Coord> candidates;
  const auto unkey = [](uint64_t k, int d) {
    constexpr int64_t off = int64_t(1) << 20, mask = (int64_t(1) << 21) - 1;
    return int64_t((k >> (42 - 21 * d)) & uint64_t(mask)) - off;
  };
  for (const auto& [k, count] : occupied)
    for (int i = -ring; i <= ring; ++i)
      for (int j = -ring; j <= ring; ++j)
        for (int l = -ring; l <= ring; ++l) {
          const int64_t b[3] = {unkey(k, 0) + i, unkey(k, 1) + j, unkey(k, 2) + l};
          if (candidateKeys.insert(key(b[0], b[1], b[2])).second)
            candidates.emplace_back(int(b[0] * kBlock), int(b[1] * kBlock), int(b[2] * kBlock));
        }

  // Classify each block from its corners and centre: the field grows at
  // most about as fast as the distance, so a block whose centre is farther
  // out than its half-diagonal holds no surface; one sampled deep inside
  // everywhere is a tile of the inside.
  enum Kind : uint8_t { Outside, Inside, Crossed };
  std::vector<uint8_t> kinds(candidates.size());
  // A block whose neighbourhood is filled at half the rest density or more
  // is inside without sampling: in a large pool, almost every block.
  const double full = 0.5 * std::pow(blockSize / (2 * particleRadius), 3);
  const auto filled = [&](const Coord& o) {
    const int64_t b[3] = {o.x() / kBlock, o.y() / kBlock, o.z() / kBlock};
    for (int i = -ring; i <= ring; ++i)
      for (int j = -ring; j <= ring; ++j)
        for (int l = -ring; l <= ring; ++l) {
          auto it = occupied.find(key(b[0] + i, b[1] + j, b[2] + l));
          if (it == occupied.end() || it->second < full) return false;
        }
    return true;
  };
  const double halfDiagonal = 0.5 * std::sqrt(3.0) * blockSize;
  const double deep = -0.5 * field.surfaceRadius();
  // An exception may not leave an OpenMP region: kept, rethrown after it.
  std::exception_ptr failure;
  const auto keep = [&failure] {
#pragma omp critical(surface_failure)
    if (!failure) failure = std::current_exception();
  };
#pragma omp parallel
  {
    Gathered g;
#pragma omp for schedule(dynamic, 16)
    for (size_t c = 0; c < candidates.size(); ++c) try {
      const Coord& o = candidates[c];
      if (filled(o)) {
        kinds[c] = Inside;
        continue;
      }
      const double lo[3] = {(o.x() - 0.5) * voxel, (o.y() - 0.5) * voxel, (o.z() - 0.5) * voxel};
      const double hi[3] = {lo[0] + blockSize, lo[1] + blockSize, lo[2] + blockSize};
      g.from(buckets, lo, hi, R);
      const double centre[3] = {0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])};
      const FieldSample mid = field.at(centre, g.x, g.y, g.z);
      if (!mid.reached && g.x.empty()) {
        kinds[c] = Outside;
        continue;
      }
      if (mid.reached && mid.phi > halfDiagonal + voxel) {
        kinds[c] = Outside;
        continue;
      }
      bool inside = mid.reached && mid.phi < deep;
      for (int corner = 0; corner < 8 && inside; ++corner) {
        const double x[3] = {corner & 1 ? hi[0] : lo[0], corner & 2 ? hi[1] : lo[1], corner & 4 ? hi[2] : lo[2]};
        const FieldSample cs = field.at(x, g.x, g.y, g.z);
        inside = cs.reached && cs.phi < deep;
      }
      kinds[c] = inside ? Inside : Crossed;
    } catch (...) {
      keep();
    }
  }
  if (failure) std::rethrow_exception(failure);

  const auto since = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
  };
  out.classifyMs = since(t0);
  const auto tFill = std::chrono::steady_clock::now();
  // The crossed blocks' leaves, created serially, filled in parallel.
  std::vector<LeafT*> leaves(candidates.size(), nullptr);
  std::vector<openvdb::Vec3STree::LeafNodeType*> velocityLeaves(candidates.size(), nullptr);
  for (size_t c = 0; c < candidates.size(); ++c) {
    if (kinds[c] == Inside) sdf->tree().addTile(1, candidates[c], -band, false);
    if (kinds[c] != Crossed) continue;
    leaves[c] = sdf->tree().touchLeaf(candidates[c]);
    velocityLeaves[c] = velocity->tree().touchLeaf(candidates[c]);
  }
  // Each crossed block: every nearby particle adds its weight k(s) to the
  // voxels of its kernel ball, row by row (z is the leaf's fastest index),
  // then [ZB05] Sec. 6 per voxel: phi = |x - x̄| - r̄, and the mean velocity.
#pragma omp parallel
  {
    Gathered g;
    std::vector<double> acc;  // w, w x, w y, w z, w v per voxel
    try {
      acc.resize(7 * LeafT::SIZE);
    } catch (...) {
      keep();
    }
#pragma omp for schedule(dynamic, 4)
    for (size_t c = 0; c < candidates.size(); ++c) try {
      if (!leaves[c] || acc.empty()) continue;
      const Coord& o = candidates[c];
      const double lo[3] = {o.x() * voxel, o.y() * voxel, o.z() * voxel};
      const double hi[3] = {lo[0] + (kBlock - 1) * voxel, lo[1] + (kBlock - 1) * voxel, lo[2] + (kBlock - 1) * voxel};
      g.from(buckets, lo, hi, R);
      std::fill(acc.begin(), acc.end(), 0.0);
      const double invVoxel = 1.0 / voxel, rv = R * invVoxel, invR2 = 1.0 / (R * R);
      for (size_t n = 0; n < g.x.size(); ++n) {
        const double p[3] = {g.x[n], g.y[n], g.z[n]};
        const double u[3] = {(p[0] - lo[0]) * invVoxel, (p[1] - lo[1]) * invVoxel, (p[2] - lo[2]) * invVoxel};
        const int i0 = std::max(0, int(std::ceil(u[0] - rv))), i1 = std::min(kBlock - 1, int(std::floor(u[0] + rv)));
        for (int i = i0; i <= i1; ++i) {
          const double dx = (lo[0] + i * voxel) - p[0];
          const double rx2 = R * R - dx * dx;
          if (rx2 <= 0) continue;
          const double ry = std::sqrt(rx2) * invVoxel;
          const int j0 = std::max(0, int(std::ceil(u[1] - ry))), j1 = std::min(kBlock - 1, int(std::floor(u[1] + ry)));
          for (int j = j0; j <= j1; ++j) {
            const double dy = (lo[1] + j * voxel) - p[1];
            const double ryz2 = rx2 - dy * dy;
            if (ryz2 <= 0) continue;
            const double rz = std::sqrt(ryz2) * invVoxel;
            const int k0 = std::max(0, int(std::ceil(u[2] - rz))), k1 = std::min(kBlock - 1, int(std::floor(u[2] + rz)));
            const double dxy2 = dx * dx + dy * dy;
            double* a = &acc[7 * size_t((i << 6) | (j << 3))];
            if (planar) {  // the plane z = 0 only, in the column's first slot
              const double t = 1 - dxy2 * invR2, w = t * t * t;
              a[0] += w, a[1] += w * p[0], a[2] += w * p[1];
              a[4] += w * g.v[3 * n], a[5] += w * g.v[3 * n + 1];
              continue;
            }
            for (int k = k0; k <= k1; ++k) {
              const double dz = (lo[2] + k * voxel) - p[2];
              const double t = 1 - (dxy2 + dz * dz) * invR2;
              if (t <= 0) continue;
              const double w = t * t * t;
              double* v = a + 7 * k;
              v[0] += w, v[1] += w * p[0], v[2] += w * p[1], v[3] += w * p[2];
              v[4] += w * g.v[3 * n], v[5] += w * g.v[3 * n + 1], v[6] += w * g.v[3 * n + 2];
            }
          }
        }
      }
      LeafT& leaf = *leaves[c];
      auto& vleaf = *velocityLeaves[c];
      for (openvdb::Index n = 0; n < LeafT::SIZE; ++n) {
        const double* a = &acc[7 * (planar ? n & ~openvdb::Index(kBlock - 1) : n)];
        const Coord ijk = leaf.offsetToGlobalCoord(n);
        double phi = band;
        if (a[0] > 0) {
          // A 2D liquid's slab: its plane's field, rounded off in z.
          const double mx = a[1] / a[0] - ijk.x() * voxel, my = a[2] / a[0] - ijk.y() * voxel,
                       mz = planar ? -ijk.z() * voxel : a[3] / a[0] - ijk.z() * voxel;
          phi = std::sqrt(mx * mx + my * my + mz * mz) - field.surfaceRadius();
        }
        if (std::abs(phi) < band) {
          leaf.setValueOn(n, float(phi));
          vleaf.setValueOn(n, openvdb::Vec3s(float(a[4] / a[0]), float(a[5] / a[0]), float(a[6] / a[0])));
        } else {
          leaf.setValueOff(n, phi < 0 ? -band : band);
          vleaf.setValueOff(n, openvdb::Vec3s(0.0f));
        }
      }
    } catch (...) {
      keep();
    }
  }
  if (failure) std::rethrow_exception(failure);
  out.fillMs = since(tFill);
  const auto tSmooth = std::chrono::steady_clock::now();
  if (s.smoothing > 0) {
    openvdb::tools::Filter<openvdb::FloatGrid> smooth(*sdf);
    smooth.mean(1, s.smoothing);
  }
  sdf->pruneGrid();
  velocity->pruneGrid();
  out.volumes = std::make_shared<SurfaceVolumes>(SurfaceVolumes{sdf, velocity});
  out.smoothMs = since(tSmooth);

  const auto tMesh = std::chrono::steady_clock::now();
  if (withMesh) {
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    openvdb::tools::volumeToMesh(*sdf, points, triangles, quads, 0.0, s.adaptivity);
    SurfaceMesh& m = out.mesh;
    m.points.resize(points.size());
    m.velocities.resize(points.size());
    openvdb::tools::GridSampler<openvdb::Vec3STree, openvdb::tools::BoxSampler> sampler(velocity->tree(),
                                                                                         velocity->transform());
    for (size_t i = 0; i < points.size(); ++i) {
      m.points[i] = {points[i][0], points[i][1], points[i][2]};
      const openvdb::Vec3s v = sampler.wsSample(points[i]);
      m.velocities[i] = {v[0], v[1], v[2]};
    }
    // OpenVDB winds its polygons clockwise seen from outside; renderers and
    // the enclosed-volume sum expect counter-clockwise.
    m.triangles.reserve(triangles.size() + 2 * quads.size());
    for (const auto& t : triangles) m.triangles.push_back({t[0], t[2], t[1]});
    for (const auto& q : quads) {
      m.triangles.push_back({q[0], q[2], q[1]});
      m.triangles.push_back({q[0], q[3], q[2]});
    }
  }
  out.meshMs = since(tMesh);
  out.ms = since(t0);
  return out;
}

}  // namespace fc
