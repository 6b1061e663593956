#pragma once
// Affine maps x -> A x + t, with A any invertible linear part (rotation,
// per-axis scale, reflection). Used for instance placement and obstacles.
#include "core/types.h"
#include <Eigen/LU>

namespace fc {

template <int D>
struct Affine {
  Mat<D> linear = Mat<D>::Identity();
  Vec<D> translation = Vec<D>::Zero();

  Vec<D> point(const Vec<D>& x) const { return linear * x + translation; }
  Vec<D> vector(const Vec<D>& v) const { return linear * v; }
  Affine inverse() const {
    Affine r;
    r.linear = linear.inverse();
    r.translation = -(r.linear * translation);
    return r;
  }
  Affine operator*(const Affine& o) const {
    Affine r;
    r.linear = linear * o.linear;
    r.translation = linear * o.translation + translation;
    return r;
  }
  Real determinant() const { return linear.determinant(); }
  bool reflects() const { return determinant() < 0; }

  static Affine translate(const Vec<D>& t) {
    Affine r;
    r.translation = t;
    return r;
  }
  static Affine scale(const Vec<D>& s) {
    Affine r;
    r.linear = s.asDiagonal();
    return r;
  }
  // Homogeneous (D+1)x(D+1) matrix, row-major order, for the wire and export.
  Eigen::Matrix<Real, D + 1, D + 1> homogeneous() const {
    Eigen::Matrix<Real, D + 1, D + 1> m = Eigen::Matrix<Real, D + 1, D + 1>::Identity();
    m.template topLeftCorner<D, D>() = linear;
    m.template topRightCorner<D, 1>() = translation;
    return m;
  }
};

}  // namespace fc
