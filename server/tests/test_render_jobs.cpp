// Key paths into a scene (io/key_path.h), the service's child processes
// (service/child_process.h) and render jobs driven by a stand-in for
// flowclip-batch (service/render_jobs.h): progress followed line by line,
// results published whole, a failure or a cancel leaving nothing.
#include "io/key_path.h"
#include "service/child_process.h"
#include "service/render_jobs.h"

#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>

namespace fc {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

json scene() {
  return json::parse(R"({"particle_radius": 0.01, "settings": {"frame_rate": 60},
                          "instances": [{"name": "drop", "speed": 1}, {"name": "jet", "speed": 2}]})");
}

TEST(KeyPath, SetsKeysNamedElementsAndIndices) {
  json s = scene();
  setKeyPath(s, "particle_radius", 0.005);
  setKeyPath(s, "settings.frame_rate", 30);
  setKeyPath(s, "instances[jet].speed", 0.5);
  setKeyPath(s, "instances[0].start", 0.25);  // a new last key
  EXPECT_EQ(s["particle_radius"], 0.005);
  EXPECT_EQ(s["settings"]["frame_rate"], 30);
  EXPECT_EQ(s["instances"][1]["speed"], 0.5);
  EXPECT_EQ(s["instances"][0]["start"], 0.25);
  EXPECT_EQ(s["instances"][0]["speed"], 1);
}

TEST(KeyPath, RefusesWhatNamesNothingSayingWhich) {
  const auto message = [](const std::string& path) {
    json s = scene();
    try {
      setKeyPath(s, path, 1);
    } catch (const KeyPathError& e) {
      EXPECT_EQ(s, scene()) << "a refused path changed the scene";
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  EXPECT_NE(message("instances[nope].speed").find("no element of instances named \"nope\" (names: drop, jet)"),
            std::string::npos);
  EXPECT_NE(message("instances[5].speed").find("instances has 2 elements"), std::string::npos);
  EXPECT_NE(message("solver.method").find("the scene has no solver"), std::string::npos);
  EXPECT_NE(message("particle_radius.x").find("particle_radius is not an object"), std::string::npos);
  EXPECT_NE(message("settings[0]").find("settings is not a list"), std::string::npos);
  for (const char* bad : {"", ".a", "a.", "a..b", "[0]", "a[0", "a]b"})
    EXPECT_NE(message(bad).find("not a key path"), std::string::npos) << bad;
}

TEST(ChildProcess, ReadsLinesAndKillsItsWholeGroup) {
  const fs::path dir = fs::temp_directory_path() / ("fc-child-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  // The child prints, then starts a grandchild that outlives it unless its group is killed.
  service::ChildProcess p({"/bin/sh", "-c", "echo one; printf 'two\\nthree'; echo oops >&2; sleep 600 & echo $! > grandchild; wait"},
                          dir.string(), (dir / "err.log").string());
  std::string line;
  ASSERT_TRUE(p.readLine(line));
  EXPECT_EQ(line, "one");
  ASSERT_TRUE(p.readLine(line));
  EXPECT_EQ(line, "two");
  // "three" has no newline: it comes with the end of the output, after the kill.
  for (int i = 0; i < 6000 && !fs::exists(dir / "grandchild"); ++i) usleep(10000);
  pid_t grandchild = 0;
  for (int i = 0; i < 6000 && grandchild == 0; ++i) {
    std::ifstream(dir / "grandchild") >> grandchild;
    if (grandchild == 0) usleep(10000);
  }
  ASSERT_GT(grandchild, 0);
  EXPECT_EQ(::kill(grandchild, 0), 0);
  p.signalGroup(SIGKILL);
  ASSERT_TRUE(p.readLine(line));
  EXPECT_EQ(line, "three");
  EXPECT_FALSE(p.readLine(line));
  EXPECT_EQ(p.wait(), 128 + SIGKILL);
  // The grandchild was in the group: gone (a zombie of init at most, reaped soon).
  bool gone = false;
  for (int i = 0; i < 6000 && !gone; ++i) {
    std::ifstream stat("/proc/" + std::to_string(grandchild) + "/stat");
    std::string pid, comm, state;
    gone = !(stat >> pid >> comm >> state) || state == "Z";
    if (!gone) usleep(10000);
  }
  EXPECT_TRUE(gone);
  std::ifstream err(dir / "err.log");
  std::getline(err, line);
  EXPECT_EQ(line, "oops");
  fs::remove_all(dir);
}

// A stand-in for flowclip-batch: a shell script that writes what the real
// one would (JSON lines, task folders) and fails or hangs when asked.
struct FakeBatch {
  fs::path dir;
  fs::path script;
  explicit FakeBatch(const std::string& body) {
    dir = fs::temp_directory_path() / ("fc-jobs-" + std::to_string(::getpid()) + "-" +
                                       ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir);
    fs::create_directories(dir / "jobs");
    script = dir / "flowclip-batch";
    std::ofstream(script) << "#!/bin/sh\n" << body;
    fs::permissions(script, fs::perms::owner_all);
  }
  ~FakeBatch() { fs::remove_all(dir); }
  service::RenderJobsOptions options() const {
    return {(dir / "jobs").string(), script.string(), "/bin/true", (dir / "templates").string(), "", 1};
  }
};

// What a jobs directory holds besides the servers' lock.
std::vector<std::string> leftovers(const fs::path& jobs) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(jobs))
    if (e.path().filename() != ".lock") out.push_back(e.path().filename().string());
  return out;
}

service::RenderJobRequest request(std::vector<json> variants) {
  service::RenderJobRequest r;
  r.session = "s1";
  r.name = "shot";
  r.scene = scene();
  r.spec = {{"frames", 2}};
  r.variants = std::move(variants);
  return r;
}

service::RenderJobInfo waitFinished(service::RenderJobs& jobs, const std::string& id) {
  for (int i = 0; i < 120000; ++i) {
    const auto j = jobs.job(id);
    if (j.finished()) return j;
    usleep(1000);
  }
  ADD_FAILURE() << "job " << id << " did not finish";
  return jobs.job(id);
}

TEST(RenderJobs, FollowsTheBatchAndPublishesItsFolderWhole) {
  FakeBatch fake(R"(test "$1 $2 $3 $4" = "run spec.json --progress json" || exit 9
grep -q '"instances\[drop\]\.speed": 0.5' spec.json || exit 8
test -f scene.json || exit 7
echo '{"event":"plan","tasks":[{"id":"aaa"},{"id":"bbb"}]}'
echo '{"event":"task","id":"aaa","frame":1,"frames":2}'
echo 'a stray line'
mkdir -p aaa/surface bbb && echo 1 > aaa/stats.json && echo 2 > aaa/surface/x.ply && echo 3 > bbb/stats.json
echo '{"event":"done","id":"aaa","wall_s":1.5}'
echo '{"event":"done","id":"bbb","wall_s":2.5}'
echo '{"event":"end","tasks":2,"ran":2}'
)");
  std::vector<service::RenderJobInfo> seen;
  std::mutex m;
  auto hub = std::make_unique<service::RenderJobs>(fake.options());
  service::RenderJobs& jobs = *hub;
  auto r = request({{{"instances[drop].speed", 0.5}}, {{"instances[drop].speed", 2}}});
  r.progress = [&](const service::RenderJobInfo& j) {
    std::lock_guard lk(m);
    seen.push_back(j);
  };
  const auto queued = jobs.start(std::move(r));
  EXPECT_EQ(queued.id, "j1");
  const auto done = waitFinished(jobs, "j1");
  ASSERT_EQ(done.state, service::JobState::Done) << done.error;
  ASSERT_EQ(done.tasks.size(), 2u);
  EXPECT_EQ(done.tasks[0].id, "aaa");
  EXPECT_EQ(done.tasks[0].files, (std::vector<std::string>{"stats.json", "surface/x.ply"}));
  EXPECT_EQ(done.tasks[1].wallSeconds, 2.5);
  EXPECT_EQ(done.frames, 4);
  EXPECT_EQ(done.framesDone, 4);
  EXPECT_TRUE(fs::exists(fake.dir / "jobs/j1/aaa/surface/x.ply"));
  EXPECT_FALSE(fs::exists(fake.dir / "jobs/.j1.stage"));
  {
    std::lock_guard lk(m);
    ASSERT_GE(seen.size(), 4u);
    EXPECT_EQ(seen.front().state, service::JobState::Queued);
    // After "task aaa frame 1 of 2": one frame of four (the other task counted as long).
    const bool halfway =
        std::any_of(seen.begin(), seen.end(), [](const auto& j) { return j.framesDone == 1 && j.frames == 4; });
    EXPECT_TRUE(halfway);
  }
  // A new hub over the same directory numbers after it.
  hub.reset();
  EXPECT_EQ(service::RenderJobs(fake.options()).start(request({json::object()})).id, "j2");
}

TEST(RenderJobs, AFailedBatchSaysWhyAndLeavesNothing) {
  FakeBatch fake(R"(mkdir half && echo x > half/frames.h5
echo '{"event":"error","message":"wedge.key: no such key"}'
exit 2
)");
  service::RenderJobs jobs(fake.options());
  jobs.start(request({json::object()}));
  const auto end = waitFinished(jobs, "j1");
  EXPECT_EQ(end.state, service::JobState::Failed);
  EXPECT_EQ(end.error, "wedge.key: no such key");
  EXPECT_EQ(leftovers(fake.dir / "jobs"), std::vector<std::string>{});
}

TEST(RenderJobs, CancelKillsTheBatchAndLeavesNothing) {
  FakeBatch fake(R"(echo '{"event":"plan","tasks":[{"id":"aaa"}]}'
mkdir aaa && sleep 600 &
echo $! > ../../sleeper
echo '{"event":"task","id":"aaa","frame":1,"frames":1000}'
wait
)");
  service::RenderJobs jobs(fake.options());
  jobs.start(request({json::object()}));
  for (int i = 0; i < 120000 && jobs.job("j1").framesDone < 1; ++i) usleep(1000);
  ASSERT_EQ(jobs.job("j1").framesDone, 1);
  EXPECT_TRUE(jobs.cancel("j1").cancelRequested);
  const auto end = waitFinished(jobs, "j1");
  EXPECT_EQ(end.state, service::JobState::Cancelled);
  EXPECT_EQ(leftovers(fake.dir / "jobs"), std::vector<std::string>{});
  // What the batch started went with it (its group was killed, then reaped by init).
  pid_t sleeper = 0;
  std::ifstream(fake.dir / "sleeper") >> sleeper;
  ASSERT_GT(sleeper, 0);
  bool gone = false;
  for (int i = 0; i < 60000 && !gone; ++i) {
    std::ifstream stat("/proc/" + std::to_string(sleeper) + "/stat");
    std::string pid, comm, state;
    gone = !(stat >> pid >> comm >> state) || state == "Z";
    if (!gone) usleep(1000);
  }
  EXPECT_TRUE(gone) << "the batch's sleep " << sleeper << " survived the cancel";
  EXPECT_EQ(jobs.cancel("j1").state, service::JobState::Cancelled);  // again: as it is
  try {
    jobs.cancel("j9");
    ADD_FAILURE() << "no such job";
  } catch (const service::RecipeJobError& e) {
    EXPECT_EQ(e.status, 404);
  }
}

}  // namespace
}  // namespace fc
