// The volume map of a scene's static solids: see volume_map.h.
#include "sph/boundary/volume_map.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>

namespace fc {
namespace {

// 4224046848 -> "4.22e+09": counts in messages, readable.
std::string readable(double count) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g", count);
  return text;
}

}  // namespace

template <int D>
VolumeMap<D>::VolumeMap(const AABB<D>& domain, const std::vector<Obstacle<D>>& obstacles, const CubicSpline<D>& kernel,
                        Real particleRadius, Real latticeVolume, const Options& options)
    : domain_(domain),
      obstacles_(obstacles),
      kernel_(kernel),
      r_(particleRadius),
      h_(kernel.radius()),
      density_(options.density) {
  if (!(options.spacing > 0)) throw std::invalid_argument("volume map: the grid spacing must be positive");
  if (options.quadrature < 2 || options.quadrature > 64)
    throw std::invalid_argument("volume map: quadrature must be 2 to 64 points per support radius");

  // Quadrature: the centres of a regular grid of cells h/q wide inside the support.
  const int q = options.quadrature;
  const Real step = h_ / Real(q);
  cellVolume_ = Real(std::pow(double(step), D));
  std::array<int, D> k{};
  while (true) {
    Vec<D> y;
    for (int d = 0; d < D; ++d) y[d] = (Real(k[d]) + Real(0.5)) * step - h_;
    if (y.squaredNorm() < h_ * h_) offsets_.push_back(y);
    int d = 0;
    while (d < D && ++k[d] >= 2 * q) k[d++] = 0;
    if (d == D) break;
  }

  // c: a lattice particle one radius from a flat wall at rest density. Its
  // lattice neighbours (rows at 0, 2r, 4r, ... above the wall at -r) give
  // V_lat Σ W; the virtual sample 2r below it gives c I W(2r), I the
  // integral over the flat wall; together 1.
  {
    const Real s = 2 * r_;
    const double missing = flatWallMissingVolume(kernel_, s, latticeVolume);
    const double missingGrad = flatWallMissingPush(kernel_, s, latticeVolume);
    double below = 0;  // the lattice points the wall removes from the particle's support
    forEachLatticeOffset<D>(kernel_, s, [&](const Vec<D>& p) { below += p[1] < 0 && p.norm() < h_ ? 1 : 0; });
    missing_ = Real(missing);
    missingSamples_ = Real(below);
    if (density_) {
      const double flat = integrateDensity([&](const Vec<D>& y) { return r_ + y[1]; });
      if (!(missing > 0 && flat > 0)) throw std::logic_error("density map: no calibration for this kernel");
      scale_ = Real(missing / flat);
      // Where the wall's push acts from: the depth below the particle of the
      // solid it pushes with, weighted by each part's share of ∇B.
      double num = 0, den = 0;
      for (const Vec<D>& y : offsets_) {
        if (r_ + y[1] > 0) continue;
        Real w;
        Vec<D> g;
        kernel_.evaluate(y, w, g);
        num += double(-y[1]) * std::abs(double(g[1]));
        den += std::abs(double(g[1]));
      }
      depth_ = Real(den > 0 ? num / den : double(2 * r_));
      // The lattice's missing ∇W sum against c ∫_solid ∇W: the continuum's
      // solid starts a radius nearer than the first missing row, so its
      // gradient is a fifth short of the lattice's at equal density.
      double grad = 0;
      for (const Vec<D>& y : offsets_) {
        if (r_ + y[1] > 0) continue;
        Real w;
        Vec<D> g;
        kernel_.evaluate(Vec<D>(-y), w, g);
        grad += double(g[1]);
      }
      grad *= double(cellVolume_) * double(scale_);
      gradScale_ = grad != 0 ? Real(missingGrad / grad) : Real(1);
    } else {
      const double flat = integrate([&](const Vec<D>& y) { return r_ + y[1]; });
      const double w2r = double(kernel_.W(2 * r_));
      if (!(missing > 0 && flat > 0 && w2r > 0)) throw std::logic_error("volume map: no calibration for this kernel");
      scale_ = Real(missing / (flat * w2r));
      // The same for the virtual sample at 2r: its V ∇W against the lattice's missing ∇W sum.
      Real w;
      Vec<D> g, up = Vec<D>::Zero();
      up[1] = 2 * r_;
      kernel_.evaluate(up, w, g);
      const double virtualGrad = missing / w2r * double(g[1]);
      gradScale_ = virtualGrad != 0 ? Real(missingGrad / virtualGrad) : Real(1);
    }
  }

  // The grid covers the domain and one cell more on every side.
  spacing_ = options.spacing;
  invSpacing_ = Real(1) / spacing_;
  origin_ = domain_.min - Vec<D>::Constant(spacing_);
  double nodes = 1;
  for (int d = 0; d < D; ++d) {
    const double along = std::ceil((double(domain_.size()[d]) + 2 * double(spacing_)) / double(spacing_)) + 1;
    nodes *= along;
    // Checked in floating point first: a huge domain must not overflow the count.
    if (!(nodes <= double(options.maxNodes)))
      throw std::invalid_argument("volume map: the grid would have more than " + std::to_string(options.maxNodes) +
                                  " nodes (the domain is large for the particle radius; raise map_spacing)");
    count_[d] = long(along);
  }
  const size_t total = size_t(nodes);
  values_.assign(total, 0.0f);

  // Only nodes a particle's interpolation can reach need the integral: those
  // within a cell's diagonal of the band 0 < Φ < h.
  const Real reach = spacing_ * std::sqrt(Real(D)) * Real(1.01);
  const auto coordsAt = [&](long flat) {
    std::array<long, D> c{};
    for (int d = 0; d < D; ++d) {
      c[d] = flat % count_[d];
      flat /= count_[d];
    }
    return c;
  };
  const auto positionOf = [&](const std::array<long, D>& c) {
    Vec<D> x;
    for (int d = 0; d < D; ++d) x[d] = origin_[d] + Real(c[d]) * spacing_;
    return x;
  };
  const auto obstacleDistance = [&](const Vec<D>& x) {
    Real phi = std::numeric_limits<Real>::max();
    for (const auto& o : obstacles_) phi = std::min(phi, o.signedDistance(x));
    return phi;
  };

  // A node whose support no obstacle reaches sees the domain's walls alone,
  // and its integral depends only on its distances to them, which its grid
  // coordinates fix; a wall 2h away cannot reach the support. So such nodes
  // are integrated once per class: along each axis, every coordinate near a
  // wall is a class of its own and all the others are one.
  const Real far = 2 * h_ + spacing_;
  std::array<std::vector<size_t>, D> classOf;  // per axis: the class of each coordinate (0: far from both walls)
  std::array<std::vector<long>, D> member;     // per axis: one coordinate of each class
  std::array<size_t, D> stride{};
  size_t classes = 1;
  for (int d = 0; d < D; ++d) {
    classOf[d].resize(size_t(count_[d]));
    member[d].assign(1, -1);
    for (long k = 0; k < count_[d]; ++k) {
      const Real x = origin_[d] + Real(k) * spacing_;
      if (x - domain_.min[d] >= far && domain_.max[d] - x >= far) {
        classOf[d][size_t(k)] = 0;
        if (member[d][0] < 0) member[d][0] = k;
      } else {
        classOf[d][size_t(k)] = member[d].size();
        member[d].push_back(k);
      }
    }
    stride[d] = classes;
    classes *= member[d].size();
  }
  const auto classKey = [&](const std::array<long, D>& c) {
    size_t key = 0;
    for (int d = 0; d < D; ++d) key += classOf[d][size_t(c[d])] * stride[d];
    return key;
  };
  // -1: outside the band; -2: an obstacle is near; otherwise the node's class.
  const auto kindOf = [&](long flat) -> long {
    const auto c = coordsAt(flat);
    const Vec<D> x = positionOf(c);
    const Real obstacle = obstacleDistance(x);
    const Real phi = std::min(wallDistance(x), obstacle);
    if (!(phi > -reach && phi < h_ + reach)) return -1;
    return obstacle >= far ? long(classKey(c)) : -2;
  };

  std::vector<unsigned char> used(classes, 0);
  size_t general = 0;
#pragma omp parallel for schedule(static) reduction(+ : general)
  for (long flat = 0; flat < long(total); ++flat) {
    const long kind = kindOf(flat);
    if (kind == -2) ++general;
    if (kind >= 0) {
#pragma omp atomic write
      used[size_t(kind)] = 1;
    }
  }
  std::vector<long> keys;
  for (size_t key = 0; key < classes; ++key)
    if (used[key]) keys.push_back(long(key));
  const double evaluations = double(general + keys.size()) * double(offsets_.size());
  if (evaluations > options.maxEvaluations)
    throw std::invalid_argument("volume map: integrating it would take " + readable(evaluations) +
                                " distance evaluations, more than " + readable(options.maxEvaluations) +
                                " (lower quadrature or raise map_spacing)");

  const auto integrateAt = [&](const Vec<D>& x, bool wallsOnly) {
    const auto phi = [&](const Vec<D>& y) {
      const Vec<D> p = x + y;
      return wallsOnly ? wallDistance(p) : distance(p);
    };
    return double(scale_) * (density_ ? integrateDensity(phi) : integrate(phi));
  };
  std::vector<float> classValue(classes, 0.0f);
#pragma omp parallel for schedule(dynamic, 16)
  for (long i = 0; i < long(keys.size()); ++i) {
    size_t key = size_t(keys[size_t(i)]);
    std::array<long, D> c{};
    for (int d = D - 1; d >= 0; --d) {
      c[size_t(d)] = member[d][key / stride[d]];
      key %= stride[d];
    }
    classValue[size_t(keys[size_t(i)])] = float(integrateAt(positionOf(c), true));
  }
  size_t integrated = 0;
#pragma omp parallel for schedule(dynamic, 64) reduction(+ : integrated)
  for (long flat = 0; flat < long(total); ++flat) {
    const long kind = kindOf(flat);
    if (kind == -1) continue;
    values_[size_t(flat)] = kind >= 0 ? classValue[size_t(kind)] : float(integrateAt(positionOf(coordsAt(flat)), false));
    ++integrated;
  }
  integrated_ = integrated;
}

template <int D>
template <class Phi>
double VolumeMap<D>::integrate(const Phi& phi) const {
  const double w0 = double(kernel_.W0());
  double sum = 0;
  for (const Vec<D>& y : offsets_) {
    const Real d = phi(y);
    if (d <= 0) sum += 1;
    else if (d < h_) sum += double(kernel_.W(d)) / w0;
  }
  return sum * double(cellVolume_);
}

template <int D>
template <class Phi>
double VolumeMap<D>::integrateDensity(const Phi& phi) const {
  double sum = 0;
  for (const Vec<D>& y : offsets_)
    if (phi(y) <= 0) sum += double(kernel_.W(y));
  return sum * double(cellVolume_);
}

template <int D>
double VolumeMap<D>::integral(const Vec<D>& x) const {
  const auto phi = [&](const Vec<D>& y) { return distance(Vec<D>(x + y)); };
  return density_ ? integrateDensity(phi) : integrate(phi);
}

template <int D>
Real VolumeMap<D>::wallDistance(const Vec<D>& x) const {
  return fc::wallDistance(domain_, x);
}

template <int D>
Real VolumeMap<D>::distance(const Vec<D>& x) const {
  return solidDistance(domain_, obstacles_, x);
}

template <int D>
size_t VolumeMap<D>::index(const std::array<long, D>& c) const {
  size_t i = 0;
  for (int d = D - 1; d >= 0; --d) i = i * size_t(count_[d]) + size_t(c[d]);
  return i;
}

template <int D>
Real VolumeMap<D>::volume(const Vec<D>& x) const {
  // Multilinear interpolation in the cell that holds x (clamped to the grid).
  std::array<long, D> base{};
  std::array<Real, D> t{};
  for (int d = 0; d < D; ++d) {
    // Clamped before the conversion: a point far outside must not overflow the index.
    const double u = std::clamp(double((x[d] - origin_[d]) * invSpacing_), 0.0, double(count_[d] - 1));
    const long c = std::min(long(u), count_[d] - 2);
    base[d] = c;
    t[d] = std::clamp(Real(u - double(c)), Real(0), Real(1));
  }
  Real v = 0;
  for (int corner = 0; corner < (1 << D); ++corner) {
    std::array<long, D> c = base;
    Real w = 1;
    for (int d = 0; d < D; ++d) {
      const bool up = (corner >> d) & 1;
      c[d] += up;
      w *= up ? t[d] : 1 - t[d];
    }
    v += w * Real(values_[index(c)]);
  }
  return v;
}

template <int D>
Vec<D> VolumeMap<D>::normal(const Vec<D>& x) const {
  // Over a tenth of the support, as SPlisHSPlasH's approximateNormal.
  return solidDistanceGradient(domain_, obstacles_, x, Real(0.1) * h_);
}

template <int D>
Real VolumeMap<D>::virtualSample(const Vec<D>& x, Vec<D>& xb) const {
  const Real phi = distance(x);
  if (!(phi > 0 && phi < h_)) return 0;
  const Real v = volume(x);
  if (!(v > 0)) return 0;
  Vec<D> n = normal(x);
  const Real len = n.norm();
  if (!(len > Real(1e-6))) return 0;
  n /= len;
  // SPlisHSPlasH's placement: half a radius inside the surface, never nearer than a diameter.
  xb = x - std::max(phi + Real(0.5) * r_, 2 * r_) * n;
  return v;
}

template <int D>
bool VolumeMap<D>::densityTerms(const Vec<D>& x, const Vec<D>& gravity, StaticBoundaryTerms<D>& t) const {
  const Real phi = distance(x);
  if (!(phi < h_ && phi > -h_)) return false;
  const Real b = volume(x);
  if (!(b > 0)) return false;
  // ∇B over one grid cell each way: the multilinear interpolant's slope
  // changes from cell to cell, its difference across two cells does not jump.
  Vec<D> grad;
  for (int d = 0; d < D; ++d) {
    Vec<D> a = x, c = x;
    a[d] += spacing_;
    c[d] -= spacing_;
    grad[d] = (volume(a) - volume(c)) / (2 * spacing_);
  }
  Vec<D> n = normal(x);
  const Real len = n.norm();
  n = len > Real(1e-6) ? Vec<D>(n / len) : Vec<D>::Zero();
  t.volume = b;
  grad *= gradScale_;
  t.grad = grad;
  // The solid's pressure grows with its depth below the particle: Δp_b/ρ0 = g·(x_b - x_i), x_b - x_i ≈ -(depth) n.
  t.extrapolation = (-(depth_ + (phi - r_)) * gravity.dot(n)) * grad;
  t.samples = unsigned(std::lround(double(missingSamples_) * double(b) / double(missing_)));
  return true;
}

template class VolumeMap<2>;
template class VolumeMap<3>;

}  // namespace fc
