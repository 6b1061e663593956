// Sessions (service/session.h): transport on the session's own thread, edits
// validated and applied at frame boundaries with the frame they took effect
// in, the quantized replay history with its byte cap, seek, frame
// publication, the error state of a non-finite simulation, and independence
// of parallel sessions. Scenes are small 2D tanks built here; templates are
// written to a temporary directory.
#include "service/session.h"

#include "io/scene.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include "tests/hdf5_test_util.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>
#include <omp.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>
#include <thread>

namespace fc::service {
namespace {

using nlohmann::json;
using fc::test::TempDir;
using namespace std::chrono_literals;

constexpr auto kWait = 4000ms;

using fc::test::smallTankScene;
using fc::test::writeSmallTemplate;

struct Fixture {
  TempDir tmp;
  std::string dir = tmp.file("templates");
  TemplateDatabase db{dir};
  Fixture() { writeSmallTemplate<2>(dir, "blob", 13, {0.05, 0.05}, {0.35, 0.35}); }
};

EditResult resultOf(const EditTicket& t) {
  EXPECT_EQ(t.result.wait_for(kWait), std::future_status::ready);
  return t.result.get();
}

int historyFrames(const Session& s) { return s.state()["history"]["frames"].get<int>(); }

// ------------------------------------------------------------------ create ---

// A stream asked for layers and left before the session's thread got to it:
// the queued layer request must not break the session's closing.
TEST(SessionLayers, SessionClosesWithALayerRequestStillQueued) {
  Fixture fx;
  for (int k = 0; k < 20; ++k) {
    auto s = createSession("t", "", smallTankScene(), fx.db);
    wire::LayerFlags layers;
    layers.boundary = true;
    s->play();
    s->demandLayers(layers, +1);
  }
  auto s = createSession("t", "", smallTankScene(), fx.db);
  wire::LayerFlags layers;
  layers.boundary = true;
  s->demandLayers(layers, +1);
  ASSERT_TRUE(s->waitIdle(kWait));
  const auto layered = s->layeredFrame();
  ASSERT_NE(layered, nullptr);
  EXPECT_EQ(layered->frame, 0);
  EXPECT_TRUE(layered->layers.boundary);
}

TEST(SessionCreate, InvalidSceneThrowsWithKeyPath) {
  Fixture fx;
  json bad = smallTankScene();
  bad["settings"] = {{"cfl_factor", 7}};
  try {
    createSession("s", "", bad, fx.db);
    ADD_FAILURE() << "expected SceneError";
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "settings.cfl_factor");
  }
  json unknown = smallTankScene();
  unknown["instances"] = json::array({{{"template", "nope"}}});
  try {
    createSession("s", "", unknown, fx.db);
    ADD_FAILURE() << "expected SceneError";
  } catch (const SceneError& e) {
    EXPECT_EQ(e.path, "instances[0].template");
  }
}

TEST(SessionCreate, ThreeDimensionalScene) {
  Fixture fx;
  const json scene = json::parse(R"({
    "dimension": 3, "particle_radius": 0.02,
    "domain": {"min": [0, 0, 0], "max": [0.3, 0.3, 0.3]},
    "fluid_blocks": [{"min": [0, 0, 0], "max": [0.12, 0.12, 0.12]}]
  })");
  auto s = createSession("3d", "named", scene, fx.db);
  EXPECT_EQ(s->dimension(), 3);
  EXPECT_EQ(s->name(), "named");
  s->step(2);
  ASSERT_TRUE(s->waitIdle(kWait));
  const FramePtr f = s->latestFrame();
  EXPECT_EQ(f->frame, 2);
  EXPECT_EQ(f->particles(), 27u);
  EXPECT_EQ(f->positions.size(), 81u);
  EXPECT_EQ(f->bytes(), FrameSnapshot::estimateBytes(3, 27, 0));
  EXPECT_EQ(s->sceneJson()["dimension"], 3);
}

TEST(SessionCreate, StartsPausedAtFrameZeroWithState) {
  Fixture fx;
  auto s = createSession("abc", "", smallTankScene("tank"), fx.db);
  EXPECT_EQ(s->id(), "abc");
  EXPECT_EQ(s->name(), "tank");
  EXPECT_EQ(s->dimension(), 2);
  EXPECT_EQ(s->status(), SessionStatus::Paused);
  const json st = s->state();
  EXPECT_EQ(st["status"], "paused");
  EXPECT_EQ(st["frame"], 0);
  EXPECT_EQ(st["particles"]["liquid"], 100);
  EXPECT_GT(st["particles"]["boundary"].get<int>(), 0);
  EXPECT_EQ(st["history"]["frames"], 1);
  EXPECT_EQ(st["history"]["first"], 0);
  EXPECT_EQ(st["history"]["dropped"], 0);
  EXPECT_EQ(st["history"]["cap"], size_t(512) << 20);
  EXPECT_TRUE(st["shown"]["live"].get<bool>());
  EXPECT_FALSE(st.contains("error"));
  const FramePtr f = s->latestFrame();
  ASSERT_TRUE(f);
  EXPECT_EQ(f->frame, 0);
  EXPECT_EQ(f->particles(), 100u);
  EXPECT_EQ(f->positions.size(), 200u);
  // The block's lower-left particle sits one radius from the walls.
  double minX = 1;
  for (size_t i = 0; i < f->particles(); ++i) minX = std::min(minX, f->position(i, 0));
  EXPECT_NEAR(minX, 0.02, 2.0 / 65535);
  // Memory per frame: 100 particles × (2 × 2 + 2 × 2 + 2) bytes plus a fixed part.
  EXPECT_EQ(f->bytes(), FrameSnapshot::estimateBytes(2, 100, 0));
  EXPECT_EQ(st["memory"]["history_bytes_per_1000_frames"], 1000 * f->bytes());
  // The scene as saved parses back.
  const json scene = s->sceneJson();
  EXPECT_EQ(scene["settings"]["cfl_factor"], 1.0);
  EXPECT_NO_THROW(parseScene<2>(scene));
  EXPECT_TRUE(scene["instances"].empty());
}

// --------------------------------------------------------------- transport ---

TEST(SessionTransport, StepPlayPauseReset) {
  Fixture fx;
  auto s = createSession("t", "", smallTankScene(), fx.db);
  s->step(3);
  ASSERT_TRUE(s->waitIdle(kWait));
  EXPECT_EQ(s->currentFrame(), 3);
  EXPECT_EQ(s->status(), SessionStatus::Paused);
  EXPECT_EQ(historyFrames(*s), 4);  // 0..3
  EXPECT_NEAR(s->state()["time"].get<double>(), 3.0 / 60, 1e-9);

  s->play();
  EXPECT_EQ(s->status(), SessionStatus::Playing);
  ASSERT_TRUE(s->waitForFrame(6, kWait));
  s->pause();
  ASSERT_TRUE(s->waitIdle(kWait));
  const int paused = s->currentFrame();
  EXPECT_GE(paused, 6);
  EXPECT_EQ(s->status(), SessionStatus::Paused);
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(s->currentFrame(), paused);  // paused means paused
  EXPECT_EQ(historyFrames(*s), paused + 1);

  s->reset();
  ASSERT_TRUE(s->waitIdle(kWait));
  const json st = s->state();
  EXPECT_EQ(st["frame"], 0);
  EXPECT_EQ(st["time"], 0.0);
  EXPECT_EQ(st["history"]["frames"], 1);
  EXPECT_EQ(st["history"]["first"], 0);
  EXPECT_EQ(st["history"]["last"], 0);
  EXPECT_EQ(s->status(), SessionStatus::Paused);
  EXPECT_THROW(s->step(0), SessionError);
  EXPECT_THROW(s->setPlaybackSpeed(-1), SessionError);
}

TEST(SessionTransport, PlaybackSpeedCapsTheFrameRate) {
  Fixture fx;
  auto s = createSession("t", "", smallTankScene(), fx.db);
  s->setPlaybackSpeed(20);  // 50 ms per frame at most
  EXPECT_EQ(s->state()["playback_speed"], 20.0);
  const auto t0 = std::chrono::steady_clock::now();
  s->play();
  ASSERT_TRUE(s->waitForFrame(5, kWait));
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  s->pause();
  EXPECT_GE(took, 4 * 0.05 - 0.01);  // frames 2..5 each waited for their slot
}

TEST(SessionTransport, FrameListenersSeeEveryFrameInOrder) {
  Fixture fx;
  std::mutex m;  // listener state outlives the session
  std::vector<int> seen;
  std::vector<std::string> states;
  auto s = createSession("t", "", smallTankScene(), fx.db);
  const uint64_t id = s->subscribe({[&](const FramePtr& f) {
                                      std::lock_guard lk(m);
                                      seen.push_back(f->frame);
                                    },
                                    nullptr,
                                    [&](const json& st) {
                                      std::lock_guard lk(m);
                                      states.push_back(st["status"]);
                                    }});
  s->step(4);
  ASSERT_TRUE(s->waitIdle(kWait));
  {
    std::lock_guard lk(m);
    EXPECT_EQ(seen, (std::vector<int>{1, 2, 3, 4}));
    ASSERT_FALSE(states.empty());
    EXPECT_EQ(states.back(), "paused");
  }
  s->unsubscribe(id);
  s->step(1);
  ASSERT_TRUE(s->waitIdle(kWait));
  std::lock_guard lk(m);
  EXPECT_EQ(seen.size(), 4u);
  EXPECT_EQ(s->latestFrame()->frame, 5);
}

// ------------------------------------------------------------------- edits ---

TEST(SessionEdits, FromJsonNamesTheBadKey) {
  const auto path = [](const json& j) {
    try {
      Edit::fromJson(j);
    } catch (const SceneError& e) {
      return e.path;
    }
    return std::string("(accepted)");
  };
  EXPECT_EQ(path(json{{"type", "jump"}}), "type");
  EXPECT_EQ(path(json{{"name", "x"}}), "type");
  EXPECT_EQ(path(json{{"type", "add_instance"}}), "instance");
  EXPECT_EQ(path(json{{"type", "add_instance"}, {"instance", 3}}), "instance");
  EXPECT_EQ(path(json{{"type", "update_instance"}, {"patch", json::object()}}), "name");
  EXPECT_EQ(path(json{{"type", "remove_instance"}, {"name", "a"}, {"extra", 1}}), "extra");
  EXPECT_EQ(path(json{{"type", "settings"}, {"settings", 1}}), "settings");
  EXPECT_EQ(path(json{{"type", "settings"}, {"particle_radius", 1}}), "particle_radius");
  const Edit e = Edit::fromJson(json{{"type", "update_instance"}, {"name", "a"}, {"patch", {{"speed", 2}}}});
  EXPECT_EQ(e.kind, EditKind::UpdateInstance);
  EXPECT_EQ(e.instance, "a");
  EXPECT_EQ(e.payload["speed"], 2);
}

// Adding the first instance to a scene without instances adds the control
// stage; the ack names the first frame it changes (its start: frame 1),
// which the session re-simulates, and frame 0 carries no instance.
TEST(SessionEdits, FirstInstanceAddsControlAtTheAcknowledgedFrame) {
  Fixture fx;
  auto s = createSession("e", "", smallTankScene(), fx.db);
  s->step(2);
  ASSERT_TRUE(s->waitIdle(kWait));
  EXPECT_FALSE(s->latestFrame()->stats.instances.size());
  EditResult r = resultOf(s->submit(Edit::fromJson(json{{"type", "add_instance"}, {"instance", {{"template", "blob"}}}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_EQ(r.frame, 1);  // it starts at 0: every frame after the initial state changes
  EXPECT_EQ(r.instance, "blob");
  EXPECT_EQ(s->editResult(r.id)->frame, 1);
  EXPECT_EQ(s->sceneJson()["instances"].size(), 1u);
  EXPECT_EQ(s->state()["instances"], 1);
  ASSERT_TRUE(s->waitIdle(kWait));
  EXPECT_EQ(s->frame(2)->stats.instances.size(), 1u) << "frame 2 was re-simulated with the instance";
  s->step(1);
  ASSERT_TRUE(s->waitIdle(kWait));
  const FramePtr f = s->latestFrame();
  EXPECT_EQ(f->frame, 3);
  ASSERT_EQ(f->stats.instances.size(), 1u);
  EXPECT_TRUE(f->stats.instances[0].active);
  ASSERT_EQ(f->instances.size(), 1u);
  EXPECT_EQ(f->instances[0].name, "blob");
  EXPECT_TRUE(f->instances[0].active);
  // Played where it was recorded: the region's centre maps to itself.
  const auto& m = f->instances[0].toWorld;
  EXPECT_NEAR(m[0] * 0.2 + m[4] * 0.2 + m[12], 0.2, 1e-9);
  EXPECT_NEAR(m[1] * 0.2 + m[5] * 0.2 + m[13], 0.2, 1e-9);
  EXPECT_EQ(s->frame(0)->instances.size(), 0u);
  EXPECT_TRUE(s->state()["stats"].contains("control_ms"));

  // Update (merge patch), then remove.
  r = resultOf(s->submit(Edit::fromJson(
      json{{"type", "update_instance"}, {"name", "blob"}, {"patch", {{"speed", 0.5}, {"name", "slow"}}}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_EQ(r.frame, 1);
  EXPECT_EQ(r.instance, "slow");
  json inst = s->sceneJson()["instances"][0];
  EXPECT_EQ(inst["name"], "slow");
  EXPECT_EQ(inst["speed"], 0.5);
  EXPECT_EQ(inst["template"], "blob");
  r = resultOf(s->submit(Edit::fromJson(json{{"type", "remove_instance"}, {"name", "slow"}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_TRUE(s->sceneJson()["instances"].empty());
  s->step(1);
  ASSERT_TRUE(s->waitIdle(kWait));
  EXPECT_EQ(s->latestFrame()->instances.size(), 0u);
  EXPECT_EQ(s->latestFrame()->stats.instances.size(), 0u);
  EXPECT_EQ(s->status(), SessionStatus::Paused);
}

// While playing, an instance added with a later start changes only the
// frames from its start: the frame before it has no active instance, the
// frame at it has one, and playing goes on.
TEST(SessionEdits, AppliedAtAFrameBoundaryWhilePlaying) {
  Fixture fx;
  auto s = createSession("e", "", smallTankScene(), fx.db);
  s->play();
  ASSERT_TRUE(s->waitForFrame(2, kWait));
  const EditResult r = resultOf(s->submit(
      Edit::fromJson(json{{"type", "add_instance"}, {"instance", {{"template", "blob"}, {"start", 0.5}}}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_EQ(r.frame, 31);  // it starts at 0.5 s, where frame 30 ends
  ASSERT_TRUE(s->waitForFrame(31, 30 * kWait));
  s->pause();
  ASSERT_TRUE(s->waitIdle(30 * kWait));
  const FramePtr before = s->frame(29), at = s->frame(31);
  ASSERT_TRUE(before && at);
  ASSERT_EQ(before->stats.instances.size(), 1u);
  EXPECT_FALSE(before->stats.instances[0].active);
  ASSERT_EQ(at->stats.instances.size(), 1u);
  EXPECT_TRUE(at->stats.instances[0].active);
}

TEST(SessionEdits, InvalidEditsAreRejectedNamingTheFieldAndNotApplied) {
  Fixture fx;
  json scene = smallTankScene();
  scene["instances"] = json::array({{{"template", "blob"}, {"name", "a"}}});
  std::mutex m;
  std::vector<EditResult> heard;
  auto s = createSession("e", "", scene, fx.db);
  const json before = s->sceneJson();
  s->subscribe({nullptr, [&](const EditResult& r) {
                  std::lock_guard lk(m);
                  heard.push_back(r);
                }, nullptr});
  struct Case {
    json edit;
    std::string path;
    std::string mention;
  };
  const std::vector<Case> cases = {
      {{{"type", "add_instance"}, {"instance", {{"template", "nope"}}}}, "instances[1].template", "nope"},
      {{{"type", "add_instance"}, {"instance", {{"template", "blob"}, {"speed", -1}}}}, "instances[1].speed", "> 0"},
      {{{"type", "add_instance"}, {"instance", {{"template", "blob"}, {"name", "a"}}}}, "instances[1].name",
       "duplicate"},
      {{{"type", "add_instance"}, {"instance", {{"template", "blob"}, {"colour", 1}}}}, "instances[1].colour", ""},
      {{{"type", "add_instance"}, {"instance", {{"template", "blob"}, {"crop_end", 5}}}}, "instances[1].crop_end", ""},
      {{{"type", "update_instance"}, {"name", "a"}, {"patch", {{"phase", "oil"}}}}, "instances[0].phase", "oil"},
      {{{"type", "update_instance"}, {"name", "zz"}, {"patch", {{"speed", 2}}}}, "name", "zz"},
      {{{"type", "remove_instance"}, {"name", "zz"}}, "name", "zz"},
      {{{"type", "settings"}, {"settings", {{"cfl_factor", 5}}}}, "settings.cfl_factor", "5"},
      {{{"type", "settings"}, {"settings", {{"dt_min", 0.01}, {"dt_max", 0.001}}}}, "settings.dt_min", ""},
      {{{"type", "settings"}, {"solver", {{"density_tolerance_pct", 50}}}}, "solver.density_tolerance_pct", "50"},
      {{{"type", "settings"}, {"solver", {{"method", "magic"}}}}, "solver.method", "magic"},
      {{{"type", "settings"}, {"control", {{"fidelity_cell", 0}}}}, "control.fidelity_cell", ""},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.edit.dump());
    const EditResult r = resultOf(s->submit(Edit::fromJson(c.edit)));
    EXPECT_FALSE(r.accepted);
    EXPECT_EQ(r.frame, -1);
    EXPECT_EQ(r.path, c.path) << r.message;
    EXPECT_EQ(r.message.rfind(c.path + ": ", 0), 0u) << r.message;
    EXPECT_NE(r.message.find(c.mention), std::string::npos) << r.message;
    const json rj = r.toJson();
    EXPECT_FALSE(rj["accepted"].get<bool>());
    EXPECT_EQ(rj["error"]["path"], c.path);
  }
  EXPECT_EQ(s->sceneJson(), before);
  EXPECT_EQ(s->state()["pending_edits"], 0);
  s->step(1);
  ASSERT_TRUE(s->waitIdle(kWait));
  EXPECT_EQ(s->latestFrame()->stats.instances.size(), 1u);  // still only "a"
  std::lock_guard lk(m);
  EXPECT_EQ(heard.size(), cases.size());
}

// ------------------------------------------------------------ re-simulation ---

constexpr auto kResimWait = 120000ms;  // generous: a loaded machine

bool sameParticles(const FrameSnapshot& a, const FrameSnapshot& b) {
  return a.frame == b.frame && a.positions == b.positions && a.velocities == b.velocities && a.kind == b.kind &&
         a.phase == b.phase && a.velocityMax == b.velocityMax;
}

// A session of `scene` simulated `frames` frames from scratch: the reference
// an edited session must match bit for bit.
std::vector<FramePtr> freshRun(const json& scene, TemplateDatabase& db, int frames) {
  auto s = createSession("ref", "", scene, db);
  s->step(frames);
  EXPECT_TRUE(s->waitIdle(kResimWait));
  return s->history();
}

json sceneWithBlob(double start) {
  json scene = smallTankScene();
  scene["instances"] = json::array({{{"template", "blob"}, {"name", "blob"}, {"start", start}}});
  return scene;
}

// An edit at time t: the session re-simulates the frames after t by itself
// (no transport command), keeps every frame before t as it was (the same
// snapshots), and ends with exactly the frames a fresh run of the edited
// scene gives.
TEST(SessionResimulation, AnEditResimulatesTheFramesItChangesByItself) {
  Fixture fx;
  auto s = createSession("e", "", sceneWithBlob(0.2), fx.db);
  s->step(30);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  const std::vector<FramePtr> before = s->history();
  ASSERT_EQ(before.size(), 31u);
  // Dense (the default): every frame, memory allowing.
  json every = json::array();
  for (int f = 1; f <= 30; ++f) every.push_back(f);
  EXPECT_EQ(s->state()["cache"]["checkpoints"], every);
  EXPECT_TRUE(s->state()["cache"]["checkpoint_dense"].get<bool>());
  const EditResult r = resultOf(s->submit(Edit::fromJson(
      json{{"type", "update_instance"}, {"name", "blob"}, {"patch", {{"attraction_weight", 3}}}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_EQ(r.frame, 13);  // the instance starts at 0.2 s, where frame 12 ends: frame 13 is the first to read it
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->status(), SessionStatus::Paused);
  const std::vector<FramePtr> after = s->history();
  ASSERT_EQ(after.size(), 31u);
  for (int f = 0; f < 13; ++f) EXPECT_EQ(after[size_t(f)], before[size_t(f)]) << "frame " << f << " was replaced";
  bool changed = false;
  for (int f = 13; f <= 30; ++f) changed = changed || !sameParticles(*after[size_t(f)], *before[size_t(f)]);
  EXPECT_TRUE(changed) << "the stronger attraction changed no frame";
  json edited = sceneWithBlob(0.2);
  edited["instances"][0]["attraction_weight"] = 3;
  const std::vector<FramePtr> reference = freshRun(edited, fx.db, 30);
  ASSERT_EQ(reference.size(), 31u);
  for (int f = 0; f <= 30; ++f)
    EXPECT_TRUE(sameParticles(*after[size_t(f)], *reference[size_t(f)])) << "frame " << f << " differs from a fresh run";
  const json cache = s->state()["cache"];
  EXPECT_EQ(cache["valid"], json::array({json::array({0, 30})}));
  EXPECT_EQ(cache["stale"], json::array());
  EXPECT_TRUE(cache["simulating"].is_null());
  EXPECT_EQ(s->currentFrame(), 30);
}

// An edit arriving while a re-simulation runs restarts it from the earlier
// frame; the stream's states show the stale range shrinking, then none.
TEST(SessionResimulation, AnEditDuringResimulationRestartsFromTheEarlierFrame) {
  Fixture fx;
  const json twoKeys = json::array({{{"time", 0}, {"translation", {0.2, 0.2}}}, {{"time", 0.5}, {"translation", {0.2, 0.2}}}});
  json scene = sceneWithBlob(0.05);
  scene["instances"][0]["transform"] = twoKeys;
  auto s = createSession("e", "", scene, fx.db);
  s->step(40);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  std::mutex m;
  std::vector<json> states;
  std::atomic<bool> sent{false};
  std::atomic<int> secondFrame{-1};
  Session* raw = s.get();
  s->subscribe({[&](const FramePtr& f) {
                  // The first re-simulated frame past 30: the second edit, from inside.
                  if (f->frame > 31 && !sent.exchange(true)) {
                    const EditTicket t = raw->submit(Edit::fromJson(json{
                        {"type", "update_instance"}, {"name", "blob"}, {"patch", {{"velocity_weight", 0.5}}}}));
                    (void)t;
                  }
                },
                [&](const EditResult& r) {
                  if (r.accepted && r.id == 2) secondFrame = r.frame;
                },
                [&](const json& st) {
                  std::lock_guard lk(m);
                  states.push_back(st);
                }});
  // A key after the last: the track changes after 0.5 s (frame 31 on).
  const EditResult r = resultOf(s->submit(Edit::fromJson(json{
      {"type", "update_instance"},
      {"name", "blob"},
      {"patch", {{"transform", json::array({{{"time", 0}, {"translation", {0.2, 0.2}}},
                                        {{"time", 0.5}, {"translation", {0.2, 0.2}}},
                                        {{"time", 0.6}, {"translation", {0.3, 0.2}}}})}}}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_EQ(r.frame, 31);
  ASSERT_TRUE(test::waitFor([&] { return secondFrame.load() >= 0; }, kResimWait));
  EXPECT_EQ(secondFrame.load(), 4);  // start 0.05 s, where frame 3 ends
  ASSERT_TRUE(s->waitIdle(kResimWait));
  json edited = sceneWithBlob(0.05);
  edited["instances"][0]["transform"] = json::array({{{"time", 0}, {"translation", {0.2, 0.2}}},
                                                {{"time", 0.5}, {"translation", {0.2, 0.2}}},
                                                {{"time", 0.6}, {"translation", {0.3, 0.2}}}});
  edited["instances"][0]["velocity_weight"] = 0.5;
  const std::vector<FramePtr> reference = freshRun(edited, fx.db, 40);
  const std::vector<FramePtr> after = s->history();
  ASSERT_EQ(after.size(), reference.size());
  for (size_t f = 0; f < after.size(); ++f)
    EXPECT_TRUE(sameParticles(*after[f], *reference[f])) << "frame " << f << " differs from a fresh run";
  std::lock_guard lk(m);
  bool sawStaleFrom30 = false, sawRestartBelow30 = false;
  for (const json& st : states) {
    const json& c = st["cache"];
    if (!c["stale"].empty() && c["stale"][0][0].get<int>() >= 31) sawStaleFrom30 = true;
    if (c["simulating"].is_object() && c["simulating"]["from"].get<int>() < 30 &&
        c["stale"][0][0].get<int>() <= 4)
      sawRestartBelow30 = true;
  }
  EXPECT_TRUE(sawStaleFrom30);
  EXPECT_TRUE(sawRestartBelow30);
  EXPECT_EQ(states.back()["cache"]["stale"], json::array());
  EXPECT_TRUE(states.back()["cache"]["simulating"].is_null());
}

// A replaying viewer keeps its frame (replaced once re-simulated); an edit
// that changes only frames not simulated yet leaves the cache valid.
TEST(SessionResimulation, AReplayingViewerSeesItsFrameReplaced) {
  Fixture fx;
  auto s = createSession("e", "", sceneWithBlob(0.1), fx.db);
  s->step(20);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  const FramePtr old15 = s->seek(15);
  ASSERT_TRUE(resultOf(s->submit(Edit::fromJson(
                           json{{"type", "update_instance"}, {"name", "blob"}, {"patch", {{"attraction_weight", 2}}}})))
                  .accepted);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  const json st = s->state();
  EXPECT_FALSE(st["shown"]["live"].get<bool>());
  EXPECT_EQ(st["shown"]["frame"], 15);
  EXPECT_NE(s->latestFrame(), old15);
  EXPECT_EQ(s->latestFrame(), s->frame(15));
  EXPECT_EQ(s->currentFrame(), 20);
  // Past the frames simulated: nothing stale, nothing re-simulated.
  const FramePtr f20 = s->frame(20);
  ASSERT_TRUE(resultOf(s->submit(Edit::fromJson(json{{"type", "add_instance"},
                                                     {"instance", {{"template", "blob"}, {"name", "late"}, {"start", 1}}}})))
                  .accepted);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->frame(20), f20);
  EXPECT_EQ(s->state()["cache"]["valid"], json::array({json::array({0, 20})}));
}

// The layers of a recorded frame (control and boundary particles, moving
// bodies among them) are not in the history: a viewer scrubbing back gets
// the very bytes the live run encoded for that frame (the simulation goes
// back to it from a checkpoint, or from frame 0 without any), and the
// simulation then carries on exactly as a run nobody scrubbed.
TEST(SessionResimulation, RecordedFramesShowTheLayersOfTheLiveRun) {
  for (const int every : {10, 0}) {
    SCOPED_TRACE("checkpoint_every " + std::to_string(every));
    Fixture fx;
    SessionOptions o;
    o.checkpointEvery = every;
    auto s = createSession("e", "", sceneWithBlob(0.05), fx.db, o);
    wire::LayerFlags layers;
    layers.control = true;
    layers.boundary = true;
    std::mutex m;
    std::map<int, std::vector<uint8_t>> live;
    Session* raw = s.get();
    s->subscribe({[&](const FramePtr& f) {
                    const auto l = raw->layeredFrame();
                    std::lock_guard lk(m);
                    if (l && l->frame == f->frame && !live.count(f->frame)) live[f->frame] = l->envelope;
                  },
                  nullptr, nullptr});
    s->demandLayers(layers, +1);
    s->step(24);
    ASSERT_TRUE(s->waitIdle(kResimWait));
    {
      std::lock_guard lk(m);
      ASSERT_EQ(live.size(), 25u);  // frames 0..24, each with its layers
    }
    // Back and forth, onward from where the simulation is, back to frame 1
    // (before any checkpoint) and to frame 0.
    for (const int f : {12, 13, 17, 6, 1, 0, 23}) {
      SCOPED_TRACE("frame " + std::to_string(f));
      s->seek(f);
      ASSERT_TRUE(s->waitIdle(kResimWait));
      const auto l = s->layeredFrame();
      ASSERT_NE(l, nullptr);
      ASSERT_EQ(l->frame, f);
      EXPECT_TRUE(l->layers.control && l->layers.boundary);
      std::lock_guard lk(m);
      EXPECT_TRUE(l->envelope == live[f]) << "the layered frame differs from the live run's";
    }
    // Live again: the next frames are a fresh run's, bit for bit.
    s->seek(24);
    s->step(6);
    ASSERT_TRUE(s->waitIdle(kResimWait));
    const std::vector<FramePtr> after = s->history();
    const std::vector<FramePtr> reference = freshRun(sceneWithBlob(0.05), fx.db, 30);
    ASSERT_EQ(after.size(), reference.size());
    for (size_t f = 0; f < after.size(); ++f)
      EXPECT_TRUE(sameParticles(*after[f], *reference[f])) << "frame " << f << " differs from a fresh run";
    const auto l = s->layeredFrame();
    ASSERT_NE(l, nullptr);
    EXPECT_EQ(l->frame, 30);
  }
}

// A settings change rebuilds the simulation at frame 0 with the new
// settings and re-simulates every frame up to the one reached.
TEST(SessionResimulation, ASettingsChangeResimulatesFromFrameZero) {
  Fixture fx;
  auto s = createSession("e", "", sceneWithBlob(0), fx.db);
  s->step(8);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  const EditResult r = resultOf(s->submit(Edit::fromJson(json{{"type", "settings"},
                                                             {"settings", {{"cfl_factor", 0.5}, {"dt_max", 0.002}}},
                                                             {"solver", {{"density_tolerance_pct", 0.05}}}})));
  ASSERT_TRUE(r.accepted) << r.message;
  EXPECT_EQ(r.frame, 0);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  const json scene = s->sceneJson();
  EXPECT_EQ(scene["settings"]["cfl_factor"], 0.5);
  EXPECT_EQ(scene["solver"]["method"], "dfsph");
  const std::vector<FramePtr> after = s->history();
  const std::vector<FramePtr> reference = freshRun(scene, fx.db, 8);
  ASSERT_EQ(after.size(), reference.size());
  for (size_t f = 0; f < after.size(); ++f)
    EXPECT_TRUE(sameParticles(*after[f], *reference[f])) << "frame " << f << " differs from a fresh run";
  EXPECT_LE(after.back()->stats.maxDt, 0.002 + 1e-9);
  // A method change takes the new method's defaults.
  const EditResult w = resultOf(s->submit(Edit::fromJson(json{{"type", "settings"}, {"solver", {{"method", "wcsph"}}}})));
  ASSERT_TRUE(w.accepted) << w.message;
  EXPECT_EQ(s->sceneJson()["solver"]["method"], "wcsph");
  EXPECT_FALSE(s->sceneJson()["solver"].contains("density_tolerance_pct"));
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->currentFrame(), 8);
  // A frame-rate change: the same scene time, in the new frames.
  ASSERT_TRUE(resultOf(s->submit(Edit::fromJson(json{{"type", "settings"}, {"settings", {{"frame_rate", 30}}}})))
                  .accepted);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->currentFrame(), 4);
  EXPECT_NEAR(s->latestFrame()->time, 8.0 / 60, 1e-9);
}

// Playback stops at the scene's duration; from a replayed frame it plays
// the recorded frames first, then simulates on.
TEST(SessionResimulation, PlayStopsAtTheDurationAndPlaysRecordedFramesFirst) {
  Fixture fx;
  json scene = smallTankScene();
  scene["duration"] = 0.2;  // 12 frames
  auto s = createSession("e", "", scene, fx.db);
  EXPECT_EQ(s->state()["end_frame"], 12);
  s->play();
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->currentFrame(), 12);
  EXPECT_EQ(s->status(), SessionStatus::Paused);
  s->play(16);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->currentFrame(), 16);
  const std::vector<FramePtr> recorded = s->history();
  std::mutex m;
  std::vector<int> shown;
  s->seek(5);
  s->subscribe({[&](const FramePtr& f) {
                  std::lock_guard lk(m);
                  shown.push_back(f->frame);
                },
                nullptr, nullptr});
  s->play(20);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->currentFrame(), 20);
  std::lock_guard lk(m);
  ASSERT_FALSE(shown.empty());
  std::vector<int> expected;
  for (int f = 6; f <= 20; ++f) expected.push_back(f);
  EXPECT_EQ(shown, expected);
  for (int f = 6; f <= 16; ++f) EXPECT_EQ(s->frame(f), recorded[size_t(f)]) << "a recorded frame was re-simulated";
}

// Exports and templates take only frames of the scene as it is: asked for
// stale frames during a re-simulation they refuse, naming them; once the
// cache is valid they work.
TEST(SessionResimulation, ExportsRefuseStaleFrames) {
  Fixture fx;
  auto s = createSession("e", "", sceneWithBlob(0.1), fx.db);
  s->step(30);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  std::atomic<bool> tried{false};
  std::string exportError, templateError;
  Session* raw = s.get();
  s->subscribe({[&](const FramePtr& f) {
                  if (f->frame < 10 || tried.exchange(true)) return;  // a re-simulated frame: 7.. are stale
                  try {
                    raw->exportHistory(fx.tmp.file("stale.h5"));
                  } catch (const StaleFramesError& e) {
                    exportError = e.what();
                  }
                  try {
                    raw->recordTemplate(fx.db, "stale", {0, 0}, {0.5, 0.5}, 0, 20, false);
                  } catch (const StaleFramesError& e) {
                    templateError = e.what();
                  }
                },
                nullptr, nullptr});
  ASSERT_TRUE(resultOf(s->submit(Edit::fromJson(
                           json{{"type", "update_instance"}, {"name", "blob"}, {"patch", {{"attraction_weight", 2}}}})))
                  .accepted);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  ASSERT_TRUE(tried.load());
  EXPECT_NE(exportError.find("are stale"), std::string::npos) << exportError;
  EXPECT_NE(templateError.find("are stale"), std::string::npos) << templateError;
  EXPECT_FALSE(std::filesystem::exists(fx.tmp.file("stale.h5")));
  EXPECT_EQ(s->exportHistory(fx.tmp.file("valid.h5")).frames, 31);
}

// Checkpoints and history share the session's cap.
TEST(SessionResimulation, CheckpointsAndHistoryStayUnderTheCap) {
  Fixture fx;
  SessionOptions o;
  o.historyCapBytes = 200 * 1000;
  o.checkpointEvery = 2;
  auto s = createSession("e", "", sceneWithBlob(0), fx.db, o);
  s->step(100);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  const json st = s->state();
  const size_t history = st["memory"]["history_bytes"], checkpoints = st["memory"]["checkpoint_bytes"];
  EXPECT_GT(checkpoints, 0u);
  EXPECT_LE(checkpoints, o.historyCapBytes / 4);
  EXPECT_LE(history + checkpoints, o.historyCapBytes);
  EXPECT_GT(st["history"]["dropped"].get<int>(), 0);
  // An edit before the oldest kept checkpoint re-simulates from frame 0.
  ASSERT_TRUE(resultOf(s->submit(Edit::fromJson(
                           json{{"type", "update_instance"}, {"name", "blob"}, {"patch", {{"attraction_weight", 2}}}})))
                  .accepted);
  ASSERT_TRUE(s->waitIdle(kResimWait));
  EXPECT_EQ(s->currentFrame(), 100);
  EXPECT_EQ(s->state()["cache"]["stale"], json::array());
}

// ------------------------------------------------------------------ history ---

TEST(SessionHistory, CapDropsTheOldestFramesAndSaysSo) {
  Fixture fx;
  const size_t frameBytes = FrameSnapshot::estimateBytes(2, 100, 0);
  SessionOptions opt;
  opt.historyCapBytes = frameBytes * 5 + frameBytes / 2;  // room for 5 frames
  auto s = createSession("h", "", smallTankScene(), fx.db, opt);
  s->step(10);
  ASSERT_TRUE(s->waitIdle(kWait));
  const json h = s->state()["history"];
  EXPECT_EQ(h["frames"], 5);
  EXPECT_EQ(h["first"], 6);
  EXPECT_EQ(h["last"], 10);
  EXPECT_EQ(h["dropped"], 6);  // frames 0..5
  EXPECT_EQ(h["bytes"], 5 * frameBytes);
  EXPECT_LE(h["bytes"].get<size_t>(), h["cap"].get<size_t>());
  EXPECT_FALSE(s->frame(5));
  EXPECT_TRUE(s->frame(6));
  EXPECT_THROW(s->seek(2), std::out_of_range);
  EXPECT_EQ(s->history().size(), 5u);
  EXPECT_EQ(s->history().front()->frame, 6);
  // Reset clears the history and the dropped count.
  s->reset();
  ASSERT_TRUE(s->waitIdle(kWait));
  EXPECT_EQ(s->state()["history"]["dropped"], 0);
  EXPECT_EQ(s->state()["history"]["frames"], 1);
}

TEST(SessionHistory, SeekShowsTheRecordedFrameAsPublished) {
  Fixture fx;
  std::mutex m;
  std::map<int, std::vector<uint16_t>> published;
  auto s = createSession("h", "", smallTankScene(), fx.db);
  s->subscribe({[&](const FramePtr& f) {
                  std::lock_guard lk(m);
                  published[f->frame] = f->positions;
                },
                nullptr, nullptr});
  s->step(6);
  ASSERT_TRUE(s->waitIdle(kWait));
  std::vector<uint16_t> at2;
  {
    std::lock_guard lk(m);
    ASSERT_TRUE(published.count(2));
    at2 = published[2];
  }
  const FramePtr f = s->seek(2);
  ASSERT_TRUE(f);
  EXPECT_EQ(f->frame, 2);
  EXPECT_EQ(f->positions, at2);
  EXPECT_NE(f->positions, s->frame(6)->positions);
  EXPECT_EQ(s->latestFrame(), f);
  json st = s->state();
  EXPECT_FALSE(st["shown"]["live"].get<bool>());
  EXPECT_EQ(st["shown"]["frame"], 2);
  EXPECT_EQ(st["frame"], 6);  // the simulation did not move
  EXPECT_EQ(st["status"], "paused");
  // Seeking the newest frame is live again (the timeline's end); back to 2.
  EXPECT_EQ(s->seek(6)->frame, 6);
  EXPECT_TRUE(s->state()["shown"]["live"].get<bool>());
  EXPECT_EQ(s->seek(2)->frame, 2);
  EXPECT_FALSE(s->state()["shown"]["live"].get<bool>());
  // Stepping leaves replay and continues from the newest frame.
  s->step(1);
  ASSERT_TRUE(s->waitIdle(kWait));
  st = s->state();
  EXPECT_TRUE(st["shown"]["live"].get<bool>());
  EXPECT_EQ(s->latestFrame()->frame, 7);
}

TEST(SessionHistory, VelocitiesMatchTheSimulationWithinQuantization) {
  Fixture fx;
  SessionOptions opt;
  opt.threads = 1;  // the reference below runs on one thread too: same frames
  auto s = createSession("v", "", smallTankScene(), fx.db, opt);
  // Frame 0: at rest, every axis's box is 0 and decodes to exactly 0.
  const FramePtr f0 = s->frame(0);
  ASSERT_TRUE(f0);
  ASSERT_EQ(f0->velocities.size(), 200u);
  EXPECT_EQ(f0->velocityMax[0], 0);
  EXPECT_EQ(f0->velocityMax[1], 0);
  EXPECT_EQ(f0->velocities[0], 32768);
  EXPECT_EQ(f0->velocity(0, 1), 0);
  s->step(5);
  ASSERT_TRUE(s->waitIdle(kWait));

  const int threads = omp_get_max_threads();
  omp_set_num_threads(1);
  Simulation<2> sim(parseScene<2>(smallTankScene()));
  for (int k = 0; k < 5; ++k) sim.advanceFrame();
  omp_set_num_threads(threads);

  const FramePtr f = s->frame(5);
  ASSERT_TRUE(f);
  ASSERT_EQ(f->particles(), sim.fluid.size());
  ASSERT_EQ(f->velocities.size(), 2 * f->particles());
  double vmax[2] = {0, 0};
  for (size_t i = 0; i < sim.fluid.size(); ++i)
    for (int d = 0; d < 2; ++d) vmax[d] = std::max(vmax[d], std::abs(double(sim.fluid.v[i][d])));
  EXPECT_GT(vmax[1], 0.1);  // falling under gravity for 5 frames
  for (int d = 0; d < 2; ++d) EXPECT_DOUBLE_EQ(f->velocityMax[size_t(d)], vmax[d]);
  for (size_t i = 0; i < f->particles(); ++i)
    for (int d = 0; d < 2; ++d) {
      // Half a quantization step, plus float rounding of the simulation's value.
      EXPECT_NEAR(f->velocity(i, d), sim.fluid.v[i][d], vmax[d] / 65535 + 1e-6) << "particle " << i << " axis " << d;
      EXPECT_NEAR(f->position(i, d), sim.fluid.x[i][d], 0.5 / 65535 + 1e-6);
    }
  // The velocity box is symmetric: the fastest particle decodes to ±vmax.
  bool extreme = false;
  for (size_t i = 0; i < f->particles(); ++i)
    extreme = extreme || f->velocities[2 * i + 1] == 0 || f->velocities[2 * i + 1] == 65535;
  EXPECT_TRUE(extreme);
}

// ----------------------------------------------------- parallel and errors ---

TEST(SessionParallel, TwoSessionsRunIndependently) {
  Fixture fx;
  SessionOptions opt;
  opt.threads = 1;  // identical scenes then give identical frames
  auto a = createSession("a", "", smallTankScene(), fx.db, opt);
  auto b = createSession("b", "", smallTankScene(), fx.db, opt);
  a->play();
  b->play();
  ASSERT_TRUE(a->waitForFrame(8, kWait));
  ASSERT_TRUE(b->waitForFrame(8, kWait));
  a->pause();
  ASSERT_TRUE(a->waitIdle(kWait));
  const int aFrame = a->currentFrame();
  ASSERT_TRUE(b->waitForFrame(aFrame + 5, kWait));  // b goes on while a is paused
  EXPECT_EQ(a->currentFrame(), aFrame);
  EXPECT_EQ(b->status(), SessionStatus::Playing);
  b->pause();
  ASSERT_TRUE(b->waitIdle(kWait));
  EXPECT_EQ(a->frame(8)->positions, b->frame(8)->positions);
  // An edit of one is not seen by the other.
  ASSERT_TRUE(resultOf(a->submit(Edit::fromJson(json{{"type", "settings"}, {"settings", {{"cfl_factor", 0.4}}}})))
                  .accepted);
  EXPECT_EQ(a->sceneJson()["settings"]["cfl_factor"], 0.4);
  EXPECT_EQ(b->sceneJson()["settings"]["cfl_factor"], 1.0);
}

TEST(SessionErrors, NonFiniteFramePausesWithErrorOtherSessionContinues) {
  Fixture fx;
  // A frame of 1 s at substeps of at most 1 ms against a limit of 20
  // substeps: the watchdog stops frame 1 (a runaway simulation's symptom).
  json blowup = smallTankScene("blowup");
  blowup["settings"] = {{"frame_rate", 1}, {"dt_max", 0.001}, {"max_substeps_per_frame", 20}};
  std::atomic<bool> nonFinitePublished = false;
  auto bad = createSession("bad", "", blowup, fx.db);
  auto good = createSession("good", "", smallTankScene(), fx.db);
  bad->subscribe({[&](const FramePtr& f) {
                    if (!f->stats.finite) nonFinitePublished = true;
                  },
                  nullptr, nullptr});
  good->play();
  bad->play();
  ASSERT_TRUE(bad->waitIdle(kWait));
  EXPECT_EQ(bad->status(), SessionStatus::Error);
  const json st = bad->state();
  EXPECT_EQ(st["status"], "error");
  ASSERT_TRUE(st.contains("error"));
  const int errorFrame = st["error"]["frame"];
  EXPECT_GE(errorFrame, 1);
  EXPECT_NE(st["error"]["message"].get<std::string>().find("more than 20 substeps"), std::string::npos)
      << st["error"]["message"];
  // The broken frame was never published nor recorded.
  EXPECT_FALSE(nonFinitePublished);
  EXPECT_EQ(bad->currentFrame(), errorFrame - 1);
  EXPECT_FALSE(bad->frame(errorFrame));
  EXPECT_EQ(st["history"]["last"], errorFrame - 1);
  EXPECT_THROW(bad->play(), SessionError);
  EXPECT_THROW(bad->step(1), SessionError);
  // The other session keeps running.
  const int g = good->currentFrame();
  ASSERT_TRUE(good->waitForFrame(g + 3, kWait));
  EXPECT_EQ(good->status(), SessionStatus::Playing);
  good->pause();
  // Reset clears the error (the scene still blows up when played again).
  bad->reset();
  ASSERT_TRUE(bad->waitIdle(kWait));
  EXPECT_EQ(bad->status(), SessionStatus::Paused);
  EXPECT_FALSE(bad->state().contains("error"));
}

// 400 particles at 1 µs substeps for a 1 s frame: a million substeps, a
// frame that would run for minutes.
json endlessFrameScene(const std::string& name) {
  json j = smallTankScene(name);
  j["fluid_blocks"] = json::array({{{"min", {0, 0}}, {"max", {0.8, 0.8}}}});
  j["settings"] = {{"frame_rate", 1}, {"dt_min", 1e-6}, {"dt_max", 1e-6}, {"max_substeps_per_frame", 1e7}};
  return j;
}

TEST(SessionWatchdog, AFrameRunningPastTheTimeLimitPutsTheSessionInErrorAndReleasesIt) {
  Fixture fx;
  SessionOptions o;
  o.threads = 1;
  o.frameTimeout = 200ms;
  auto s = createSession("slow", "", endlessFrameScene("slow"), fx.db, o);
  s->step(1);
  // Generous: the watchdog ends the frame after 0.2 s of wall time.
  ASSERT_TRUE(s->waitIdle(60s));
  const json st = s->state();
  ASSERT_EQ(st["status"], "error") << st.dump();
  EXPECT_NE(st["error"]["message"].get<std::string>().find("watchdog"), std::string::npos) << st["error"]["message"];
  EXPECT_EQ(st["frame"], 0);
  EXPECT_EQ(st["history"]["last"], 0);
  // Edits are still answered and reset recovers.
  const EditResult r = resultOf(s->submit(Edit::fromJson(json{{"type", "remove_instance"}, {"name", "none"}})));
  EXPECT_FALSE(r.accepted);
  s->reset();
  ASSERT_TRUE(s->waitIdle(60s));
  EXPECT_EQ(s->status(), SessionStatus::Paused);
}

TEST(SessionWatchdog, DeletingOrResettingASessionMidFrameStopsTheFrame) {
  Fixture fx;
  SessionOptions o;
  o.threads = 1;
  o.frameTimeout = std::chrono::hours(1);
  // Reset: the frame in progress is abandoned, the session is back at frame 0.
  auto r = createSession("r", "", endlessFrameScene("r"), fx.db, o);
  r->play();
  ASSERT_TRUE(fc::test::waitFor([&] { return r->state().value("computing", false); }, 60s));
  r->reset();
  ASSERT_TRUE(r->waitIdle(60s)) << "the reset waited for the whole frame";
  EXPECT_EQ(r->status(), SessionStatus::Paused);
  EXPECT_EQ(r->currentFrame(), 0);
  EXPECT_FALSE(r->state().contains("error"));
  // Destruction: returns once the next substep sees the cancellation (were
  // it to wait for the frame, this test would run into ctest's timeout).
  auto d = createSession("d", "", endlessFrameScene("d"), fx.db, o);
  d->play();
  ASSERT_TRUE(fc::test::waitFor([&] { return d->state().value("computing", false); }, 60s));
  d.reset();
  SUCCEED();
}

TEST(SessionLifetime, DestructionDuringPlayIsPrompt) {
  Fixture fx;
  auto s = createSession("d", "", smallTankScene(), fx.db);
  s->play();
  ASSERT_TRUE(s->waitForFrame(2, kWait));
  auto t0 = std::chrono::steady_clock::now();
  const EditTicket t = s->submit(Edit::fromJson(json{{"type", "remove_instance"}, {"name", "none"}}));
  s.reset();
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(took, 0.5);
  // An edit submitted just before is answered (applied or closed), never lost.
  ASSERT_EQ(t.result.wait_for(0ms), std::future_status::ready);
  EXPECT_FALSE(t.result.get().accepted);

  // Paced playback waiting for its next slot also stops at once.
  auto p = createSession("p", "", smallTankScene(), fx.db);
  p->setPlaybackSpeed(0.2);  // one frame per 5 s
  p->play();
  ASSERT_TRUE(p->waitForFrame(1, kWait));
  t0 = std::chrono::steady_clock::now();
  p.reset();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), 0.5);
}

}  // namespace
}  // namespace fc::service
