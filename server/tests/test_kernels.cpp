// Kernel normalisation and discrete consistency on regular lattices.
#include "core/kernel_sums.h"
#include "core/kernels.h"
#include <gtest/gtest.h>
#include <cmath>
#include <vector>

using namespace fc;

namespace {
// Tolerances scale with the precision Real was built with.
constexpr double kTight = sizeof(Real) == 8 ? 1e-9 : 2e-5;

// ∫W over its support by the midpoint rule on a fine grid.
template <int D, class K>
double integrate(const K& kernel, int cellsPerRadius) {
  const double h = kernel.radius();
  const double dx = h / cellsPerRadius;
  double sum = 0;
  const int n = cellsPerRadius;
  if constexpr (D == 2) {
    for (int i = -n; i < n; ++i)
      for (int j = -n; j < n; ++j) sum += kernel.W(Vec<2>(Real((i + 0.5) * dx), Real((j + 0.5) * dx)));
    return sum * dx * dx;
  } else {
    for (int i = -n; i < n; ++i)
      for (int j = -n; j < n; ++j)
        for (int k = -n; k < n; ++k)
          sum += kernel.W(Vec<3>(Real((i + 0.5) * dx), Real((j + 0.5) * dx), Real((k + 0.5) * dx)));
    return sum * dx * dx * dx;
  }
}

// On a lattice of spacing s with particle volume s^D:
//   Σ V W_ij ≈ 1, Σ V ∇W_ij = 0 (by symmetry, exactly), Σ V (x_j - x_i) ⊗ ∇W_ij ≈ I.
template <int D, class K>
void latticeSums(const K& kernel, Real spacing, double& sumW, Vec<D>& sumGrad, Mat<D>& moment) {
  const double V = std::pow(double(spacing), D);
  const int n = int(std::ceil(kernel.radius() / spacing)) + 1;
  sumW = 0;
  sumGrad.setZero();
  moment.setZero();
  Eigen::Matrix<double, D, 1> g = Eigen::Matrix<double, D, 1>::Zero();
  Eigen::Matrix<double, D, D> m = Eigen::Matrix<double, D, D>::Zero();
  auto visit = [&](const Vec<D>& xj) {  // x_i = 0
    sumW += V * kernel.W(Vec<D>(-xj));
    const Vec<D> gw = kernel.gradW(Vec<D>(-xj));
    g += V * gw.template cast<double>();
    m += V * xj.template cast<double>() * gw.template cast<double>().transpose();
  };
  if constexpr (D == 2) {
    for (int i = -n; i <= n; ++i)
      for (int j = -n; j <= n; ++j) visit(Vec<2>(i * spacing, j * spacing));
  } else {
    for (int i = -n; i <= n; ++i)
      for (int j = -n; j <= n; ++j)
        for (int k = -n; k <= n; ++k) visit(Vec<3>(i * spacing, j * spacing, k * spacing));
  }
  sumGrad = g.template cast<Real>();
  moment = m.template cast<Real>();
}
}  // namespace

TEST(Kernels, CubicSplineIntegratesToOne2D) { EXPECT_NEAR(integrate<2>(CubicSpline<2>(0.4f), 400), 1.0, 1e-4); }
TEST(Kernels, CubicSplineIntegratesToOne3D) { EXPECT_NEAR(integrate<3>(CubicSpline<3>(0.4f), 100), 1.0, 1e-3); }
TEST(Kernels, Poly6IntegratesToOne2D) { EXPECT_NEAR(integrate<2>(Poly6<2>(0.3f), 400), 1.0, 1e-4); }
TEST(Kernels, Poly6IntegratesToOne3D) { EXPECT_NEAR(integrate<3>(Poly6<3>(0.3f), 100), 1.0, 1e-3); }

TEST(Kernels, CubicSplineShapeAndGradient) {
  CubicSpline<3> k(1.0f);
  EXPECT_NEAR(k.W(Real(0)), 8.0 / M_PI, 1e-5);
  EXPECT_EQ(k.W(Real(1.0001)), 0);
  EXPECT_NEAR(k.W(Real(0.5)), 8.0 / M_PI * 2 * 0.125, 1e-5);  // both branches meet at q = 1/2
  // The gradient matches a central difference and points from j to i with negative slope.
  const Vec<3> r(0.3f, -0.2f, 0.25f);
  const Vec<3> g = k.gradW(r);
  for (int d = 0; d < 3; ++d) {
    Vec<3> e = Vec<3>::Zero();
    e[d] = 1e-3f;
    EXPECT_NEAR(g[d], (k.W(Vec<3>(r + e)) - k.W(Vec<3>(r - e))) / 2e-3, 2e-3);
  }
  EXPECT_LT(g.dot(r), 0);
  Real w;
  Vec<3> g2;
  k.evaluate(r, w, g2);
  EXPECT_NEAR(w, k.W(r), 1e-6);
  EXPECT_NEAR((g2 - g).norm(), 0, 1e-5);
  EXPECT_EQ(k.gradW(Vec<3>::Zero()).norm(), 0);
  // The branch-free form used by the vectorised density loop agrees.
  for (Real q : {0.0f, 0.1f, 0.3f, 0.5f, 0.51f, 0.8f, 0.999f, 1.0f, 1.2f}) {
    const Vec<3> rq = q * Vec<3>(0.6f, 0.0f, 0.8f);
    Real wf, fac;
    k.evaluateSquared(rq.squaredNorm(), wf, fac);
    EXPECT_NEAR(wf, k.W(rq), 1e-5) << "q = " << q;
    EXPECT_NEAR((fac * rq - k.gradW(rq)).norm(), 0, 1e-4) << "q = " << q;
  }
}

TEST(Kernels, LatticeConsistency2D) {
  const Real r = 0.01f;
  CubicSpline<2> k(4 * r);
  double sumW;
  Vec<2> g;
  Mat<2> m;
  latticeSums<2>(k, 2 * r, sumW, g, m);
  EXPECT_NEAR(sumW, 1.0, 0.02);
  EXPECT_NEAR(g.norm() * 2 * r, 0.0, kTight);  // exact by symmetry, up to rounding
  EXPECT_NEAR((m - Mat<2>::Identity()).norm(), 0.0, 0.02);
}

TEST(Kernels, LatticeConsistency3D) {
  const Real r = 0.01f;
  CubicSpline<3> k(4 * r);
  double sumW;
  Vec<3> g;
  Mat<3> m;
  latticeSums<3>(k, 2 * r, sumW, g, m);
  EXPECT_NEAR(sumW, 1.0, 0.02);
  EXPECT_NEAR(g.norm() * 2 * r, 0.0, kTight);
  // With only two lattice spacings per support radius the moment is off by
  // about 2 % per diagonal entry (Frobenius norm 0.035).
  EXPECT_NEAR((m - Mat<3>::Identity()).norm(), 0.0, 0.05);
}

TEST(Kernels, Poly6LatticeConsistency3D) {
  // Poly6 is flat near the centre, so it needs a wider support than the cubic
  // spline for the same discrete accuracy: three lattice spacings.
  const Real r = 0.01f;
  Poly6<3> k(6 * r);
  double sumW;
  Vec<3> g;
  Mat<3> m;
  latticeSums<3>(k, 2 * r, sumW, g, m);
  EXPECT_NEAR(sumW, 1.0, 0.02);
  EXPECT_NEAR(g.norm() * 2 * r, 0.0, kTight);
  EXPECT_NEAR((m - Mat<3>::Identity()).norm(), 0.0, 0.03);
}

// sumRanges: the per-axis sum over [begin, end), whatever the range's length
// and offset (sixteen-wide bodies, masked tails, empty ranges), equals the
// sum taken in double.
template <int D>
void checkSumRanges() {
  std::vector<std::vector<Real>> axes(D, std::vector<Real>(200));
  for (int d = 0; d < D; ++d)
    for (size_t k = 0; k < axes[d].size(); ++k) axes[d][k] = Real(std::sin(0.7 * double(k) + d) * (1 + d));
  const Real* a[D];
  for (int d = 0; d < D; ++d) a[d] = axes[d].data();
  for (size_t begin : {0, 1, 5, 16, 31})
    for (size_t length = 0; length <= 70; ++length) {
      const Vec<D> s = sumRanges<D>(a, begin, begin + length);
      for (int d = 0; d < D; ++d) {
        double expected = 0, magnitude = 0;
        for (size_t k = begin; k < begin + length; ++k) {
          expected += double(a[d][k]);
          magnitude += std::abs(double(a[d][k]));
        }
        EXPECT_NEAR(double(s[d]), expected, kTight * (1 + magnitude))
            << "axis " << d << ", begin " << begin << ", length " << length;
      }
    }
}
TEST(KernelSums, SumRangesEqualTheSumForEveryLengthAndOffset2D) { checkSumRanges<2>(); }
TEST(KernelSums, SumRangesEqualTheSumForEveryLengthAndOffset3D) { checkSumRanges<3>(); }
