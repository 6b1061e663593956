#pragma once
// Surface exports from the service (POST /api/sessions/{id}/export with
// "formats"): after the session's history is written as NAME.h5, a job
// meshes its frames into the formats asked (export/surface_export.h), one
// job at a time on a worker thread of its own. The files are written into a
// hidden directory beside the exports and renamed to EXPORTS/NAME/ when
// every frame is done, so the directory appears complete or not at all; a
// cancelled or failed job leaves nothing. Each frame's progress is reported
// to the job's callback (the session's state "export", on its stream).
//
// Job ids are "x1", "x2", ...; finished jobs are kept (the newest
// kMaxFinishedJobs) for clients that poll them.
#include "export/surface_export.h"
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

struct SurfaceJobInfo : JobProgress {  // frames: those of NAME.h5, framesDone: meshed and written
  std::string id;
  std::string session;  // whose history
  std::string name;     // EXPORTS/NAME.h5 in, EXPORTS/NAME/ out
  std::vector<std::string> formats;
  size_t bytes = 0;                // written so far
  std::vector<std::string> files;  // done: every file of EXPORTS/NAME/, manifest first
};
nlohmann::json surfaceJobJson(const SurfaceJobInfo& job);

struct SurfaceJobRequest {
  std::string session;
  std::string name;
  std::string h5Path;     // the frames file to mesh
  std::string outDir;     // EXPORTS/NAME: created at the end, replaced if it exists
  std::vector<std::string> formats;
  SurfaceSettings surface;
  std::map<std::string, ParamValues> formatParams;
  // After every change, in order: on the caller's thread for queued and a
  // queued job's cancel, then on the worker thread.
  std::function<void(const SurfaceJobInfo&)> progress;
};

class SurfaceJobs {
 public:
  explicit SurfaceJobs(int threads);
  ~SurfaceJobs();  // cancels every job and joins the worker
  SurfaceJobs(const SurfaceJobs&) = delete;
  SurfaceJobs& operator=(const SurfaceJobs&) = delete;

  SurfaceJobInfo start(SurfaceJobRequest request);
  // Throws RecipeJobError 400 (not a job id) or 404 (no such job).
  SurfaceJobInfo job(const std::string& id) const;
  // A queued job is cancelled at once, a running one before its next frame;
  // a done or failed one is 409.
  SurfaceJobInfo cancel(const std::string& id);

  static constexpr size_t kMaxFinishedJobs = 64;
  static bool isJobId(const std::string& id);

 private:
  struct Job {
    SurfaceJobInfo info;
    SurfaceJobRequest request;
  };
  void run();
  void exportJob(Job& job);
  void changed(Job& job, std::unique_lock<std::mutex>& lk);  // calls the callback without the lock
  std::shared_ptr<Job> find(const std::string& id) const;

  int threads_;
  mutable std::mutex mutex_;
  std::condition_variable wake_;
  std::map<uint64_t, std::shared_ptr<Job>> jobs_;
  std::deque<std::shared_ptr<Job>> queue_;
  uint64_t next_ = 1;
  bool stopping_ = false;
  std::thread worker_;
};

}  // namespace fc::service
