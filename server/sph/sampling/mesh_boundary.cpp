// Boundary sampling of mesh obstacles (declared in sph/sampling/boundary.h).
//
// Layer l lies on the offset surface at depth t = r + l·s inside the solid
// (s = 2r), as for box obstacles: one particle radius behind the surface,
// where the fluid lattice would continue, then a spacing deeper per layer.
//
// Flat parts: the triangles are grouped into planar regions (neighbours
// across an edge with the same normal: a quad, a whole box face). Each
// region gets, per layer, a square lattice in its plane offset t inward,
// aligned with the region's longest boundary edge and stretched, like
// sampleBoxShell's axes, so that its first and last rows lie on the bounding
// rectangle inset by t (where a convex neighbour's offset plane meets it);
// a lattice point is kept if its exact signed distance is -t (no other part
// of the surface is nearer). So a box mesh of any orientation is sampled
// exactly as a box obstacle, and a resting particle sees the same solid
// everywhere on a face. (Projecting a 3D lattice onto a slanted face instead
// left samples irregular: a resting particle's boundary density then varied
// by ±20 % along the face.)
//
// Curved parts: the offset surface around reflex edges and vertices, the
// strips a lattice's inset leaves there, and regions too small for a lattice
// (tessellated curved surfaces) get the points of a 3D lattice of spacing s
// that lie within s/2 of an offset surface, projected onto it by Newton
// steps along the exact distance gradient: about one sample per s² per layer
// whatever the orientation. Of these, only those farther than 0.75 s from
// every planar lattice point are kept (the centre of a lattice cell is
// 0.71 s from its nodes), so they fill what the lattices leave and do not
// crowd them; where they crowd each other, Akinci's volume (buildBoundary)
// shrinks their volumes. Points that cannot reach their offset surface (a
// part thinner than the layers) are dropped.
//
// Thin walls: a flat wall thinner than two radii has no point at depth r.
// Its first layer lies on its mid-surface instead (half its thickness deep,
// laid by the larger of its two faces), so that the pressure solve sees it:
// without it only the contact model would keep the liquid out.
//
// Cost: one exact distance query (a BVH descent) per lattice point within
// two grid cells of a layer, a few per projected point; linear in the
// surface area over s².
#include "sph/sampling/boundary.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <unordered_map>

namespace fc {

namespace {

// Newton steps onto the offset surface sd = target; false if not reached.
bool project(const MeshSdf& mesh, Vec3d& p, double target, double s, MeshSdf::Nearest& at) {
  at = mesh.nearestPoint(p);
  for (int it = 0; it < 8 && std::abs(at.distance - target) > 1e-4 * s; ++it) {
    p -= (at.distance - target) * at.gradient;
    at = mesh.nearestPoint(p);
  }
  return std::abs(at.distance - target) <= 0.05 * s;
}

struct Region {
  std::vector<uint32_t> triangles;
  Vec3d normal = Vec3d::Zero();
  double area = 0;
  Vec3d origin = Vec3d::Zero(), u = Vec3d::Zero(), v = Vec3d::Zero();  // frame in the plane
  double umin = 0, umax = 0, vmin = 0, vmax = 0;                         // bounding rectangle
};

// Triangles joined across edges whose faces have the same normal.
std::vector<Region> planarRegions(const MeshSdf& mesh, std::vector<int>& regionOf) {
  const TriangleMesh& m = mesh.mesh();
  const size_t nt = m.triangles.size();
  std::vector<uint32_t> parent(nt);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  std::unordered_map<uint64_t, uint32_t> directed;  // edge a->b -> triangle
  directed.reserve(3 * nt);
  auto key = [](uint32_t a, uint32_t b) { return (uint64_t(a) << 32) | b; };
  for (uint32_t t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) directed[key(m.triangles[t][size_t(k)], m.triangles[t][size_t((k + 1) % 3)])] = t;
  std::vector<std::array<uint32_t, 3>> across(nt);  // neighbour over each edge
  for (uint32_t t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const auto it = directed.find(key(m.triangles[t][size_t((k + 1) % 3)], m.triangles[t][size_t(k)]));
      across[t][size_t(k)] = it == directed.end() ? t : it->second;
      if (it != directed.end() && mesh.faceNormal(t).dot(mesh.faceNormal(it->second)) > 1 - 1e-9) {
        const uint32_t a = find(t), b = find(it->second);
        if (a != b) parent[std::max(a, b)] = std::min(a, b);
      }
    }
  std::vector<Region> regions;
  std::map<uint32_t, int> index;
  regionOf.assign(nt, -1);
  for (uint32_t t = 0; t < nt; ++t) {
    const auto [it, fresh] = index.try_emplace(find(t), int(regions.size()));
    if (fresh) regions.emplace_back();
    Region& r = regions[size_t(it->second)];
    r.triangles.push_back(t);
    const auto& v = m.triangles[t];
    r.area += 0.5 * (m.vertices[v[1]] - m.vertices[v[0]]).cross(m.vertices[v[2]] - m.vertices[v[0]]).norm();
    regionOf[t] = it->second;
  }
  // Frames: u along the longest boundary edge, from its first vertex.
  for (Region& r : regions) {
    r.normal = mesh.faceNormal(r.triangles.front());
    double longest = -1;
    for (uint32_t t : r.triangles)
      for (int k = 0; k < 3; ++k) {
        if (regionOf[across[t][size_t(k)]] == regionOf[t] && across[t][size_t(k)] != t) continue;  // inner edge
        const Vec3d& a = m.vertices[m.triangles[t][size_t(k)]];
        const Vec3d& b = m.vertices[m.triangles[t][size_t((k + 1) % 3)]];
        if ((b - a).norm() > longest) longest = (b - a).norm(), r.origin = a, r.u = (b - a).normalized();
      }
    r.u = (r.u - r.u.dot(r.normal) * r.normal).normalized();
    r.v = r.normal.cross(r.u);
    r.umin = r.vmin = std::numeric_limits<double>::max();
    r.umax = r.vmax = std::numeric_limits<double>::lowest();
    for (uint32_t t : r.triangles)
      for (uint32_t vi : m.triangles[t]) {
        const Vec3d d = m.vertices[vi] - r.origin;
        r.umin = std::min(r.umin, d.dot(r.u)), r.umax = std::max(r.umax, d.dot(r.u));
        r.vmin = std::min(r.vmin, d.dot(r.v)), r.vmax = std::max(r.vmax, d.dot(r.v));
      }
  }
  return regions;
}

// Lattice coordinates from lo to hi, both included, spacing close to s.
std::vector<double> stretched(double lo, double hi, double s) {
  if (hi < lo - 1e-9 * s) return {};
  if (hi - lo < 0.5 * s) return {0.5 * (lo + hi)};
  const int n = std::max(1, int(std::lround((hi - lo) / s)));
  std::vector<double> c;
  for (int k = 0; k <= n; ++k) c.push_back(lo + (hi - lo) * double(k) / double(n));
  return c;
}

// Points in a hash grid, asked whether any lies within `radius` of a point.
class PointHash {
 public:
  explicit PointHash(double radius) : radius_(radius) {}
  bool anyWithin(const Vec3d& p) const {
    const Eigen::Vector3i c = cell(p);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const auto it = cells_.find(key(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == cells_.end()) continue;
          for (const Vec3d& q : it->second)
            if ((q - p).squaredNorm() < radius_ * radius_) return true;
        }
    return false;
  }
  void insert(const Vec3d& p) { cells_[key(cell(p))].push_back(p); }

 private:
  Eigen::Vector3i cell(const Vec3d& p) const {
    return Eigen::Vector3i(int(std::floor(p[0] / radius_)), int(std::floor(p[1] / radius_)), int(std::floor(p[2] / radius_)));
  }
  static uint64_t key(const Eigen::Vector3i& c) {
    return (uint64_t(uint32_t(c[0]) & 0x1fffff) << 42) | (uint64_t(uint32_t(c[1]) & 0x1fffff) << 21) |
           uint64_t(uint32_t(c[2]) & 0x1fffff);
  }
  double radius_;
  std::unordered_map<uint64_t, std::vector<Vec3d>> cells_;
};

}  // namespace

size_t sampleMeshShell(const MeshSdf& mesh, Real radius, Real spacing, int layers, std::vector<Vec3>& out) {
  const double s = spacing, r = radius;
  std::vector<int> regionOf;
  const std::vector<Region> regions = planarRegions(mesh, regionOf);
  // A region takes a lattice if it holds a few lattice cells.
  std::vector<char> flat(regions.size());
  for (size_t i = 0; i < regions.size(); ++i) flat[i] = regions[i].area >= 4 * s * s;
  size_t examined = 0;

  // Flat parts: per region and layer, its plane's lattice.
  std::vector<std::vector<Vec3d>> planar(regions.size());
#pragma omp parallel for schedule(dynamic, 1) reduction(+ : examined)
  for (long ri = 0; ri < long(regions.size()); ++ri) {
    if (!flat[size_t(ri)]) continue;
    const Region& g = regions[size_t(ri)];
    for (int l = 0; l < layers; ++l) {
      const double t = r + l * s;
      for (double a : stretched(g.umin + t, g.umax - t, s))
        for (double b : stretched(g.vmin + t, g.vmax - t, s)) {
          const Vec3d q = g.origin + a * g.u + b * g.v - t * g.normal;
          ++examined;
          if (std::abs(double(mesh.gridSignedDistance(q.cast<Real>())) + t) > 2 * mesh.spacing()) continue;
          const MeshSdf::Nearest at = mesh.nearestPoint(q);
          const double tolerance = 1e-6 * s + 1e-9;
          if (std::abs(at.distance + t) <= tolerance) {
            planar[size_t(ri)].push_back(q);
            continue;
          }
          // A wall thinner than two radii: its far face (facing the other
          // way) is nearer than t, T - t away. Layer 0 then lies on the
          // wall's mid-surface, T/2 deep, laid by the larger of the two
          // faces (one lattice per wall).
          if (l != 0 || mesh.faceNormal(at.triangle).dot(g.normal) > -0.5) continue;
          const int far = regionOf[at.triangle];
          if (far >= 0 && (regions[size_t(far)].area > g.area || (regions[size_t(far)].area == g.area && far < ri)))
            continue;
          const double half = 0.5 * (t - at.distance);
          if (!(half > 0.05 * s && half < t)) continue;
          const Vec3d mid = q + (t - half) * g.normal;
          if (std::abs(mesh.nearestPoint(mid).distance + half) <= tolerance) planar[size_t(ri)].push_back(mid);
        }
    }
  }

  // Curved parts: a 3D lattice's band points, projected; kept only where the
  // nearest surface point is on an edge or vertex, or in a region too small
  // for a lattice.
  const AABB<3> b = mesh.bounds();
  const double deepest = r + (layers - 0.5) * s;  // band of the last layer ends here
  Eigen::Vector3i n;
  Vec3d origin;
  for (int d = 0; d < 3; ++d) {
    origin[d] = double(b.min[d]) + r - s;  // one point beyond: bands reach the bounds
    n[d] = int(std::floor((double(b.max[d]) + s - origin[d]) / s)) + 1;
  }
  // One list per lattice row, joined in order: the same samples in the same
  // order whatever the thread count.
  const long rows = long(n[1]) * n[2];
  std::vector<std::vector<Vec3d>> curved(static_cast<size_t>(rows));
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : examined)
  for (long row = 0; row < rows; ++row) {
    const long j = row % n[1], k = row / n[1];
    for (long i = 0; i < n[0]; ++i) {
      Vec3d p = origin + s * Vec3d(double(i), double(j), double(k));
      ++examined;
      // The grid's value is within a cell diagonal (√3 h) of the exact one:
      // skip what is clearly out of the layers.
      const double coarse = double(mesh.gridSignedDistance(p.cast<Real>()));
      if (coarse > 2 * mesh.spacing() || coarse < -deepest - 2 * mesh.spacing()) continue;
      MeshSdf::Nearest at = mesh.nearestPoint(p);
      if (at.distance > 0 || at.distance <= -deepest) continue;
      const int layer = std::clamp(int(std::floor((-at.distance - r) / s + 0.5)), 0, layers - 1);
      if (!project(mesh, p, -(r + layer * s), s, at)) continue;
      curved[size_t(row)].push_back(p);
    }
  }

  // The planar lattices first (where two meet on an offset edge, once),
  // then the projected points the lattices do not cover: farther than 0.75 s
  // from every lattice point (a square lattice's cells have their centres
  // 0.71 s from the nodes).
  PointHash lattice(0.5 * s), cover(0.75 * s);
  std::vector<Vec3d> pts;
  for (const auto& f : planar)
    for (const Vec3d& p : f)
      if (!lattice.anyWithin(p)) lattice.insert(p), cover.insert(p), pts.push_back(p);
  for (const auto& f : curved)
    for (const Vec3d& p : f)
      if (!cover.anyWithin(p)) pts.push_back(p);
  for (const Vec3d& p : pts) out.push_back(p.cast<Real>());
  return examined;
}

}  // namespace fc
