// Instance model (paper §3.5): keyframed transform track and time map.
//   x_world = R · S · F · (x_template − c) + t
// Expected matrices are built here independently of control/instance.cpp
// (explicit rotation matrices, not Eigen's AngleAxis/Quaternion).
#include "control/instance.h"
#include <gtest/gtest.h>
#include <cmath>
#include <numbers>
#include <random>
#include <string>

using namespace fc;

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDeg = kPi / 180;
// Tolerances for values that went through Real (float by default).
constexpr double kRealEps = sizeof(Real) == 8 ? 1e-12 : 1e-6;
// Evaluate() works in double throughout.
constexpr double kDoubleTol = 1e-12;

template <int D>
using VecD = Eigen::Matrix<double, D, 1>;
template <int D>
using MatD = Eigen::Matrix<double, D, D>;

bool startsWith(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

MatD<2> rot2(double deg) {
  const double a = deg * kDeg;
  MatD<2> r;
  r << std::cos(a), -std::sin(a), std::sin(a), std::cos(a);
  return r;
}

MatD<3> rotX(double deg) {
  const double a = deg * kDeg, c = std::cos(a), s = std::sin(a);
  MatD<3> r;
  r << 1, 0, 0, 0, c, -s, 0, s, c;
  return r;
}
MatD<3> rotY(double deg) {
  const double a = deg * kDeg, c = std::cos(a), s = std::sin(a);
  MatD<3> r;
  r << c, 0, s, 0, 1, 0, -s, 0, c;
  return r;
}
MatD<3> rotZ(double deg) {
  const double a = deg * kDeg, c = std::cos(a), s = std::sin(a);
  MatD<3> r;
  r << c, -s, 0, s, c, 0, 0, 0, 1;
  return r;
}
// Intrinsic XYZ (three.js default): R = Rx · Ry · Rz.
MatD<3> rot3(const std::array<double, 3>& deg) { return rotX(deg[0]) * rotY(deg[1]) * rotZ(deg[2]); }

template <int D>
MatD<D> rotationOf(const TransformKey<D>& k) {
  if constexpr (D == 2) return rot2(k.rotationDeg[0]);
  else return rot3(k.rotationDeg);
}

// R · S · F of a key, built independently.
template <int D>
MatD<D> expectedLinear(const TransformKey<D>& k) {
  MatD<D> s = MatD<D>::Zero();
  MatD<D> f = MatD<D>::Identity();
  for (int d = 0; d < D; ++d) {
    s(d, d) = k.scale[d];
    if (k.reflect[d]) f(d, d) = -1;
  }
  return rotationOf(k) * s * f;
}

template <int D>
TransformKey<D> randomKey(std::mt19937& rng, double time) {
  std::uniform_real_distribution<double> pos(-10, 10), ang(-180, 180), sc(0.25, 4);
  std::bernoulli_distribution coin(0.5);
  TransformKey<D> k;
  k.time = time;
  for (int d = 0; d < D; ++d) {
    k.translation[d] = pos(rng);
    k.scale[d] = sc(rng);
    k.reflect[d] = coin(rng);
  }
  for (auto& r : k.rotationDeg) r = ang(rng);
  return k;
}

template <int D>
TransformTrack<D> randomTrack(std::mt19937& rng, int nKeys) {
  TransformTrack<D> track;
  std::uniform_real_distribution<double> dt(0.1, 2);
  double t = std::uniform_real_distribution<double>(-1, 1)(rng);
  for (int i = 0; i < nKeys; ++i) {
    track.keys.push_back(randomKey<D>(rng, t));
    t += dt(rng);
  }
  return track;
}

template <int D>
Vec<D> randomPoint(std::mt19937& rng, double half = 10) {
  std::uniform_real_distribution<double> pos(-half, half);
  Vec<D> p;
  for (int d = 0; d < D; ++d) p[d] = Real(pos(rng));
  return p;
}

template <int D>
double maxAbsDiff(const MatD<D>& a, const MatD<D>& b) {
  return (a - b).cwiseAbs().maxCoeff();
}

// ---------------------------------------------------------------------------
// Transform track: generic checks for both dimensions.

template <int D>
void checkRoundTripAndCentre(unsigned seed) {
  std::mt19937 rng(seed);
  for (int trial = 0; trial < 200; ++trial) {
    const TransformTrack<D> track = randomTrack<D>(rng, 1 + trial % 4);
    ASSERT_EQ(track.validate(), "");
    const Vec<D> c = randomPoint<D>(rng, 5);
    const double t0 = track.keys.front().time - 0.5, t1 = track.keys.back().time + 0.5;
    for (int s = 0; s < 10; ++s) {
      const double t = std::uniform_real_distribution<double>(t0, t1)(rng);
      const Affine<D> fwd = track.templateToWorld(t, c);
      const Affine<D> inv = fwd.inverse();
      for (int p = 0; p < 10; ++p) {
        const Vec<D> x = randomPoint<D>(rng);
        const Vec<D> back = inv.point(fwd.point(x));
        // Scales in [0.25, 4], |x|, |t| ≤ ~20: condition number ≤ 16.
        EXPECT_LT((back - x).norm(), 2000 * kRealEps * (1 + x.norm()))
            << "trial " << trial << " t " << t << " x " << x.transpose() << " back " << back.transpose();
        const Vec<D> y = fwd.point(inv.point(x));
        EXPECT_LT((y - x).norm(), 2000 * kRealEps * (1 + x.norm()));
      }
      // The centre lands on the evaluated translation.
      MatD<D> m;
      VecD<D> tr;
      track.evaluate(t, m, tr);
      const VecD<D> cw = fwd.point(c).template cast<double>();
      EXPECT_LT((cw - tr).norm(), 200 * kRealEps * (1 + tr.norm() + c.norm()));
      EXPECT_LT(maxAbsDiff<D>(fwd.linear.template cast<double>(), m), 10 * kRealEps * (1 + m.norm()));
    }
    // At key times: the centre maps exactly to the key translation.
    for (const auto& k : track.keys) {
      const Vec<D> cw = track.templateToWorld(k.time, c).point(c);
      EXPECT_LT((cw.template cast<double>() - k.translation).norm(),
                200 * kRealEps * (1 + k.translation.norm() + c.norm()));
    }
  }
}

template <int D>
void checkKeysExact(unsigned seed) {
  std::mt19937 rng(seed);
  for (int trial = 0; trial < 200; ++trial) {
    const TransformTrack<D> track = randomTrack<D>(rng, 1 + trial % 5);
    for (const auto& k : track.keys) {
      MatD<D> m;
      VecD<D> t;
      track.evaluate(k.time, m, t);
      EXPECT_LT(maxAbsDiff<D>(m, expectedLinear(k)), kDoubleTol * 100) << "trial " << trial << " key t " << k.time;
      EXPECT_LT((t - k.translation).norm(), kDoubleTol);
      // And through the Real-typed map: x_world = M (x − c) + t.
      const Vec<D> c = randomPoint<D>(rng, 5);
      const Vec<D> x = randomPoint<D>(rng);
      const VecD<D> expect = expectedLinear(k) * (x - c).template cast<double>() + k.translation;
      const VecD<D> got = track.templateToWorld(k.time, c).point(x).template cast<double>();
      EXPECT_LT((got - expect).norm(), 200 * kRealEps * (1 + expect.norm()));
    }
  }
}

template <int D>
void checkHeldOutside(unsigned seed) {
  std::mt19937 rng(seed);
  for (int trial = 0; trial < 50; ++trial) {
    const TransformTrack<D> track = randomTrack<D>(rng, 2 + trial % 3);
    const auto& first = track.keys.front();
    const auto& last = track.keys.back();
    for (double dt : {1e-6, 0.3, 5.0, 1e6}) {
      MatD<D> m;
      VecD<D> t;
      track.evaluate(first.time - dt, m, t);
      EXPECT_LT(maxAbsDiff<D>(m, expectedLinear(first)), 100 * kDoubleTol);
      EXPECT_LT((t - first.translation).norm(), kDoubleTol);
      track.evaluate(last.time + dt, m, t);
      EXPECT_LT(maxAbsDiff<D>(m, expectedLinear(last)), 100 * kDoubleTol);
      EXPECT_LT((t - last.translation).norm(), kDoubleTol);
    }
  }
}

// Translation and scale are linear between keys (no rotation, so the linear
// part is diag(scale · ±1)).
template <int D>
void checkLinearInterpolation() {
  TransformTrack<D> track;
  TransformKey<D> a, b;
  a.time = 1;
  b.time = 3;
  for (int d = 0; d < D; ++d) {
    a.translation[d] = 1 + d;
    b.translation[d] = -3 + 2 * d;
    a.scale[d] = 0.5 + d;
    b.scale[d] = 2.5 + 0.5 * d;
  }
  a.reflect[0] = b.reflect[0] = true;
  track.keys = {a, b};
  ASSERT_EQ(track.validate(), "");
  for (double u : {0.0, 0.25, 0.5, 0.75}) {
    MatD<D> m;
    VecD<D> t;
    track.evaluate(a.time + u * (b.time - a.time), m, t);
    const VecD<D> expectT = (1 - u) * a.translation + u * b.translation;
    EXPECT_LT((t - expectT).norm(), kDoubleTol) << "u " << u;
    for (int d = 0; d < D; ++d) {
      const double s = (1 - u) * a.scale[d] + u * b.scale[d];
      EXPECT_NEAR(m(d, d), d == 0 ? -s : s, kDoubleTol) << "u " << u << " axis " << d;
      for (int e = 0; e < D; ++e)
        if (e != d) {
          EXPECT_NEAR(m(d, e), 0, kDoubleTol);
        }
    }
  }
}

// Reflection: sign of det(M) is (−1)^(number of reflected axes); with no
// rotation, a reflected axis sends template +axis to world −axis.
template <int D>
void checkReflection() {
  for (int mask = 0; mask < (1 << D); ++mask) {
    TransformKey<D> k;
    k.translation.setConstant(2);
    k.scale.setConstant(1.5);
    int count = 0;
    for (int d = 0; d < D; ++d) {
      k.reflect[d] = (mask >> d) & 1;
      count += k.reflect[d];
    }
    TransformTrack<D> track;
    track.keys = {k};
    Vec<D> c;
    for (int d = 0; d < D; ++d) c[d] = Real(0.3 * (d + 1));
    const Affine<D> a = track.templateToWorld(0, c);
    if (count % 2) {
      EXPECT_LT(a.determinant(), 0) << "mask " << mask;
      EXPECT_TRUE(a.reflects());
    } else {
      EXPECT_GT(a.determinant(), 0) << "mask " << mask;
      EXPECT_FALSE(a.reflects());
    }
    EXPECT_NEAR(std::abs(double(a.determinant())), std::pow(1.5, D), 1e-5);
    for (int d = 0; d < D; ++d) {
      const Vec<D> e = Vec<D>::Unit(d);
      const Vec<D> w = a.point(c + e) - a.point(c);
      const Real sign = k.reflect[d] ? -1 : 1;
      EXPECT_LT((w - sign * Real(1.5) * e).norm(), 1e-5) << "mask " << mask << " axis " << d;
    }
    // Also with a rotation: the sign of the determinant does not change.
    TransformTrack<D> rotated = track;
    for (auto& r : rotated.keys[0].rotationDeg) r = 37;
    const Real det = rotated.templateToWorld(0, c).determinant();
    EXPECT_EQ(det < 0, count % 2 == 1) << "mask " << mask;
    // Random multi-key tracks: det sign follows the active key's reflect.
  }
  std::mt19937 rng(11 + D);
  for (int trial = 0; trial < 100; ++trial) {
    const TransformTrack<D> track = randomTrack<D>(rng, 3);
    for (int s = 0; s < 10; ++s) {
      const double t = std::uniform_real_distribution<double>(track.keys.front().time - 1,
                                                               track.keys.back().time + 1)(rng);
      size_t active = 0;
      for (size_t i = 0; i < track.keys.size(); ++i)
        if (track.keys[i].time <= t) active = i;
      int count = 0;
      for (bool r : track.keys[active].reflect) count += r;
      MatD<D> m;
      VecD<D> tr;
      track.evaluate(t, m, tr);
      EXPECT_EQ(m.determinant() < 0, count % 2 == 1) << "trial " << trial << " t " << t;
    }
  }
}

// Reflection is discrete: the earlier key's until the later key's time.
template <int D>
void checkReflectSwitchesAtLaterKey() {
  TransformKey<D> a, b;
  a.time = 0;
  b.time = 1;
  b.reflect[0] = true;
  b.scale.setConstant(3);
  TransformTrack<D> track;
  track.keys = {a, b};
  for (double t : {0.0, 0.25, 0.5, 0.999, 1 - 1e-9}) {
    MatD<D> m;
    VecD<D> tr;
    track.evaluate(t, m, tr);
    EXPECT_GT(m.determinant(), 0) << "t " << t;
    EXPECT_GT(m(0, 0), 0) << "t " << t;
    // The scale still interpolates while the reflection holds.
    EXPECT_NEAR(m(0, 0), 1 + 2 * t, 1e-9);
  }
  for (double t : {1.0, 1.5, 10.0}) {
    MatD<D> m;
    VecD<D> tr;
    track.evaluate(t, m, tr);
    EXPECT_LT(m.determinant(), 0) << "t " << t;
    EXPECT_NEAR(m(0, 0), -3, 1e-12) << "t " << t;
  }
  // And the other way round: reflected, then not.
  std::swap(track.keys[0].reflect, track.keys[1].reflect);
  MatD<D> m;
  VecD<D> tr;
  track.evaluate(0.999, m, tr);
  EXPECT_LT(m.determinant(), 0);
  track.evaluate(1.0, m, tr);
  EXPECT_GT(m.determinant(), 0);
}

// Central finite difference of templateToWorld for the point the instance
// carries through xWorld at time t.
template <int D>
Vec<D> finiteDifferenceVelocity(const TransformTrack<D>& track, double t, const Vec<D>& c, const Vec<D>& xWorld,
                                double h) {
  const Vec<D> xTemplate = track.templateToWorld(t, c).inverse().point(xWorld);
  const Vec<D> xp = track.templateToWorld(t + h, c).point(xTemplate);
  const Vec<D> xm = track.templateToWorld(t - h, c).point(xTemplate);
  return (xp - xm) / Real(2 * h);
}

}  // namespace

TEST(InstanceTransform, RoundTripAndCentre2D) { checkRoundTripAndCentre<2>(1234); }
TEST(InstanceTransform, RoundTripAndCentre3D) { checkRoundTripAndCentre<3>(4321); }

TEST(InstanceTransform, KeyTimesMatchRSF2D) { checkKeysExact<2>(77); }
TEST(InstanceTransform, KeyTimesMatchRSF3D) { checkKeysExact<3>(78); }

TEST(InstanceTransform, SingleKeyAtRecordingPlaceIsIdentity) {
  // {translation: c} plays the template where it was recorded.
  TransformTrack<3> track;
  TransformKey<3> k;
  k.translation = VecD<3>(1.5, -2, 0.25);
  track.keys = {k};
  const Affine<3> a = track.templateToWorld(0.7, Vec<3>(1.5f, -2, 0.25f));
  EXPECT_LT((a.linear - Mat<3>::Identity()).norm(), 1e-6);
  EXPECT_LT(a.translation.norm(), 1e-6);
}

TEST(InstanceTransform, EmptyTrackActsAsDefaultKey) {
  // An empty track is filled in at bind time; evaluated directly it behaves
  // like one default key (translation 0): identity linear part, the centre
  // mapped to the origin.
  TransformTrack<2> track;
  EXPECT_EQ(track.validate(), "");
  EXPECT_FALSE(track.animated());
  MatD<2> m;
  VecD<2> t;
  track.evaluate(3, m, t);
  EXPECT_EQ(m, MatD<2>::Identity());
  EXPECT_EQ(t, VecD<2>::Zero());
  const Vec<2> c(4, 5);
  const Affine<2> a = track.templateToWorld(3, c);
  const Vec<2> x(1, 2);
  EXPECT_LT((a.point(x) - (x - c)).norm(), 1e-6);
}

TEST(InstanceTransform, EulerOrderIsXYZ3D) {
  // Rx(90)·Ry(90): a template +z axis goes to Rx(90)·(1,0,0)... check explicitly
  // that the order is Rx·Ry·Rz and not Rz·Ry·Rx.
  TransformKey<3> k;
  k.rotationDeg = {90, 90, 0};
  TransformTrack<3> track;
  track.keys = {k};
  MatD<3> m;
  VecD<3> t;
  track.evaluate(0, m, t);
  // Rx(90)·Ry(90)·e_z = Rx(90)·e_x = e_x.
  EXPECT_LT((m * VecD<3>::UnitZ() - VecD<3>::UnitX()).norm(), 1e-12);
  // Rx(90)·Ry(90)·e_x = Rx(90)·(−e_z) = e_y.
  EXPECT_LT((m * VecD<3>::UnitX() - VecD<3>::UnitY()).norm(), 1e-12);
}

TEST(InstanceTransform, HeldBeforeFirstAndAfterLastKey2D) { checkHeldOutside<2>(5); }
TEST(InstanceTransform, HeldBeforeFirstAndAfterLastKey3D) { checkHeldOutside<3>(6); }

TEST(InstanceTransform, TranslationAndScaleLinear2D) { checkLinearInterpolation<2>(); }
TEST(InstanceTransform, TranslationAndScaleLinear3D) { checkLinearInterpolation<3>(); }

TEST(InstanceTransform, AngleInterpolatesLinearly2D) {
  // 0 → 720 degrees: two full turns, passing 360 at the midpoint and 180 at
  // a quarter (a shortest-path interpolation would not move at all).
  TransformKey<2> a, b;
  a.time = 0;
  b.time = 4;
  b.rotationDeg = {720};
  TransformTrack<2> track;
  track.keys = {a, b};
  for (double u : {0.125, 0.25, 0.5, 0.625, 0.75}) {
    MatD<2> m;
    VecD<2> t;
    track.evaluate(4 * u, m, t);
    EXPECT_LT(maxAbsDiff<2>(m, rot2(720 * u)), 1e-12) << "u " << u;
  }
  MatD<2> m;
  VecD<2> t;
  track.evaluate(1, m, t);  // 180 degrees: −I
  EXPECT_LT(maxAbsDiff<2>(m, -MatD<2>::Identity()), 1e-12);
  track.evaluate(2, m, t);  // 360 degrees: I
  EXPECT_LT(maxAbsDiff<2>(m, MatD<2>::Identity()), 1e-12);
  // Negative direction too: 30 → −60 at u = 0.5 is −15.
  track.keys[0].rotationDeg = {30};
  track.keys[1].rotationDeg = {-60};
  track.evaluate(2, m, t);
  EXPECT_LT(maxAbsDiff<2>(m, rot2(-15)), 1e-12);
}

TEST(InstanceTransform, SlerpMidpoint3D) {
  // 0 → 90 degrees about z: 45 at the midpoint, 22.5 at a quarter (slerp has
  // constant angular rate).
  TransformKey<3> a, b;
  a.time = 0;
  b.time = 2;
  b.rotationDeg = {0, 0, 90};
  TransformTrack<3> track;
  track.keys = {a, b};
  for (double u : {0.25, 0.5, 0.75}) {
    MatD<3> m;
    VecD<3> t;
    track.evaluate(2 * u, m, t);
    EXPECT_LT(maxAbsDiff<3>(m, rotZ(90 * u)), 1e-12) << "u " << u;
  }
  // About x, with a non-zero start: 20 → 100 gives 60 at the midpoint.
  track.keys[0].rotationDeg = {20, 0, 0};
  track.keys[1].rotationDeg = {100, 0, 0};
  MatD<3> m;
  VecD<3> t;
  track.evaluate(1, m, t);
  EXPECT_LT(maxAbsDiff<3>(m, rotX(60)), 1e-12);
  // General orientations: the midpoint is the geodesic midpoint, i.e.
  // Ra⁻¹·Rmid == Rmid⁻¹·Rb (equal half-steps), and rotates by half the angle.
  std::mt19937 rng(99);
  for (int trial = 0; trial < 100; ++trial) {
    TransformKey<3> ka = randomKey<3>(rng, 0), kb = randomKey<3>(rng, 1);
    ka.scale.setOnes();
    kb.scale.setOnes();
    ka.reflect = kb.reflect = {};
    track.keys = {ka, kb};
    track.evaluate(0.5, m, t);
    const MatD<3> ra = rot3(ka.rotationDeg), rb = rot3(kb.rotationDeg);
    const MatD<3> step1 = ra.transpose() * m, step2 = m.transpose() * rb;
    EXPECT_LT(maxAbsDiff<3>(step1, step2), 1e-9) << "trial " << trial;
    const double full = std::acos(std::clamp(((ra.transpose() * rb).trace() - 1) / 2, -1.0, 1.0));
    const double half = std::acos(std::clamp((step1.trace() - 1) / 2, -1.0, 1.0));
    EXPECT_NEAR(half, full / 2, 1e-6) << "trial " << trial;
    EXPECT_NEAR(m.determinant(), 1, 1e-12);
  }
}

TEST(InstanceTransform, Reflection2D) { checkReflection<2>(); }
TEST(InstanceTransform, Reflection3D) { checkReflection<3>(); }

TEST(InstanceTransform, ReflectSwitchesAtLaterKey2D) { checkReflectSwitchesAtLaterKey<2>(); }
TEST(InstanceTransform, ReflectSwitchesAtLaterKey3D) { checkReflectSwitchesAtLaterKey<3>(); }

// ---------------------------------------------------------------------------
// pointVelocity

TEST(InstanceTransformVelocity, ZeroForSingleKeyTrack) {
  std::mt19937 rng(3);
  TransformTrack<2> t2;
  t2.keys = {randomKey<2>(rng, 0.5)};
  TransformTrack<3> t3;
  t3.keys = {randomKey<3>(rng, 0.5)};
  EXPECT_FALSE(t2.animated());
  EXPECT_FALSE(t3.animated());
  for (double t : {-1.0, 0.5, 2.0}) {
    EXPECT_EQ(t2.pointVelocity(t, Vec<2>(1, 1), Vec<2>(3, -2)), Vec<2>::Zero());
    EXPECT_EQ(t3.pointVelocity(t, Vec<3>(1, 1, 1), Vec<3>(3, -2, 4)), Vec<3>::Zero());
  }
  TransformTrack<2> empty;
  EXPECT_EQ(empty.pointVelocity(0, Vec<2>(1, 1), Vec<2>(3, -2)), Vec<2>::Zero());
}

TEST(InstanceTransformVelocity, PureTranslation2D) {
  TransformKey<2> a, b;
  a.time = 0;
  a.translation = VecD<2>(0, 0);
  b.time = 2;
  b.translation = VecD<2>(1, 2);
  TransformTrack<2> track;
  track.keys = {a, b};
  std::mt19937 rng(8);
  const Vec<2> c(0.4f, 0.7f);
  for (double t : {0.01, 0.3, 1.0, 1.5, 1.99}) {
    for (int p = 0; p < 10; ++p) {
      const Vec<2> x = randomPoint<2>(rng);
      const Vec<2> v = track.pointVelocity(t, c, x);
      EXPECT_NEAR(v[0], 0.5, 1e-4) << "t " << t;
      EXPECT_NEAR(v[1], 1.0, 1e-4) << "t " << t;
      EXPECT_LT((v - finiteDifferenceVelocity(track, t, c, x, 1e-3)).norm(), 1e-2);
    }
  }
  // Held outside the keys: no motion well before or after.
  EXPECT_LT(track.pointVelocity(-1, c, Vec<2>(0, 0)).norm(), 1e-6);
  EXPECT_LT(track.pointVelocity(3, c, Vec<2>(0, 0)).norm(), 1e-6);
}

TEST(InstanceTransformVelocity, RotationAboutPivot2D) {
  // 0 → 90 degrees over 1 s about the key translation: ω = π/2 rad/s,
  // v = ω ẑ × (x − pivot) = ω (−(y − py), x − px).
  const VecD<2> pivot(1.5, -0.5);
  TransformKey<2> a, b;
  a.time = 0;
  b.time = 1;
  a.translation = b.translation = pivot;
  b.rotationDeg = {90};
  TransformTrack<2> track;
  track.keys = {a, b};
  const double omega = kPi / 2;
  std::mt19937 rng(21);
  const Vec<2> c(3, 4);  // the template centre does not matter
  for (double t : {0.1, 0.25, 0.5, 0.8, 0.95}) {
    for (int p = 0; p < 20; ++p) {
      const Vec<2> x = randomPoint<2>(rng, 3);
      const VecD<2> r = x.cast<double>() - pivot;
      const VecD<2> expect(-omega * r[1], omega * r[0]);
      const Vec<2> v = track.pointVelocity(t, c, x);
      EXPECT_LT((v.cast<double>() - expect).norm(), 1e-3 * (1 + expect.norm()))
          << "t " << t << " x " << x.transpose() << " v " << v.transpose() << " expect " << expect.transpose();
      EXPECT_LT((v - finiteDifferenceVelocity(track, t, c, x, 1e-2)).norm(), 1e-2 * (1 + expect.norm()));
    }
  }
}

TEST(InstanceTransformVelocity, RotationAboutZ3D) {
  const VecD<3> pivot(0.5, 1, -2);
  TransformKey<3> a, b;
  a.time = 2;
  b.time = 3;
  a.translation = b.translation = pivot;
  b.rotationDeg = {0, 0, 90};
  TransformTrack<3> track;
  track.keys = {a, b};
  const VecD<3> omega(0, 0, kPi / 2);
  std::mt19937 rng(22);
  const Vec<3> c(-1, 2, 0.5f);
  for (double t : {2.1, 2.5, 2.9}) {
    for (int p = 0; p < 20; ++p) {
      const Vec<3> x = randomPoint<3>(rng, 3);
      const VecD<3> expect = omega.cross(x.cast<double>() - pivot);
      const Vec<3> v = track.pointVelocity(t, c, x);
      EXPECT_LT((v.cast<double>() - expect).norm(), 1e-3 * (1 + expect.norm())) << "t " << t;
      EXPECT_LT((v - finiteDifferenceVelocity(track, t, c, x, 1e-2)).norm(), 1e-2 * (1 + expect.norm()));
    }
  }
}

template <int D>
void checkVelocityMatchesFiniteDifference(unsigned seed) {
  std::mt19937 rng(seed);
  for (int trial = 0; trial < 50; ++trial) {
    TransformTrack<D> track = randomTrack<D>(rng, 3);
    // Random tracks with reflection changes jump at keys; sample mid-segment.
    const Vec<D> c = randomPoint<D>(rng, 2);
    for (size_t k = 0; k + 1 < track.keys.size(); ++k) {
      const double ta = track.keys[k].time, tb = track.keys[k + 1].time;
      for (double u : {0.3, 0.5, 0.7}) {
        const double t = ta + u * (tb - ta);
        const Vec<D> x = randomPoint<D>(rng, 3);
        const Vec<D> v = track.pointVelocity(t, c, x);
        const Vec<D> fd = finiteDifferenceVelocity(track, t, c, x, 1e-3 * (tb - ta));
        EXPECT_LT((v - fd).norm(), 2e-2 * (1 + v.norm())) << "trial " << trial << " t " << t;
      }
    }
  }
}

TEST(InstanceTransformVelocity, MatchesFiniteDifference2D) { checkVelocityMatchesFiniteDifference<2>(31); }
TEST(InstanceTransformVelocity, MatchesFiniteDifference3D) { checkVelocityMatchesFiniteDifference<3>(32); }

// ---------------------------------------------------------------------------
// validate()

TEST(InstanceTransformValidate, ValidTrackIsEmptyString) {
  std::mt19937 rng(40);
  EXPECT_EQ(randomTrack<2>(rng, 4).validate(), "");
  EXPECT_EQ(randomTrack<3>(rng, 4).validate(), "");
  EXPECT_EQ(TransformTrack<3>{}.validate(), "");
}

TEST(InstanceTransformValidate, OutOfOrderKeys) {
  TransformTrack<2> track;
  TransformKey<2> a, b;
  a.time = 1;
  b.time = 0.5;
  track.keys = {a, b};
  EXPECT_TRUE(startsWith(track.validate(), "[1].time")) << track.validate();
  track.keys[1].time = 1;  // equal times are not strictly increasing
  EXPECT_TRUE(startsWith(track.validate(), "[1].time")) << track.validate();
  track.keys[1].time = 2;
  EXPECT_EQ(track.validate(), "");
  TransformKey<2> c;
  c.time = 1.5;
  track.keys.push_back(c);
  EXPECT_TRUE(startsWith(track.validate(), "[2].time")) << track.validate();
  track.keys[2].time = std::nan("");
  EXPECT_TRUE(startsWith(track.validate(), "[2].time")) << track.validate();
}

TEST(InstanceTransformValidate, NonPositiveScale) {
  TransformTrack<3> track;
  track.keys.resize(1);
  track.keys[0].scale = VecD<3>(1, 0, 1);
  EXPECT_TRUE(startsWith(track.validate(), "[0].scale[1]")) << track.validate();
  track.keys[0].scale = VecD<3>(1, -2, 1);
  EXPECT_TRUE(startsWith(track.validate(), "[0].scale[1]")) << track.validate();
  track.keys[0].scale = VecD<3>(1, 1, std::numeric_limits<double>::infinity());
  EXPECT_TRUE(startsWith(track.validate(), "[0].scale[2]")) << track.validate();
  track.keys[0].scale = VecD<3>(std::nan(""), 1, 1);
  EXPECT_TRUE(startsWith(track.validate(), "[0].scale[0]")) << track.validate();
  TransformTrack<2> t2;
  t2.keys.resize(2);
  t2.keys[1].time = 1;
  t2.keys[1].scale = VecD<2>(2, -0.5);
  EXPECT_TRUE(startsWith(t2.validate(), "[1].scale[1]")) << t2.validate();
}

TEST(InstanceTransformValidate, NonFiniteTranslationAndRotation) {
  TransformTrack<2> track;
  track.keys.resize(1);
  track.keys[0].translation = VecD<2>(std::nan(""), 0);
  EXPECT_TRUE(startsWith(track.validate(), "[0].translation")) << track.validate();
  track.keys[0].translation = VecD<2>(0, -std::numeric_limits<double>::infinity());
  EXPECT_TRUE(startsWith(track.validate(), "[0].translation")) << track.validate();
  track.keys[0].translation.setZero();
  track.keys[0].rotationDeg = {std::numeric_limits<double>::infinity()};
  EXPECT_TRUE(startsWith(track.validate(), "[0].rotation")) << track.validate();

  TransformTrack<3> t3;
  t3.keys.resize(2);
  t3.keys[1].time = 1;
  t3.keys[1].rotationDeg = {0, std::nan(""), 0};
  EXPECT_TRUE(startsWith(t3.validate(), "[1].rotation")) << t3.validate();
  t3.keys[1].rotationDeg = {0, 0, 0};
  t3.keys[1].translation = VecD<3>(0, 0, std::nan(""));
  EXPECT_TRUE(startsWith(t3.validate(), "[1].translation")) << t3.validate();
}

// ---------------------------------------------------------------------------
// TimeMap

TEST(InstanceTimeMap, StartOffset) {
  TimeMap tm;
  tm.start = 2;
  const double dur = 3;
  EXPECT_DOUBLE_EQ(tm.sceneDuration(dur), 3);
  EXPECT_FALSE(tm.active(0, dur));
  EXPECT_FALSE(tm.active(1.99, dur));
  EXPECT_TRUE(tm.active(2, dur));
  EXPECT_TRUE(tm.active(3.5, dur));
  EXPECT_TRUE(tm.active(5, dur));
  EXPECT_FALSE(tm.active(5.01, dur));
  EXPECT_FALSE(tm.active(100, dur));
  EXPECT_DOUBLE_EQ(tm.templateTime(2, dur), 0);
  EXPECT_DOUBLE_EQ(tm.templateTime(3.25, dur), 1.25);
  EXPECT_DOUBLE_EQ(tm.templateTime(5, dur), 3);
  // Clamped outside.
  EXPECT_DOUBLE_EQ(tm.templateTime(0, dur), 0);
  EXPECT_DOUBLE_EQ(tm.templateTime(9, dur), 3);
  // Negative start is allowed: already running at scene time 0.
  tm.start = -1;
  EXPECT_TRUE(tm.active(0, dur));
  EXPECT_DOUBLE_EQ(tm.templateTime(0, dur), 1);
}

TEST(InstanceTimeMap, Crop) {
  TimeMap tm;
  tm.start = 1;
  tm.cropBegin = 0.5;
  tm.cropEnd = 2;
  const double dur = 3;
  EXPECT_EQ(tm.validate(dur), "");
  EXPECT_DOUBLE_EQ(tm.end(dur), 2);
  EXPECT_DOUBLE_EQ(tm.sceneDuration(dur), 1.5);
  EXPECT_DOUBLE_EQ(tm.templateTime(1, dur), 0.5);
  EXPECT_DOUBLE_EQ(tm.templateTime(1.75, dur), 1.25);
  EXPECT_DOUBLE_EQ(tm.templateTime(2.5, dur), 2);
  EXPECT_DOUBLE_EQ(tm.templateTime(0, dur), 0.5);   // clamped to the crop window
  EXPECT_DOUBLE_EQ(tm.templateTime(10, dur), 2);
  EXPECT_TRUE(tm.active(1, dur));
  EXPECT_TRUE(tm.active(2.5, dur));
  EXPECT_FALSE(tm.active(2.6, dur));
}

TEST(InstanceTimeMap, CropEndNegativeMeansTemplateEnd) {
  TimeMap tm;
  tm.cropBegin = 1;
  EXPECT_LT(tm.cropEnd, 0);
  EXPECT_DOUBLE_EQ(tm.end(4), 4);
  EXPECT_DOUBLE_EQ(tm.sceneDuration(4), 3);
  EXPECT_DOUBLE_EQ(tm.templateTime(3, 4), 4);
  EXPECT_DOUBLE_EQ(tm.templateTime(100, 4), 4);
  EXPECT_EQ(tm.validate(4), "");
  tm.cropEnd = -0.5;
  EXPECT_DOUBLE_EQ(tm.end(4), 4);
  tm.reverse = true;
  tm.cropEnd = -1;
  EXPECT_DOUBLE_EQ(tm.templateTime(0, 4), 4);
  EXPECT_DOUBLE_EQ(tm.templateTime(3, 4), 1);
}

TEST(InstanceTimeMap, Speed) {
  TimeMap base;
  base.start = 1;
  base.cropBegin = 0.5;
  base.cropEnd = 2.5;
  TimeMap fast = base;
  fast.speed = 2;
  const double dur = 3;
  EXPECT_DOUBLE_EQ(base.sceneDuration(dur), 2);
  EXPECT_DOUBLE_EQ(fast.sceneDuration(dur), 1);
  EXPECT_TRUE(fast.active(2, dur));
  EXPECT_FALSE(fast.active(2.01, dur));
  for (double s : {0.0, 0.1, 0.4, 0.8}) {
    const double slow = base.templateTime(1 + s, dur) - base.cropBegin;
    const double quick = fast.templateTime(1 + s, dur) - fast.cropBegin;
    EXPECT_NEAR(slow, s, 1e-12);
    EXPECT_NEAR(quick, 2 * s, 1e-12);
  }
  EXPECT_DOUBLE_EQ(fast.templateTime(2, dur), 2.5);
  EXPECT_DOUBLE_EQ(base.velocityFactor(), 1);
  EXPECT_DOUBLE_EQ(fast.velocityFactor(), 2);
  fast.speed = 0.5;
  EXPECT_DOUBLE_EQ(fast.sceneDuration(dur), 4);
  EXPECT_DOUBLE_EQ(fast.velocityFactor(), 0.5);
}

TEST(InstanceTimeMap, Reverse) {
  TimeMap tm;
  tm.start = 1;
  tm.cropBegin = 0.5;
  tm.cropEnd = 2;
  tm.reverse = true;
  const double dur = 3;
  EXPECT_DOUBLE_EQ(tm.sceneDuration(dur), 1.5);
  EXPECT_DOUBLE_EQ(tm.templateTime(1, dur), 2);
  EXPECT_DOUBLE_EQ(tm.templateTime(1.5, dur), 1.5);
  EXPECT_DOUBLE_EQ(tm.templateTime(2.5, dur), 0.5);
  EXPECT_DOUBLE_EQ(tm.templateTime(0, dur), 2);
  EXPECT_DOUBLE_EQ(tm.templateTime(10, dur), 0.5);
  EXPECT_DOUBLE_EQ(tm.velocityFactor(), -1);
  tm.speed = 3;
  EXPECT_DOUBLE_EQ(tm.velocityFactor(), -3);
  EXPECT_DOUBLE_EQ(tm.templateTime(1.25, dur), 1.25);
  // Same window forwards and backwards: mirror images.
  TimeMap fwd = tm;
  fwd.reverse = false;
  for (double s = 1; s <= 1.5; s += 0.05)
    EXPECT_NEAR(tm.templateTime(s, dur), tm.cropBegin + tm.cropEnd - fwd.templateTime(s, dur), 1e-12);
}

TEST(InstanceTimeMap, FrameAtNearest) {
  // 31 frames at 10 fps: 3 s.
  TimeMap tm;
  const double fps = 10;
  const size_t n = 31;
  EXPECT_EQ(tm.frameAt(0, fps, n), 0u);
  EXPECT_EQ(tm.frameAt(1.04, fps, n), 10u);
  EXPECT_EQ(tm.frameAt(1.06, fps, n), 11u);
  EXPECT_EQ(tm.frameAt(0.96, fps, n), 10u);
  EXPECT_EQ(tm.frameAt(3, fps, n), 30u);
  EXPECT_EQ(tm.frameAt(1e6, fps, n), 30u);
  EXPECT_EQ(tm.frameAt(-5, fps, n), 0u);
  // Sweep: the nearest frame to the template time, always in range.
  for (double s = -0.5; s < 4; s += 0.013) {
    const size_t f = tm.frameAt(s, fps, n);
    ASSERT_LE(f, n - 1);
    const double tt = tm.templateTime(s, (n - 1) / fps);
    EXPECT_LE(std::abs(double(f) / fps - tt), 0.5 / fps + 1e-9) << "s " << s;
  }
  // With a start offset and speed.
  tm.start = 2;
  tm.speed = 2;
  EXPECT_EQ(tm.frameAt(2, fps, n), 0u);
  EXPECT_EQ(tm.frameAt(2.5, fps, n), 10u);
  EXPECT_EQ(tm.frameAt(3.5, fps, n), 30u);
  EXPECT_EQ(tm.frameAt(10, fps, n), 30u);
  EXPECT_EQ(tm.frameAt(0, 10, 0), 0u);
  EXPECT_EQ(tm.frameAt(5, 10, 1), 0u);
}

TEST(InstanceTimeMap, FrameAtRespectsCropWindow) {
  const double fps = 10;
  const size_t n = 31;
  TimeMap tm;
  tm.start = 1;
  tm.cropBegin = 0.51;  // frame 5 (0.5 s) lies before the window
  tm.cropEnd = 0.87;    // frame 9 (0.9 s) lies after it
  EXPECT_EQ(tm.validate((n - 1) / fps), "");
  EXPECT_EQ(tm.frameAt(1, fps, n), 6u);
  EXPECT_EQ(tm.frameAt(0, fps, n), 6u);
  EXPECT_EQ(tm.frameAt(1 + tm.sceneDuration(3), fps, n), 8u);
  EXPECT_EQ(tm.frameAt(100, fps, n), 8u);
  for (bool reverse : {false, true}) {
    tm.reverse = reverse;
    size_t lo = n, hi = 0;
    for (double s = 0.5; s < 2; s += 0.001) {
      const size_t f = tm.frameAt(s, fps, n);
      EXPECT_NE(f, 5u) << "s " << s;
      EXPECT_GE(f, 6u) << "s " << s;
      EXPECT_LE(f, 8u) << "s " << s;
      lo = std::min(lo, f);
      hi = std::max(hi, f);
    }
    EXPECT_EQ(lo, 6u);
    EXPECT_EQ(hi, 8u);
  }
  // Reverse starts at the last cropped frame and ends at the first.
  tm.reverse = true;
  EXPECT_EQ(tm.frameAt(1, fps, n), 8u);
  EXPECT_EQ(tm.frameAt(1 + tm.sceneDuration(3), fps, n), 6u);
  // Crop boundaries on frames are inclusive (within rounding).
  tm.reverse = false;
  tm.cropBegin = 0.5;
  tm.cropEnd = 0.9;
  EXPECT_EQ(tm.frameAt(1, fps, n), 5u);
  EXPECT_EQ(tm.frameAt(1 + tm.sceneDuration(3), fps, n), 9u);
  tm.cropBegin = 0.3;  // 0.3 · 10 is not exactly 3 in binary
  EXPECT_EQ(tm.frameAt(1, fps, n), 3u);
}

TEST(InstanceTimeMap, FrameAtNeverExceedsLastFrame) {
  const double fps = 30;
  const size_t n = 46;  // 1.5 s
  for (bool reverse : {false, true}) {
    TimeMap tm;
    tm.reverse = reverse;
    tm.speed = 1.7;
    for (double s = -1; s < 5; s += 0.0037) EXPECT_LE(tm.frameAt(s, fps, n), n - 1);
    // A crop end exactly at the template's end (and just past it, within
    // rounding) still stays in range.
    tm.cropEnd = 1.5;
    for (double s = -1; s < 5; s += 0.0037) EXPECT_LE(tm.frameAt(s, fps, n), n - 1);
    tm.cropEnd = 1.5 + 1e-10;
    for (double s = -1; s < 5; s += 0.0037) EXPECT_LE(tm.frameAt(s, fps, n), n - 1);
  }
  TimeMap rev;
  rev.reverse = true;
  EXPECT_EQ(rev.frameAt(0, fps, n), n - 1);  // full template reversed: last frame first
  EXPECT_EQ(rev.frameAt(1.5, fps, n), 0u);
}

TEST(InstanceTimeMap, VelocityFactor) {
  TimeMap tm;
  for (double s : {0.25, 1.0, 3.0}) {
    tm.speed = s;
    tm.reverse = false;
    EXPECT_DOUBLE_EQ(tm.velocityFactor(), s);
    tm.reverse = true;
    EXPECT_DOUBLE_EQ(tm.velocityFactor(), -s);
  }
}

TEST(InstanceTimeMap, Validate) {
  const double dur = 2;
  TimeMap ok;
  EXPECT_EQ(ok.validate(dur), "");
  ok.cropBegin = 0.5;
  ok.cropEnd = 2;  // exactly the template's end
  ok.speed = 0.1;
  ok.reverse = true;
  ok.start = -3;
  EXPECT_EQ(ok.validate(dur), "");

  TimeMap tm;
  tm.speed = 0;
  EXPECT_TRUE(startsWith(tm.validate(dur), "speed")) << tm.validate(dur);
  tm.speed = -1;
  EXPECT_TRUE(startsWith(tm.validate(dur), "speed")) << tm.validate(dur);
  tm.speed = std::nan("");
  EXPECT_TRUE(startsWith(tm.validate(dur), "speed")) << tm.validate(dur);
  tm.speed = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(startsWith(tm.validate(dur), "speed")) << tm.validate(dur);

  tm = TimeMap{};
  tm.cropBegin = 1;
  tm.cropEnd = 1;
  EXPECT_TRUE(startsWith(tm.validate(dur), "crop_end")) << tm.validate(dur);
  tm.cropEnd = 0.5;
  EXPECT_TRUE(startsWith(tm.validate(dur), "crop_end")) << tm.validate(dur);

  tm = TimeMap{};
  tm.cropEnd = 2.5;  // past the template's end
  EXPECT_TRUE(startsWith(tm.validate(dur), "crop_end")) << tm.validate(dur);
  EXPECT_NE(tm.validate(dur).find("past"), std::string::npos) << tm.validate(dur);

  tm = TimeMap{};
  tm.cropBegin = 3;  // past the template's end
  EXPECT_TRUE(startsWith(tm.validate(dur), "crop_begin")) << tm.validate(dur);
  EXPECT_NE(tm.validate(dur).find("past"), std::string::npos) << tm.validate(dur);

  tm = TimeMap{};
  tm.cropBegin = 2;  // at the end with cropEnd = template end: empty window
  EXPECT_NE(tm.validate(dur), "");

  tm = TimeMap{};
  tm.cropBegin = -0.1;
  EXPECT_TRUE(startsWith(tm.validate(dur), "crop_begin")) << tm.validate(dur);

  tm = TimeMap{};
  tm.start = std::nan("");
  EXPECT_TRUE(startsWith(tm.validate(dur), "start")) << tm.validate(dur);

  tm = TimeMap{};
  tm.cropEnd = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(startsWith(tm.validate(dur), "crop_end")) << tm.validate(dur);
}

// A reflection switching at a key is not motion: the carried point's
// velocity is differentiated inside the segment holding t (a central
// difference across the key measured ~1e4 m/s per metre from the pivot).
TEST(InstanceTransformVelocity, FiniteAcrossReflectSwitch) {
  TransformKey<2> a, b;
  a.time = 0;
  b.time = 1;
  b.reflect[0] = true;
  TransformTrack<2> track;
  track.keys = {a, b};
  for (double t : {0.5, 1 - 5e-5, 1.0, 1 + 5e-5, 1.5})
    EXPECT_LT(track.pointVelocity(t, Vec<2>(0, 0), Vec<2>(1, 0)).norm(), 1e-3) << "t " << t;
}
