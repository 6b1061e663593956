// Control over whole runs: temporary particles (paper §3.4, Algorithms 1
// and 2) and reproduction of a recorded template (fidelity IoU).
#include "control/control.h"
#include "sph/simulation.h"
#include <gtest/gtest.h>
#include <cmath>
#include <cstdio>
#include <memory>

using namespace fc;

namespace {

constexpr Real kR = Real(0.01);
constexpr double kRho0 = 1000;

AABB<2> box2(Real x0, Real y0, Real x1, Real y1) { return AABB<2>(Vec<2>(x0, y0), Vec<2>(x1, y1)); }

SimulationSetup<2> tank(std::vector<AABB<2>> blocks, Real gravity = Real(-9.81)) {
  SimulationSetup<2> s;
  s.particleRadius = kR;
  s.domain = box2(0, 0, 1, 0.8f);
  s.gravity = Vec<2>(0, gravity);
  for (const auto& b : blocks) {
    FluidBlock<2> f;
    f.box = b;
    s.fluidBlocks.push_back(f);
  }
  s.solver.name = "dfsph";
  s.settings.frameRate = 60;
  s.effects.push_back({"viscosity_standard", ParamValues()});
  return s;
}

// A static blob of liquid hanging in the air: every frame the same lattice
// block (spacing 2r), at rest.
std::shared_ptr<Template<2>> blobTemplate(const AABB<2>& region, const AABB<2>& blob, int frames) {
  auto t = std::make_shared<Template<2>>();
  t->header.name = "blob";
  t->header.dimension = 2;
  t->header.frameRate = 30;
  t->header.particleRadius = kR;
  t->header.supportRadius = 4 * kR;
  t->header.restDensity = kRho0;
  t->header.regionMin = {region.min.x(), region.min.y()};
  t->header.regionMax = {region.max.x(), region.max.y()};
  TemplateFrame<2> f;
  for (Real x = blob.min.x() + kR; x < blob.max.x(); x += 2 * kR)
    for (Real y = blob.min.y() + kR; y < blob.max.y(); y += 2 * kR) {
      f.x.push_back(Vec<2>(x, y));
      f.v.push_back(Vec<2>::Zero());
      f.mass.push_back(Real(kRho0 * 4 * kR * kR));
      f.phase.push_back(0);
    }
  t->frames.assign(size_t(frames), f);
  return t;
}

BoundInstance<2> bindAtRecordingPlace(std::shared_ptr<const Template<2>> tpl) {
  BoundInstance<2> b;
  b.spec.name = tpl->header.name;
  b.spec.templateName = tpl->header.name;
  b.spec.params = instanceParamTable(2).defaults();
  TransformKey<2> k;
  k.translation = tpl->region().center().cast<double>();
  b.spec.transform.keys = {k};
  b.accel = std::make_shared<TemplateAccel<2>>(TemplateAccel<2>::build(tpl));
  return b;
}

Control<2>* attach(Simulation<2>& sim, std::vector<BoundInstance<2>> instances,
                   const ControlSettings& settings = controlSettingsTable().defaults()) {
  auto c = std::make_unique<Control<2>>(std::move(instances), settings);
  Control<2>* raw = c.get();
  sim.addEffect(std::move(c), "control");
  return raw;
}

size_t countKind(const Simulation<2>& sim, ParticleKind k) {
  size_t n = 0;
  for (uint8_t v : sim.fluid.kind) n += v == uint8_t(k);
  return n;
}

}  // namespace

// Algorithm 1: candidates outward along −∇ρ at d_tp = l h from surface
// particles, kept only where the template holds liquid the simulation lacks,
// never next to a liquid particle, another candidate or a solid, and never in
// the falloff band.
TEST(TemporaryParticles, SeedingFollowsAlgorithm1) {
  // A pool, and a template blob sitting on it and rising above its surface.
  const auto region = box2(0.3f, 0.1f, 0.7f, 0.5f);
  auto tpl = blobTemplate(region, box2(0.4f, 0.1f, 0.6f, 0.4f), 31);  // 1 s at 30 fps
  Simulation<2> sim(tank({box2(0, 0, 1, 0.2f)}));
  auto inst = bindAtRecordingPlace(tpl);
  inst.spec.params.falloffWidth = 0.1;
  Control<2>* control = attach(sim, {inst});
  const size_t n0 = sim.fluid.size();
  FrameStats fs;
  control->beginFrame(sim, fs);  // seeds (no substep yet: positions are exact)
  const size_t n1 = sim.fluid.size();
  ASSERT_GT(n1, n0) << "the blob above the pool must seed temporary particles";
  EXPECT_EQ(countKind(sim, ParticleKind::Temporary), n1 - n0);
  const Real dtp = Real(0.5) * sim.supportRadius();  // l = 0.5
  for (size_t i = n0; i < n1; ++i) {
    const Vec<2> x = sim.fluid.x[i];
    EXPECT_EQ(sim.fluid.kind[i], uint8_t(ParticleKind::Temporary));
    // Only where the template has liquid (the blob, with the kernel's reach)
    // and inside the instance box proper, not its band.
    EXPECT_TRUE(region.contains(x)) << x.transpose();
    EXPECT_GE(x.x(), 0.4f - dtp) << x.transpose();
    EXPECT_LE(x.x(), 0.6f + dtp) << x.transpose();
    EXPECT_LE(x.y(), 0.4f + dtp) << x.transpose();
    EXPECT_GE(x.y(), 0.2f) << "seeded below the pool surface: " << x.transpose();
    // Spacing: no other particle (original or temporary) closer than d_tp − ε.
    for (size_t j = 0; j < n1; ++j)
      if (j != i) ASSERT_GE((sim.fluid.x[j] - x).norm(), Real(0.95) * dtp - Real(1e-6)) << i << " vs " << j;
    EXPECT_EQ(sim.fluid.mass[i], sim.fluid.mass[0]);
  }
  // The blob fills layer by layer; afterwards seeding only replaces what
  // gravity drains from a blob hanging in the air: no runaway.
  size_t seeded = n1 - n0, seededLate = 0;
  for (int f = 0; f < 60; ++f) {
    const FrameStats s = sim.advanceFrame();
    ASSERT_TRUE(s.finite);
    ASSERT_EQ(s.escapedParticles, 0u);
    seeded += s.seededParticles;
    if (f >= 45) seededLate += s.seededParticles;
  }
  std::printf("[ measured ] blob: %zu temporary particles seeded in 1 s, %zu of them in the last 0.25 s\n", seeded,
              seededLate);
  const size_t blobAboveThePool = 10 * 10;  // lattice sites of the blob above y = 0.2
  EXPECT_GT(seeded, blobAboveThePool / 2);
  EXPECT_LT(seeded, 2 * blobAboveThePool);
  EXPECT_LT(seededLate, seeded / 4) << "seeding did not settle";
}

// Temporary particles past their grace period fade out: at most
// temporary_fade_share of the liquid's mass leaves per frame, the longest
// outside first, so a whole blob's worth goes over several frames instead of
// one (a visible pop), and then the liquid is exactly the scene's again.
TEST(TemporaryParticles, PastTheGracePeriodTheyFadeOutABoundedShareAFrame) {
  const auto region = box2(0.3f, 0.1f, 0.7f, 0.6f);
  auto tpl = blobTemplate(region, box2(0.42f, 0.18f, 0.58f, 0.45f), 16);  // 0.5 s at 30 fps
  Simulation<2> sim(tank({box2(0, 0, 1, 0.2f)}));
  auto inst = bindAtRecordingPlace(tpl);
  ControlSettings settings = controlSettingsTable().defaults();
  settings.temporaryGraceFrames = 0;  // every temporary particle outside the box is overdue at once
  settings.temporaryFadeShare = 0.01;
  attach(sim, {inst}, settings);
  const size_t n0 = sim.fluid.size();
  size_t most = 0, fadingFrames = 0, faded = 0;
  bool ended = false;
  for (int f = 0; f < 200; ++f) {
    const FrameStats s = sim.advanceFrame();
    ASSERT_TRUE(s.finite) << "frame " << s.frame;
    most = std::max(most, s.temporaryParticles);
    // Equal masses: the share is a count (at least one particle a frame).
    const size_t bound = std::max<size_t>(1, size_t(0.01 * double(s.particles + s.removedParticles - s.seededParticles)));
    EXPECT_LE(s.fadedParticles, bound) << "frame " << s.frame;
    EXPECT_LE(s.fadedParticles, s.removedParticles);
    faded += s.fadedParticles;
    fadingFrames += s.fadedParticles > 0;
    ended = ended || (!s.instances[0].active && s.frame > 1);
    if (ended && s.temporaryParticles == 0) break;
  }
  ASSERT_TRUE(ended);
  EXPECT_EQ(countKind(sim, ParticleKind::Temporary), 0u) << "all must go in the end";
  EXPECT_EQ(sim.fluid.size(), n0);
  EXPECT_GT(faded, 20u) << "the blob's temporary particles should have outlived their grace";
  EXPECT_GE(fadingFrames, faded / std::max<size_t>(1, size_t(0.01 * double(n0 + most))))
      << "they left in fewer frames than the bound allows";
  std::printf("[ measured ] %zu temporary particles faded out over %zu frames (at most %.0f a frame)\n", faded,
              fadingFrames, 0.01 * double(n0 + most));
}

// Algorithm 2 and the mass guarantee: after every instance has ended, all
// temporary particles go (past temporary_grace_frames, 60, at most
// temporary_fade_share of the mass a frame), and the liquid count returns
// exactly to the scene's.
TEST(TemporaryParticles, AllRemovedAfterTheInstancesEnd) {
  const auto region = box2(0.3f, 0.1f, 0.7f, 0.6f);
  auto tpl = blobTemplate(region, box2(0.42f, 0.18f, 0.58f, 0.45f), 16);  // 0.5 s at 30 fps
  Simulation<2> sim(tank({box2(0, 0, 1, 0.2f)}));
  auto inst = bindAtRecordingPlace(tpl);
  Control<2>* control = attach(sim, {inst});
  (void)control;
  const size_t n0 = sim.fluid.size();
  size_t most = 0, endFrame = 0;
  bool ended = false;
  for (int f = 0; f < 160; ++f) {
    const FrameStats s = sim.advanceFrame();
    ASSERT_TRUE(s.finite) << "frame " << s.frame;
    ASSERT_EQ(s.escapedParticles, 0u) << "frame " << s.frame;
    ASSERT_EQ(s.particles, n0 + s.temporaryParticles) << "only temporary particles come and go";
    ASSERT_EQ(s.temporaryParticles, countKind(sim, ParticleKind::Temporary));
    most = std::max(most, s.temporaryParticles);
    if (!s.instances[0].active && !ended && s.frame > 1) ended = true, endFrame = size_t(s.frame);
    if (ended && s.temporaryParticles == 0) {
      std::printf("[ measured ] %zu temporary particles at most; all removed %zu frames after the instance ended\n",
                  most, size_t(s.frame) - endFrame);
      break;
    }
  }
  ASSERT_TRUE(ended);
  EXPECT_GT(most, 20u) << "the blob should have needed temporary particles";
  EXPECT_EQ(countKind(sim, ParticleKind::Temporary), 0u);
  EXPECT_EQ(sim.fluid.size(), n0);
  // Identities of the original particles are intact.
  std::vector<uint8_t> seen(n0, 0);
  for (uint32_t id : sim.fluid.id) {
    ASSERT_LT(id, n0);
    seen[id] = 1;
  }
  for (uint8_t s : seen) EXPECT_EQ(s, 1);
}

namespace {
// Records, in memory, every liquid particle inside `region` at every frame of
// a simulation (what `flowclip record` does), after `skip` frames.
std::shared_ptr<Template<2>> record(const SimulationSetup<2>& setup, const AABB<2>& region, int skip, int frames) {
  Simulation<2> sim(setup);
  for (int f = 0; f < skip; ++f) sim.advanceFrame();
  auto t = std::make_shared<Template<2>>();
  t->header.name = "drop";
  t->header.dimension = 2;
  t->header.frameRate = 1.0 / sim.frameDuration();
  t->header.particleRadius = sim.particleRadius();
  t->header.supportRadius = sim.supportRadius();
  t->header.restDensity = kRho0;
  t->header.regionMin = {region.min.x(), region.min.y()};
  t->header.regionMax = {region.max.x(), region.max.y()};
  for (int f = 0; f < frames; ++f) {
    if (f > 0) sim.advanceFrame();
    TemplateFrame<2> fr;
    for (size_t i = 0; i < sim.fluid.size(); ++i)
      if (region.contains(sim.fluid.x[i])) {
        fr.x.push_back(sim.fluid.x[i]);
        fr.v.push_back(sim.fluid.v[i]);
        fr.mass.push_back(sim.fluid.mass[i]);
        fr.phase.push_back(0);
      }
    t->frames.push_back(fr);
  }
  return t;
}

struct FidelityRun {
  double mean = 0, min = 1;
  size_t frames = 0;
};

// Runs `setup` with one instance of `tpl` starting at `start`; `steer`
// false zeroes every weight and disables temporary particles (the instance
// then only measures).
FidelityRun runWithInstance(const SimulationSetup<2>& setup, std::shared_ptr<const Template<2>> tpl, double start,
                            bool steer, int frames) {
  Simulation<2> sim(setup);
  auto inst = bindAtRecordingPlace(tpl);
  inst.spec.time.start = start;
  if (!steer) {
    inst.spec.params.attractionWeight = inst.spec.params.velocityWeight = inst.spec.params.repulsionWeight = 0;
    inst.spec.params.temporaryParticles = false;
  }
  attach(sim, {inst});
  FidelityRun r;
  for (int f = 0; f < frames; ++f) {
    const FrameStats s = sim.advanceFrame();
    EXPECT_TRUE(s.finite);
    EXPECT_EQ(s.escapedParticles, 0u);
    if (!s.instances[0].active || s.instances[0].fidelity < 0) continue;
    r.mean += s.instances[0].fidelity;
    r.min = std::min(r.min, s.instances[0].fidelity);
    ++r.frames;
  }
  if (r.frames) r.mean /= double(r.frames);
  return r;
}
}  // namespace

// Reproduction (paper §5.1, "2D rectangular drop"): a drop falling into a
// pool is recorded; the template is then instanced, where it was recorded,
//  (a) on a copy of its source scene at another resolution (r × 0.8), and
//  (b) on the pool alone, without the falling drop (the paper's use: the
//      impact and its ripples without the drop's fall).
// Fidelity (occupancy IoU in the instance box) must stay above documented
// thresholds for the whole run and clearly above the same scenes uncontrolled.
TEST(ControlReproduction, DropTemplateOnItsSourceScene) {
  const auto pool = box2(0, 0, 1, 0.16f);
  const auto drop = box2(0.42f, 0.4f, 0.58f, 0.56f);
  const auto region = box2(0.2f, 0, 0.8f, 0.7f);
  SimulationSetup<2> source = tank({pool, drop});
  const int skip = 10, frames = 40;  // the capture starts just before the impact
  auto tpl = record(source, region, skip, frames);
  const double start = skip / 60.0;
  const int run = skip + frames - 1;

  SimulationSetup<2> copy = source;
  copy.particleRadius = kR * Real(0.8);
  const FidelityRun copyOn = runWithInstance(copy, tpl, start, true, run);
  const FidelityRun copyOff = runWithInstance(copy, tpl, start, false, run);
  SimulationSetup<2> poolOnly = tank({pool});
  const FidelityRun poolOn = runWithInstance(poolOnly, tpl, start, true, run);
  const FidelityRun poolOff = runWithInstance(poolOnly, tpl, start, false, run);
  std::printf("[ measured ] fidelity IoU, mean (min) over %zu frames: copy at r x 0.8 controlled %.3f (%.3f), "
              "uncontrolled %.3f (%.3f); pool without the drop controlled %.3f (%.3f), uncontrolled %.3f (%.3f)\n",
              copyOn.frames, copyOn.mean, copyOn.min, copyOff.mean, copyOff.min, poolOn.mean, poolOn.min, poolOff.mean,
              poolOff.min);
  ASSERT_GE(copyOn.frames, size_t(frames - 1));
  // Documented thresholds (docs/templates.md, "Reproduction, measured"). The copy diverges
  // from its template only through the resolution change, so uncontrolled it
  // already scores high; control must still lift it. Without the drop, the
  // splash exists only through control.
  // The lift on the copy is small and the splash chaotic: builds whose sums
  // differ only in rounding measured a mean lift of 0.011 to 0.027 and a
  // lift of the worst frame of 0.021 to 0.044.
  EXPECT_GE(copyOn.min, 0.85);
  EXPECT_GT(copyOn.mean, copyOff.mean + 0.005);
  EXPECT_GT(copyOn.min, copyOff.min + 0.01);
  EXPECT_GE(poolOn.min, 0.65);
  EXPECT_GT(poolOn.mean, poolOff.mean + 0.1);
}

// Resolution independence of the whole effect: the drop played over the pool
// looks the same (fidelity) when the liquid's particle radius is halved.
TEST(ControlReproduction, SameLookAtHalfTheRadius) {
  const auto pool = box2(0, 0, 1, 0.16f);
  const auto region = box2(0.2f, 0, 0.8f, 0.7f);
  auto tpl = record(tank({pool, box2(0.42f, 0.4f, 0.58f, 0.56f)}), region, 10, 30);
  const double start = 10 / 60.0;
  const FidelityRun coarse = runWithInstance(tank({pool}), tpl, start, true, 39);
  SimulationSetup<2> fineSetup = tank({pool});
  fineSetup.particleRadius = kR / 2;
  const FidelityRun fine = runWithInstance(fineSetup, tpl, start, true, 39);
  const FidelityRun fineOff = runWithInstance(fineSetup, tpl, start, false, 39);
  std::printf("[ measured ] pool without the drop, fidelity mean (min): r = %.3g m %.3f (%.3f), r = %.3g m %.3f (%.3f), "
              "uncontrolled at r = %.3g m %.3f\n",
              double(kR), coarse.mean, coarse.min, double(kR / 2), fine.mean, fine.min, double(kR / 2), fineOff.mean);
  EXPECT_NEAR(fine.mean, coarse.mean, 0.04);
  EXPECT_GT(fine.mean, fineOff.mean + 0.1);
}
