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

constexpr int kVoxels = kBlockVoxels;

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

Kind fieldOfBlock(const Sums& s, const Sums* trail, float voxel, float rs, float band,
                  float* phi, float* vel) {
  const auto distance = [&](float w, float x, float y, float z, int i, int j, int k) {
    const float iw = 1.0f / w;
    const float mx = x * iw - float(i), my = y * iw - float(j);
    const float mz = z * iw - float(k);
    return voxel * std::sqrt(mx * mx + my * my + mz * mz) - rs;
  };
  if (!trail) {  // the same, a row of 8 voxels per vector
    int in = 0, out = 0, near = 0;
    for (int i = 0; i < kBlock; ++i)
      for (int j = 0; j < kBlock; ++j) {
        const int r = (i << 6) | (j << 3);
#pragma omp simd reduction(| : in, out, near)
        for (int k = 0; k < kBlock; ++k) {
          const int n = r + k;
          const float w = s.w[n];
          const bool has = w > 0;
          const float iw = has ? 1.0f / w : 0.0f;
          const float mx = s.x[n] * iw - float(i), my = s.y[n] * iw - float(j), mz = s.z[n] * iw - float(k);
          float p = has ? voxel * std::sqrt(mx * mx + my * my + mz * mz) - rs : band;
          p = std::min(band, std::max(-band, p));
          phi[n] = p;
          vel[3 * n] = s.vx[n] * iw, vel[3 * n + 1] = s.vy[n] * iw, vel[3 * n + 2] = s.vz[n] * iw;
          in |= p <= -band, out |= p >= band, near |= std::abs(p) < band;
        }
      }
    return near || (in && out) ? Crossed : in ? Inside : Outside;
  }
  bool in = false, out = false, near = false;
  for (int n = 0; n < kVoxels; ++n) {
    const int i = n >> 6, j = (n >> 3) & 7, k = n & 7, c = n;
    float p = band, w = s.w[c];
    vel[3 * n] = vel[3 * n + 1] = vel[3 * n + 2] = 0.0f;
    if (w > 0) p = distance(w, s.x[c], s.y[c], s.z[c], i, j, k);
    float vx = s.vx[c], vy = s.vy[c], vz = s.vz[c];
    if (trail && trail->w[c] > 0) {
      // With the trails: the union of the liquid and its trails. The trails'
      // samples alone would also draw the front back towards them.
      const Sums& t = *trail;
      w += t.w[c], vx += t.vx[c], vy += t.vy[c], vz += t.vz[c];
      p = std::min(p, distance(w, s.x[c] + t.x[c], s.y[c] + t.y[c], s.z[c] + t.z[c], i, j, k));
    }
    if (w > 0) vel[3 * n] = vx / w, vel[3 * n + 1] = vy / w, vel[3 * n + 2] = vz / w;
    p = std::min(band, std::max(-band, p));
    phi[n] = p;
    in |= p <= -band, out |= p >= band, near |= std::abs(p) < band;
  }
  return near || (in && out) ? Crossed : in ? Inside : Outside;
}

}  // namespace fc::surface_detail
