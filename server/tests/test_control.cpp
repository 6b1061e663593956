// Control forces (paper §3.3, §3.5): coverage α (eq. 3), attraction (eq. 2),
// velocity (eq. 4), repulsion (eq. 5), falloff, phase selection, evaluation
// in template space, and resolution independence of the normalisation.
//
// Templates here are built in code: lattice blocks of control particles
// (spacing 2r_T), so every expectation follows from geometry.
#include "control/control.h"
#include "sph/simulation.h"
#include <gtest/gtest.h>
#include <cmath>
#include <memory>
#include <numbers>
#include <random>

using namespace fc;

namespace {

constexpr Real kRT = Real(0.01);  // template particle radius
constexpr double kRho0 = 1000;

// A template whose every frame is a lattice block `fill` (spacing 2r_T)
// moving at `velocity`, captured in `region`.
template <int D>
std::shared_ptr<Template<D>> blockTemplate(const AABB<D>& region, const AABB<D>& fill,
                                           const Vec<D>& velocity = Vec<D>::Zero(), int frames = 3) {
  auto t = std::make_shared<Template<D>>();
  t->header.name = "block";
  t->header.dimension = D;
  t->header.frameRate = 30;
  t->header.particleRadius = kRT;
  t->header.supportRadius = 4 * kRT;
  t->header.restDensity = kRho0;
  for (int d = 0; d < D; ++d) {
    t->header.regionMin.push_back(region.min[d]);
    t->header.regionMax.push_back(region.max[d]);
  }
  TemplateFrame<D> f;
  const Real s = 2 * kRT;
  VecI<D> n;
  for (int d = 0; d < D; ++d) n[d] = int(std::floor(fill.size()[d] / s + Real(1e-4)));
  VecI<D> i = VecI<D>::Zero();
  while (true) {
    Vec<D> p;
    for (int d = 0; d < D; ++d) p[d] = fill.min[d] + s * (Real(i[d]) + Real(0.5));
    f.x.push_back(p);
    f.v.push_back(velocity);
    f.mass.push_back(Real(kRho0 * std::pow(double(s), D)));
    f.phase.push_back(0);
    int d = 0;
    while (d < D && ++i[d] >= n[d]) i[d] = 0, ++d;
    if (d == D) break;
  }
  t->frames.assign(size_t(frames), f);
  return t;
}

template <int D>
BoundInstance<D> bind(std::shared_ptr<Template<D>> tpl, const TransformKey<D>* key = nullptr) {
  BoundInstance<D> b;
  b.spec.name = "instance";
  b.spec.templateName = tpl->header.name;
  b.spec.params = instanceParamTable(D).defaults();
  TransformKey<D> k;
  if (key) k = *key;
  else k.translation = tpl->region().center().template cast<double>();
  b.spec.transform.keys = {k};
  b.accel = std::make_shared<TemplateAccel<D>>(TemplateAccel<D>::build(std::shared_ptr<const Template<D>>(tpl)));
  return b;
}

template <int D>
SimulationSetup<D> liquidSetup(const AABB<D>& domain, std::vector<AABB<D>> blocks, Real radius,
                               std::vector<int> phases = {}) {
  SimulationSetup<D> s;
  s.particleRadius = radius;
  s.domain = domain;
  s.gravity = Vec<D>::Zero();
  s.phases = {Phase{}, Phase{"oil", 800, 0, {1, 1, 0}}};
  for (size_t k = 0; k < blocks.size(); ++k) {
    FluidBlock<D> b;
    b.box = blocks[k];
    b.phase = k < phases.size() ? phases[k] : 0;
    s.fluidBlocks.push_back(b);
  }
  s.solver.name = "dfsph";
  return s;
}

template <int D>
struct Rig {
  std::unique_ptr<Simulation<D>> sim;
  Control<D>* control = nullptr;
  Rig(const SimulationSetup<D>& setup, std::vector<BoundInstance<D>> instances,
      const ControlSettings& settings = controlSettingsTable().defaults()) {
    sim = std::make_unique<Simulation<D>>(setup);
    auto c = std::make_unique<Control<D>>(std::move(instances), settings);
    control = c.get();
    sim->addEffect(std::move(c), "control");
  }
  // Control accelerations for the current particles at scene time t.
  const std::vector<Vec<D>>& evaluate(double t = 0) {
    sim->refreshNeighbors();
    control->selectActive(t);
    control->computeForces(*sim, Real(1.0 / 60));
    return control->controlAcceleration();
  }
};

AABB<2> box2(Real x0, Real y0, Real x1, Real y1) { return AABB<2>(Vec<2>(x0, y0), Vec<2>(x1, y1)); }

}  // namespace

// Equation (3): α_j = 1 − min(Σ_i V_i W, 1). The paper's α is the attraction
// factor: 0 where liquid fully covers a control particle, 1 where none does.
TEST(ControlCoverage, ZeroUnderFullLiquidOneWithout) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  auto tpl = blockTemplate<2>(region, region);
  // Liquid of the template's own spacing covering the block with a margin.
  Rig<2> covered(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.3f, 0.3f, 0.7f, 0.7f)}, kRT), {bind<2>(tpl)});
  covered.evaluate();
  const auto& alpha = covered.control->coverage(0);
  ASSERT_EQ(alpha.size(), tpl->frames[0].size());
  for (size_t j = 0; j < alpha.size(); ++j) {
    EXPECT_GE(alpha[j], 0);
    EXPECT_LT(alpha[j], 0.05) << "control particle " << j << " is under liquid";
  }
  // No liquid anywhere near: every α is exactly 1.
  Rig<2> empty(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.0f, 0.0f, 1.0f, 0.1f)}, kRT), {bind<2>(tpl)});
  empty.evaluate();
  for (Real a : empty.control->coverage(0)) EXPECT_EQ(a, 1);
  // Half covered: the covered half is low, the uncovered far edge is 1.
  Rig<2> half(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.3f, 0.3f, 0.5f, 0.7f)}, kRT), {bind<2>(tpl)});
  half.evaluate();
  const auto& xs = tpl->frames[0].x;
  for (size_t j = 0; j < xs.size(); ++j) {
    if (xs[j].x() < 0.46f) EXPECT_LT(half.control->coverage(0)[j], 0.1);
    if (xs[j].x() > 0.55f) EXPECT_EQ(half.control->coverage(0)[j], 1);
  }
}

// Equation (2): liquid next to an empty template region is pulled into it.
TEST(ControlForces, AttractionPointsIntoTheEmptyTemplate) {
  const auto region = box2(0.3f, 0.3f, 0.7f, 0.7f);
  auto tpl = blockTemplate<2>(region, box2(0.5f, 0.3f, 0.7f, 0.7f));  // right half filled
  auto inst = bind<2>(tpl);
  inst.spec.params.velocityWeight = 0;
  inst.spec.params.repulsion = false;
  // A thin liquid column left of the control block, inside the box.
  Rig<2> rig(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.45f, 0.44f, 0.49f, 0.56f)}, kRT), {inst});
  const auto& acc = rig.evaluate();
  const auto& f = rig.sim->fluid;
  size_t pulled = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    const Real gap = Real(0.51) - f.x[i].x();  // distance to the block's first column
    if (gap < 4 * kRT - Real(1e-4)) {  // within h_T of the block: pulled right, towards it
      EXPECT_GT(acc[i].x(), 0) << "particle " << i;
      EXPECT_GT(acc[i].x(), 5 * std::abs(acc[i].y())) << "particle " << i;
      ++pulled;
    } else {
      EXPECT_EQ(acc[i].norm(), 0) << "particle " << i << " is beyond h_T of every control particle";
    }
  }
  EXPECT_GT(pulled, 0u);
}

// Equation (4): nothing when the liquid already moves like the template;
// towards the template's velocity otherwise.
TEST(ControlForces, VelocityForceVanishesWhenVelocitiesMatch) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  const Vec<2> vT(Real(0.5), Real(-0.25));
  auto tpl = blockTemplate<2>(region, region, vT);
  auto inst = bind<2>(tpl);
  inst.spec.params.attractionWeight = 0;
  inst.spec.params.repulsion = false;
  auto setup = liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.38f, 0.38f, 0.62f, 0.62f)}, kRT);
  Rig<2> rig(setup, {inst});
  for (auto& v : rig.sim->fluid.v) v = vT;
  const auto matched = rig.evaluate();
  Rig<2> still(setup, {inst});
  const auto& pulled = still.evaluate();
  Real strongest = 0;
  for (size_t i = 0; i < matched.size(); ++i) {
    EXPECT_LT(matched[i].norm(), 1e-4f) << "particle " << i;
    strongest = std::max(strongest, pulled[i].norm());
    // At rest, the force points along the template velocity.
    if (pulled[i].norm() > 0) EXPECT_GT(pulled[i].normalized().dot(vT.normalized()), 0.999f);
  }
  EXPECT_GT(strongest, 1.0f);
}

// Equation (5): a particle in the repulsion layer above a slab is pushed back
// down, along the slab normal (the paper's n_k, the density gradient).
TEST(ControlForces, RepulsionPushesBackAlongTheNormal) {
  const auto region = box2(0.2f, 0.2f, 0.8f, 0.8f);
  auto tpl = blockTemplate<2>(region, box2(0.2f, 0.2f, 0.8f, 0.5f));  // slab, top face at y = 0.5
  auto inst = bind<2>(tpl);
  inst.spec.params.attractionWeight = 0;
  inst.spec.params.velocityWeight = 0;
  Rig<2> rig(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.46f, 0.52f, 0.54f, 0.6f)}, kRT), {inst});
  const auto& acc = rig.evaluate();
  const auto& f = rig.sim->fluid;
  size_t pushed = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    if (acc[i].norm() == 0) continue;
    EXPECT_LT(acc[i].y(), 0) << "particle " << i;
    EXPECT_LT(std::abs(acc[i].x()), Real(0.05) * std::abs(acc[i].y())) << "particle " << i;
    ++pushed;
  }
  EXPECT_GT(pushed, 0u);
  // Off: nothing.
  inst.spec.params.repulsion = false;
  Rig<2> off(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.46f, 0.52f, 0.54f, 0.6f)}, kRT), {inst});
  for (const auto& a : off.evaluate()) EXPECT_EQ(a.norm(), 0);
}

// Falloff (§3.5): full weight inside the box, t^γ across the band, nothing
// beyond; only particles in the box and band are visited.
TEST(ControlForces, FalloffFadesAcrossTheBand) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  auto tpl = blockTemplate<2>(region, region, Vec<2>(1, 0));
  auto inst = bind<2>(tpl);
  inst.spec.params.attractionWeight = 0;
  inst.spec.params.repulsion = false;
  inst.spec.params.falloffWidth = 0.1;
  inst.spec.params.falloffDecay = 2;
  // A liquid strip along y = 0.5 from x = 0.1 to 0.9.
  Rig<2> rig(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.1f, 0.49f, 0.9f, 0.51f)}, kRT), {inst});
  const auto& acc = rig.evaluate();
  const auto& f = rig.sim->fluid;
  for (size_t i = 0; i < f.size(); ++i) {
    const Real x = f.x[i].x();
    const Real out = std::max({Real(0.4) - x, x - Real(0.6), Real(0)});
    if (out >= Real(0.1)) EXPECT_EQ(acc[i].norm(), 0) << "x = " << x;
  }
  // The band has no control particle within reach beyond h_T, so compare the
  // fade on an instance whose control particles reach into it: the same
  // particle's force with and without the band weight.
  auto flat = inst;
  flat.spec.params.falloffDecay = 0;  // t^0 = 1 across the band
  Rig<2> rig0(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.1f, 0.49f, 0.9f, 0.51f)}, kRT), {flat});
  const auto& acc0 = rig0.evaluate();
  size_t inBand = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    const Real x = f.x[i].x();
    const Real out = std::max({Real(0.4) - x, x - Real(0.6), Real(0)});
    if (out <= 0) EXPECT_NEAR(acc[i].x(), acc0[i].x(), 1e-4f * std::abs(acc0[i].x()) + 1e-6f);
    else if (out < Real(0.1) && acc0[i].norm() > 0) {
      const Real t = 1 - out / Real(0.1);
      EXPECT_NEAR(acc[i].x(), t * t * acc0[i].x(), 1e-3f * std::abs(acc0[i].x()) + 1e-6f) << "x = " << x;
      ++inBand;
    }
  }
  EXPECT_GT(inBand, 0u);
  // Visited: only the particles of the box and band (not the whole strip).
  size_t expected = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    const Real x = f.x[i].x();
    if (x > Real(0.3) && x < Real(0.7)) ++expected;
  }
  rig.sim->advanceFrame();
  FrameStats fs = rig.sim->advanceFrame();
  ASSERT_EQ(fs.instances.size(), 1u);
  EXPECT_LE(fs.instances[0].controlled, expected);
  EXPECT_GT(fs.instances[0].controlled, expected / 2);
}

// §3.5 multiphase: an instance moves only the phase it names.
TEST(ControlForces, OnlyTheNamedPhase) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  auto tpl = blockTemplate<2>(region, region, Vec<2>(1, 0));
  auto inst = bind<2>(tpl);
  inst.spec.phase = 1;
  Rig<2> rig(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.38f, 0.38f, 0.5f, 0.62f), box2(0.5f, 0.38f, 0.62f, 0.62f)},
                            kRT, {0, 1}),
             {inst});
  const auto& acc = rig.evaluate();
  const auto& f = rig.sim->fluid;
  size_t moved = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    if (f.phase[i] == 0) EXPECT_EQ(acc[i].norm(), 0);
    else moved += acc[i].norm() > 0;
  }
  EXPECT_GT(moved, 0u);
}

// §3.5: forces are evaluated in template space and mapped back. Rotating the
// instance by 90° and scaling it by 2, with the liquid transformed the same
// way, gives the same forces rotated and scaled.
TEST(ControlForces, TemplateSpaceEvaluationCommutesWithTheTransform) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  auto tpl = blockTemplate<2>(region, box2(0.4f, 0.4f, 0.52f, 0.6f), Vec<2>(Real(0.3), Real(0.1)));
  const auto liquidBox = box2(0.44f, 0.36f, 0.64f, 0.6f);
  auto instA = bind<2>(tpl);
  Rig<2> a(liquidSetup<2>(box2(0, 0, 1, 1), {liquidBox}, kRT), {instA});
  for (size_t i = 0; i < a.sim->fluid.size(); ++i)
    a.sim->fluid.v[i] = Vec<2>(Real(0.2) * std::sin(Real(i)), Real(-0.1));
  const auto accA = a.evaluate();

  TransformKey<2> key;
  key.translation << 2.0, 2.0;
  key.rotationDeg = {90};
  key.scale << 2.0, 2.0;
  auto instB = bind<2>(tpl, &key);
  instB.spec.params = instA.spec.params;
  // The falloff band is a world width: twice as wide for the same band in
  // template space.
  instB.spec.params.falloffWidth = key.scale[0] * instanceParamTable(2).defaults().falloffWidth;
  const Affine<2> map = instB.spec.transform.templateToWorld(0, tpl->region().center());
  AABB<2> worldDomain(map.point(Vec<2>(0, 0)).cwiseMin(map.point(Vec<2>(1, 1))),
                      map.point(Vec<2>(0, 0)).cwiseMax(map.point(Vec<2>(1, 1))));
  AABB<2> worldLiquid(map.point(liquidBox.min).cwiseMin(map.point(liquidBox.max)),
                      map.point(liquidBox.min).cwiseMax(map.point(liquidBox.max)));
  Rig<2> b(liquidSetup<2>(worldDomain, {worldLiquid}, Real(key.scale[0]) * kRT), {instB});
  ASSERT_EQ(a.sim->fluid.size(), b.sim->fluid.size());
  for (size_t i = 0; i < a.sim->fluid.size(); ++i) {
    b.sim->fluid.x[i] = map.point(a.sim->fluid.x[i]);
    b.sim->fluid.v[i] = map.vector(a.sim->fluid.v[i]);
  }
  const auto& accB = b.evaluate();
  // Coverage is a property of template space: identical.
  ASSERT_EQ(a.control->coverage(0).size(), b.control->coverage(0).size());
  for (size_t j = 0; j < a.control->coverage(0).size(); ++j)
    EXPECT_NEAR(a.control->coverage(0)[j], b.control->coverage(0)[j], 1e-4f) << "control particle " << j;
  Real scale = 0;
  for (const auto& v : accA) scale = std::max(scale, v.norm());
  ASSERT_GT(scale, 1.0f);
  for (size_t i = 0; i < accA.size(); ++i) {
    const Vec<2> expected = map.vector(accA[i]);
    EXPECT_LT((accB[i] - expected).norm(), 2e-3f * 2 * scale)
        << "particle " << i << " at " << a.sim->fluid.x[i].transpose() << ": " << accA[i].transpose() << " -> "
        << expected.transpose() << " vs " << accB[i].transpose() << " rho " << a.sim->fluid.density[i] << " "
        << b.sim->fluid.density[i];
  }
}

// The normalisation: halving the liquid's particle radius leaves the control
// acceleration field unchanged (compared at matching places).
TEST(ControlForces, IndependentOfTheLiquidResolution) {
  const auto region = box2(0.3f, 0.3f, 0.7f, 0.7f);
  auto tpl = blockTemplate<2>(region, box2(0.4f, 0.3f, 0.7f, 0.7f), Vec<2>(Real(0.2), 0));
  const auto liquidBox = box2(0.3f, 0.3f, 0.5f, 0.62f);
  Rig<2> coarse(liquidSetup<2>(box2(0, 0, 1, 1), {liquidBox}, kRT), {bind<2>(tpl)});
  Rig<2> fine(liquidSetup<2>(box2(0, 0, 1, 1), {liquidBox}, kRT / 2), {bind<2>(tpl)});
  const auto& ac = coarse.evaluate();
  const auto& af = fine.evaluate();
  // Average force over the liquid per unit mass, and the force on the
  // particles near a few probe points: within a few percent.
  auto mean = [](const Simulation<2>& s, const std::vector<Vec<2>>& a) {
    Vec<2> m = Vec<2>::Zero();
    for (size_t i = 0; i < s.fluid.size(); ++i) m += a[i];
    return Vec<2>(m / Real(s.fluid.size()));
  };
  const Vec<2> mc = mean(*coarse.sim, ac), mf = mean(*fine.sim, af);
  ASSERT_GT(mc.norm(), 1.0f);
  EXPECT_LT((mc - mf).norm(), 0.05f * mc.norm()) << mc.transpose() << " vs " << mf.transpose();
  // Probes inside the liquid: at its free surface the SPH sums are truncated
  // differently at each resolution (a discretisation error, not the weights).
  for (Vec<2> probe : {Vec<2>(0.38f, 0.5f), Vec<2>(0.45f, 0.4f), Vec<2>(0.44f, 0.52f)}) {
    auto near = [&](const Simulation<2>& s, const std::vector<Vec<2>>& a) {
      Vec<2> m = Vec<2>::Zero();
      int c = 0;
      for (size_t i = 0; i < s.fluid.size(); ++i)
        if ((s.fluid.x[i] - probe).norm() < 2 * kRT) m += a[i], ++c;
      return Vec<2>(m / Real(std::max(c, 1)));
    };
    const Vec<2> pc = near(*coarse.sim, ac), pf = near(*fine.sim, af);
    EXPECT_LT((pc - pf).norm(), 0.12f * pc.norm() + 0.5f) << "probe " << probe.transpose() << ": " << pc.transpose()
                                                          << " vs " << pf.transpose();
  }
}

// §3.5: a keyframed instance carries its liquid (its own velocity adds to the
// control velocities); play speed multiplies them; reverse negates them.
TEST(ControlForces, InstanceMotionSpeedAndReverseShapeTheTargetVelocity) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  const Vec<2> vT(Real(0.4), Real(0.1));
  auto still = blockTemplate<2>(region, region, Vec<2>::Zero(), 61);  // 2 s at 30 fps
  auto moving = blockTemplate<2>(region, region, vT, 61);
  const auto liquid = box2(0.38f, 0.38f, 0.62f, 0.62f);
  // Velocity force on liquid moving at `v` (attraction and repulsion off).
  auto velocityForce = [&](BoundInstance<2> inst, const Vec<2>& v, double t) {
    inst.spec.params.attractionWeight = 0;
    inst.spec.params.repulsion = false;
    Rig<2> rig(liquidSetup<2>(box2(0, 0, 1, 1), {liquid}, kRT), {inst});
    for (auto& x : rig.sim->fluid.v) x = v;
    const auto& acc = rig.evaluate(t);
    Real largest = 0;
    Vec<2> sum = Vec<2>::Zero();
    for (const auto& a : acc) largest = std::max(largest, a.norm()), sum += a;
    return std::make_pair(largest, sum);
  };
  // A static template on an instance translating at (0.5, -0.2) m/s.
  auto carried = bind<2>(still);
  TransformKey<2> k0, k1;
  k0.time = 0;
  k0.translation = region.center().cast<double>();
  k1.time = 2;
  k1.translation = k0.translation + Eigen::Vector2d(1.0, -0.4);
  carried.spec.transform.keys = {k0, k1};
  const Vec<2> vInstance(Real(0.5), Real(-0.2));
  // At t = 1 the instance sits at its mid-point: move the liquid there.
  auto atMid = [&](BoundInstance<2> inst, const Vec<2>& v) {
    inst.spec.params.attractionWeight = 0;
    inst.spec.params.repulsion = false;
    Rig<2> rig(liquidSetup<2>(box2(0, 0, 2, 1), {AABB<2>(liquid.min + Vec<2>(Real(0.5), Real(-0.2)),
                                                          liquid.max + Vec<2>(Real(0.5), Real(-0.2)))},
                              kRT),
               {inst});
    for (auto& x : rig.sim->fluid.v) x = v;
    const auto& acc = rig.evaluate(1.0);
    Real largest = 0;
    Vec<2> sum = Vec<2>::Zero();
    for (const auto& a : acc) largest = std::max(largest, a.norm()), sum += a;
    return std::make_pair(largest, sum);
  };
  const auto [withIt, sumWith] = atMid(carried, vInstance);
  const auto [atRest, sumRest] = atMid(carried, Vec<2>::Zero());
  EXPECT_LT(withIt, 1e-3f * atRest) << "liquid moving with the instance feels no velocity force";
  EXPECT_GT(sumRest.normalized().dot(vInstance.normalized()), 0.999f) << "liquid at rest is pushed along";

  // Speed 2: the target velocity is 2 v_T.
  auto fast = bind<2>(moving);
  fast.spec.time.speed = 2;
  const auto [fastMatched, s1] = velocityForce(fast, Vec<2>(2 * vT), 0.1);
  const auto [fastSlow, s2] = velocityForce(fast, vT, 0.1);
  EXPECT_LT(fastMatched, 1e-3f * fastSlow);
  EXPECT_GT(s2.normalized().dot(vT.normalized()), 0.999f);
  // Reverse: the target velocity is −v_T.
  auto back = bind<2>(moving);
  back.spec.time.reverse = true;
  const auto [backMatched, s3] = velocityForce(back, Vec<2>(-vT), 0.1);
  const auto [backForward, s4] = velocityForce(back, vT, 0.1);
  EXPECT_LT(backMatched, 1e-3f * backForward);
  EXPECT_LT(s4.normalized().dot(vT.normalized()), -0.999f);
  (void)s1;
  (void)s3;
  (void)sumWith;
}

// An instance outside its time window is not evaluated at all.
TEST(ControlForces, InactiveOutsideTheTimeWindow) {
  const auto region = box2(0.4f, 0.4f, 0.6f, 0.6f);
  auto tpl = blockTemplate<2>(region, region, Vec<2>(1, 0), 4);  // 0.1 s at 30 fps
  auto inst = bind<2>(tpl);
  inst.spec.time.start = 0.5;
  Rig<2> rig(liquidSetup<2>(box2(0, 0, 1, 1), {box2(0.38f, 0.38f, 0.62f, 0.62f)}, kRT), {inst});
  for (double t : {0.0, 0.49, 0.61, 2.0}) {
    const auto& acc = rig.evaluate(t);
    EXPECT_FALSE(rig.control->isActive(0)) << "t = " << t;
    for (const auto& a : acc) ASSERT_EQ(a.norm(), 0) << "t = " << t;
  }
  rig.evaluate(0.55);
  EXPECT_TRUE(rig.control->isActive(0));
  EXPECT_EQ(rig.control->templateFrame(0), 2u);  // 0.05 s into the template at 30 fps: frame 1.5 → 2
}

// The coverage and force sums (equations (2)–(5)) run over the template
// grids' cell-sorted arrays, sixteen candidates at a time where the CPU
// allows. They must equal the equations evaluated directly, pair by pair,
// over every control and repulsion particle: jittered liquid with random
// velocities over part of a moving block, so every term and every partial
// row of candidates is exercised.
template <int D>
void checkSumsAgainstDirectEvaluation() {
  AABB<D> region, fill, liquidBox, domain;
  for (int d = 0; d < D; ++d) {
    region.min[d] = Real(0.3);
    region.max[d] = Real(0.7);
    fill.min[d] = Real(0.36);
    fill.max[d] = Real(0.6);
    liquidBox.min[d] = Real(0.4);
    liquidBox.max[d] = Real(0.66);
    domain.min[d] = 0;
    domain.max[d] = 1;
  }
  Vec<D> vT = Vec<D>::Zero();
  vT[0] = Real(0.7);
  auto tpl = blockTemplate<D>(region, fill, vT);
  auto inst = bind<D>(tpl);
  Rig<D> rig(liquidSetup<D>(domain, {liquidBox}, kRT), {inst});
  auto& f = rig.sim->fluid;
  std::mt19937 rng(11);
  std::uniform_real_distribution<Real> jitter(-Real(0.4) * kRT, Real(0.4) * kRT), speed(-1, 1);
  for (size_t i = 0; i < f.size(); ++i)
    for (int d = 0; d < D; ++d) {
      f.x[i][d] += jitter(rng);
      f.v[i][d] = speed(rng);
    }
  // A short application: neither cap (pull, relaxation rate) binds.
  rig.sim->refreshNeighbors();
  rig.control->selectActive(0);
  const Real applyFor = Real(1e-5);
  rig.control->computeForces(*rig.sim, applyFor);
  const auto& acc = rig.control->controlAcceleration();
  const auto& alpha = rig.control->coverage(0);

  const auto gridsHeld = inst.accel->frame(rig.control->templateFrame(0));
  const auto& grids = *gridsHeld;
  const auto& xc = grids.controlPositions();
  const auto& mc = grids.controlMasses();
  const Real hT = inst.accel->supportRadius;
  const Poly6<D> W(hT);
  const Affine<D> toTemplate = rig.control->toWorld(0).inverse();
  std::vector<Vec<D>> y(f.size());
  for (size_t i = 0; i < f.size(); ++i) y[i] = toTemplate.point(f.x[i]);

  // Equation (3), directly.
  ASSERT_EQ(alpha.size(), xc.size());
  size_t partial = 0;
  for (size_t j = 0; j < xc.size(); ++j) {
    double sum = 0;
    for (size_t i = 0; i < f.size(); ++i) sum += double(f.mass[i] / f.density[i]) * double(W.W(Vec<D>(xc[j] - y[i])));
    const double expected = 1 - std::min(sum, 1.0);
    EXPECT_NEAR(alpha[j], expected, 2e-4) << "control particle " << j;
    partial += expected > 0.05 && expected < 0.95;
  }
  EXPECT_GT(partial, 10u) << "the liquid should cover part of the block only";

  // Equations (2), (4), (5), directly (the instance is not transformed, so
  // template and world axes coincide, and the liquid is inside the box).
  const InstanceParams& p = inst.spec.params;
  const double wa = p.attractionWeight * kAccelerationScale;
  const double wv = p.velocityWeight * kRateScale;
  const double wr = p.repulsionWeight * kAccelerationScale;
  const double rho0 = tpl->header.restDensity, dMin = hT / 16;
  const auto& xr = grids.repulsionPositions();
  const auto& nr = grids.repulsionNormals();
  const auto& src = grids.repulsionSources();
  ASSERT_GT(xr.size(), 0u);
  double largest = 0;
  size_t checked = 0;
  for (size_t i = 0; i < f.size(); ++i) {
    Eigen::Matrix<double, D, 1> a = Eigen::Matrix<double, D, 1>::Zero();
    for (size_t j = 0; j < xc.size(); ++j) {
      const Vec<D> r = xc[j] - y[i];
      const double w = mc[j] / rho0 * W.W(r);
      if (w == 0) continue;
      const double dist = std::max(double(r.norm()), dMin);
      a += wa * alpha[j] * w / dist * r.template cast<double>();
      a += wv * (1 - alpha[j]) * w * (vT - f.v[i]).template cast<double>();
    }
    for (size_t k = 0; k < xr.size(); ++k)
      a -= wr * mc[src[k]] / rho0 * W.W(Vec<D>(xr[k] - y[i])) * nr[k].template cast<double>();
    largest = std::max(largest, a.norm());
    EXPECT_LT((acc[i].template cast<double>() - a).norm(), 1e-3 * std::max(10.0, a.norm())) << "particle " << i;
    checked += a.norm() > 0;
  }
  EXPECT_GT(checked, f.size() / 2);
  EXPECT_GT(largest, 10.0);
}

TEST(ControlForces, SumsEqualTheEquationsEvaluatedDirectly2D) { checkSumsAgainstDirectEvaluation<2>(); }
TEST(ControlForces, SumsEqualTheEquationsEvaluatedDirectly3D) { checkSumsAgainstDirectEvaluation<3>(); }
