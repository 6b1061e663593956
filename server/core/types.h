#pragma once
// Scalar and vector types shared by every layer.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <cstddef>

namespace fc {

#ifdef FLOWCLIP_DOUBLE
using Real = double;
#else
using Real = float;
#endif

template <int D> using Vec = Eigen::Matrix<Real, D, 1>;
template <int D> using Mat = Eigen::Matrix<Real, D, D>;
template <int D> using VecI = Eigen::Matrix<int, D, 1>;
using Vec2 = Vec<2>;
using Vec3 = Vec<3>;

constexpr const char* realName() { return sizeof(Real) == 8 ? "double" : "float"; }

}  // namespace fc

// Every dimension-generic class is instantiated for 2D and 3D exactly once,
// in its own .cpp, through this macro.
#define FC_INSTANTIATE_DIMS(T) \
  template class T<2>;         \
  template class T<3>;
