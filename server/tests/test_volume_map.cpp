// The volume map of static solids (sph/boundary/volume_map.h): a particle of
// the fluid lattice one radius from a flat wall has the rest density with
// its virtual sample, the map falls with the distance to zero at the
// support radius, a corner holds more solid than a flat wall, the virtual
// sample lies along the surface normal (also of a curved obstacle), every
// node holds its own integral, and a grid too large or too long to
// integrate is refused with a message.
#include "sph/boundary/volume_map.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace fc {
namespace {

template <int D>
struct Fixture {
  Real r = Real(0.01);
  CubicSpline<D> kernel{4 * r};
  Real vlat = latticeParticleVolume(kernel, 2 * r);
  AABB<D> domain{Vec<D>::Zero(), Vec<D>::Constant(Real(0.4))};
  typename VolumeMap<D>::Options options() const {
    typename VolumeMap<D>::Options o;
    o.spacing = r;
    return o;
  }
};

// ρ/ρ0 of a lattice particle at x (lattice rows from r above the floor, far
// from the other walls) with the floor's virtual sample: V_lat Σ_j W + V_b W(x - x_b).
template <int D>
double relativeDensity(const Fixture<D>& f, const VolumeMap<D>& map, const Vec<D>& x) {
  const Real s = 2 * f.r;
  const int n = int(std::ceil(f.kernel.radius() / s));
  double sum = 0;
  VecI<D> k = VecI<D>::Constant(-n);
  while (true) {
    const Vec<D> p = x + s * k.template cast<Real>();
    if (p[1] > 0) sum += f.kernel.W(Vec<D>(x - p));
    int d = 0;
    while (d < D && ++k[d] > n) k[d++] = -n;
    if (d == D) break;
  }
  Vec<D> xb;
  const Real vb = map.virtualSample(x, xb);
  return double(f.vlat) * sum + double(vb) * double(f.kernel.W(Vec<D>(x - xb)));
}

template <int D>
void flatWallAtRestDensity() {
  Fixture<D> f;
  VolumeMap<D> map(f.domain, {}, f.kernel, f.r, f.vlat, f.options());
  // A lattice particle in the row against the floor, between grid nodes on every axis.
  Vec<D> x = Vec<D>::Constant(Real(0.2) + Real(0.37) * f.r);
  x[1] = f.r;
  EXPECT_NEAR(relativeDensity(f, map, x), 1.0, 0.005) << "first row, D = " << D;
  Vec<D> xb;
  const Real vb = map.virtualSample(x, xb);
  EXPECT_GT(vb, 0);
  EXPECT_NEAR(double(xb[1]), -double(f.r), 1e-5) << "the sample two radii below, along the normal";
  EXPECT_NEAR(double(xb[0]), double(x[0]), 1e-5);
}

TEST(VolumeMap, FirstRowAtOneRadiusHasRestDensity2D) { flatWallAtRestDensity<2>(); }
TEST(VolumeMap, FirstRowAtOneRadiusHasRestDensity3D) { flatWallAtRestDensity<3>(); }

TEST(VolumeMap, FallsWithDistanceToZeroAtTheSupport) {
  Fixture<2> f;
  f.domain = AABB<2>(Vec<2>::Zero(), Vec<2>::Constant(1));
  VolumeMap<2> map(f.domain, {}, f.kernel, f.r, f.vlat, f.options());
  const Real h = f.kernel.radius();
  Real last = std::numeric_limits<Real>::max();
  for (Real y = Real(0.25) * f.r; y < h; y += Real(0.25) * f.r) {
    const Real v = map.volume(Vec<2>(Real(0.2), y));
    EXPECT_LT(v, last) << "at " << y / f.r << " r";
    EXPECT_GE(v, 0);
    last = v;
  }
  Vec<2> xb;
  EXPECT_EQ(map.virtualSample(Vec<2>(Real(0.2), h * Real(1.01)), xb), 0) << "beyond the support: no sample";
  EXPECT_EQ(map.virtualSample(Vec<2>(Real(0.2), Real(-0.001)), xb), 0) << "inside the solid: no sample";
  // Only the band near the walls is integrated.
  EXPECT_LT(map.integratedNodes(), map.nodes() / 2);
  EXPECT_GT(map.integratedNodes(), 0u);
}

TEST(VolumeMap, CornerHoldsMoreSolidThanAFlatWall) {
  Fixture<2> f;
  VolumeMap<2> map(f.domain, {}, f.kernel, f.r, f.vlat, f.options());
  const Real v = map.volume(Vec<2>(f.r, f.r));
  const Real flat = map.volume(Vec<2>(Real(0.2), f.r));
  EXPECT_GT(v, Real(1.3) * flat);
  Vec<2> xb;
  ASSERT_GT(map.virtualSample(Vec<2>(f.r, f.r), xb), 0);
  EXPECT_NEAR(double(xb[0]), double(xb[1]), 1e-6) << "the corner's sample lies on the diagonal";
}

TEST(VolumeMap, SampleOfACurvedObstacleLiesAlongItsNormal) {
  Fixture<3> f;
  Obstacle<3> ball;
  ball.shape = ObstacleShape::Sphere;
  ball.center = Vec<3>::Constant(Real(0.2));
  ball.radius = Real(0.05);
  VolumeMap<3> map(f.domain, {ball}, f.kernel, f.r, f.vlat, f.options());
  const Vec<3> dir = Vec<3>(1, 2, 2) / 3;
  const Vec<3> x = ball.center + (ball.radius + f.r) * dir;
  EXPECT_NEAR(double(map.distance(x)), double(f.r), 1e-6);
  Vec<3> xb;
  const Real vb = map.virtualSample(x, xb);
  ASSERT_GT(vb, 0);
  const Vec<3> toSample = (x - xb).normalized();
  EXPECT_GT(double(toSample.dot(dir)), 0.999);
  // A convex solid holds less than a flat wall at the same distance.
  EXPECT_LT(vb, map.volume(Vec<3>(Real(0.1), f.r, Real(0.1))));
}

// Nodes that see only the domain's walls are integrated once per class of
// distances to them; every node must still hold its own integral: at the
// corners, edges and faces, near an obstacle and far from everything.
template <int D>
void everyNodeHoldsItsOwnIntegral(bool density) {
  Fixture<D> f;
  Obstacle<D> ball;
  ball.shape = ObstacleShape::Sphere;
  ball.center = Vec<D>::Constant(Real(0.3));
  ball.radius = Real(0.04);
  auto o = f.options();
  o.density = density;
  VolumeMap<D> map(f.domain, {ball}, f.kernel, f.r, f.vlat, o);
  const long count = long(std::lround(double((f.domain.max[0] - f.domain.min[0]) / f.r))) + 3;
  size_t checked = 0, nonzero = 0;
  double worst = 0;
  // Against the map one radius from a flat wall: near the ball, the test's
  // node positions round differently from the map's, which can move a
  // quadrature point across its surface (one point weighs about 1e-4 of it);
  // a node given another node's class would be off by a tenth or more.
  Vec<D> mid = Vec<D>::Constant(Real(0.1));
  mid[1] = f.r;
  const double flat = double(map.scale()) * map.integral(mid);
  ASSERT_GT(flat, 0);
  VecI<D> k = VecI<D>::Zero();
  while (true) {
    // Every other node along each axis, all of them within the support of a wall.
    const Vec<D> x = f.domain.min - Vec<D>::Constant(f.r) + f.r * k.template cast<Real>();
    const double expected = double(map.scale()) * map.integral(x);
    const double got = double(map.volume(x));
    const Real phi = map.distance(x);
    if (phi > -f.r && phi < f.kernel.radius()) {
      worst = std::max(worst, std::abs(got - expected) / flat);
      ++checked;
      nonzero += expected > 0;
    }
    int d = 0;
    while (d < D) {
      k[d] += (k[d] < 8 || k[d] > count - 10) ? 1 : 2;
      if (k[d] < count) break;
      k[d++] = 0;
    }
    if (d == D) break;
  }
  EXPECT_GT(nonzero, size_t(100)) << "D = " << D;
  EXPECT_GT(checked, nonzero / 2);
  EXPECT_LT(worst, 1e-3) << "D = " << D << (density ? ", density map" : ", volume map")
                         << ": the largest difference, relative to the map at one radius from a flat wall";
}

TEST(VolumeMap, EveryNodeHoldsItsOwnIntegral) {
  everyNodeHoldsItsOwnIntegral<2>(false);
  everyNodeHoldsItsOwnIntegral<2>(true);
  everyNodeHoldsItsOwnIntegral<3>(false);
  everyNodeHoldsItsOwnIntegral<3>(true);
}

// A large box without obstacles costs one integration per class of wall
// distances, not one per node: the 3D dam break at r = 0.0125 m is built.
TEST(VolumeMap, ALargeBoxIsIntegratedOncePerClassOfWallDistances) {
  const Real r = Real(0.0125);
  CubicSpline<3> kernel{4 * r};
  const AABB<3> domain{Vec<3>::Zero(), Vec<3>(Real(3.22), Real(1.0), Real(1.0))};
  VolumeMap<3>::Options o;
  o.spacing = r;
  o.maxEvaluations = 1e8;
  VolumeMap<3> map(domain, {}, kernel, r, latticeParticleVolume(kernel, 2 * r), o);
  EXPECT_GT(map.integratedNodes(), size_t(100000));
  // The map of a face far from the edges equals that of the middle of another face.
  const double face = double(map.volume(Vec<3>(Real(1.6), r, Real(0.5))));
  EXPECT_GT(face, 0);
  EXPECT_NEAR(double(map.volume(Vec<3>(Real(0.5), Real(0.5), r))), face, 1e-4 * face);
}

TEST(VolumeMap, TooLargeAGridIsRefused) {
  Fixture<3> f;
  auto o = f.options();
  o.maxNodes = 1000;
  try {
    VolumeMap<3> map(f.domain, {}, f.kernel, f.r, f.vlat, o);
    FAIL() << "a grid of more than 1000 nodes was built";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("map_spacing"), std::string::npos) << e.what();
  }
  // So is one whose integration would take too long (a scene may ask for 32
  // points per support radius): the nodes near an obstacle count one by one.
  Obstacle<3> ball;
  ball.shape = ObstacleShape::Sphere;
  ball.center = Vec<3>::Constant(Real(0.2));
  ball.radius = Real(0.05);
  auto q = f.options();
  q.quadrature = 32;
  q.maxEvaluations = 1e6;
  try {
    VolumeMap<3> map(f.domain, {ball}, f.kernel, f.r, f.vlat, q);
    FAIL() << "a map of more than 1e6 evaluations was integrated";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("quadrature"), std::string::npos) << what;
    EXPECT_NE(what.find("e+"), std::string::npos) << "counts in a readable form: " << what;
    EXPECT_EQ(what.find(".000000"), std::string::npos) << what;
  }
}

}  // namespace
}  // namespace fc
