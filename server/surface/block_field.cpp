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

// [ZB05] Sec. 6, scattered: every particle adds k(s) and k(s) x_i, k(s) v_i
// to the voxels of its kernel ball, a whole row of the block at a time.
void sumBlock(const Points& g, float rv, Sums& s) {
  std::memset(&s, 0, sizeof s);
  const float rv2 = rv * rv, inv = 1.0f / rv2;
  for (size_t n = 0; n < g.size(); ++n) {
    const float ux = g.x[n], uy = g.y[n], uz = g.z[n], ax = g.vx[n], ay = g.vy[n], az = g.vz[n];
    // The distance from the particle to the block's rows along z leaves
    // this much of the kernel's reach (squared) across x and y: only rows
    // inside it are visited, without a test per row.
    const float zOut = uz < 0 ? -uz : uz > kBlock - 1 ? uz - (kBlock - 1) : 0.0f;
    const float rz2 = rv2 - zOut * zOut;
    if (rz2 <= 0) continue;
    const float rx = std::sqrt(rz2);
    const int i0 = std::max(0, int(std::ceil(ux - rx))), i1 = std::min(kBlock - 1, int(std::floor(ux + rx)));
    for (int i = i0; i <= i1; ++i) {
      const float dx = float(i) - ux, ry2 = rz2 - dx * dx;
      if (ry2 <= 0) continue;
      const float ry = std::sqrt(ry2);
      const int j0 = std::max(0, int(std::ceil(uy - ry))), j1 = std::min(kBlock - 1, int(std::floor(uy + ry)));
      for (int j = j0; j <= j1; ++j) {
        const float dy = float(j) - uy, dxy2 = dx * dx + dy * dy;
        const int row = (i << 6) | (j << 3);
        float* __restrict w = s.w + row;
        float* __restrict x = s.x + row;
        float* __restrict y = s.y + row;
        float* __restrict z = s.z + row;
        float* __restrict vx = s.vx + row;
        float* __restrict vy = s.vy + row;
        float* __restrict vz = s.vz + row;
#pragma omp simd
        for (int k = 0; k < kBlock; ++k) {
          const float dz = float(k) - uz;
          const float c = kernelWeight(dxy2 + dz * dz, inv);
          w[k] += c, x[k] += c * ux, y[k] += c * uy, z[k] += c * uz;
          vx[k] += c * ax, vy[k] += c * ay, vz[k] += c * az;
        }
      }
    }
  }
}

namespace {

// fieldOfBlock, a row of 8 voxels per vector; with the trails (a separate
// instance, so that the liquid alone pays nothing for them), the union of
// the liquid and its trails. The trails' samples alone would also draw the
// front back towards them.
template <bool kTrails>
Kind field(const Sums& s, const Sums* trail, float voxel, float rs, float band, float* phi, float* vel) {
  int in = 0, out = 0, near = 0;
  for (int i = 0; i < kBlock; ++i)
    for (int j = 0; j < kBlock; ++j) {
      const int r = (i << 6) | (j << 3);
#pragma omp simd reduction(| : in, out, near)
      for (int k = 0; k < kBlock; ++k) {
        const int n = r + k;
        const auto distance = [&](float w, float x, float y, float z) {
          const float iw = 1.0f / w;
          const float mx = x * iw - float(i), my = y * iw - float(j), mz = z * iw - float(k);
          return voxel * std::sqrt(mx * mx + my * my + mz * mz) - rs;
        };
        float w = s.w[n], vx = s.vx[n], vy = s.vy[n], vz = s.vz[n];
        float p = w > 0 ? distance(w, s.x[n], s.y[n], s.z[n]) : band;
        if constexpr (kTrails) {
          const Sums& t = *trail;
          if (t.w[n] > 0) {
            w += t.w[n], vx += t.vx[n], vy += t.vy[n], vz += t.vz[n];
            p = std::min(p, distance(w, s.x[n] + t.x[n], s.y[n] + t.y[n], s.z[n] + t.z[n]));
          }
        }
        const float iw = w > 0 ? 1.0f / w : 0.0f;
        vel[3 * n] = vx * iw, vel[3 * n + 1] = vy * iw, vel[3 * n + 2] = vz * iw;
        p = std::min(band, std::max(-band, p));
        phi[n] = p;
        in |= p <= -band, out |= p >= band, near |= std::abs(p) < band;
      }
    }
  return near || (in && out) ? Crossed : in ? Inside : Outside;
}

}  // namespace

Kind fieldOfBlock(const Sums& s, const Sums* trail, float voxel, float rs, float band, float* phi, float* vel) {
  return trail ? field<true>(s, trail, voxel, rs, band, phi, vel) : field<false>(s, nullptr, voxel, rs, band, phi, vel);
}

}  // namespace fc::surface_detail
