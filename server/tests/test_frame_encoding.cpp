// The WebSocket wire format (proto/flowclip.fbs, service/frame_encoding.h):
// frames of real simulations round-trip within the quantization bound,
// control layers carry the instance's placement and α, the verifier refuses
// malformed buffers without crashing, client messages parse or fail with a
// message naming the field.
#include "service/frame_encoding.h"
#include "tests/support/frame_decoding.h"

#include "control/control.h"
#include "sph/simulation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <memory>
#include <random>

using namespace fc;
using namespace fc::wire;

namespace {

constexpr Real kR = Real(0.02);

template <int D>
SimulationSetup<D> tankSetup(const AABB<D>& domain, const AABB<D>& block, Real radius) {
  SimulationSetup<D> s;
  s.particleRadius = radius;
  s.domain = domain;
  s.gravity = Vec<D>::Zero();
  s.gravity[1] = Real(-9.81);
  s.phases = {Phase{}, Phase{"oil", 800, 0, {1, 1, 0}}};
  FluidBlock<D> b;
  b.box = block;
  s.fluidBlocks.push_back(b);
  s.solver.name = "dfsph";
  s.settings.frameRate = 60;
  return s;
}

AABB<2> box2(Real x0, Real y0, Real x1, Real y1) { return AABB<2>(Vec<2>(x0, y0), Vec<2>(x1, y1)); }

std::vector<uint8_t> bytes(const flatbuffers::FlatBufferBuilder& fbb) {
  return std::vector<uint8_t>(fbb.GetBufferPointer(), fbb.GetBufferPointer() + fbb.GetSize());
}

// Decoded vs exact, per axis, against the documented bound (plus double
// rounding).
template <int D>
void expectWithinBound(const DecodedPoints& p, size_t i, const Eigen::Matrix<double, D, 1>& exact, const char* what) {
  const auto bound = p.maxError();
  for (int d = 0; d < D; ++d) {
    const double tol = bound[size_t(d)] * (1 + 1e-9) + 1e-12;
    EXPECT_LE(std::abs(p.x[i][size_t(d)] - exact[d]), tol) << what << " " << i << " axis " << d;
  }
}

// The round trip of one simulated frame, with and without boundary particles.
template <int D>
void roundTrip(Simulation<D>& sim) {
  // Some particles of the second phase, so that phases are not all 0.
  for (size_t i = 0; i < sim.fluid.size(); i += 3) sim.fluid.phase[i] = 1;
  sim.advanceFrame();
  const FrameStats fs = sim.advanceFrame();
  ASSERT_TRUE(fs.finite);
  flatbuffers::FlatBufferBuilder fbb;
  for (bool withBoundary : {false, true}) {
    SCOPED_TRACE(withBoundary ? "with boundary" : "liquid only");
    LayerFlags layers;
    layers.boundary = withBoundary;
    encodeFrame<D>(sim, fs, nullptr, "session-7", layers, fbb);
    const auto buf = bytes(fbb);
    ASSERT_EQ(verifyEnvelope(buf.data(), buf.size()), "");
    const DecodedFrame f = decodeFrame(buf.data(), buf.size());
    EXPECT_EQ(f.sessionId, "session-7");
    EXPECT_EQ(f.frame, 2);
    EXPECT_EQ(f.frame, fs.frame);
    EXPECT_DOUBLE_EQ(f.time, fs.time);
    EXPECT_EQ(f.dimension, D);
    for (int d = 0; d < D; ++d) {
      EXPECT_EQ(f.domainMin[size_t(d)], double(sim.setup().domain.min[d]));
      EXPECT_EQ(f.domainMax[size_t(d)], double(sim.setup().domain.max[d]));
    }
    EXPECT_EQ(f.layers.boundary, withBoundary);
    EXPECT_FALSE(f.layers.control);
    EXPECT_FALSE(f.layers.repulsion);
    EXPECT_FALSE(f.layers.instances);  // no instances
    const size_t nl = sim.fluid.size(), nb = withBoundary ? sim.boundary.size() : 0;
    ASSERT_EQ(f.particles.x.size(), nl + nb);
    ASSERT_EQ(f.kind.size(), nl + nb);
    ASSERT_EQ(f.phase.size(), nl + nb);
    // Liquid inside the domain: the box is the domain itself.
    if (!withBoundary) {
      for (int d = 0; d < D; ++d) {
        EXPECT_EQ(f.particles.boxMin[size_t(d)], double(sim.setup().domain.min[d]));
        EXPECT_EQ(f.particles.boxMax[size_t(d)], double(sim.setup().domain.max[d]));
      }
      // The bound is the documented one: (max − min) / 65535 / 2.
      EXPECT_DOUBLE_EQ(f.particles.maxError()[0],
                       double(sim.setup().domain.max[0] - sim.setup().domain.min[0]) / 65535 / 2);
    }
    size_t phase1 = 0;
    for (size_t i = 0; i < nl; ++i) {
      expectWithinBound<D>(f.particles, i, sim.fluid.x[i].template cast<double>(), "particle");
      EXPECT_EQ(f.kind[i], sim.fluid.kind[i]);
      EXPECT_EQ(f.phase[i], sim.fluid.phase[i]);
      phase1 += f.phase[i] == 1;
    }
    EXPECT_GT(phase1, 0u);
    for (size_t b = 0; b < nb; ++b) {
      expectWithinBound<D>(f.particles, nl + b, sim.boundary.x[b].template cast<double>(), "boundary particle");
      EXPECT_EQ(f.kind[nl + b], uint8_t(ParticleKind::Boundary));
      EXPECT_EQ(f.phase[nl + b], 255);
    }
    // Counts by kind and timings.
    EXPECT_EQ(f.stats.particles, fs.particles);
    EXPECT_EQ(f.stats.temporaryParticles, 0u);
    EXPECT_EQ(f.stats.boundaryParticles, sim.boundary.size());
    EXPECT_EQ(f.stats.substeps, fs.substeps);
    EXPECT_EQ(f.stats.divergenceIterations, fs.divergenceIterations);
    EXPECT_EQ(f.stats.densityIterations, fs.densityIterations);
    EXPECT_EQ(f.stats.converged, fs.converged);
    EXPECT_FLOAT_EQ(float(f.stats.wallMs), float(fs.wallMs));
    EXPECT_FLOAT_EQ(float(f.stats.pressureMs), float(fs.pressureMs));
    EXPECT_FLOAT_EQ(float(f.stats.avgDensityErrorPct), float(fs.avgDensityErrorPct));
    EXPECT_FLOAT_EQ(float(f.stats.maxDensityErrorPct), float(fs.maxDensityErrorPct));
    EXPECT_FLOAT_EQ(float(f.stats.maxSpeed), float(fs.maxSpeed));
    EXPECT_FLOAT_EQ(float(f.stats.minDt), float(fs.minDt));
    EXPECT_EQ(f.stats.controlMs, 0);
    // Bytes per particle: D × 2 (positions) + kind + phase, plus a bounded
    // header.
    EXPECT_LE(buf.size(), (nl + nb) * (2 * D + 2) + 1024);
  }
}

// A template whose every frame is a lattice blob (spacing 2r) at rest.
std::shared_ptr<Template<2>> blobTemplate(const AABB<2>& region, const AABB<2>& blob, int frames) {
  auto t = std::make_shared<Template<2>>();
  t->header.name = "blob";
  t->header.dimension = 2;
  t->header.frameRate = 30;
  t->header.particleRadius = kR;
  t->header.supportRadius = 4 * kR;
  t->header.restDensity = 1000;
  t->header.regionMin = {region.min.x(), region.min.y()};
  t->header.regionMax = {region.max.x(), region.max.y()};
  TemplateFrame<2> f;
  for (Real x = blob.min.x() + kR; x < blob.max.x(); x += 2 * kR)
    for (Real y = blob.min.y() + kR; y < blob.max.y(); y += 2 * kR) {
      f.x.push_back(Vec<2>(x, y));
      f.v.push_back(Vec<2>::Zero());
      f.mass.push_back(Real(1000 * 4 * kR * kR));
      f.phase.push_back(0);
    }
  t->frames.assign(size_t(frames), f);
  return t;
}

// A scene with one keyframed, rotated instance of the blob over a pool.
struct ControlledScene {
  std::shared_ptr<Template<2>> tpl;
  std::unique_ptr<Simulation<2>> sim;
  Control<2>* control = nullptr;
  ControlledScene() {
    const auto region = box2(0.3f, 0.1f, 0.7f, 0.5f);
    tpl = blobTemplate(region, box2(0.4f, 0.1f, 0.6f, 0.4f), 31);
    sim = std::make_unique<Simulation<2>>(tankSetup<2>(box2(0, 0, 1, 0.8f), box2(0, 0, 1, 0.2f), kR));
    BoundInstance<2> b;
    b.spec.name = "blob-1";
    b.spec.templateName = "blob";
    b.spec.params = instanceParamTable(2).defaults();
    b.spec.params.falloffWidth = 0.07;
    TransformKey<2> k0, k1;
    k0.time = 0;
    k0.translation = Eigen::Vector2d(0.52, 0.31);
    k0.rotationDeg = {12};
    k1 = k0;
    k1.time = 1;
    k1.translation = Eigen::Vector2d(0.58, 0.31);  // moving: the matrix depends on the time it is taken at
    k1.rotationDeg = {20};
    b.spec.transform.keys = {k0, k1};
    b.accel = std::make_shared<TemplateAccel<2>>(TemplateAccel<2>::build(std::shared_ptr<const Template<2>>(tpl)));
    auto c = std::make_unique<Control<2>>(std::vector<BoundInstance<2>>{b}, controlSettingsTable().defaults());
    control = c.get();
    sim->addEffect(std::move(c), "control");
  }
};

ParseFailure expectFailure(const ClientMessage& m, fb::ErrorCode code, const std::string& mentions) {
  EXPECT_TRUE(std::holds_alternative<ParseFailure>(m)) << "expected a failure mentioning '" << mentions << "'";
  if (!std::holds_alternative<ParseFailure>(m)) return {};
  const ParseFailure f = std::get<ParseFailure>(m);
  EXPECT_EQ(f.code, code) << f.message;
  EXPECT_NE(f.message.find(mentions), std::string::npos) << "message: " << f.message;
  return f;
}

ClientMessage parse(const flatbuffers::FlatBufferBuilder& fbb) {
  return parseClientMessage(fbb.GetBufferPointer(), fbb.GetSize());
}

}  // namespace

TEST(WireFrame, RoundTrip2D) {
  Simulation<2> sim(tankSetup<2>(box2(0, 0, 1, 0.8f), box2(0, 0, 0.4f, 0.4f), kR));
  roundTrip<2>(sim);
}

// Layer.Speed from the simulation: |v| per liquid particle (none for the
// boundary ones appended after them), 8 bits against the largest.
TEST(WireFrame, SpeedLayerFromTheSimulation) {
  Simulation<2> sim(tankSetup<2>(box2(0, 0, 1, 0.8f), box2(0, 0, 0.4f, 0.4f), kR));
  for (size_t i = 0; i < sim.fluid.size(); ++i) sim.fluid.v[i] = Vec<2>(Real(0.01 * double(i % 100)), Real(-0.5));
  FrameStats fs;
  fs.frame = 3;
  LayerFlags layers;
  layers.speed = true;
  layers.boundary = true;
  flatbuffers::FlatBufferBuilder fbb;
  encodeFrame<2>(sim, fs, nullptr, "s", layers, fbb);
  const DecodedFrame d = decodeFrame(fbb.GetBufferPointer(), fbb.GetSize());
  ASSERT_TRUE(d.layers.speed);
  ASSERT_EQ(d.speed.size(), sim.fluid.size());
  double vmax = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) vmax = std::max(vmax, double(sim.fluid.v[i].norm()));
  EXPECT_NEAR(d.speedMax, vmax, 1e-6);
  for (size_t i = 0; i < sim.fluid.size(); i += 37) EXPECT_NEAR(d.speed[i], double(sim.fluid.v[i].norm()), vmax / 255 + 1e-6) << i;
  // Without the flag, no speeds.
  encodeFrame<2>(sim, fs, nullptr, "s", LayerFlags{}, fbb);
  EXPECT_TRUE(decodeFrame(fbb.GetBufferPointer(), fbb.GetSize()).speed.empty());
}

TEST(WireFrame, RoundTrip3D) {
  const AABB<3> domain(Vec<3>(0, 0, 0), Vec<3>(0.5f, 0.4f, 0.3f));
  const AABB<3> block(Vec<3>(0, 0, 0), Vec<3>(0.2f, 0.2f, 0.16f));
  Simulation<3> sim(tankSetup<3>(domain, block, Real(0.02)));
  roundTrip<3>(sim);
}

// A builder reused frame after frame starts each message afresh.
TEST(WireFrame, BuilderIsReused) {
  Simulation<2> sim(tankSetup<2>(box2(0, 0, 1, 0.8f), box2(0, 0, 0.4f, 0.4f), kR));
  flatbuffers::FlatBufferBuilder fbb;
  for (int k = 0; k < 3; ++k) {
    const FrameStats fs = sim.advanceFrame();
    encodeFrame<2>(sim, fs, nullptr, "s", LayerFlags{}, fbb);
    const DecodedFrame f = decodeFrame(fbb.GetBufferPointer(), fbb.GetSize());
    EXPECT_EQ(f.frame, k + 1);
    ASSERT_EQ(f.particles.x.size(), sim.fluid.size());
    for (size_t i = 0; i < sim.fluid.size(); ++i)
      expectWithinBound<2>(f.particles, i, sim.fluid.x[i].cast<double>(), "particle");
  }
  // The initial state (no frame simulated yet) encodes as frame 0.
  FrameStats initial;
  encodeFrame<2>(sim, initial, nullptr, "s", LayerFlags{}, fbb);
  EXPECT_EQ(decodeFrame(fbb.GetBufferPointer(), fbb.GetSize()).frame, 0);
}

TEST(WireFrame, NonFinitePositionIsNeverEncoded) {
  Simulation<2> sim(tankSetup<2>(box2(0, 0, 1, 0.8f), box2(0, 0, 0.4f, 0.4f), kR));
  flatbuffers::FlatBufferBuilder fbb;
  sim.fluid.x[5].y() = std::numeric_limits<Real>::quiet_NaN();
  try {
    encodeFrame<2>(sim, FrameStats{}, nullptr, "s", LayerFlags{}, fbb);
    FAIL() << "a NaN position was encoded";
  } catch (const EncodeError& e) {
    EXPECT_NE(std::string(e.what()).find("particle 5"), std::string::npos) << e.what();
  }
  EXPECT_EQ(fbb.GetSize(), 0u) << "nothing partial is left in the builder";
  sim.fluid.x[5].y() = std::numeric_limits<Real>::infinity();
  EXPECT_THROW(encodeFrame<2>(sim, FrameStats{}, nullptr, "s", LayerFlags{}, fbb), EncodeError);
}

// Control layers: the instance's placement at the frame's start, its control
// particles in world space with α, its repulsion layer, its record.
TEST(WireFrame, InstanceAndControlLayers) {
  ControlledScene scene;
  Simulation<2>& sim = *scene.sim;
  const FrameStats fs = sim.advanceFrame();
  ASSERT_TRUE(fs.finite);
  ASSERT_EQ(fs.instances.size(), 1u);
  ASSERT_TRUE(scene.control->isActive(0));
  LayerFlags layers;
  layers.control = layers.repulsion = layers.instances = true;
  flatbuffers::FlatBufferBuilder fbb;
  encodeFrame<2>(sim, fs, scene.control, "ctl", layers, fbb);
  const DecodedFrame f = decodeFrame(fbb.GetBufferPointer(), fbb.GetSize());
  EXPECT_TRUE(f.layers.control && f.layers.repulsion && f.layers.instances);
  EXPECT_FALSE(f.layers.boundary);

  const BoundInstance<2>& inst = scene.control->instances()[0];
  const size_t tf = scene.control->templateFrame(0);
  const auto& grids = *inst.accel->frame(tf);
  // Control selected the template frame at the frame's start, t = 0.
  const Affine<2> toWorld = inst.spec.transform.templateToWorld(0.0, inst.centre());

  ASSERT_EQ(f.instances.size(), 1u);
  const DecodedInstance& r = f.instances[0];
  EXPECT_EQ(r.name, "blob-1");
  EXPECT_EQ(r.templateName, "blob");
  EXPECT_TRUE(r.active);
  EXPECT_EQ(r.templateFrame, int(tf));
  EXPECT_EQ(r.phase, 0);
  ASSERT_EQ(r.worldRowMajor.size(), 9u);  // 2D: 3×3 row-major
  const auto h = toWorld.homogeneous();
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col)
      EXPECT_FLOAT_EQ(r.worldRowMajor[size_t(row * 3 + col)], float(h(row, col))) << row << "," << col;
  // The template region's centre lands on the key's translation at t = 0
  // (0.52, 0.31), not at t = 1/60, the frame's end.
  const Vec<2> c = inst.centre();
  EXPECT_NEAR(r.worldRowMajor[0] * c.x() + r.worldRowMajor[1] * c.y() + r.worldRowMajor[2], 0.52, 1e-6);
  EXPECT_NEAR(r.worldRowMajor[3] * c.x() + r.worldRowMajor[4] * c.y() + r.worldRowMajor[5], 0.31, 1e-6);
  EXPECT_DOUBLE_EQ(r.templateMin[0], double(Real(0.3f)));
  EXPECT_DOUBLE_EQ(r.templateMax[1], double(Real(0.5f)));
  EXPECT_FLOAT_EQ(float(r.falloffWidth), 0.07f);
  EXPECT_FLOAT_EQ(float(r.fidelity), float(fs.instances[0].fidelity));
  EXPECT_EQ(r.controlled, fs.instances[0].controlled);
  EXPECT_GT(r.controlled, 0u);

  // Control particles: world positions within the bound, α within 1/255.
  ASSERT_EQ(r.controlOffset, 0u);
  ASSERT_EQ(r.controlCount, grids.controlCount());
  ASSERT_EQ(f.control.x.size(), grids.controlCount());
  ASSERT_EQ(f.alpha.size(), grids.controlCount());
  const auto& alpha = scene.control->coverage(0);
  ASSERT_EQ(alpha.size(), grids.controlCount());
  size_t covered = 0, uncovered = 0;
  for (size_t j = 0; j < grids.controlCount(); ++j) {
    const Eigen::Vector2d w = toWorld.linear.cast<double>() * grids.controlPositions()[j].cast<double>() +
                              toWorld.translation.cast<double>();
    expectWithinBound<2>(f.control, j, w, "control particle");
    EXPECT_LE(std::abs(f.alpha[j] - double(alpha[j])), 1.0 / 255) << "control particle " << j;
    covered += f.alpha[j] < 0.5;
    uncovered += f.alpha[j] > 0.5;
  }
  EXPECT_GT(covered, 0u) << "the pool covers the blob's lower part";
  EXPECT_GT(uncovered, 0u) << "the blob rises above the pool";

  // Repulsion particles, same placement.
  ASSERT_GT(grids.repulsionCount(), 0u);
  ASSERT_EQ(r.repulsionCount, grids.repulsionCount());
  ASSERT_EQ(f.repulsion.x.size(), grids.repulsionCount());
  for (size_t k = 0; k < grids.repulsionCount(); ++k) {
    const Eigen::Vector2d w = toWorld.linear.cast<double>() * grids.repulsionPositions()[k].cast<double>() +
                              toWorld.translation.cast<double>();
    expectWithinBound<2>(f.repulsion, k, w, "repulsion particle");
  }

  // Temporary particles keep their kind; counts by kind and control stats.
  size_t temporaries = 0;
  for (size_t i = 0; i < sim.fluid.size(); ++i) {
    EXPECT_EQ(f.kind[i], sim.fluid.kind[i]);
    temporaries += f.kind[i] == uint8_t(ParticleKind::Temporary);
  }
  EXPECT_GT(temporaries, 0u) << "the blob above the pool seeds temporary particles";
  EXPECT_EQ(f.stats.temporaryParticles, temporaries);
  EXPECT_EQ(f.stats.particles, sim.fluid.size());
  EXPECT_EQ(f.stats.controlParticles, fs.controlParticles);
  EXPECT_EQ(f.stats.repulsionParticles, fs.repulsionParticles);
  EXPECT_EQ(f.stats.controlledParticles, fs.controlledParticles);
  EXPECT_EQ(f.stats.seededParticles, fs.seededParticles);
  EXPECT_FLOAT_EQ(float(f.stats.controlMs), float(fs.controlMs));
  EXPECT_GT(f.stats.controlMs, 0);

  // Layers not asked for are not sent.
  encodeFrame<2>(sim, fs, scene.control, "ctl", LayerFlags{}, fbb);
  const DecodedFrame plain = decodeFrame(fbb.GetBufferPointer(), fbb.GetSize());
  EXPECT_FALSE(plain.layers.control || plain.layers.repulsion);
  EXPECT_TRUE(plain.layers.instances);
  EXPECT_TRUE(plain.control.x.empty());
  ASSERT_EQ(plain.instances.size(), 1u);
  EXPECT_EQ(plain.instances[0].controlCount, 0u);
  EXPECT_EQ(plain.instances[0].worldRowMajor.size(), 9u);
}

// Frames quantized ahead of time (the replay history) keep their bytes.
TEST(WireFrame, QuantizedFrameRoundTrip) {
  const std::vector<uint16_t> q = {0, 65535, 32768, 1, 65535, 0};
  const std::vector<uint8_t> kind = {0, 1, 0}, phase = {0, 0, 2};
  FrameStats fs;
  fs.frame = 12;
  fs.time = 0.2;
  fs.wallMs = 3.5;
  fs.boundaryParticles = 40;
  InstanceRecord rec;
  rec.name = "a";
  rec.templateName = "drop2d";
  rec.active = true;
  rec.templateFrame = 4;
  // Column-major 4×4 (three.js) of x' = 2x + 0.1, y' = 3y + 0.2 in 2D.
  std::array<double, 16> cm{};
  cm[0] = 2, cm[5] = 3, cm[10] = 1, cm[15] = 1, cm[12] = 0.1, cm[13] = 0.2;
  rec.setWorldFromColumnMajor4x4(cm, 2);
  const std::array<double, 9> expected = {2, 0, 0.1, 0, 3, 0.2, 0, 0, 1};
  for (size_t k = 0; k < 9; ++k) EXPECT_EQ(rec.worldRowMajor[k], expected[k]) << k;
  QuantizedFrame f;
  f.sessionId = "replay";
  f.dimension = 2;
  f.domainMin = {0, 0, 0};
  f.domainMax = {2, 1, 0};
  f.positions = q;
  f.kind = kind;
  f.phase = phase;
  f.stats = &fs;
  f.instances = std::span<const InstanceRecord>(&rec, 1);
  flatbuffers::FlatBufferBuilder fbb;
  encodeQuantizedFrame(f, LayerFlags{}, fbb);
  const DecodedFrame d = decodeFrame(fbb.GetBufferPointer(), fbb.GetSize());
  EXPECT_EQ(d.sessionId, "replay");
  EXPECT_EQ(d.frame, 12);
  ASSERT_EQ(d.particles.x.size(), 3u);
  EXPECT_DOUBLE_EQ(d.particles.x[0][0], 0);
  EXPECT_DOUBLE_EQ(d.particles.x[0][1], 1);
  EXPECT_DOUBLE_EQ(d.particles.x[1][0], 2 * 32768 / 65535.0);
  EXPECT_EQ(d.kind, kind);
  EXPECT_EQ(d.phase, phase);
  EXPECT_EQ(d.stats.temporaryParticles, 1u);
  EXPECT_EQ(d.stats.particles, 3u);
  EXPECT_EQ(d.stats.boundaryParticles, 40u);
  ASSERT_EQ(d.instances.size(), 1u);
  ASSERT_EQ(d.instances[0].worldRowMajor.size(), 9u);
  for (size_t k = 0; k < 9; ++k) EXPECT_FLOAT_EQ(d.instances[0].worldRowMajor[k], float(expected[k]));
  EXPECT_TRUE(d.speed.empty());  // not asked for
  // Layer.Speed from the recorded velocities: |v| within 1/255 of the frame's largest.
  const std::array<double, 2> vmax = {2.0, 1.0};
  const std::vector<double> vx = {2.0, -1.0, 0.0}, vy = {0.0, 1.0, 0.0};
  std::vector<uint16_t> vq;
  for (size_t i = 0; i < 3; ++i) {
    vq.push_back(uint16_t(std::lround((vx[i] / vmax[0] + 1) / 2 * 65535)));
    vq.push_back(uint16_t(std::lround((vy[i] / vmax[1] + 1) / 2 * 65535)));
  }
  f.velocities = vq;
  f.velocityMax = {vmax[0], vmax[1], 0};
  LayerFlags withSpeed;
  withSpeed.speed = true;
  encodeQuantizedFrame(f, withSpeed, fbb);
  const DecodedFrame ds = decodeFrame(fbb.GetBufferPointer(), fbb.GetSize());
  ASSERT_TRUE(ds.layers.speed);
  ASSERT_EQ(ds.speed.size(), 3u);
  EXPECT_NEAR(ds.speedMax, 2.0, 1e-3);
  for (size_t i = 0; i < 3; ++i) EXPECT_NEAR(ds.speed[i], std::hypot(vx[i], vy[i]), 2.0 / 255 + 1e-3) << i;
  // Inconsistent sizes are refused.
  f.phase = std::span<const uint8_t>(phase.data(), 2);
  EXPECT_THROW(encodeQuantizedFrame(f, LayerFlags{}, fbb), EncodeError);
  EXPECT_EQ(fbb.GetSize(), 0u);
}

TEST(WireVerifier, RejectsTruncatedGarbageAndWrongIdentifier) {
  Simulation<2> sim(tankSetup<2>(box2(0, 0, 1, 0.8f), box2(0, 0, 0.2f, 0.2f), kR));
  const FrameStats fs = sim.advanceFrame();
  flatbuffers::FlatBufferBuilder fbb;
  encodeFrame<2>(sim, fs, nullptr, "v", LayerFlags{}, fbb);
  const auto good = bytes(fbb);
  ASSERT_EQ(verifyEnvelope(good.data(), good.size()), "");

  EXPECT_NE(verifyEnvelope(nullptr, 0), "");
  EXPECT_NE(verifyEnvelope(good.data(), 0), "");
  EXPECT_NE(verifyEnvelope(good.data(), 7).find("too short"), std::string::npos);
  // Every truncation is refused (copied, so that reading past the end would
  // be caught by sanitizers rather than land in the original).
  for (size_t len = 8; len < good.size(); len += (len < 256 ? 1 : 61)) {
    std::vector<uint8_t> cut(good.begin(), good.begin() + long(len));
    EXPECT_NE(verifyEnvelope(cut.data(), cut.size()), "") << "truncated to " << len << " bytes";
    EXPECT_THROW(decodeFrame(cut.data(), cut.size()), std::invalid_argument);
  }
  // Wrong file identifier.
  auto wrong = good;
  std::memcpy(wrong.data() + 4, "FCW0", 4);
  const std::string err = verifyEnvelope(wrong.data(), wrong.size());
  EXPECT_NE(err.find("FCW0"), std::string::npos) << err;
  EXPECT_NE(err.find("FCW1"), std::string::npos) << err;
  // Garbage behind a correct identifier.
  std::mt19937 rng(5);
  for (int k = 0; k < 200; ++k) {
    std::vector<uint8_t> junk(8 + rng() % 512);
    for (auto& b : junk) b = uint8_t(rng());
    std::memcpy(junk.data() + 4, "FCW1", 4);
    EXPECT_NE(verifyEnvelope(junk.data(), junk.size()), "") << "garbage " << k;
  }
  // Random corruption of a valid frame: refused, or decodes (or throws)
  // without reading out of bounds.
  size_t refused = 0;
  for (int k = 0; k < 300; ++k) {
    auto bad = good;
    for (int flips = 0; flips < 4; ++flips) bad[rng() % bad.size()] ^= uint8_t(1u << (rng() % 8));
    if (!verifyEnvelope(bad.data(), bad.size()).empty()) {
      ++refused;
      continue;
    }
    try {
      (void)decodeFrame(bad.data(), bad.size());
    } catch (const std::invalid_argument&) {
    }
  }
  EXPECT_GT(refused, 0u);
  // A verified message of another type is not a frame.
  buildAck(fbb, 3, 10);
  EXPECT_THROW(decodeFrame(fbb.GetBufferPointer(), fbb.GetSize()), std::invalid_argument);
}

TEST(WireMessages, ServerMessagesRoundTrip) {
  flatbuffers::FlatBufferBuilder fbb;
  buildAck(fbb, 42, 17);
  ASSERT_EQ(verifyEnvelope(fbb.GetBufferPointer(), fbb.GetSize()), "");
  const auto* ack = fb::GetEnvelope(fbb.GetBufferPointer())->message_as_Ack();
  ASSERT_NE(ack, nullptr);
  EXPECT_EQ(ack->edit_id(), 42u);
  EXPECT_EQ(ack->frame(), 17);

  buildError(fbb, fb::ErrorCode::InvalidEdit, "instances[0].speed: must be > 0", 42);
  ASSERT_EQ(verifyEnvelope(fbb.GetBufferPointer(), fbb.GetSize()), "");
  const auto* err = fb::GetEnvelope(fbb.GetBufferPointer())->message_as_Error();
  ASSERT_NE(err, nullptr);
  EXPECT_EQ(err->code(), fb::ErrorCode::InvalidEdit);
  EXPECT_EQ(err->message()->str(), "instances[0].speed: must be > 0");
  EXPECT_EQ(err->request_id(), 42u);

  StateChangeInfo info;
  info.sessionId = "abc";
  info.status = fb::SessionStatus::Error;
  info.frame = 31;
  info.time = 31.0 / 60;
  info.shownFrame = 12;
  info.live = false;
  info.playbackSpeed = 30;
  info.historyFirstFrame = 0;
  info.historyLastFrame = 31;
  info.message = "particle 4 has a non-finite position";
  info.requestId = 9;
  info.stateJson = R"({"status":"error"})";
  buildStateChange(fbb, info);
  ASSERT_EQ(verifyEnvelope(fbb.GetBufferPointer(), fbb.GetSize()), "");
  const auto* sc = fb::GetEnvelope(fbb.GetBufferPointer())->message_as_StateChange();
  ASSERT_NE(sc, nullptr);
  EXPECT_EQ(sc->session_id()->str(), "abc");
  EXPECT_EQ(sc->status(), fb::SessionStatus::Error);
  EXPECT_EQ(sc->frame(), 31);
  EXPECT_DOUBLE_EQ(sc->time(), 31.0 / 60);
  EXPECT_EQ(sc->shown_frame(), 12);
  EXPECT_FALSE(sc->live());
  EXPECT_EQ(sc->playback_speed(), 30.0f);
  EXPECT_EQ(sc->history_last_frame(), 31);
  EXPECT_EQ(sc->message()->str(), info.message);
  EXPECT_EQ(sc->request_id(), 9u);
  EXPECT_EQ(sc->state_json()->str(), info.stateJson);
  // A server message sent back by a client is refused.
  expectFailure(parse(fbb), fb::ErrorCode::UnsupportedMessage, "StateChange is a server");
}

TEST(WireClient, ValidMessagesParse) {
  flatbuffers::FlatBufferBuilder fbb;
  buildEdit(fbb, EditRequest{7, R"({"type":"remove_instance","name":"drop"})"});
  auto m = parse(fbb);
  ASSERT_TRUE(std::holds_alternative<EditRequest>(m));
  EXPECT_EQ(std::get<EditRequest>(m).editId, 7u);
  EXPECT_EQ(std::get<EditRequest>(m).json, R"({"type":"remove_instance","name":"drop"})");

  TransportRequest t;
  t.requestId = 3;
  t.command = fb::TransportCommand::Step;
  t.steps = 25;
  buildTransport(fbb, t);
  m = parse(fbb);
  ASSERT_TRUE(std::holds_alternative<TransportRequest>(m));
  EXPECT_EQ(std::get<TransportRequest>(m).command, fb::TransportCommand::Step);
  EXPECT_EQ(std::get<TransportRequest>(m).steps, 25u);
  EXPECT_EQ(std::get<TransportRequest>(m).requestId, 3u);

  t.command = fb::TransportCommand::Seek;
  t.frame = 0;
  buildTransport(fbb, t);
  m = parse(fbb);
  ASSERT_TRUE(std::holds_alternative<TransportRequest>(m));
  EXPECT_EQ(std::get<TransportRequest>(m).frame, 0);

  t.command = fb::TransportCommand::SetSpeed;
  t.speed = 0;  // as fast as possible
  buildTransport(fbb, t);
  m = parse(fbb);
  ASSERT_TRUE(std::holds_alternative<TransportRequest>(m));
  EXPECT_EQ(std::get<TransportRequest>(m).speed, 0);

  // Step without a count steps once; Play, Pause, Reset take no argument.
  {
    fbb.Clear();
    fb::TransportBuilder b(fbb);
    b.add_command(fb::TransportCommand::Step);
    const auto off = b.Finish();
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message::Transport, off.Union()));
    m = parse(fbb);
    ASSERT_TRUE(std::holds_alternative<TransportRequest>(m));
    EXPECT_EQ(std::get<TransportRequest>(m).steps, 1u);
  }
  for (auto cmd : {fb::TransportCommand::Play, fb::TransportCommand::Pause, fb::TransportCommand::Reset}) {
    t.command = cmd;
    buildTransport(fbb, t);
    m = parse(fbb);
    ASSERT_TRUE(std::holds_alternative<TransportRequest>(m)) << fb::EnumNameTransportCommand(cmd);
    EXPECT_EQ(std::get<TransportRequest>(m).command, cmd);
  }

  SubscribeRequest s;
  s.requestId = 11;
  s.maxFrameRate = 30;
  s.layers.control = true;
  s.layers.boundary = true;
  s.layers.instances = false;
  buildSubscribe(fbb, s);
  m = parse(fbb);
  ASSERT_TRUE(std::holds_alternative<SubscribeRequest>(m));
  EXPECT_EQ(std::get<SubscribeRequest>(m).maxFrameRate, 30);
  EXPECT_EQ(std::get<SubscribeRequest>(m).layers, s.layers);
  // Defaults of an empty Subscribe: no rate limit, instance records only.
  {
    fbb.Clear();
    fb::SubscribeBuilder b(fbb);
    const auto off = b.Finish();
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message::Subscribe, off.Union()));
    m = parse(fbb);
    ASSERT_TRUE(std::holds_alternative<SubscribeRequest>(m));
    EXPECT_EQ(std::get<SubscribeRequest>(m).maxFrameRate, 0);
    EXPECT_EQ(std::get<SubscribeRequest>(m).layers, LayerFlags{});
  }
}

TEST(WireClient, ParseErrorsNameTheField) {
  flatbuffers::FlatBufferBuilder fbb;
  // Not a flatbuffer / wrong identifier / truncated.
  const uint8_t junk[] = {1, 2, 3};
  expectFailure(parseClientMessage(junk, sizeof junk), fb::ErrorCode::InvalidMessage, "too short");
  buildEdit(fbb, EditRequest{1, "{}"});
  auto buf = bytes(fbb);
  std::memcpy(buf.data() + 4, "JSON", 4);
  expectFailure(parseClientMessage(buf.data(), buf.size()), fb::ErrorCode::InvalidMessage, "expected 'FCW1'");
  buf = bytes(fbb);
  expectFailure(parseClientMessage(buf.data(), buf.size() - 3), fb::ErrorCode::InvalidMessage, "verification");

  // Edit: id and json required.
  buildEdit(fbb, EditRequest{0, "{}"});
  expectFailure(parse(fbb), fb::ErrorCode::MissingField, "Edit.edit_id");
  {
    fbb.Clear();
    const auto e = fb::CreateEdit(fbb, 5);
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message::Edit, e.Union()));
    const auto f = expectFailure(parse(fbb), fb::ErrorCode::MissingField, "Edit.json is missing");
    EXPECT_EQ(f.requestId, 5u);
  }
  buildEdit(fbb, EditRequest{6, ""});
  expectFailure(parse(fbb), fb::ErrorCode::MissingField, "Edit.json is empty");

  // Transport: required and unused fields, ranges.
  auto transport = [&](fb::TransportCommand cmd, flatbuffers::Optional<uint32_t> steps,
                       flatbuffers::Optional<int32_t> frame, flatbuffers::Optional<float> speed) {
    fbb.Clear();
    const auto t = fb::CreateTransport(fbb, 8, cmd, steps, frame, speed);
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message::Transport, t.Union()));
    return parse(fbb);
  };
  using flatbuffers::nullopt;
  expectFailure(transport(fb::TransportCommand::Seek, nullopt, nullopt, nullopt), fb::ErrorCode::MissingField,
                "Transport.frame is required by Seek");
  expectFailure(transport(fb::TransportCommand::Seek, nullopt, -2, nullopt), fb::ErrorCode::InvalidArgument,
                "Transport.frame is -2");
  expectFailure(transport(fb::TransportCommand::SetSpeed, nullopt, nullopt, nullopt), fb::ErrorCode::MissingField,
                "Transport.speed is required by SetSpeed");
  expectFailure(transport(fb::TransportCommand::SetSpeed, nullopt, nullopt, -1.0f), fb::ErrorCode::InvalidArgument,
                "Transport.speed is -1");
  expectFailure(transport(fb::TransportCommand::SetSpeed, nullopt, nullopt, std::numeric_limits<float>::quiet_NaN()),
                fb::ErrorCode::InvalidArgument, "Transport.speed is nan");
  expectFailure(transport(fb::TransportCommand::Step, 0u, nullopt, nullopt), fb::ErrorCode::InvalidArgument,
                "Transport.steps is 0");
  expectFailure(transport(fb::TransportCommand::Play, nullopt, 4, nullopt), fb::ErrorCode::InvalidArgument,
                "Transport.frame is only used by Seek (command is Play)");
  expectFailure(transport(fb::TransportCommand::Seek, 2u, 4, nullopt), fb::ErrorCode::InvalidArgument,
                "Transport.steps is only used by Step");
  const auto bad = expectFailure(transport(fb::TransportCommand(17), nullopt, nullopt, nullopt),
                                  fb::ErrorCode::InvalidArgument, "Transport.command 17");
  EXPECT_EQ(bad.requestId, 8u);

  // Subscribe: ranges and unknown layer bits.
  {
    fbb.Clear();
    const auto s = fb::CreateSubscribe(fbb, 2, -5.0f, fb::Layer::Control);
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message::Subscribe, s.Union()));
    expectFailure(parse(fbb), fb::ErrorCode::InvalidArgument, "Subscribe.max_frame_rate is -5");
  }
  {
    fbb.Clear();
    const auto s = fb::CreateSubscribe(fbb, 2, 10.0f, fb::Layer(0x81));
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message::Subscribe, s.Union()));
    expectFailure(parse(fbb), fb::ErrorCode::InvalidArgument, "Subscribe.layers has unknown bits 0x80");
  }

  // Envelope: no message, an unknown union type, a type without its table,
  // a server → client type.
  {
    fbb.Clear();
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb));
    expectFailure(parse(fbb), fb::ErrorCode::MissingField, "Envelope.message is missing");
  }
  {
    fbb.Clear();
    const auto a = fb::CreateAck(fbb, 1, 2);
    fb::FinishEnvelopeBuffer(fbb, fb::CreateEnvelope(fbb, fb::Message(42), a.Union()));
    ASSERT_EQ(verifyEnvelope(fbb.GetBufferPointer(), fbb.GetSize()), "");  // forward compatible: it verifies
    expectFailure(parse(fbb), fb::ErrorCode::UnsupportedMessage, "unknown message type 42");
  }
  {
    fbb.Clear();
    fb::EnvelopeBuilder b(fbb);
    b.add_message_type(fb::Message::Transport);
    fb::FinishEnvelopeBuffer(fbb, b.Finish());
    expectFailure(parse(fbb), fb::ErrorCode::MissingField, "type is Transport but the table is missing");
  }
  buildAck(fbb, 1, 1);
  expectFailure(parse(fbb), fb::ErrorCode::UnsupportedMessage, "Ack is a server");
  buildError(fbb, fb::ErrorCode::Internal, "x");
  expectFailure(parse(fbb), fb::ErrorCode::UnsupportedMessage, "Error is a server");
}
