#pragma once
// Closed triangle meshes as static solids: an exact signed distance (a BVH
// over the triangles, sign from angle-weighted pseudonormals, Bærentzen &
// Aanæs 2005 [BA05]) and, from it, a signed-distance grid with trilinear lookup for
// the simulation (contact, "never start inside a solid", block validation).
// Reading and validating mesh files is io/obj_mesh.*; this layer assumes a
// closed, consistently oriented mesh without degenerate triangles.
#include "core/aabb.h"
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

using Vec3d = Eigen::Vector3d;

struct TriangleMesh {
  std::vector<Vec3d> vertices;
  std::vector<std::array<uint32_t, 3>> triangles;  // counter-clockwise seen from outside

  // Volume enclosed (divergence theorem); negative for an inside-out mesh.
  double signedVolume() const;
  void flip();  // reverses every triangle's orientation
  AABB<3> bounds() const;
};

// The grid would be larger than the cap (the message says by how much and
// what to change).
struct MeshGridTooLarge : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class MeshSdf {
 public:
  struct Options {
    double spacing = 0;          // grid spacing, m (the particle radius)
    double band = 0;             // margin around the mesh bounds, m (the kernel support and a cell)
#ifdef FLOWCLIP_FUZZ_LIMITS
    // Fuzz builds: a grid costs ~250× Release under ASan + UBSan at -O1 (a
    // 0.6 M-node grid: 49 ms against 12.8 s), so big ones are refused there.
    size_t maxNodes = 1u << 17;
#else
    size_t maxNodes = 1u << 24;  // 16.8 M nodes, 64 MB of floats
#endif
    // signedDistance() answers exactly where the grid says the surface is
    // nearer than this (m; 0: the grid everywhere). See signedDistance.
    // Fine nodes nearer than 4 cells to the surface are always exact, so
    // keep it below 3 cells.
    double exactBand = 0;
  };
  // Builds the BVH and the grid (OpenMP over grid rows): a coarse grid of 4
  // cells first, exact; fine nodes in coarse cells that lie wholly farther
  // than 4 cells from the surface are interpolated from it (the far field,
  // where no decision needs the exact value), the others are exact. Throws
  // MeshGridTooLarge when the grid would exceed opt.maxNodes and
  // std::invalid_argument when an edge has no opposite partner (not closed).
  MeshSdf(TriangleMesh mesh, const Options& opt);

  // Exact signed distance (negative inside), and the unit gradient (the
  // direction away from the nearest surface point) when asked.
  double exactSignedDistance(const Vec3d& p, Vec3d* gradient = nullptr) const;
  // The same with the nearest triangle and the feature of it the nearest
  // point lies on: 0-2 its vertices, 3-5 its edges (v0v1, v1v2, v2v0), 6 its face.
  struct Nearest {
    double distance = 0;  // signed
    Vec3d gradient = Vec3d::Zero();
    uint32_t triangle = 0;
    int feature = 6;
  };
  // `bound`: an upper bound of the distance, if known (prunes the BVH).
  Nearest nearestPoint(const Vec3d& p, double bound = std::numeric_limits<double>::infinity()) const;
  const Vec3d& faceNormal(uint32_t t) const { return faceNormal_[t]; }

  // The signed distance the simulation uses: the grid's value, or the exact
  // one where the grid's magnitude is below Options::exactBand. Trilinear
  // interpolation is exact beside a face but rounds convex edges and corners
  // by up to half a cell (the grid overestimates there) and errs as much
  // across the medial planes inside; near the surface, where contact and
  // the start checks decide, the answer is therefore exact, and the grid only
  // spares the far field (most particles) the BVH query.
  Real signedDistance(const Vec3& p) const {
    const Real g = gridSignedDistance(p);
    if (!(std::abs(g) < exactBand_)) return g;
    // The grid errs by at most half a cell (measured; where it errs more the
    // search finds nothing within the bound and searches again unbounded).
    return Real(nearestPoint(p.template cast<double>(), double(std::abs(g)) + 0.6 * spacing_).distance);
  }

  // Trilinear lookup in the grid; outside it, the distance to the grid box
  // plus the value at the nearest grid point (positive: the grid reaches
  // `band` beyond the mesh).
  Real gridSignedDistance(const Vec3& p) const {
    const Vec3 q = p.cwiseMax(gridMin_).cwiseMin(gridMax_);
    const Real outside = (p - q).norm();
    const Vec3 f = (q - gridMin_) * invSpacing_;
    int i[3];
    Real t[3];
    for (int d = 0; d < 3; ++d) {
      i[d] = std::min(int(f[d]), dims_[d] - 2);
      t[d] = f[d] - Real(i[d]);
    }
    const size_t sx = 1, sy = size_t(dims_[0]), sz = size_t(dims_[0]) * size_t(dims_[1]);
    const Real* v = values_.data() + size_t(i[0]) + sy * size_t(i[1]) + sz * size_t(i[2]);
    auto lerp = [](Real a, Real b, Real w) { return a + w * (b - a); };
    const Real c00 = lerp(v[0], v[sx], t[0]), c10 = lerp(v[sy], v[sy + sx], t[0]);
    const Real c01 = lerp(v[sz], v[sz + sx], t[0]), c11 = lerp(v[sz + sy], v[sz + sy + sx], t[0]);
    return outside + lerp(lerp(c00, c10, t[1]), lerp(c01, c11, t[1]), t[2]);
  }

  const TriangleMesh& mesh() const { return mesh_; }
  const AABB<3>& bounds() const { return bounds_; }  // of the mesh
  AABB<3> gridBox() const { return AABB<3>(gridMin_, gridMax_); }
  const Eigen::Vector3i& dims() const { return dims_; }
  double spacing() const { return spacing_; }
  size_t nodes() const { return values_.size(); }
  size_t exactNodes() const { return exactNodes_; }  // nodes computed exactly (the rest: far field)
  double volume() const { return volume_; }
  double buildMs() const { return buildMs_; }  // BVH and grid, wall clock

  // Nodes a grid of this spacing and band would have over `bounds`.
  static double gridNodes(const AABB<3>& bounds, double spacing, double band);

 private:
  struct Node {
    Vec3d lo, hi;
    uint32_t first = 0, count = 0;  // leaf: triangles [first, first + count) of order_
    uint32_t left = 0, right = 0;   // inner: children
  };
  uint32_t buildNode(uint32_t first, uint32_t count, std::vector<Vec3d>& centroids);
  // Nearest point on the mesh: squared distance, triangle and feature
  // (0-2 vertex, 3-5 edge, 6 face); `bound2` is an upper bound to prune with.
  void nearest(const Vec3d& p, double bound2, double& best2, uint32_t& tri, int& feature, Vec3d& closest) const;

  TriangleMesh mesh_;
  std::vector<Node> nodes_;
  std::vector<uint32_t> order_;
  std::vector<Vec3d> faceNormal_;                  // unit
  std::vector<std::array<Vec3d, 3>> edgeNormal_;   // per triangle edge (v0v1, v1v2, v2v0): sum of the two faces'
  std::vector<Vec3d> vertexNormal_;                // angle-weighted
  AABB<3> bounds_;
  Vec3 gridMin_ = Vec3::Zero(), gridMax_ = Vec3::Zero();
  Eigen::Vector3i dims_ = Eigen::Vector3i::Zero();
  double spacing_ = 0;
  Real invSpacing_ = 0;
  Real exactBand_ = 0;
  // Nearest-point query to node values (pseudonormal sign).
  double nodeDistance(const Vec3d& p, double bound) const;
  std::vector<Real> values_;  // x fastest
  double volume_ = 0;
  double buildMs_ = 0;
  size_t exactNodes_ = 0;
};

}  // namespace fc
