#pragma once
// Recording recipes (templates/recipes/NAME.json, io/recipe.h) from the
// service: the recipes of a directory, and recording jobs that run one at a
// time, in order, on one worker thread of their own (never on a session's or
// a REST worker's thread). A job publishes its templates into the database
// the way `flowclip record` does, all or nothing (recordRecipe: staged files
// moved into place at the end), so a cancelled or failed job leaves the
// database as it was.
//
// Job ids are "r1", "r2", ... in the order of the requests. Finished jobs
// are kept (the newest kMaxFinishedJobs) so that a client polling a job sees
// how it ended.
#include "io/recipe.h"

#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace fc::service {

// A request the jobs refuse: its HTTP status (400 malformed id, 404 no such
// recipe or job, 409 templates exist / job already finished, 422 invalid
// recipe) and the key it concerns.
struct RecipeJobError : std::runtime_error {
  RecipeJobError(int status, const std::string& message, std::string path = {})
      : std::runtime_error(message), status(status), path(std::move(path)) {}
  int status;
  std::string path;
};

enum class JobState { Queued, Running, Done, Failed, Cancelled };
const char* jobStateName(JobState s);

// A background job's state and progress, as every kind of job reports it
// (recordings here, surface exports in service/surface_jobs.h).
struct JobProgress {
  JobState state = JobState::Queued;
  bool cancelRequested = false;
  int framesDone = 0;  // frames done (simulated or exported)
  int frames = 0;      // frames in all
  std::string error;   // failed: why
  double elapsedSeconds = 0;  // running: so far; finished: the job's wall time (0 if it never ran)
  double progress() const { return state == JobState::Done ? 1.0 : frames > 0 ? double(framesDone) / frames : 0.0; }
  bool finished() const { return state == JobState::Done || state == JobState::Failed || state == JobState::Cancelled; }
};
// Its JSON fields: state, progress, frames_done, frames, cancel_requested, elapsed_s, error (when failed).
nlohmann::json jobProgressJson(const JobProgress& job);
// Whether `id` is a job id of this kind: `prefix` then a number from 1 ("r1", "x12").
bool isNumberedJobId(const std::string& id, char prefix);

// Drops the oldest finished jobs of `jobs` (by number, each with an `info`
// that is a JobProgress) until at most `keep` finished ones remain.
template <class Job>
void pruneFinishedJobs(std::map<uint64_t, std::shared_ptr<Job>>& jobs, size_t keep) {
  size_t finished = 0;
  for (const auto& [n, j] : jobs) finished += j->info.finished();
  for (auto it = jobs.begin(); it != jobs.end() && finished > keep;) {
    if (it->second->info.finished()) {
      it = jobs.erase(it);
      --finished;
    } else {
      ++it;
    }
  }
}

// What a client sees of a recording job (a copy, taken under the lock).
struct JobInfo : JobProgress {
  std::string id;
  std::string recipe;
  std::vector<std::string> templates;  // what it records, in recipe order
  int dimension = 0;
  bool force = false;
};
nlohmann::json jobJson(const JobInfo& job);

struct RecipeJobsOptions {
  std::string recipesDir = "templates/recipes";
  std::string templatesDir = "templates";
  int threads = 0;  // OpenMP threads of a recording (0: the runtime's default)
};

class RecipeJobs {
 public:
  explicit RecipeJobs(RecipeJobsOptions options);
  ~RecipeJobs();  // cancels every job and joins the worker
  RecipeJobs(const RecipeJobs&) = delete;
  RecipeJobs& operator=(const RecipeJobs&) = delete;

  const RecipeJobsOptions& options() const { return options_; }

  // {"directory", "recipes": [{name, dimension, templates: [{name, recorded}],
  // recorded, frames, last_seconds?, job?} | {name, error}]}, sorted by name.
  // `isRecorded(name)` tells whether the database has the template.
  nlohmann::json list(const std::function<bool(const std::string&)>& isRecorded);

  // Queues a recording of recipe `name`. A queued or running job of the same
  // recipe is returned instead (created = false). Without force, refuses
  // (409) when one of its templates is already recorded. Throws
  // RecipeJobError (400 invalid name, 404 no such recipe, 409, 422 invalid
  // recipe file).
  JobInfo start(const std::string& name, bool force, bool& created);
  // Throws RecipeJobError 400 (not a job id) or 404 (no such job).
  JobInfo job(const std::string& id) const;
  std::vector<JobInfo> jobs() const;  // oldest first
  // A queued job is cancelled at once; a running one at its next simulation
  // frame (the returned info then says cancelRequested). Cancelling a
  // cancelled job returns it; a done or failed one is 409.
  JobInfo cancel(const std::string& id);

  // Blocks until `until` holds for the job (default: it has finished) or
  // `timeout` passed; returns its info. Woken by every change of the job.
  JobInfo wait(const std::string& id, std::chrono::milliseconds timeout,
               const std::function<bool(const JobInfo&)>& until = {}) const;

  static constexpr size_t kMaxFinishedJobs = 64;
  static bool isJobId(const std::string& id);

 private:
  struct Job {
    JobInfo info;
    Recipe recipe;
    std::chrono::steady_clock::time_point started;
  };
  struct ListedRecipe {  // a recipe file's summary, kept while the file is unchanged
    uint64_t size = 0;
    int64_t mtime = 0;
    nlohmann::json summary;  // name, dimension, templates (names), frames | error
  };

  void run();
  void record(Job& job);
  std::shared_ptr<Job> find(const std::string& id) const;  // under mutex_; throws RecipeJobError 400 / 404
  std::string recipePath(const std::string& name) const;
  void prune();

  RecipeJobsOptions options_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;  // a job was queued, progressed or finished; or stopping
  std::map<uint64_t, std::shared_ptr<Job>> jobs_;  // by number
  std::deque<std::shared_ptr<Job>> queue_;
  std::map<std::string, double> lastSeconds_;  // recipe → wall time of its newest successful recording
  std::mutex listMutex_;  // listed_ alone: parsing recipes never holds up a recording's progress
  std::map<std::string, ListedRecipe> listed_;
  uint64_t next_ = 1;
  bool stopping_ = false;
  std::thread worker_;  // last: started once everything it uses exists
};

}  // namespace fc::service
