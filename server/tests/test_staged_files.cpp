// Crash-atomic publishing (io/staged_files.h): sets of files appear all new or
// all old, also when the publishing process dies at any instant (a forked
// child _exit()s at each crash point in turn, or is sent SIGKILL at random
// instants) and recoverPublishing() runs afterwards; recovery deletes the
// leftovers of dead processes, old name forms included, and nothing else.
#include "io/staged_files.h"

#include "io/recipe.h"
#include "io/template_database.h"
#include "tests/hdf5_test_util.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <omp.h>

#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <random>
#include <string>
#include <thread>
#include <vector>

namespace fc {
namespace {

namespace fs = std::filesystem;
using fc::test::readFile;
using fc::test::TempDir;

// Every entry of a directory: file name → content ("<dir>" for a directory).
using Files = std::map<std::string, std::string>;

Files filesIn(const std::string& dir) {
  Files out;
  for (const auto& e : fs::directory_iterator(dir))
    out[e.path().filename().string()] = e.is_directory() ? "<dir>" : readFile(e.path().string());
  return out;
}

void setFiles(const std::string& dir, const Files& files) {
  fs::remove_all(dir);
  fs::create_directories(dir);
  for (const auto& [name, text] : files) std::ofstream((fs::path(dir) / name).string(), std::ios::binary) << text;
}

// Runs `fn` in a forked child; its exit status (3: it threw), or -signal.
int inChild(const std::function<void()>& fn) {
  std::fflush(nullptr);
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::alarm(20);  // a hang fails the test instead of blocking it
    try {
      fn();
    } catch (...) {
      ::_exit(3);
    }
    ::_exit(0);
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
}

// The pid of a process that has exited.
long deadPid() {
  const pid_t pid = ::fork();
  if (pid == 0) ::_exit(0);
  ::waitpid(pid, nullptr, 0);
  return long(pid);
}

// "<pid>-<token>" of this process, read from a staging name.
std::string ownOwner() {
  const std::string name = fs::path(stagingPath("/x")).filename().string();  // .x.stage-<pid>-<token>-<n>
  const std::string rest = name.substr(std::string(".x.stage-").size());
  return rest.substr(0, rest.rfind('-'));
}

// Publishes `files` (name → content) into dir as one set.
void publishSet(const std::string& dir, const Files& files, bool replace) {
  StagedFiles set(replace);
  for (const auto& [name, text] : files) {
    const std::string final = (fs::path(dir) / name).string();
    const std::string staged = stagingPath(final);
    set.stage(staged, final);
    std::ofstream(staged, std::ios::binary) << text;
  }
  set.commit();
}

// Forks a publish that dies at crash point k = 1, 2, ... until one runs to
// the end; after each, recovery must leave exactly `before` or `after`.
void expectAllOrNothingAtEveryStep(const std::string& dir, const Files& before, const Files& after,
                                   const std::function<void()>& publish) {
  int olds = 0, news = 0;
  for (int k = 1;; ++k) {
    ASSERT_LT(k, 100) << "the publish never finished";
    setFiles(dir, before);
    const int status = inChild([&] {
      StagedFiles::testCrashAfter(k);
      publish();
    });
    ASSERT_TRUE(status == 0 || status == StagedFiles::kTestCrashStatus) << "step " << k << ": status " << status;
    const PublishRecovery r = recoverPublishing(dir);
    EXPECT_TRUE(r.errors.empty()) << "step " << k << ": " << r.errors.front();
    const Files now = filesIn(dir);
    if (now == before) ++olds;
    else if (now == after) ++news;
    else ADD_FAILURE() << "step " << k << ": neither all old nor all new (" << now.size() << " entries)";
    if (status == 0) {
      EXPECT_EQ(now, after);
      EXPECT_TRUE(r.removed.empty() && r.rolledBack.empty());
      break;
    }
  }
  EXPECT_GT(olds, 0);  // crashes before the commit point
  EXPECT_GT(news, 0);  // ... and after it
}

TEST(StagedFiles, StagingPathIsHiddenBesideTheFinalName) {
  const std::string a = stagingPath("/data/scenes/s.json"), b = stagingPath("/data/scenes/s.json");
  EXPECT_NE(a, b);
  EXPECT_EQ(fs::path(a).parent_path(), "/data/scenes");
  const std::string name = fs::path(a).filename().string();
  EXPECT_EQ(name.rfind(".s.json.stage-" + std::to_string(::getpid()) + "-", 0), 0u) << name;
  EXPECT_EQ(fs::path(stagingPath("t.h5")).parent_path(), "");
  EXPECT_EQ(ownOwner().size(), std::to_string(::getpid()).size() + 9);
}

TEST(StagedFiles, PublishesWithAndWithoutReplace) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  fs::create_directories(dir);
  publishSet(dir, {{"a.h5", "a1"}, {"a.xdmf", "x1"}}, false);
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "a1"}, {"a.xdmf", "x1"}}));
  // Without replace an existing name refuses the whole set.
  try {
    publishSet(dir, {{"b.h5", "b"}, {"a.xdmf", "x2"}}, false);
    ADD_FAILURE() << "replaced without replace";
  } catch (const PublishError& e) {
    EXPECT_TRUE(e.exists);
    EXPECT_EQ(e.path, (fs::path(dir) / "a.xdmf").string());
  }
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "a1"}, {"a.xdmf", "x1"}}));
  // Replacing, also where only one of the set exists.
  publishSet(dir, {{"a.h5", "a2"}, {"a.xdmf", "x2"}}, true);
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "a2"}, {"a.xdmf", "x2"}}));
  fs::remove(fs::path(dir) / "a.xdmf");
  publishSet(dir, {{"a.h5", "a3"}, {"a.xdmf", "x3"}}, true);
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "a3"}, {"a.xdmf", "x3"}}));
  // One file.
  publishFile((fs::path(dir) / "s.json").string(), "{}\n", false);
  EXPECT_THROW(publishFile((fs::path(dir) / "s.json").string(), "[]\n", false), PublishError);
  EXPECT_EQ(readFile((fs::path(dir) / "s.json").string()), "{}\n");
  publishFile((fs::path(dir) / "s.json").string(), "[]\n", true);
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "a3"}, {"a.xdmf", "x3"}, {"s.json", "[]\n"}}));
  EXPECT_THROW(publishFile(tmp.file("missing/s.json"), "{}", true), std::runtime_error);
}

// A file its writer staged itself (an HDF5 file written in place) is
// published the same way: moved, or removed with the old file left as it was.
TEST(StagedFiles, PublishStagedMovesAWrittenFileOrRemovesIt) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  setFiles(dir, {{"t.h5", "old"}});
  const std::string final = (fs::path(dir) / "t.h5").string();
  std::string staged = stagingPath(final);
  std::ofstream(staged, std::ios::binary) << "new";
  try {
    publishStaged(staged, final, false);
    ADD_FAILURE() << "replaced without replace";
  } catch (const PublishError& e) {
    EXPECT_TRUE(e.exists);
  }
  EXPECT_EQ(filesIn(dir), (Files{{"t.h5", "old"}}));
  staged = stagingPath(final);
  std::ofstream(staged, std::ios::binary) << "new";
  publishStaged(staged, final, true);
  EXPECT_EQ(filesIn(dir), (Files{{"t.h5", "new"}}));
}

TEST(StagedFiles, FailuresRollBackInProcess) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  // The writer fails after staging: staged files go.
  setFiles(dir, {{"a.h5", "old"}});
  try {
    StagedFiles set(true);
    const std::string final = (fs::path(dir) / "a.h5").string(), staged = stagingPath(final);
    set.stage(staged, final);
    std::ofstream(staged) << "half";
    throw std::runtime_error("writer failed");
  } catch (const std::runtime_error&) {
  }
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "old"}}));
  // The second name cannot be replaced (a directory): the first gets its old file back.
  setFiles(dir, {{"a.h5", "old"}});
  fs::create_directory(fs::path(dir) / "a.xdmf");
  EXPECT_THROW(publishSet(dir, {{"a.h5", "new"}, {"a.xdmf", "new"}}, true), PublishError);
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "old"}, {"a.xdmf", "<dir>"}}));
  // Files of one publish share a directory.
  StagedFiles set(true);
  EXPECT_THROW(set.stage(tmp.file("d/.x.stage-1"), tmp.file("e/x")), std::invalid_argument);
  set.stage(stagingPath(tmp.file("d/x")), tmp.file("d/x"));
  EXPECT_THROW(set.stage(stagingPath(tmp.file("e/y")), tmp.file("e/y")), std::invalid_argument);
}

TEST(StagedFiles, KilledAtEveryStepLeavesAllOldOrAllNew) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  const Files fresh = {{"a.h5", "new a"}, {"a.xdmf", "new x"}, {"b.h5", "new b"}};
  // Replacing a complete set, a partial one, none; creating without replace.
  for (const Files& before : {Files{{"a.h5", "old a"}, {"a.xdmf", "old x"}, {"b.h5", "old b"}},
                              Files{{"a.xdmf", "old x"}}, Files{}}) {
    SCOPED_TRACE("replace, " + std::to_string(before.size()) + " existing");
    expectAllOrNothingAtEveryStep(dir, before, fresh, [&] { publishSet(dir, fresh, true); });
  }
  SCOPED_TRACE("no replace");
  expectAllOrNothingAtEveryStep(dir, {{"other", "o"}}, [&] {
    Files f = fresh;
    f["other"] = "o";
    return f;
  }(), [&] { publishSet(dir, fresh, false); });
  // One file (a saved scene).
  const std::string scene = (fs::path(dir) / "s.json").string();
  expectAllOrNothingAtEveryStep(dir, {{"s.json", "old"}}, {{"s.json", "new"}},
                                [&] { publishFile(scene, "new", true); });
}

TEST(StagedFiles, KilledAtRandomInstantsLeavesAllOldOrAllNew) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  const std::vector<std::string> names = {"a.h5", "a.xdmf", "b.h5"};
  setFiles(dir, {{"a.h5", "0"}, {"a.xdmf", "0"}, {"b.h5", "0"}});
  std::mt19937 rng(12345);
  int changed = 0, interrupted = 0;
  std::string last = "0";
  for (int run = 0; run < 20; ++run) {
    int published[2];
    ASSERT_EQ(::pipe(published), 0);
    std::fflush(nullptr);
    const pid_t pid = ::fork();
    if (pid == 0) {
      ::alarm(20);
      // Generation after generation, each a set of three equal files of 64 KB;
      // a byte down the pipe after each.
      for (int g = 0;; ++g) {
        const std::string text = std::to_string(::getpid()) + ":" + std::to_string(g) + std::string(65536, '.');
        Files set;
        for (const auto& n : names) set[n] = text;
        try {
          publishSet(dir, set, true);
        } catch (...) {
          ::_exit(3);
        }
        const char c = 1;
        if (::write(published[1], &c, 1) != 1) ::_exit(4);
      }
    }
    ::close(published[1]);
    // Killed after its first publish (however slow the disk), at a random
    // instant of a later one.
    char c = 0;
    ASSERT_EQ(::read(published[0], &c, 1), 1) << "the publishing child failed";
    ::close(published[0]);
    std::this_thread::sleep_for(std::chrono::microseconds(std::uniform_int_distribution<int>(0, 5000)(rng)));
    ::kill(pid, SIGKILL);
    int status = 0;
    ::waitpid(pid, &status, 0);
    ASSERT_TRUE(WIFSIGNALED(status)) << "the publishing child failed: status " << status;
    const PublishRecovery r = recoverPublishing(dir);
    EXPECT_TRUE(r.errors.empty()) << r.errors.front();
    interrupted += !r.removed.empty();
    const Files now = filesIn(dir);
    ASSERT_EQ(now.size(), 3u) << "run " << run;
    for (const auto& n : names) ASSERT_EQ(now.count(n), 1u) << n;
    EXPECT_EQ(now.at("a.h5"), now.at("a.xdmf")) << "run " << run;
    EXPECT_EQ(now.at("a.h5"), now.at("b.h5")) << "run " << run;
    changed += now.at("a.h5") != last;
    last = now.at("a.h5");
  }
  EXPECT_EQ(changed, 20);     // every child published
  EXPECT_GT(interrupted, 0);  // ... and was killed in the middle of a publish
}

TEST(StagedFiles, RecoveryLeavesFilesOfLiveProcessesAlone) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  fs::create_directories(dir);
  // This process: a staged file, a backup, and a journal that would remove
  // a.json (its inode is the "new" one) were it a dead process's.
  std::ofstream(tmp.file("d/a.json")) << "a";
  const std::string staged = stagingPath(tmp.file("d/a.json"));
  std::ofstream(staged) << "s";
  std::ofstream(tmp.file("d/.a.json.old-" + ownOwner() + "-900")) << "b";
  struct stat st;
  ASSERT_EQ(::stat(tmp.file("d/a.json").c_str(), &st), 0);
  std::ofstream(tmp.file("d/.publish-" + ownOwner() + "-901.journal"))
      << "flowclip-publish 1\n"
      << st.st_ino << " a.json " << fs::path(staged).filename().string() << " -\nend\n";
  const Files before = filesIn(dir);
  PublishRecovery r = recoverPublishing(dir);
  EXPECT_TRUE(r.removed.empty() && r.rolledBack.empty() && r.errors.empty());
  EXPECT_EQ(filesIn(dir), before);

  // A live child's staged file stays until the child has exited.
  int ready[2], release[2];
  ASSERT_EQ(::pipe(ready), 0);
  ASSERT_EQ(::pipe(release), 0);
  std::fflush(nullptr);
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::alarm(20);
    ::close(release[1]);  // else its own end keeps the read below from ending
    std::ofstream(stagingPath(tmp.file("d/c.h5"))) << "c";
    char c = 1;
    if (::write(ready[1], &c, 1) != 1) ::_exit(2);
    (void)::read(release[0], &c, 1);  // until the parent closes it
    ::_exit(0);
  }
  ::close(release[0]);
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  const Files withChild = filesIn(dir);
  EXPECT_EQ(withChild.size(), before.size() + 1);
  r = recoverPublishing(dir);
  EXPECT_TRUE(r.removed.empty()) << r.removed.front();
  EXPECT_EQ(filesIn(dir), withChild);
  ::close(release[1]);
  ::waitpid(pid, nullptr, 0);
  ::close(ready[0]);
  ::close(ready[1]);
  r = recoverPublishing(dir);
  ASSERT_EQ(r.removed.size(), 1u);
  EXPECT_NE(r.removed[0].find(".c.h5.stage-" + std::to_string(pid) + "-"), std::string::npos) << r.removed[0];
  EXPECT_EQ(filesIn(dir), before);
}

TEST(StagedFiles, RecoveryRemovesLeftoversOfDeadProcessesOnly) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  fs::create_directories(dir);
  const std::string dead = std::to_string(deadPid()), self = std::to_string(::getpid());
  // A later process reusing a pid is told apart by the token of its start.
  std::string otherToken = ownOwner().substr(self.size() + 1);
  otherToken[7] = otherToken[7] == '0' ? '1' : '0';
  const std::vector<std::string> leftovers = {
      // Earlier versions: scenes, exports, templates, backups, staged files.
      ".s.json.tmp-" + dead, "x.h5.tmp-" + dead, "t.h5.tmp-" + dead + "-3", ".t.h5.old-" + dead + "-2",
      ".e.h5.export-" + dead + "-0", ".t.h5.rec-" + dead + "-1", "..t.h5.rec-" + dead + "-1.tmp-" + dead + "-4",
      ".own.json.tmp-" + self,
      // This version.
      ".q.h5.stage-" + dead + "-0123abcd-9", ".q.h5.old-" + dead + "-0123abcd-10",
      "..q.h5.stage-" + dead + "-0123abcd-9.stage-" + dead + "-0123abcd-12", ".p.h5.stage-" + self + "-" + otherToken + "-0",
      ".publish-" + dead + "-0123abcd-11.journal",  // cut short: no file moved yet
  };
  const Files others = {
      {"keep.h5", "k"}, {".hidden", "h"}, {"notes.tmp-" + dead, "n"}, {"data.json.tmp-" + dead, "d"},
      {".x.stage-abc", "x"}, {"x.h5.tmp-12a", "x"}, {".x.stage-" + dead + "-0123abcd", "x"},
      {".x.h5.stage-" + dead + "-0123ABCD-1", "x"}, {"t.h5.old-" + dead + "-2", "x"}};
  setFiles(dir, others);
  for (const auto& n : leftovers) std::ofstream(tmp.file("d/" + n)) << (n.find("journal") != std::string::npos ? "flowclip-pub" : "x");
  fs::create_directory(tmp.file("d/.dir.h5.tmp-" + dead));  // of folders, only a staged one is ours
  fs::create_directory(tmp.file("d/.live.stage-" + self + "-" + ownOwner().substr(self.size() + 1) + "-3"));
  fs::create_directory(tmp.file("d/.x.old-" + dead + "-0123abcd-4"));
  // A killed export job's folder, with its frames.
  const std::string job = tmp.file("d/.shot.stage-" + dead + "-0123abcd-5");
  fs::create_directories(job + "/sub");
  std::ofstream(job + "/shot.0000.ply") << "x";
  std::ofstream(job + "/sub/y") << "y";
  const PublishRecovery r = recoverPublishing(dir);
  EXPECT_TRUE(r.errors.empty()) << r.errors.front();
  EXPECT_TRUE(r.rolledBack.empty());
  EXPECT_EQ(r.removed.size(), leftovers.size() + 1);
  EXPECT_FALSE(fs::exists(job));
  Files expected = others;
  expected[".dir.h5.tmp-" + dead] = "<dir>";
  expected[".live.stage-" + self + "-" + ownOwner().substr(self.size() + 1) + "-3"] = "<dir>";
  expected[".x.old-" + dead + "-0123abcd-4"] = "<dir>";
  EXPECT_EQ(filesIn(dir), expected);
  // Nothing to do the second time; a missing directory is no error.
  EXPECT_TRUE(recoverPublishing(dir).removed.empty());
  const PublishRecovery none = recoverPublishing(tmp.file("nowhere"));
  EXPECT_TRUE(none.removed.empty() && none.errors.empty());
}

TEST(StagedFiles, RecoveryRollsBackADeadJournalAndKeepsAnUnreadableOne) {
  TempDir tmp;
  const std::string dir = tmp.file("d");
  const std::string owner = std::to_string(deadPid()) + "-0123abcd";
  // Died after replacing a.h5 and creating b.h5, before the commit point.
  setFiles(dir, {{"a.h5", "new a"}, {"b.h5", "new b"}, {".a.h5.old-" + owner + "-1", "old a"}});
  struct stat a, b;
  ASSERT_EQ(::stat(tmp.file("d/a.h5").c_str(), &a), 0);
  ASSERT_EQ(::stat(tmp.file("d/b.h5").c_str(), &b), 0);
  std::ofstream(tmp.file("d/.publish-" + owner + "-3.journal"))
      << "flowclip-publish 1\n"
      << a.st_ino << " a.h5 .a.h5.stage-" << owner << "-0 .a.h5.old-" << owner << "-1\n"
      << b.st_ino << " b.h5 .b.h5.stage-" << owner << "-2 .b.h5.old-" << owner << "-4\nend\n";
  PublishRecovery r = recoverPublishing(dir);
  EXPECT_TRUE(r.errors.empty()) << r.errors.front();
  EXPECT_EQ(r.rolledBack, (std::vector<std::string>{tmp.file("d/b.h5"), tmp.file("d/a.h5")}));
  EXPECT_EQ(filesIn(dir), (Files{{"a.h5", "old a"}}));

  // A journal naming files outside its publish is not acted on, nor are its owner's files.
  setFiles(dir, {{"a.h5", "a"}, {".a.h5.old-" + owner + "-1", "old a"}});
  ASSERT_EQ(::stat(tmp.file("d/a.h5").c_str(), &a), 0);
  std::ofstream(tmp.file("d/.publish-" + owner + "-3.journal"))
      << "flowclip-publish 1\n" << a.st_ino << " a.h5 keep.h5 .a.h5.old-" << owner << "-1\nend\n";
  const Files before = filesIn(dir);
  r = recoverPublishing(dir);
  EXPECT_EQ(r.errors.size(), 1u);
  EXPECT_EQ(filesIn(dir), before);
}

// A recipe's templates are one set: after a crash at any step of recording
// and recovery, both are old or both new.
TEST(Recipe, KilledWhilePublishingLeavesAllTemplatesOldOrAllNew) {
  TempDir tmp;
  const std::string dir = tmp.file("db");
  const nlohmann::json j = nlohmann::json::parse(R"({
    "name": "pair", "dimension": 2, "particle_radius": 0.02,
    "domain": {"min": [0, 0], "max": [0.6, 0.6]},
    "fluid_blocks": [{"min": [0.04, 0.04], "max": [0.2, 0.36]}],
    "capture": [{"name": "a", "region": {"min": [0, 0], "max": [0.3, 0.25]}, "frames": 3},
                {"name": "b", "region": {"min": [0, 0], "max": [0.6, 0.6]}, "frames": 3}]
  })");
  const Recipe recipe = parseRecipe(j);
  RecordOptions o;
  o.templatesDir = dir;
  o.force = true;
  int olds = 0, news = 0;
  for (int k = 1;; ++k) {
    ASSERT_LT(k, 50) << "the recording never finished";
    setFiles(dir, {{"a.h5", "old a"}, {"b.h5", "old b"}});
    const int status = inChild([&] {
      omp_set_num_threads(1);  // the parent's OpenMP threads do not exist here
      StagedFiles::testCrashAfter(k);
      recordRecipe(recipe, o);
    });
    ASSERT_TRUE(status == 0 || status == StagedFiles::kTestCrashStatus) << "step " << k << ": status " << status;
    EXPECT_TRUE(recoverPublishing(dir).errors.empty());
    const Files now = filesIn(dir);
    ASSERT_EQ(now.size(), 2u) << "step " << k;
    if (now.at("a.h5") == "old a") {
      ++olds;
      EXPECT_EQ(now.at("b.h5"), "old b") << "step " << k;
    } else {
      ++news;
      TemplateDatabase db(dir);
      EXPECT_EQ(db.entry("a").frames, 3u) << "step " << k;
      EXPECT_EQ(db.entry("b").frames, 3u) << "step " << k;
    }
    if (status == 0) break;
  }
  EXPECT_GT(olds, 0);
  EXPECT_GT(news, 0);
}

}  // namespace
}  // namespace fc
