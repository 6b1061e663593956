// Checkpoints (Simulation::archiveState, service/checkpoints.h): a
// simulation restored from the state saved after frame k and run on
// reproduces the original run bit for bit, in 2D and 3D, with a template
// instance seeding and removing temporary particles, a dynamic body, an
// emitter and warm-started solvers, at another thread count than the run
// that saved it; restoring in place (into a simulation already further on,
// as sessions do) too. The store's codec is lossless and its cap holds.
#include "control/control.h"
#include "io/scene.h"
#include "service/checkpoints.h"
#include "service/edit_scope.h"
#include "sph/simulation.h"
#include "sph/state_archive.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <omp.h>

#include <algorithm>
#include <climits>
#include <memory>
#include <random>
#include <vector>

using namespace fc;
using nlohmann::json;

namespace {

// A pool with a dynamic box floating on it, a nozzle pouring into it, an
// implicit viscosity (warm-started) and DFSPH (warm-started).
template <int D>
json richScene() {
  json s;
  s["dimension"] = D;
  s["name"] = "checkpoint";
  if constexpr (D == 2) {
    s["particle_radius"] = 0.01;
    s["domain"] = {{"min", {0, 0}}, {"max", {1, 0.8}}};
    s["gravity"] = {0, -9.81};
    s["fluid_blocks"] = json::array({{{"min", {0, 0}}, {"max", {1, 0.2}}}});
    s["bodies"] = json::array({{{"name", "box"}, {"type", "box"}, {"size", {0.1, 0.06}}, {"position", {0.8, 0.21}},
                                {"motion", "dynamic"}, {"density", 500}, {"carve_fluid", true}}});
    s["emitters"] = json::array(
        {{{"name", "nozzle"}, {"center", {0.15, 0.6}}, {"direction", {0, -1}}, {"radius", 0.02}, {"speed", 0.5}}});
  } else {
    s["particle_radius"] = 0.02;
    s["domain"] = {{"min", {0, 0, 0}}, {"max", {0.6, 0.6, 0.4}}};
    s["gravity"] = {0, -9.81, 0};
    s["fluid_blocks"] = json::array({{{"min", {0, 0, 0}}, {"max", {0.6, 0.12, 0.4}}}});
    s["bodies"] = json::array({{{"name", "box"}, {"type", "box"}, {"size", {0.12, 0.08, 0.12}},
                                {"position", {0.45, 0.13, 0.2}}, {"motion", "dynamic"}, {"density", 500}, {"carve_fluid", true}}});
    s["emitters"] = json::array({{{"name", "nozzle"}, {"center", {0.1, 0.45, 0.1}}, {"direction", {0, -1, 0}},
                                  {"radius", 0.04}, {"speed", 0.5}}});
  }
  s["solver"] = {{"method", "dfsph"}, {"density_tolerance_pct", 0.1}};
  s["effects"] = json::array({{{"name", "viscosity_weiler2018"}}});
  s["settings"] = {{"frame_rate", 60}};
  return s;
}

// A blob of liquid standing on the pool and rising above it, every frame the
// same, `frames` frames at 30 fps: it seeds temporary particles while it
// plays and they are removed after it.
template <int D>
std::shared_ptr<Template<D>> blobTemplate(Real r, const AABB<D>& region, const AABB<D>& blob, int frames) {
  auto t = std::make_shared<Template<D>>();
  t->header.name = "blob";
  t->header.dimension = D;
  t->header.frameRate = 30;
  t->header.particleRadius = r;
  t->header.supportRadius = 4 * r;
  t->header.restDensity = 1000;
  for (int d = 0; d < D; ++d) {
    t->header.regionMin.push_back(region.min[d]);
    t->header.regionMax.push_back(region.max[d]);
  }
  TemplateFrame<D> f;
  VecI<D> n;
  for (int d = 0; d < D; ++d) n[d] = int((blob.max[d] - blob.min[d]) / (2 * r));
  const int total = D == 2 ? n[0] * n[1] : n[0] * n[1] * n[2];
  for (int k = 0; k < total; ++k) {
    Vec<D> x;
    int rest = k;
    for (int d = 0; d < D; ++d) {
      x[d] = blob.min[d] + r + Real(rest % n[d]) * 2 * r;
      rest /= n[d];
    }
    f.x.push_back(x);
    f.v.push_back(Vec<D>::Zero());
    f.mass.push_back(Real(1000 * std::pow(2 * r, D)));
    f.phase.push_back(0);
  }
  t->frames.assign(size_t(frames), f);
  return t;
}

template <int D>
struct RichRun {
  std::unique_ptr<Simulation<D>> sim;

  RichRun() {
    sim = std::make_unique<Simulation<D>>(parseScene<D>(richScene<D>()));
    const Real r = sim->particleRadius();
    AABB<D> region, blob;
    if constexpr (D == 2) {
      region = AABB<2>(Vec<2>(0.35, 0.1), Vec<2>(0.65, 0.45));
      blob = AABB<2>(Vec<2>(0.42, 0.12), Vec<2>(0.58, 0.36));
    } else {
      region = AABB<3>(Vec<3>(0.15, 0.05, 0.1), Vec<3>(0.45, 0.35, 0.3));
      blob = AABB<3>(Vec<3>(0.2, 0.08, 0.14), Vec<3>(0.36, 0.28, 0.26));
    }
    auto tpl = blobTemplate<D>(r, region, blob, 11);  // 1/3 s: frames 1..20 of the scene
    BoundInstance<D> b;
    b.spec.name = "blob";
    b.spec.templateName = "blob";
    b.spec.params = instanceParamTable(D).defaults();
    b.spec.params.falloffWidth = 0.05;
    TransformKey<D> k;
    k.translation = tpl->region().center().template cast<double>();
    b.spec.transform.keys = {k};
    b.accel = std::make_shared<TemplateAccel<D>>(TemplateAccel<D>::build(tpl));
    ControlSettings settings = controlSettingsTable().defaults();
    settings.temporaryGraceFrames = 4;
    sim->addEffect(std::make_unique<Control<D>>(std::vector<BoundInstance<D>>{b}, settings), "control");
  }
};

template <int D>
std::vector<uint8_t> archiveOf(Simulation<D>& sim) {
  StateArchive a;
  sim.archiveState(a);
  return a.bytes();
}

template <int D>
void restoreAndCompare() {
  constexpr int kFrames = 34, kSaveEarly = 10, kSaveLate = 22;
  omp_set_num_threads(2);
  RichRun<D> original;
  std::vector<std::vector<uint8_t>> states(kFrames + 1);
  size_t seeded = 0, removed = 0, emitted = 0;
  for (int f = 1; f <= kFrames; ++f) {
    const FrameStats fs = original.sim->advanceFrame();
    ASSERT_TRUE(fs.finite) << fs.failure;
    seeded += fs.seededParticles;
    removed += fs.removedParticles;
    emitted += fs.emittedParticles;
    states[size_t(f)] = archiveOf(*original.sim);
  }
  // The run exercises what a checkpoint must carry.
  EXPECT_GT(seeded, 0u) << "no temporary particle was seeded";
  EXPECT_GT(removed, 0u) << "no temporary particle was removed";
  EXPECT_GT(emitted, 0u) << "the nozzle emitted nothing";
  ASSERT_NE(original.sim->bodies(), nullptr);

  // A fresh simulation of the same scene at one thread, restored after frame 10.
  omp_set_num_threads(1);
  RichRun<D> restored;
  {
    StateArchive load(states[kSaveEarly]);
    restored.sim->archiveState(load);
    EXPECT_TRUE(load.atEnd());
  }
  EXPECT_EQ(restored.sim->frame(), kSaveEarly);
  EXPECT_EQ(archiveOf(*restored.sim), states[kSaveEarly]) << "restore then save must give the same bytes";
  for (int f = kSaveEarly + 1; f <= kFrames; ++f) {
    const FrameStats fs = restored.sim->advanceFrame();
    ASSERT_TRUE(fs.finite) << fs.failure;
    ASSERT_EQ(archiveOf(*restored.sim), states[size_t(f)]) << "frame " << f << " differs after the restore";
  }
  // In place: the same simulation, now at frame 34, back to frame 22 (a
  // session going back for an edit), at two threads again.
  omp_set_num_threads(2);
  {
    StateArchive load(states[kSaveLate]);
    restored.sim->archiveState(load);
  }
  for (int f = kSaveLate + 1; f <= kFrames; ++f) {
    const FrameStats fs = restored.sim->advanceFrame();
    ASSERT_TRUE(fs.finite) << fs.failure;
    ASSERT_EQ(archiveOf(*restored.sim), states[size_t(f)]) << "frame " << f << " differs after the in-place restore";
  }
  omp_set_num_threads(omp_get_num_procs());
}

}  // namespace

TEST(Checkpoints, RestoreReproducesTheRunBitForBit2D) { restoreAndCompare<2>(); }
TEST(Checkpoints, RestoreReproducesTheRunBitForBit3D) { restoreAndCompare<3>(); }

// An archive from another scene or a damaged one is refused, never misread.
TEST(Checkpoints, MismatchedOrTruncatedArchivesAreRefused) {
  RichRun<2> a;
  a.sim->advanceFrame();
  std::vector<uint8_t> bytes = archiveOf(*a.sim);
  std::vector<uint8_t> cut(bytes.begin(), bytes.begin() + long(bytes.size() / 2));
  RichRun<2> b;
  {
    StateArchive load(cut);
    EXPECT_THROW(b.sim->archiveState(load), StateArchiveError);
  }
  // Without bodies: the scene differs.
  json scene = richScene<2>();
  scene.erase("bodies");
  Simulation<2> other(parseScene<2>(scene));
  StateArchive load(bytes);
  EXPECT_THROW(other.archiveState(load), StateArchiveError);
}

// The codec gives back every byte; it pays on particle state.
TEST(Checkpoints, CompressionIsLosslessAndPaysOnParticleState) {
  RichRun<2> run;
  for (int f = 0; f < 5; ++f) run.sim->advanceFrame();
  const std::vector<uint8_t> raw = archiveOf(*run.sim);
  const std::vector<uint8_t> packed = service::CheckpointStore::compress(raw);
  EXPECT_EQ(service::CheckpointStore::decompress(packed, raw.size()), raw);
  EXPECT_LT(packed.size(), raw.size() * 9 / 10) << "shuffle + deflate saves less than a tenth";
  std::printf("[ measured ] checkpoint of %zu particles: %zu bytes raw (%.1f per particle), %zu compressed (%.0f %%)\n",
              run.sim->fluid.size(), raw.size(), double(raw.size()) / double(run.sim->fluid.size()), packed.size(),
              100.0 * double(packed.size()) / double(raw.size()));
  // Odd sizes too (a tail shorter than a word).
  std::vector<uint8_t> odd(raw.begin(), raw.begin() + 1001);
  EXPECT_EQ(service::CheckpointStore::decompress(service::CheckpointStore::compress(odd), odd.size()), odd);
}

// The cap holds: past it the oldest checkpoints thin out, the newest stays.
TEST(Checkpoints, StoreThinsTheOldestToStayUnderItsCap) {
  std::mt19937 rng(7);
  std::vector<uint8_t> noise(10000);
  for (auto& b : noise) b = uint8_t(rng());
  service::CheckpointStore store(5, 45000, true);  // random bytes do not compress: 10 000 each
  for (int f = 5; f <= 100; f += 5) {
    ASSERT_TRUE(store.due(f));
    store.put(f, noise);
    EXPECT_LE(store.figures().bytes, 45000u) << "after frame " << f;
  }
  EXPECT_FALSE(store.due(0));
  EXPECT_FALSE(store.due(7));
  const std::vector<int> kept = store.frames();
  ASSERT_FALSE(kept.empty());
  EXPECT_EQ(kept.back(), 100);
  EXPECT_GE(kept.size(), 3u);
  std::vector<uint8_t> out;
  EXPECT_EQ(store.newestAtOrBefore(99, out), kept[kept.size() - 2]);
  EXPECT_EQ(out, noise);
  EXPECT_EQ(store.newestAtOrBefore(kept.front() - 1, out), 0);
  EXPECT_TRUE(out.empty());
  store.dropFrom(kept[1]);
  EXPECT_EQ(store.frames(), std::vector<int>{kept[0]});
}

// Dense: every frame is due; past the cap the in-between checkpoints go
// first, the farthest from the focus first, and the every-K grid stays.
TEST(Checkpoints, DenseStoreKeepsTheFramesNearestTheFocus) {
  std::mt19937 rng(11);
  std::vector<uint8_t> noise(10000);
  for (auto& b : noise) b = uint8_t(rng());
  service::CheckpointStore store(5, 200000, true, true);  // 20 checkpoints of 10 000 bytes
  EXPECT_TRUE(store.dense());
  store.setFocus(50);
  for (int f = 1; f <= 60; ++f) {
    ASSERT_TRUE(store.due(f)) << f;
    store.put(f, noise);
    EXPECT_LE(store.figures().bytes, 200000u) << "after frame " << f;
  }
  EXPECT_FALSE(store.due(0));
  // The 12 grid frames and the 8 nearest 50 in between.
  std::vector<int> expected;
  for (int f = 5; f <= 60; f += 5) expected.push_back(f);
  for (int f : {46, 47, 48, 49, 51, 52, 53, 54}) expected.push_back(f);
  std::sort(expected.begin(), expected.end());
  EXPECT_EQ(store.frames(), expected);
  std::vector<uint8_t> out;
  EXPECT_EQ(store.newestAtOrBefore(52, out), 52);
  EXPECT_EQ(out, noise);
  EXPECT_EQ(store.newestFrameAtOrBefore(44), 40);
  EXPECT_EQ(store.newestFrameAtOrBefore(4), 0);
  // No checkpoints at all (K = 0): nothing is due, dense or not.
  service::CheckpointStore none(0, 200000, true, true);
  EXPECT_FALSE(none.due(1));
  EXPECT_FALSE(none.dense());
}

// Which frames an edit changes.
TEST(EditScope, FirstAffectedFrameFollowsTheInstanceTimeline) {
  using service::firstAffectedFrame;
  using service::firstAffectedTime;
  const double dt = 1.0 / 60;
  EXPECT_EQ(firstAffectedFrame(0.5, dt), 31);  // frame 30 ends at 0.5 s and reads the scene before it
  EXPECT_EQ(firstAffectedFrame(0.49, dt), 30);
  EXPECT_EQ(firstAffectedFrame(0.2, dt), 13);
  EXPECT_EQ(firstAffectedFrame(0, dt), 1);
  EXPECT_EQ(firstAffectedFrame(-3, dt), 1);
  EXPECT_EQ(firstAffectedFrame(service::kAffectedFromStart, dt), 1);
  EXPECT_EQ(firstAffectedFrame(service::kNeverAffected, dt), INT_MAX);
  for (int n = 1; n < 2000; ++n) {  // on every frame end, as the simulation computes it
    EXPECT_EQ(firstAffectedFrame(double(n) * dt, dt), n + 1);
    EXPECT_EQ(firstAffectedFrame(double(n) * dt - 1e-7, dt), n);
  }

  InstanceSpec<2> a;
  a.params = instanceParamTable(2).defaults();
  a.time.start = 1.0;
  TransformKey<2> k0, k1, k2;
  k0.time = 0;
  k1.time = 2;
  k2.time = 3;
  k1.translation = Eigen::Vector2d(0.5, 0);
  k2.translation = Eigen::Vector2d(1, 0);
  a.transform.keys = {k0, k1, k2};
  InstanceSpec<2> b = a;
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), service::kNeverAffected);
  // The last key moved: from the key before it.
  b.transform.keys[2].translation.x() = 2;
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), 2.0);
  // The first key moved: from the instance's start (it acts only from there).
  b = a;
  b.transform.keys[0].translation.y() = 1;
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), 1.0);
  // A key appended after the last: from the last common key; one that
  // repeats the last pose changes nothing.
  b = a;
  TransformKey<2> k3 = k2;
  k3.time = 4;
  b.transform.keys.push_back(k3);
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), service::kNeverAffected);
  b.transform.keys.back().translation.x() = 3;
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), 3.0);
  // A key inserted on the path at its own pose: the velocity's rounding
  // may differ, so from the key before it.
  b = a;
  TransformKey<2> mid = k1;
  mid.time = 2.5;
  mid.translation = Eigen::Vector2d(0.75, 0);
  b.transform.keys.insert(b.transform.keys.begin() + 2, mid);
  const double t = firstAffectedTime<2>(&a, &b);
  EXPECT_TRUE(t == 2.0 || t == service::kNeverAffected) << t;
  // A weight: from the start; the start moved: from the earlier one.
  b = a;
  b.params.attractionWeight = 1;
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), 1.0);
  b = a;
  b.time.start = 0.25;
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), 0.25);
  // Added and removed: from its start.
  EXPECT_EQ(firstAffectedTime<2>(nullptr, &a), 1.0);
  EXPECT_EQ(firstAffectedTime<2>(&a, nullptr), 1.0);
  // A rename changes no simulated frame.
  b = a;
  b.name = "other";
  EXPECT_EQ(firstAffectedTime<2>(&a, &b), service::kNeverAffected);
}
