#pragma once
// Affine maps x -> A x + t, with A any invertible linear part (rotation,
// per-axis scale, reflection). Used for instance placement and obstacles.
#include "core/types.h"
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <array>

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

// Orientation from Euler angles in degrees, R = Rx·Ry·Rz (bodies and mesh
// placements in scene files).
inline Eigen::Quaterniond eulerXYZDegrees(const std::array<double, 3>& deg) {
  constexpr double k = 3.14159265358979323846 / 180;
  return Eigen::AngleAxisd(deg[0] * k, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(deg[1] * k, Eigen::Vector3d::UnitY()) *
         Eigen::AngleAxisd(deg[2] * k, Eigen::Vector3d::UnitZ());
}

// A scene file's rotation: 2D one counter-clockwise angle, 3D Euler XYZ, in degrees.
template <int D>
Eigen::Matrix<double, D, D> rotationFromDegrees(const std::array<double, D == 2 ? 1 : 3>& deg) {
  if constexpr (D == 2) return Eigen::Rotation2Dd(deg[0] * 3.14159265358979323846 / 180).toRotationMatrix();
  else return eulerXYZDegrees(deg).toRotationMatrix();
}

}  // namespace fc
