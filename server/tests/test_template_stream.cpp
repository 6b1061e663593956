// Templates too large to hold decoded: TemplateStream reads a file frame by
// frame, TemplateAccel keeps a bounded cache of built frames, and
// TemplateDatabase streams what would not fit its budget. What is streamed
// must be exactly what is read whole, and a liquid steered by it must move
// exactly as one steered by the whole template.
#include "control/control.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include "service/session.h"
#include "sph/simulation.h"
#include "tests/hdf5_test_util.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <vector>

using namespace fc;
using fc::test::TempDir;

namespace {

constexpr Real kR = Real(0.01);
constexpr double kRho0 = 1000;

// A blob that falls and spreads, every frame in another place, with fewer
// particles from frame 5 on (so that rows and frames do not line up), and
// two phases.
Template<2> movingBlob(int frames) {
  Template<2> t;
  t.header.name = "blob";
  t.header.dimension = 2;
  t.header.frameRate = 30;
  t.header.particleRadius = kR;
  t.header.supportRadius = 4 * kR;
  t.header.restDensity = kRho0;
  t.header.regionMin = {0.2, 0.0};
  t.header.regionMax = {0.8, 0.7};
  for (int f = 0; f < frames; ++f) {
    TemplateFrame<2> fr;
    const Real drop = Real(0.004) * Real(f * f), spread = Real(1) + Real(0.03) * Real(f);
    for (Real x = Real(-0.08) + kR; x < Real(0.08) - f * Real(0.002); x += 2 * kR)
      for (Real y = kR; y < Real(0.16); y += 2 * kR) {
        fr.x.push_back(Vec<2>(Real(0.5) + x * spread, Real(0.45) + y - drop));
        fr.v.push_back(Vec<2>(Real(0.3) * x * Real(f), -Real(0.25) * Real(f)));
        fr.mass.push_back(Real(kRho0 * 4 * kR * kR));
        fr.phase.push_back(fr.x.size() % 3 == 0 ? 1 : 0);
      }
    t.frames.push_back(std::move(fr));
  }
  return t;
}

void expectSameFrame(const TemplateFrame<2>& a, const TemplateFrame<2>& b, size_t f) {
  ASSERT_EQ(a.size(), b.size()) << "frame " << f;
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a.x[i], b.x[i]) << "frame " << f << " particle " << i;
    ASSERT_EQ(a.v[i], b.v[i]) << "frame " << f << " particle " << i;
    ASSERT_EQ(a.mass[i], b.mass[i]) << "frame " << f << " particle " << i;
    ASSERT_EQ(a.phase[i], b.phase[i]) << "frame " << f << " particle " << i;
  }
}

std::shared_ptr<const TemplateAccel<2>> streamedAccel(const std::string& path, size_t cacheBytes) {
  auto stream = std::make_shared<TemplateStream<2>>(path);
  auto header = std::make_shared<Template<2>>();
  header->header = stream->header();
  header->streamedFrames = stream->frameCount();
  return std::make_shared<TemplateAccel<2>>(TemplateAccel<2>::streamed(header, stream, cacheBytes));
}

}  // namespace

TEST(TemplateStream, FramesEqualTheWholeReadInAnyOrder) {
  TempDir dir;
  const std::string path = dir.file("blob.h5");
  writeTemplate(path, movingBlob(12));
  const Template<2> whole = readTemplate<2>(path);
  const TemplateStream<2> stream(path);
  EXPECT_EQ(stream.header().name, "blob");
  ASSERT_EQ(stream.frameCount(), whole.frames.size());
  uint64_t rows = 0;
  for (size_t f = 0; f < whole.frames.size(); ++f) {
    EXPECT_EQ(stream.frameParticles(f), whole.frames[f].size());
    rows += whole.frames[f].size();
  }
  EXPECT_EQ(stream.particleFrames(), rows);
  for (size_t f : {7, 0, 11, 3, 3, 10, 1}) expectSameFrame(stream.readFrame(f), whole.frames[f], f);
  EXPECT_THROW(stream.readFrame(12), TemplateError);
}

TEST(TemplateStream, RefusesDamagedFilesAndFilesWithoutAChecksumBlock) {
  TempDir dir;
  const std::string path = dir.file("blob.h5");
  writeTemplate(path, movingBlob(6));
  const auto message = [&](const std::string& p) {
    try {
      TemplateStream<2> s(p);
    } catch (const TemplateError& e) {
      return std::string(e.what());
    }
    return std::string("<opened>");
  };
  EXPECT_NE(message(dir.file("none.h5")).find("does not exist"), std::string::npos);
  EXPECT_NE(message(path).find("<opened>"), std::string::npos);
  {  // a byte of the particle data flipped: the checksum no longer matches
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(-100, std::ios::end);
    char c = 0;
    f.read(&c, 1);
    f.seekp(-100, std::ios::end);
    c = char(~c);
    f.write(&c, 1);
  }
  EXPECT_NE(message(path).find("does not match its checksum"), std::string::npos) << message(path);
  writeTemplate(path, movingBlob(6));
  {  // the checksum block blanked: read whole or not at all, never streamed
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    const std::string zeros(512, '\0');
    f.write(zeros.data(), std::streamsize(zeros.size()));
  }
  EXPECT_NE(message(path).find("checksum block"), std::string::npos) << message(path);
  EXPECT_THROW(TemplateStream<3>(dir.file("blob3.h5")), TemplateError);
  writeTemplate(path, movingBlob(6));
  EXPECT_NE(std::string([&] {
              try {
                TemplateStream<3> s(path);
              } catch (const TemplateError& e) {
                return std::string(e.what());
              }
              return std::string();
            }()).find("2D template, expected a 3D one"),
            std::string::npos);
}

// The cache holds at most its budget of frames nobody uses, keeps a frame
// while it is held, and builds each frame as the resident template does.
TEST(TemplateStream, CacheKeepsItsBudgetAndTheFramesInUse) {
  TempDir dir;
  const std::string path = dir.file("blob.h5");
  writeTemplate(path, movingBlob(12));
  const auto whole = std::make_shared<const Template<2>>(readTemplate<2>(path));
  const TemplateAccel<2> resident = TemplateAccel<2>::build(whole);
  const auto probe = streamedAccel(path, 0);
  const size_t frameBytes = (probe->frame(0), probe->cacheStats().peakBytes);
  ASSERT_GT(frameBytes, 0u);
  const size_t budget = frameBytes * 5 / 2;  // two or three of these frames
  const auto acc = streamedAccel(path, budget);
  EXPECT_TRUE(acc->isStreamed());
  EXPECT_EQ(acc->frameCount(), 12u);
  EXPECT_EQ(acc->source->frameCount(), 12u);
  EXPECT_NEAR(acc->source->duration(), 11.0 / 30.0, 1e-12);

  const auto held = acc->frame(0);  // kept while the others come and go
  for (int pass = 0; pass < 2; ++pass)
    for (size_t f = 0; f < 12; ++f) {
      const auto g = acc->frame(f);
      const auto& r = *resident.frame(f);
      EXPECT_EQ(g->controlPositions(), r.controlPositions()) << "frame " << f;
      EXPECT_EQ(g->repulsionPositions(), r.repulsionPositions()) << "frame " << f;
      EXPECT_EQ(g->repulsionNormals(), r.repulsionNormals()) << "frame " << f;
      const auto c = acc->cacheStats();
      // The budget, plus frame 0 (held) and the frame in hand beyond it.
      EXPECT_LE(c.residentBytes, budget + 2 * frameBytes * 3 / 2) << "frame " << f;
    }
  EXPECT_EQ(held->controlPositions(), resident.frame(0)->controlPositions());
  const auto c = acc->cacheStats();
  EXPECT_LE(c.residentFrames, 4u);
  EXPECT_GE(c.loads, 20u) << "each pass reads again the frames the budget let go";
  EXPECT_GE(c.hits, 2u) << "frame 0, held, is found in the cache";
  EXPECT_LE(c.peakBytes, budget + 3 * frameBytes);

  // A generous budget reads every frame once.
  const auto roomy = streamedAccel(path, 100 * frameBytes);
  for (int pass = 0; pass < 3; ++pass)
    for (size_t f = 0; f < 12; ++f) roomy->frame(f);
  EXPECT_EQ(roomy->cacheStats().loads, 12u);
  EXPECT_EQ(roomy->cacheStats().hits, 24u);
}

TEST(TemplateStream, ThreadsAskingForFramesAllGetTheRightOnes) {
  TempDir dir;
  const std::string path = dir.file("blob.h5");
  writeTemplate(path, movingBlob(12));
  const Template<2> whole = readTemplate<2>(path);
  const auto acc = streamedAccel(path, 1);  // every frame not in use is dropped
  std::atomic<int> wrong{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&, t] {
      std::mt19937 rng(unsigned(t + 1));
      for (int k = 0; k < 150; ++k) {
        const size_t f = rng() % 12;
        const auto g = acc->frame(f);
        if (g->controlPositions() != whole.frames[f].x) ++wrong;
      }
    });
  for (auto& th : threads) th.join();
  EXPECT_EQ(wrong.load(), 0);
  EXPECT_LE(acc->cacheStats().residentFrames, 1u) << "nothing held, a budget of one byte keeps the last frame read";
}

// The database streams a template whose decoded frames exceed its budget,
// and the liquid it steers moves bit for bit as with the whole template.
TEST(TemplateStream, DatabaseStreamsWhatExceedsItsBudgetAndSteersTheSame) {
  TempDir dir;
  writeTemplate(dir.file("blob.h5"), movingBlob(12));
  TemplateDatabase roomy(dir.path());
  TemplateDatabase tight(dir.path(), 16 * 1024);  // a few frames' worth
  const auto whole = roomy.load<2>("blob");
  const auto streamed = tight.load<2>("blob");
  EXPECT_FALSE(whole->streamed());
  ASSERT_TRUE(streamed->streamed());
  EXPECT_EQ(streamed->templ().frameCount(), 12u);
  EXPECT_TRUE(streamed->templ().frames.empty());
  EXPECT_EQ(roomy.streamedTemplates().size(), 0u);
  ASSERT_EQ(tight.streamedTemplates().size(), 1u);
  EXPECT_EQ(tight.streamedTemplates()[0].name, "blob");

  const auto run = [&](std::shared_ptr<const LoadedTemplate<2>> lt) {
    SimulationSetup<2> s;
    s.particleRadius = kR;
    s.domain = AABB<2>(Vec<2>(0, 0), Vec<2>(1, 0.8f));
    s.gravity = Vec<2>(0, Real(-9.81));
    FluidBlock<2> pool;
    pool.box = AABB<2>(Vec<2>(0, 0), Vec<2>(1, 0.16f));
    s.fluidBlocks.push_back(pool);
    s.solver.name = "dfsph";
    s.settings.frameRate = 60;
    auto sim = std::make_unique<Simulation<2>>(s);
    BoundInstance<2> b;
    b.spec.name = b.spec.templateName = "blob";
    b.spec.params = instanceParamTable(2).defaults();
    TransformKey<2> k;
    k.translation = lt->templ().region().center().cast<double>();
    b.spec.transform.keys = {k};
    b.accel = std::shared_ptr<const TemplateAccel<2>>(lt, &lt->accel);
    sim->addEffect(std::make_unique<Control<2>>(std::vector<BoundInstance<2>>{b}, controlSettingsTable().defaults()),
                   "control");
    size_t controlled = 0;
    for (int f = 0; f < 24; ++f) {
      const FrameStats st = sim->advanceFrame();
      EXPECT_TRUE(st.finite);
      if (!st.instances.empty()) controlled += st.instances[0].controlled;
    }
    EXPECT_GT(controlled, 0u) << "the instance steers the pool";
    return sim;
  };
  const auto a = run(whole);
  const auto b = run(streamed);
  ASSERT_EQ(a->fluid.size(), b->fluid.size());
  for (size_t i = 0; i < a->fluid.size(); ++i) {
    ASSERT_EQ(a->fluid.x[i], b->fluid.x[i]) << "particle " << i;
    ASSERT_EQ(a->fluid.v[i], b->fluid.v[i]) << "particle " << i;
  }
  const auto stats = tight.streamedTemplates().at(0);
  EXPECT_GE(stats.loads, 12u) << "the instance plays every frame";
}

// A template cut short in place while a session streams it (a disk that
// fails, a file written over by another program: re-recording replaces the
// file and does not do this): the frame that needs a lost frame fails with
// the file's name, the session stops in its error state, and another
// session goes on.
TEST(TemplateStream, ASessionWhoseTemplateStopsReadingFailsItsFrameNotTheServer) {
  using namespace std::chrono_literals;
  TempDir dir;
  // 24 frames of 6 400 particles: the rows span three of the file's chunks,
  // so frames past the first chunk are read from the disk when first played.
  Template<2> big = movingBlob(1);
  big.header.name = "big";
  big.header.frameRate = 60;
  TemplateFrame<2> f0;
  for (int i = 0; i < 80; ++i)
    for (int j = 0; j < 80; ++j) {
      f0.x.push_back(Vec<2>(Real(0.21) + Real(i) * Real(0.0075), Real(0.01) + Real(j) * Real(0.0075)));
      f0.v.push_back(Vec<2>::Zero());
      f0.mass.push_back(Real(0.05));
      f0.phase.push_back(0);
    }
  big.frames.assign(24, f0);
  for (size_t f = 0; f < big.frames.size(); ++f)
    for (auto& x : big.frames[f].x) x.y() += Real(0.001) * Real(f);
  const std::string path = dir.file("big.h5");
  writeTemplate(path, big);
  TemplateDatabase db(dir.path(), 256 * 1024);
  nlohmann::json scene = fc::test::smallTankScene("streamed");
  scene["instances"] = nlohmann::json::array({{{"template", "big"}, {"name", "big"}}});
  auto bad = service::createSession("bad", "", scene, db);
  auto good = service::createSession("good", "", fc::test::smallTankScene("good"), db);
  ASSERT_EQ(db.streamedTemplates().size(), 1u);
  bad->step(2);
  ASSERT_TRUE(bad->waitIdle(60s));
  ASSERT_EQ(bad->status(), service::SessionStatus::Paused) << bad->state().dump();
  std::filesystem::resize_file(path, std::filesystem::file_size(path) / 4);
  good->play();
  bad->play();
  ASSERT_TRUE(fc::test::waitFor([&] { return bad->status() == service::SessionStatus::Error; }, 60s))
      << bad->state().dump();
  const nlohmann::json st = bad->state();
  EXPECT_NE(st["error"]["message"].get<std::string>().find(path), std::string::npos) << st.dump();
  EXPECT_GE(st["error"]["frame"].get<int>(), 3);
  const int g = good->currentFrame();
  EXPECT_TRUE(good->waitForFrame(g + 3, 60s));
  EXPECT_EQ(good->status(), service::SessionStatus::Playing);
  good->pause();
}
