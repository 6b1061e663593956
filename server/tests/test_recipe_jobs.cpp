// Recording jobs (service/recipe_jobs.h): a job records its recipe's
// templates into the database; jobs run one at a time; a repeated request
// gets the running job; cancelling leaves the database untouched; bad
// requests are refused with their status.
#include "service/recipe_jobs.h"

#include "io/template_database.h"
#include "tests/hdf5_test_util.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace fc::service {
namespace {

using nlohmann::json;
using fc::test::TempDir;
using namespace std::chrono_literals;

constexpr auto kGenerous = 120s;  // a loaded machine may be slow; never a synchronisation

// The small 2D tank plus a capture of `frames` frames of its whole domain.
void writeRecipe(const TempDir& tmp, const std::string& name, const std::string& templateName, int frames) {
  json r = fc::test::smallTankScene(name);
  r["capture"] = {{"name", templateName}, {"region", {{"min", {0, 0}}, {"max", {1, 1}}}}, {"frames", frames}};
  std::filesystem::create_directories(tmp.file("recipes"));
  std::ofstream(tmp.file("recipes/" + name + ".json")) << r.dump(1);
}

struct Jobs {
  TempDir tmp;
  std::unique_ptr<RecipeJobs> jobs;
  Jobs() {
    writeRecipe(tmp, "tiny", "tiny_tpl", 5);
    writeRecipe(tmp, "long", "long_tpl", 100000);  // runs until cancelled
    jobs = std::make_unique<RecipeJobs>(RecipeJobsOptions{tmp.file("recipes"), tmp.file("templates"), 1});
  }
  // Every name in the template directory (staged files included).
  std::vector<std::string> templateFiles() const {
    std::vector<std::string> out;
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(tmp.file("templates"), ec))
      out.push_back(e.path().filename().string());
    std::sort(out.begin(), out.end());
    return out;
  }
  int statusOf(const std::function<void()>& call) {
    try {
      call();
    } catch (const RecipeJobError& e) {
      return e.status;
    }
    return 0;
  }
};

TEST(RecipeJobs, RecordsTheTemplatesOfARecipeIntoTheDatabase) {
  Jobs t;
  bool created = false;
  const JobInfo started = t.jobs->start("tiny", false, created);
  EXPECT_TRUE(created);
  EXPECT_EQ(started.id, "r1");
  EXPECT_EQ(started.templates, std::vector<std::string>{"tiny_tpl"});
  EXPECT_EQ(started.frames, 4);  // frames 1..4 are simulated, frame 0 is the initial state
  const JobInfo done = t.jobs->wait("r1", kGenerous);
  ASSERT_EQ(done.state, JobState::Done) << done.error;
  EXPECT_EQ(done.framesDone, 4);
  EXPECT_DOUBLE_EQ(done.progress(), 1.0);
  EXPECT_EQ(t.templateFiles(), std::vector<std::string>{"tiny_tpl.h5"});
  const TemplateEntry e = TemplateDatabase(t.tmp.file("templates")).entry("tiny_tpl");
  EXPECT_EQ(e.frames, 5u);
  EXPECT_GT(e.avgParticles, 0);

  const json listed = t.jobs->list([&](const std::string& n) { return n == "tiny_tpl"; });
  ASSERT_EQ(listed["recipes"].size(), 2u);
  const json& tiny = listed["recipes"][1];
  EXPECT_EQ(tiny["name"], "tiny");
  EXPECT_EQ(tiny["recorded"], true);
  EXPECT_EQ(tiny["templates"][0], json({{"name", "tiny_tpl"}, {"recorded", true}}));
  EXPECT_TRUE(tiny.contains("last_seconds"));
  EXPECT_EQ(listed["recipes"][0]["recorded"], false);

  // Recorded: again only with force.
  EXPECT_EQ(t.statusOf([&] { t.jobs->start("tiny", false, created); }), 409);
  t.jobs->start("tiny", true, created);
  EXPECT_TRUE(created);
}

TEST(RecipeJobs, ARepeatedRequestGetsTheRunningJobAndCancellingWritesNothing) {
  Jobs t;
  bool created = false;
  const JobInfo first = t.jobs->start("long", false, created);
  const JobInfo running = t.jobs->wait(first.id, kGenerous, [](const JobInfo& j) { return j.framesDone >= 2; });
  ASSERT_EQ(running.state, JobState::Running);
  EXPECT_GT(running.progress(), 0.0);
  EXPECT_LT(running.progress(), 1.0);
  const JobInfo again = t.jobs->start("long", false, created);
  EXPECT_FALSE(created);
  EXPECT_EQ(again.id, first.id);

  const JobInfo cancelling = t.jobs->cancel(first.id);
  EXPECT_TRUE(cancelling.cancelRequested);
  const JobInfo cancelled = t.jobs->wait(first.id, kGenerous);
  EXPECT_EQ(cancelled.state, JobState::Cancelled);
  EXPECT_EQ(t.jobs->cancel(first.id).state, JobState::Cancelled);  // idempotent
  EXPECT_TRUE(t.templateFiles().empty());  // no template, no staged file
}

TEST(RecipeJobs, JobsRunOneAtATimeAndAQueuedOneIsCancelledAtOnce) {
  Jobs t;
  bool created = false;
  const JobInfo a = t.jobs->start("long", false, created);
  const JobInfo b = t.jobs->start("tiny", false, created);
  EXPECT_EQ(b.state, JobState::Queued);
  ASSERT_EQ(t.jobs->wait(a.id, kGenerous, [](const JobInfo& j) { return j.framesDone >= 1; }).state,
            JobState::Running);
  EXPECT_EQ(t.jobs->job(b.id).state, JobState::Queued);
  EXPECT_EQ(t.jobs->cancel(b.id).state, JobState::Cancelled);
  t.jobs->cancel(a.id);
  EXPECT_EQ(t.jobs->wait(a.id, kGenerous).state, JobState::Cancelled);
  EXPECT_TRUE(t.templateFiles().empty());
  ASSERT_EQ(t.jobs->jobs().size(), 2u);
  EXPECT_EQ(t.jobs->jobs()[1].elapsedSeconds, 0.0);  // never ran
}

TEST(RecipeJobs, StoppingCancelsTheRunningAndQueuedJobsWithNothingWritten) {
  Jobs t;
  bool created = false;
  const JobInfo a = t.jobs->start("long", false, created);
  t.jobs->start("tiny", false, created);
  ASSERT_EQ(t.jobs->wait(a.id, kGenerous, [](const JobInfo& j) { return j.framesDone >= 1; }).state,
            JobState::Running);
  t.jobs.reset();  // returns once the worker has stopped at the end of its frame
  EXPECT_TRUE(t.templateFiles().empty());
}

TEST(RecipeJobs, RefusesBadRequestsWithTheirStatus) {
  Jobs t;
  std::ofstream(t.tmp.file("recipes/broken.json")) << R"({"dimension": 2, "capture": {"name": "x"}})";
  bool created = false;
  EXPECT_EQ(t.statusOf([&] { t.jobs->start("../tiny", false, created); }), 400);
  EXPECT_EQ(t.statusOf([&] { t.jobs->start("nosuch", false, created); }), 404);
  EXPECT_EQ(t.statusOf([&] { t.jobs->start("broken", false, created); }), 422);
  for (const char* id : {"x", "r", "r0", "r01", "1", "r1a", "r99999999999999999999"})
    EXPECT_EQ(t.statusOf([&] { t.jobs->job(id); }), 400) << id;
  EXPECT_EQ(t.statusOf([&] { t.jobs->job("r7"); }), 404);
  EXPECT_EQ(t.statusOf([&] { t.jobs->cancel("r7"); }), 404);

  const JobInfo done = t.jobs->start("tiny", false, created);
  ASSERT_EQ(t.jobs->wait(done.id, kGenerous).state, JobState::Done);
  EXPECT_EQ(t.statusOf([&] { t.jobs->cancel(done.id); }), 409);

  const json listed = t.jobs->list([](const std::string&) { return false; });
  ASSERT_EQ(listed["recipes"][0]["name"], "broken");
  EXPECT_TRUE(listed["recipes"][0].contains("error"));

  RecipeJobs none(RecipeJobsOptions{"", t.tmp.file("templates"), 1});
  EXPECT_TRUE(none.list([](const std::string&) { return false; })["recipes"].empty());
  EXPECT_EQ(t.statusOf([&] { none.start("tiny", false, created); }), 404);
}

}  // namespace
}  // namespace fc::service
