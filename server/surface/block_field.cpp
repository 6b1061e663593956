// Zhu & Bridson's field over one block: the sums scattered from the
// particles, then the distance to their weighted mean.
//
// References (docs/references.md):
//   [ZB05]  Y. Zhu, R. Bridson. Animating sand as a fluid. ACM TOG
//           (SIGGRAPH) 24(3), 2005. DOI 10.1145/1073204.1073298
#include "surface/block_field.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace fc::surface_detail {

namespace {

// One particle of a block's sums: its place in voxels, its velocity, and
// what its kernel leaves (squared) across x and y once its distance to the
// block's rows along z is taken: rows farther than that see none of it.
struct Scattered {
  float u[3], a[3], reach2;
  int i0, i1;  // the range of x it reaches
  bool reaches() const { return i0 <= i1; }
};

Scattered scattered(const Points& g, size_t n, float rv2) {
  Scattered p{{g.x[n], g.y[n], g.z[n]}, {g.vx[n], g.vy[n], g.vz[n]}, 0, 0, -1};
  const float uz = p.u[2];
  const float zOut = uz < 0 ? -uz : uz > kBlock - 1 ? uz - (kBlock - 1) : 0.0f;
  p.reach2 = rv2 - zOut * zOut;
  if (p.reach2 <= 0) return p;
  const float rx = std::sqrt(p.reach2);
  p.i0 = std::max(0, int(std::ceil(p.u[0] - rx))), p.i1 = std::min(kBlock - 1, int(std::floor(p.u[0] + rx)));
  return p;
}

// The rows j of x = i the particle reaches: [j0, j1], empty when j0 > j1;
// dx2 its squared distance along x.
[[gnu::always_inline]] inline void rowsOf(const Scattered& p, int i, float& dx2, int& j0, int& j1) {
  const float dx = float(i) - p.u[0];
  dx2 = dx * dx;
  const float ry2 = p.reach2 - dx2;
  j0 = 0, j1 = -1;
  if (i < p.i0 || i > p.i1 || ry2 <= 0) return;
  const float ry = std::sqrt(ry2);
  j0 = std::max(0, int(std::ceil(p.u[1] - ry))), j1 = std::min(kBlock - 1, int(std::floor(p.u[1] + ry)));
}

// [ZB05] Sec. 6, scattered: the particles `count` (1 or 2) add k(s), k(s) x
// and k(s) v to the voxels of row (i, j), in their order. A row one of two
// does not reach gets 0 from it (its kernel is 0 beyond its reach, up to
// the rounding of that reach), so the sums are the ones each particle would
// make alone; two at a time, each row is loaded and stored once for both.
template <int count>
void addToRow(const Scattered* p, const float* dxy2, float inv, int row, Sums& s) {
  float* __restrict w = s.w + row;
  float* __restrict x = s.x + row;
  float* __restrict y = s.y + row;
  float* __restrict z = s.z + row;
  float* __restrict vx = s.vx + row;
  float* __restrict vy = s.vy + row;
  float* __restrict vz = s.vz + row;
#pragma omp simd
  for (int k = 0; k < kBlock; ++k) {
    float sw = w[k], sx = x[k], sy = y[k], sz = z[k], svx = vx[k], svy = vy[k], svz = vz[k];
    for (int q = 0; q < count; ++q) {
      const float dz = float(k) - p[q].u[2];
      const float c = kernelWeight(dxy2[q] + dz * dz, inv);
      sw += c, sx += c * p[q].u[0], sy += c * p[q].u[1], sz += c * p[q].u[2];
      svx += c * p[q].a[0], svy += c * p[q].a[1], svz += c * p[q].a[2];
    }
    w[k] = sw, x[k] = sx, y[k] = sy, z[k] = sz, vx[k] = svx, vy[k] = svy, vz[k] = svz;
  }
}

void scatterOne(const Scattered& p, float inv, Sums& s) {
  for (int i = p.i0; i <= p.i1; ++i) {
    float dx2;
    int j0, j1;
    rowsOf(p, i, dx2, j0, j1);
    for (int j = j0; j <= j1; ++j) {
      const float dy = float(j) - p.u[1], dxy2 = dx2 + dy * dy;
      addToRow<1>(&p, &dxy2, inv, (i << 6) | (j << 3), s);
    }
  }
}

void scatterTwo(const Scattered* p, float inv, Sums& s) {
  for (int i = std::min(p[0].i0, p[1].i0); i <= std::max(p[0].i1, p[1].i1); ++i) {
    float dx2[2];
    int j0[2], j1[2];
    rowsOf(p[0], i, dx2[0], j0[0], j1[0]);
    rowsOf(p[1], i, dx2[1], j0[1], j1[1]);
    const bool a = j0[0] <= j1[0], b = j0[1] <= j1[1];
    if (!a && !b) continue;
    for (int j = a && b ? std::min(j0[0], j0[1]) : a ? j0[0] : j0[1],
             last = a && b ? std::max(j1[0], j1[1]) : a ? j1[0] : j1[1];
         j <= last; ++j) {
      const float dy0 = float(j) - p[0].u[1], dy1 = float(j) - p[1].u[1];
      const float dxy2[2] = {dx2[0] + dy0 * dy0, dx2[1] + dy1 * dy1};
      addToRow<2>(p, dxy2, inv, (i << 6) | (j << 3), s);
    }
  }
}

}  // namespace

// [ZB05] Sec. 6, scattered: every particle adds k(s) and k(s) x_i, k(s) v_i
// to the voxels of its kernel ball, a whole row of the block at a time, two
// particles per row where both reach it.
void sumBlock(const Points& g, float rv, Sums& s) {
  std::memset(&s, 0, sizeof s);
  const float rv2 = rv * rv, inv = 1.0f / rv2;
  Scattered pending[2];
  int held = 0;
  for (size_t n = 0; n < g.size(); ++n) {
    pending[held] = scattered(g, n, rv2);
    if (!pending[held].reaches()) continue;
    if (++held == 2) scatterTwo(pending, inv, s), held = 0;
  }
  if (held) scatterOne(pending[0], inv, s);
}

namespace {

// fieldOfBlock, a row of 8 voxels per vector; with the trails (a separate
// instance, so that the liquid alone pays nothing for them), the union of
// the liquid and its trails. The trails' samples alone would also draw the
// front back towards them.
template <bool kTrails>
Kind field(const Sums& s, const Sums* trail, float voxel, float rs, float band, float* __restrict phi,
           float* __restrict vel) {
  for (int i = 0; i < kBlock; ++i)
    for (int j = 0; j < kBlock; ++j) {
      const int r = (i << 6) | (j << 3);
      const float fi = float(i), fj = float(j);
      // Branch-free, so that the row is one vector: a voxel without weight
      // divides by 1 and that result is not taken (a division that might
      // trap is never made a vector one).
#pragma omp simd
      for (int k = 0; k < kBlock; ++k) {
        const int n = r + k;
        float w = s.w[n], x = s.x[n], y = s.y[n], z = s.z[n], vx = s.vx[n], vy = s.vy[n], vz = s.vz[n];
        float iw = 1.0f / (w > 0 ? w : 1.0f);
        float mx = x * iw - fi, my = y * iw - fj, mz = z * iw - float(k);
        float p = w > 0 ? voxel * std::sqrt(mx * mx + my * my + mz * mz) - rs : band;
        if constexpr (kTrails) {
          // Where no trail sample reaches, every sum of the trails is 0 and adds nothing.
          const float tw = trail->w[n];
          w += tw, vx += trail->vx[n], vy += trail->vy[n], vz += trail->vz[n];
          x += trail->x[n], y += trail->y[n], z += trail->z[n];
          iw = 1.0f / (w > 0 ? w : 1.0f);
          mx = x * iw - fi, my = y * iw - fj, mz = z * iw - float(k);
          const float joined = std::min(p, voxel * std::sqrt(mx * mx + my * my + mz * mz) - rs);
          p = tw > 0 ? joined : p;
        }
        iw = w > 0 ? iw : 0.0f;
        vel[3 * n] = vx * iw, vel[3 * n + 1] = vy * iw, vel[3 * n + 2] = vz * iw;
        phi[n] = std::min(band, std::max(-band, p));
      }
    }
  int in = 0, out = 0, near = 0;
#pragma omp simd reduction(| : in, out, near)
  for (int n = 0; n < kBlockVoxels; ++n) in |= phi[n] <= -band, out |= phi[n] >= band, near |= std::abs(phi[n]) < band;
  return near || (in && out) ? Crossed : in ? Inside : Outside;
}

}  // namespace

Kind fieldOfBlock(const Sums& s, const Sums* trail, float voxel, float rs, float band, float* phi, float* vel) {
  return trail ? field<true>(s, trail, voxel, rs, band, phi, vel) : field<false>(s, nullptr, voxel, rs, band, phi, vel);
}

}  // namespace fc::surface_detail
