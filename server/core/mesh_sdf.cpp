#include "core/mesh_sdf.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <sstream>

namespace fc {

double TriangleMesh::signedVolume() const {
  double v = 0;
  for (const auto& t : triangles) v += vertices[t[0]].dot(vertices[t[1]].cross(vertices[t[2]]));
  return v / 6;
}

void TriangleMesh::flip() {
  for (auto& t : triangles) std::swap(t[1], t[2]);
}

AABB<3> TriangleMesh::bounds() const {
  AABB<3> b;
  for (const Vec3d& v : vertices) b.extend(Vec3(v.cast<Real>()));
  return b;
}

namespace {

// Closest point on triangle abc to p (Ericson, Real-Time Collision
// Detection [Eri05], 5.1.5), with the feature it lies on: 0, 1, 2 the vertices a, b,
// c; 3 edge ab, 4 edge bc, 5 edge ca; 6 the face.
Vec3d closestOnTriangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c, int& feature) {
  const Vec3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return feature = 0, a;
  const Vec3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return feature = 1, b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return feature = 3, Vec3d(a + (d1 / (d1 - d3)) * ab);
  const Vec3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return feature = 2, c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return feature = 5, Vec3d(a + (d2 / (d2 - d6)) * ac);
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return feature = 4, Vec3d(b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b));
  const double denom = 1 / (va + vb + vc);
  feature = 6;
  return a + ab * (vb * denom) + ac * (vc * denom);
}

double boxDistance2(const Vec3d& p, const Vec3d& lo, const Vec3d& hi) {
  return (lo - p).cwiseMax(p - hi).cwiseMax(Vec3d::Zero()).squaredNorm();
}

constexpr uint32_t kLeafSize = 4;

}  // namespace

double MeshSdf::gridNodes(const AABB<3>& bounds, double spacing, double band) {
  double n = 1;
  for (int d = 0; d < 3; ++d) n *= std::ceil((double(bounds.size()[d]) + 2 * band) / spacing) + 1;
  return n;
}

uint32_t MeshSdf::buildNode(uint32_t first, uint32_t count, std::vector<Vec3d>& centroids) {
  const uint32_t id = uint32_t(nodes_.size());
  nodes_.emplace_back();
  Vec3d lo = Vec3d::Constant(std::numeric_limits<double>::max()), hi = -lo;
  Vec3d clo = lo, chi = hi;
  for (uint32_t k = first; k < first + count; ++k) {
    const auto& t = mesh_.triangles[order_[k]];
    for (uint32_t v : t) lo = lo.cwiseMin(mesh_.vertices[v]), hi = hi.cwiseMax(mesh_.vertices[v]);
    clo = clo.cwiseMin(centroids[order_[k]]), chi = chi.cwiseMax(centroids[order_[k]]);
  }
  nodes_[id].lo = lo;
  nodes_[id].hi = hi;
  if (count <= kLeafSize) {
    nodes_[id].first = first;
    nodes_[id].count = count;
    return id;
  }
  // Median split along the longest axis of the centroids.
  int axis = 0;
  (chi - clo).maxCoeff(&axis);
  const uint32_t half = count / 2;
  std::nth_element(order_.begin() + first, order_.begin() + first + half, order_.begin() + first + count,
                   [&](uint32_t a, uint32_t b) { return centroids[a][axis] < centroids[b][axis]; });
  const uint32_t left = buildNode(first, half, centroids);
  const uint32_t right = buildNode(first + half, count - half, centroids);
  nodes_[id].left = left;
  nodes_[id].right = right;
  return id;
}

void MeshSdf::nearest(const Vec3d& p, double bound2, double& best2, uint32_t& tri, int& feature, Vec3d& closest) const {
  best2 = bound2;
  tri = std::numeric_limits<uint32_t>::max();
  uint32_t stack[64];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& n = nodes_[stack[--top]];
    if (boxDistance2(p, n.lo, n.hi) >= best2) continue;
    if (n.count > 0) {
      for (uint32_t k = n.first; k < n.first + n.count; ++k) {
        const uint32_t t = order_[k];
        const auto& v = mesh_.triangles[t];
        int f;
        const Vec3d c = closestOnTriangle(p, mesh_.vertices[v[0]], mesh_.vertices[v[1]], mesh_.vertices[v[2]], f);
        const double d2 = (p - c).squaredNorm();
        if (d2 < best2) best2 = d2, tri = t, feature = f, closest = c;
      }
      continue;
    }
    // Nearer child last, so it is popped first.
    const Node& l = nodes_[n.left];
    const Node& r = nodes_[n.right];
    const bool leftNear = boxDistance2(p, l.lo, l.hi) <= boxDistance2(p, r.lo, r.hi);
    stack[top++] = leftNear ? n.right : n.left;
    stack[top++] = leftNear ? n.left : n.right;
  }
}

MeshSdf::Nearest MeshSdf::nearestPoint(const Vec3d& p, double bound) const {
  Nearest r;
  double best2;
  Vec3d c;
  const double b2 = bound * bound * (1 + 1e-9) + 1e-24;
  nearest(p, std::isfinite(b2) ? b2 : std::numeric_limits<double>::infinity(), best2, r.triangle, r.feature, c);
  if (r.triangle == std::numeric_limits<uint32_t>::max())  // nothing within the bound (rounding): search all
    nearest(p, std::numeric_limits<double>::infinity(), best2, r.triangle, r.feature, c);
  const auto& v = mesh_.triangles[r.triangle];
  const Vec3d n = r.feature < 3 ? vertexNormal_[v[size_t(r.feature)]]
                  : r.feature < 6 ? edgeNormal_[r.triangle][size_t(r.feature - 3)]
                                  : faceNormal_[r.triangle];
  const Vec3d diff = p - c;
  const double dist = std::sqrt(best2);
  const double sign = diff.dot(n) < 0 ? -1 : 1;
  r.gradient = dist > 1e-12 ? Vec3d(sign * diff / dist) : n.normalized();
  r.distance = sign * dist;
  return r;
}

double MeshSdf::nodeDistance(const Vec3d& p, double bound) const { return nearestPoint(p, bound).distance; }

double MeshSdf::exactSignedDistance(const Vec3d& p, Vec3d* gradient) const {
  const Nearest r = nearestPoint(p);
  if (gradient) *gradient = r.gradient;
  return r.distance;
}

MeshSdf::MeshSdf(TriangleMesh mesh, const Options& opt) : mesh_(std::move(mesh)) {
  const auto t0 = std::chrono::steady_clock::now();
  if (mesh_.triangles.empty()) throw std::invalid_argument("mesh has no triangles");
  if (!(opt.spacing > 0) || !(opt.band > 0)) throw std::invalid_argument("mesh grid spacing and band must be > 0");
  bounds_ = mesh_.bounds();
  volume_ = mesh_.signedVolume();
  spacing_ = opt.spacing;
  exactBand_ = Real(opt.exactBand);

  const double nodes = gridNodes(bounds_, opt.spacing, opt.band);
  if (nodes > double(opt.maxNodes)) {
    std::ostringstream m;
    m << "its signed-distance grid at the particle radius (" << opt.spacing << " m) over the mesh bounds ("
      << bounds_.size()[0] << " x " << bounds_.size()[1] << " x " << bounds_.size()[2] << " m) plus " << opt.band
      << " m would have " << nodes << " nodes, more than the limit of " << opt.maxNodes
      << "; use a larger particle_radius or a smaller mesh";
    throw MeshGridTooLarge(m.str());
  }

  // Pseudonormals: face normals, per edge the sum of its two faces', per
  // vertex the angle-weighted sum of its faces'.
  const size_t nt = mesh_.triangles.size();
  faceNormal_.resize(nt);
  edgeNormal_.assign(nt, {Vec3d::Zero(), Vec3d::Zero(), Vec3d::Zero()});
  vertexNormal_.assign(mesh_.vertices.size(), Vec3d::Zero());
  std::map<std::pair<uint32_t, uint32_t>, std::pair<uint32_t, int>> open;  // directed edge -> (triangle, edge)
  for (uint32_t t = 0; t < nt; ++t) {
    const auto& v = mesh_.triangles[t];
    const Vec3d& a = mesh_.vertices[v[0]];
    const Vec3d& b = mesh_.vertices[v[1]];
    const Vec3d& c = mesh_.vertices[v[2]];
    faceNormal_[t] = (b - a).cross(c - a).normalized();
    for (int k = 0; k < 3; ++k) {
      const Vec3d& p0 = mesh_.vertices[v[size_t(k)]];
      const Vec3d e1 = (mesh_.vertices[v[size_t((k + 1) % 3)]] - p0).normalized();
      const Vec3d e2 = (mesh_.vertices[v[size_t((k + 2) % 3)]] - p0).normalized();
      vertexNormal_[v[size_t(k)]] += std::acos(std::clamp(e1.dot(e2), -1.0, 1.0)) * faceNormal_[t];
      const uint32_t i = v[size_t(k)], j = v[size_t((k + 1) % 3)];
      auto it = open.find({j, i});
      if (it != open.end()) {
        const Vec3d sum = faceNormal_[t] + faceNormal_[it->second.first];
        edgeNormal_[t][size_t(k)] = sum;
        edgeNormal_[it->second.first][size_t(it->second.second)] = sum;
        open.erase(it);
      } else {
        open[{i, j}] = {t, k};
      }
    }
  }
  if (!open.empty())
    throw std::invalid_argument("mesh is not closed: " + std::to_string(open.size()) + " edges without an opposite partner");

  std::vector<Vec3d> centroids(nt);
  for (size_t t = 0; t < nt; ++t) {
    const auto& v = mesh_.triangles[t];
    centroids[t] = (mesh_.vertices[v[0]] + mesh_.vertices[v[1]] + mesh_.vertices[v[2]]) / 3;
  }
  order_.resize(nt);
  for (uint32_t t = 0; t < nt; ++t) order_[t] = t;
  nodes_.reserve(2 * nt / kLeafSize + 2);
  buildNode(0, uint32_t(nt), centroids);

  // The grid: nodes gridMin + i h over the bounds plus the band.
  Vec3d lo;
  for (int d = 0; d < 3; ++d) {
    dims_[d] = int(std::ceil((double(bounds_.size()[d]) + 2 * opt.band) / opt.spacing)) + 1;
    const double span = (dims_[d] - 1) * opt.spacing;
    lo[d] = 0.5 * (double(bounds_.min[d]) + double(bounds_.max[d])) - 0.5 * span;
  }
  gridMin_ = lo.cast<Real>();
  for (int d = 0; d < 3; ++d) gridMax_[d] = Real(lo[d] + (dims_[d] - 1) * opt.spacing);
  invSpacing_ = Real(1 / opt.spacing);
  values_.resize(size_t(dims_[0]) * size_t(dims_[1]) * size_t(dims_[2]));
  const double h = opt.spacing;
  const double inf = std::numeric_limits<double>::infinity();

  // The coarse grid: every 4th node (and one beyond the fine grid's end).
  constexpr int C = 4;
  Eigen::Vector3i cd;
  for (int d = 0; d < 3; ++d) cd[d] = (dims_[d] - 1 + C - 1) / C + 1;
  std::vector<double> coarse(size_t(cd[0]) * size_t(cd[1]) * size_t(cd[2]));
  const long coarseRows = long(cd[1]) * long(cd[2]);
#pragma omp parallel for schedule(dynamic, 4)
  for (long row = 0; row < coarseRows; ++row) {
    const int j = int(row % cd[1]), k = int(row / cd[1]);
    double prev = inf;
    for (int i = 0; i < cd[0]; ++i) {
      const Vec3d p = lo + C * h * Vec3d(i, j, k);
      // The previous node's distance plus one step bounds this one's
      // (distance is 1-Lipschitz), which prunes most of the BVH.
      const double d = nodeDistance(p, std::isfinite(prev) ? std::abs(prev) + C * h : inf);
      coarse[size_t(i) + size_t(cd[0]) * size_t(row)] = d;
      prev = d;
    }
  }
  auto cv = [&](int i, int j, int k) { return coarse[size_t(i) + size_t(cd[0]) * (size_t(j) + size_t(cd[1]) * size_t(k))]; };
  // Far coarse cells: every point of them farther than 4 fine cells from the
  // surface (each point is within half a diagonal of a corner).
  const double diag = std::sqrt(3.0) * C * h;
  std::vector<uint8_t> far(size_t(cd[0] - 1) * size_t(cd[1] - 1) * size_t(cd[2] - 1));
  std::vector<double> cellMin(far.size());
  for (int k = 0; k + 1 < cd[2]; ++k)
    for (int j = 0; j + 1 < cd[1]; ++j)
      for (int i = 0; i + 1 < cd[0]; ++i) {
        double m = inf;
        bool same = true;
        const double c0 = cv(i, j, k);
        for (int c = 0; c < 8; ++c) {
          const double v = cv(i + (c & 1), j + ((c >> 1) & 1), k + (c >> 2));
          m = std::min(m, std::abs(v));
          same = same && ((v < 0) == (c0 < 0));
        }
        const size_t id = size_t(i) + size_t(cd[0] - 1) * (size_t(j) + size_t(cd[1] - 1) * size_t(k));
        far[id] = same && m > 0.5 * diag + C * h;
        cellMin[id] = m;
      }
  const long rows = long(dims_[1]) * long(dims_[2]);
  size_t exactNodes = 0;
#pragma omp parallel for schedule(dynamic, 4) reduction(+ : exactNodes)
  for (long row = 0; row < rows; ++row) {
    const int j = int(row % dims_[1]), k = int(row / dims_[1]);
    const int cj = std::min(j / C, cd[1] - 2), ck = std::min(k / C, cd[2] - 2);
    double prev = inf;
    for (int i = 0; i < dims_[0]; ++i) {
      const int ci = std::min(i / C, cd[0] - 2);
      const size_t id = size_t(ci) + size_t(cd[0] - 1) * (size_t(cj) + size_t(cd[1] - 1) * size_t(ck));
      double d;
      if (far[id]) {
        const double tx = double(i - ci * C) / C, ty = double(j - cj * C) / C, tz = double(k - ck * C) / C;
        d = 0;
        for (int c = 0; c < 8; ++c)
          d += ((c & 1) ? tx : 1 - tx) * (((c >> 1) & 1) ? ty : 1 - ty) * ((c >> 2) ? tz : 1 - tz) *
               cv(ci + (c & 1), cj + ((c >> 1) & 1), ck + (c >> 2));
        prev = inf;
      } else {
        const Vec3d p = lo + h * Vec3d(i, j, k);
        const double bound = std::min(std::isfinite(prev) ? std::abs(prev) + h : inf, cellMin[id] + diag);
        d = nodeDistance(p, bound);
        prev = d;
        ++exactNodes;
      }
      values_[size_t(i) + size_t(dims_[0]) * size_t(row)] = Real(d);
    }
  }
  exactNodes_ = exactNodes;
  buildMs_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace fc
