#pragma once
// The particles a surface is made of, for the 3D reconstruction
// (surface/surface.cpp) and the 2D one (surface/planar_surface.cpp): sorted
// into cells of the kernel's radius, and gathered around one block of the
// grid, in voxels from its first voxel.
#include "core/key_map.h"
#include "core/parallel_sort.h"
#include "io/particle_frame.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

namespace fc::surface_detail {

constexpr int kBlock = 8;        // voxels per block side, an OpenVDB leaf's
constexpr double kMaxSpeed = 1e6;  // m/s: a particle faster than this counts as at rest

constexpr int64_t kKeyOffset = int64_t(1) << 20, kKeyMask = (int64_t(1) << 21) - 1;
inline uint64_t key(int64_t i, int64_t j, int64_t k) {
  return (uint64_t((i + kKeyOffset) & kKeyMask) << 42) | (uint64_t((j + kKeyOffset) & kKeyMask) << 21) |
         uint64_t((k + kKeyOffset) & kKeyMask);
}
inline int64_t unkey(uint64_t k, int d) { return int64_t((k >> (42 - 21 * d)) & uint64_t(kKeyMask)) - kKeyOffset; }

// How far from the origin (m) a point may lie for its cell (`cell` wide)
// and its block (`block` wide) to keep a key of their own, with room for
// the rings around them.
inline double keyReach(double cell, double block) { return double(int64_t(1) << 19) * std::min(cell, block); }

// The surface particles sorted into cubic cells of the kernel's radius.
class Buckets {
 public:
  // trail (s): each particle also leaves samples along its last trail
  // seconds of motion, x - v t, at most `spacing` apart (and 16 of them).
  // A point farther than `reach` from the origin on an axis is left out,
  // as a non-finite one is: the grid has no place for it.
  Buckets(const ParticleFrame& f, double cell, double trail, double spacing, double reach) : inv_(1.0 / cell) {
    const auto placed = [reach](double a, double b, double c) {
      return std::abs(a) < reach && std::abs(b) < reach && std::abs(c) < reach;
    };
    // Particle i's samples: itself, then its trail's (as far as they stay
    // placed), at x - v t. None when it is not liquid or not placed.
    const auto samplesOf = [&](size_t i, auto&& emit) {
      const float* p = &f.position[3 * i];
      const float* u = &f.velocity[3 * i];
      if (!formsSurface(f.kind[i]) || !placed(p[0], p[1], p[2])) return;  // NaN fails the test too
      // A speed no liquid has (or not a number) counts as rest: its sums would overflow.
      const double speed = std::sqrt(double(u[0]) * u[0] + double(u[1]) * u[1] + double(u[2]) * u[2]);
      const bool moving = speed < kMaxSpeed;
      const int samples = trail > 0 && moving ? int(std::min(16.0, std::ceil(speed * trail / spacing))) : 0;
      for (int m = 0; m <= samples; ++m) {
        const double t = samples ? trail * m / samples : 0.0;
        double q[3] = {p[0], p[1], p[2]};
        if (m > 0)
          for (int d = 0; d < 3; ++d) q[d] -= u[d] * t;
        if (m > 0 && !placed(q[0], q[1], q[2])) break;
        emit(q, moving ? u : nullptr, m > 0);
      }
    };
    // Counted, then written on the threads at each particle's offset.
    const size_t particles = f.count();
    std::vector<uint32_t> first(particles + 1, 0);
#pragma omp parallel for schedule(static)
    for (size_t i = 0; i < particles; ++i) {
      uint32_t n = 0;
      samplesOf(i, [&](const double*, const float*, bool) { ++n; });
      first[i + 1] = n;
    }
    for (size_t i = 0; i < particles; ++i) {
      particles_ += first[i + 1] > 0;
      first[i + 1] += first[i];
    }
    const size_t count = first[particles];
    std::vector<float> x(3 * count), v(3 * count);  // the particles and their trails' samples
    std::vector<uint8_t> isTrail(count);
#pragma omp parallel for schedule(static)
    for (size_t i = 0; i < particles; ++i) {
      size_t n = first[i];
      samplesOf(i, [&](const double* q, const float* u, bool isSample) {
        for (int d = 0; d < 3; ++d) x[3 * n + size_t(d)] = float(q[d]), v[3 * n + size_t(d)] = u ? u[d] : 0.0f;
        isTrail[n++] = isSample;
      });
    }
    std::vector<std::pair<uint64_t, uint32_t>> keyed(count);
#pragma omp parallel for schedule(static)
    for (size_t n = 0; n < count; ++n)
      keyed[n] = {key(cellOf(x[3 * n]), cellOf(x[3 * n + 1]), cellOf(x[3 * n + 2])), uint32_t(n)};
    parallelSort(keyed);
    pos_.resize(count * 3);
    vel_.resize(count * 3);
    trail_.resize(count);
#pragma omp parallel for schedule(static)
    for (size_t n = 0; n < count; ++n) {
      for (int d = 0; d < 3; ++d) {
        pos_[3 * n + d] = x[3 * size_t(keyed[n].second) + d];
        vel_[3 * n + d] = v[3 * size_t(keyed[n].second) + d];
      }
      trail_[n] = isTrail[keyed[n].second];
    }
    for (size_t n = 0; n < count; ++n)
      if (n == 0 || keyed[n].first != keyed[n - 1].first) {
        cells_.insert(keyed[n].first, uint32_t(starts_.size()));
        starts_.push_back(uint32_t(n));
      }
    starts_.push_back(uint32_t(count));
  }
  size_t particles() const { return particles_; }
  size_t size() const { return pos_.size() / 3; }  // particles and trail samples
  int64_t cellOf(double x) const { return int64_t(std::floor(x * inv_)); }
  const float* pos(size_t n) const { return &pos_[3 * n]; }
  const float* vel(size_t n) const { return &vel_[3 * n]; }
  bool trail(size_t n) const { return trail_[n] != 0; }
  // The last cells one thread looked up: neighbouring blocks, gathered one
  // after another, ask for mostly the same cells, which the map would fetch
  // from memory each time.
  struct Recent {
    static constexpr int kSlots = 256;
    uint64_t key[kSlots];
    uint32_t cell[kSlots];
    Recent() { std::fill_n(key, kSlots, KeyMap::kEmpty); }
  };
  uint32_t cellIndex(uint64_t k, Recent* recent) const {
    if (!recent) return cells_.find(k);
    const size_t slot = size_t((k * 0x9E3779B97F4A7C15ULL) >> 56);
    if (recent->key[slot] != k) recent->key[slot] = k, recent->cell[slot] = cells_.find(k);
    return recent->cell[slot];
  }
  // Calls f(n) for the particles of every cell overlapping [lo, hi].
  template <class F>
  void forRange(const double lo[3], const double hi[3], F&& f, Recent* recent = nullptr) const {
    int64_t a[3], b[3];
    for (int d = 0; d < 3; ++d) a[d] = cellOf(lo[d]), b[d] = cellOf(hi[d]);
    for (int64_t i = a[0]; i <= b[0]; ++i)
      for (int64_t j = a[1]; j <= b[1]; ++j)
        for (int64_t k = a[2]; k <= b[2]; ++k) {
          const uint32_t c = cellIndex(key(i, j, k), recent);
          if (c == KeyMap::kMissing) continue;
          for (uint32_t n = starts_[c]; n < starts_[c + 1]; ++n) f(n);
        }
  }

 private:
  double inv_;
  size_t particles_ = 0;
  std::vector<float> pos_, vel_;
  std::vector<uint8_t> trail_;  // a trail's sample, not a particle
  std::vector<uint32_t> starts_;  // each cell's first particle, then the end
  KeyMap cells_;                  // cell → its index in starts_
};

// The particles within the kernel radius of a block, in voxels from the
// block's first voxel (small numbers: the sums keep their digits in float).
struct Points {
  std::vector<float> x, y, z, vx, vy, vz;
  size_t size() const { return x.size(); }
  void clear() { x.clear(), y.clear(), z.clear(), vx.clear(), vy.clear(), vz.clear(); }
};
struct Gathered {
  Points real, trail;  // the particles, and their trails' samples
  Buckets::Recent recent;  // of the one Buckets this gathers from
  size_t size() const { return real.size() + trail.size(); }
  void from(const Buckets& b, const double origin[3], double voxel, double R) {
    real.clear(), trail.clear();
    const double side = (kBlock - 1) * voxel;
    const double lo[3] = {origin[0] - R, origin[1] - R, origin[2] - R};
    const double hi[3] = {origin[0] + side + R, origin[1] + side + R, origin[2] + side + R};
    const double inv = 1.0 / voxel;
    const double R2 = R * R;
    b.forRange(lo, hi, [&](size_t n) {
      const float* p = b.pos(n);
      // Only particles within R of the block's voxels: the box's corners hold about a quarter more.
      double d2 = 0;
      for (int d = 0; d < 3; ++d) {
        const double below = origin[d] - p[d], above = p[d] - (origin[d] + side);
        const double out = below > 0 ? below : above > 0 ? above : 0.0;
        d2 += out * out;
      }
      if (!(d2 <= R2)) return;
      Points& to = b.trail(n) ? trail : real;
      to.x.push_back(float((p[0] - origin[0]) * inv)), to.y.push_back(float((p[1] - origin[1]) * inv));
      to.z.push_back(float((p[2] - origin[2]) * inv));
      const float* u = b.vel(n);
      to.vx.push_back(u[0]), to.vy.push_back(u[1]), to.vz.push_back(u[2]);
    }, &recent);
  }
};

// [ZB05]'s kernel k(s) = max(0, 1 - s²)³ at s² = d² · inv (inv = 1 / R²).
inline float kernelWeight(float d2, float inv) {
  float t = 1.0f - d2 * inv;
  t = t > 0.0f ? t : 0.0f;
  return t * t * t;
}


}  // namespace fc::surface_detail
