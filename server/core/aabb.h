#pragma once
#include "core/types.h"
#include <algorithm>
#include <limits>

namespace fc {

template <int D>
struct AABB {
  Vec<D> min = Vec<D>::Constant(std::numeric_limits<Real>::max());
  Vec<D> max = Vec<D>::Constant(std::numeric_limits<Real>::lowest());

  AABB() = default;
  AABB(const Vec<D>& lo, const Vec<D>& hi) : min(lo), max(hi) {}

  bool empty() const { return (max.array() < min.array()).any(); }
  Vec<D> size() const { return max - min; }
  Vec<D> center() const { return Real(0.5) * (min + max); }
  Real volume() const { return empty() ? Real(0) : size().prod(); }
  void extend(const Vec<D>& p) {
    min = min.cwiseMin(p);
    max = max.cwiseMax(p);
  }
  void extend(const AABB& b) {
    min = min.cwiseMin(b.min);
    max = max.cwiseMax(b.max);
  }
  AABB grown(Real d) const { return AABB(min.array() - d, max.array() + d); }
  bool contains(const Vec<D>& p) const {
    return (p.array() >= min.array()).all() && (p.array() <= max.array()).all();
  }
  bool contains(const AABB& b) const { return contains(b.min) && contains(b.max); }
  bool intersects(const AABB& b) const {
    return (b.min.array() <= max.array()).all() && (b.max.array() >= min.array()).all();
  }
  // Distance from p to the box (0 inside).
  Real distance(const Vec<D>& p) const {
    Vec<D> d = (min - p).cwiseMax(p - max).cwiseMax(Vec<D>::Zero());
    return d.norm();
  }
};

}  // namespace fc
