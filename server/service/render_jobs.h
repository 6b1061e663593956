#pragma once
// Render jobs (POST /api/jobs): a session's scene run again as a batch, at
// the final resolution and with a wedge of one parameter, by flowclip-batch
// (clients/python/flowclip/batch.py) on a Dask cluster: the scheduler given
// to `flowclip serve --scheduler`, or a LocalCluster of the server's own.
// The service writes the job spec, starts flowclip-batch in a process group
// of its own and follows its JSON progress lines; every change reaches the
// job's callback (the session's state "jobs", on its stream).
//
// A job writes into a hidden directory beside the others (JOBS/.jN.stage)
// renamed to JOBS/jN/ when every task is done, so a job's directory appears
// whole or not at all; a cancelled or failed job leaves nothing. Jobs run
// one at a time, in order, each one's tasks in parallel on the cluster.
//
// Job ids are "j1", "j2", ..., numbered after the directories already in
// JOBS; finished jobs are kept (the newest kMaxFinishedJobs) for clients
// that poll them.
#include "service/recipe_jobs.h"

#include <nlohmann/json.hpp>

#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace fc::service {

class ChildProcess;

struct RenderJobsOptions {
  std::string jobsDir = "jobs";
  std::string batchCommand;  // flowclip-batch's path; "": jobs are unavailable
  std::string binary;        // the flowclip executable the tasks run
  std::string templatesDir = "templates";
  std::string scheduler;     // a Dask scheduler's address; "": a LocalCluster of localWorkers
  int localWorkers = 1;
};

struct RenderTaskInfo {
  std::string id;          // the batch's task id (a hash of its inputs), its folder's name
  nlohmann::json overrides = nlohmann::json::object();
  std::string state = "queued";  // queued, running, done
  int frame = 0, frames = 0;
  double wallSeconds = 0;
  std::vector<std::string> files;  // done: its files, relative to its folder
};

struct RenderJobInfo : JobProgress {  // frames: every task's frames; framesDone: those simulated
  std::string id;
  std::string name;
  std::string session;
  nlohmann::json request;  // what was asked (the POST body without the session's scene)
  std::vector<RenderTaskInfo> tasks;
};
nlohmann::json renderJobJson(const RenderJobInfo& job);

struct RenderJobRequest {
  std::string session;
  std::string name;
  nlohmann::json request;  // shown back in the job
  nlohmann::json scene;    // the scene every task starts from
  nlohmann::json spec;     // the job spec's frames/seconds, grid, outputs, threads (no scene, templates, out)
  std::vector<nlohmann::json> variants;  // the tasks' overrides, in the spec's order
  // After every change, in order: on the caller's thread for queued and a
  // queued job's cancel, then on the job thread.
  std::function<void(const RenderJobInfo&)> progress;
};

class RenderJobs {
 public:
  explicit RenderJobs(RenderJobsOptions options);
  ~RenderJobs();  // cancels every job and joins the job thread
  RenderJobs(const RenderJobs&) = delete;
  RenderJobs& operator=(const RenderJobs&) = delete;

  const RenderJobsOptions& options() const { return options_; }
  bool available() const { return !options_.batchCommand.empty(); }
  // Where tasks run: the scheduler's address, or "local (N workers)".
  std::string where() const;

  RenderJobInfo start(RenderJobRequest request);
  // Throws RecipeJobError 400 (not a job id) or 404 (no such job).
  RenderJobInfo job(const std::string& id) const;
  std::vector<RenderJobInfo> jobs() const;  // oldest first
  // A queued job is cancelled at once; a running one's processes are
  // killed and its directory removed. A done or failed job is 409.
  RenderJobInfo cancel(const std::string& id);

  static constexpr size_t kMaxFinishedJobs = 64;
  static bool isJobId(const std::string& id);

 private:
  struct Job {
    RenderJobInfo info;
    RenderJobRequest request;
    ChildProcess* process = nullptr;  // while it runs, under mutex_
    std::mutex reporting;  // taken under mutex_ before it is released: reports leave in the order they were made
  };
  void run();
  void runJob(Job& job);
  void follow(Job& job, const nlohmann::json& event);  // one progress line, under mutex_
  void changed(Job& job, std::unique_lock<std::mutex>& lk);
  std::shared_ptr<Job> find(const std::string& id) const;

  RenderJobsOptions options_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::map<uint64_t, std::shared_ptr<Job>> jobs_;
  std::deque<std::shared_ptr<Job>> queue_;
  uint64_t next_ = 1;
  bool stopping_ = false;
  int lock_ = -1;  // flock of JOBS/.lock: this server owns the directory's staged jobs
  std::thread worker_;
};

}  // namespace fc::service
