#include "service/surface_jobs.h"

#include "io/frames_file.h"
#include "io/staged_files.h"

#include <fcntl.h>
#include <omp.h>
#include <stdio.h>

#include <cerrno>
#include <system_error>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>

namespace fc::service {

namespace fs = std::filesystem;
using json = nlohmann::json;

json surfaceJobJson(const SurfaceJobInfo& j) {
  json out = jobProgressJson(j);
  out.update({{"id", j.id}, {"session", j.session}, {"name", j.name}, {"formats", j.formats}, {"bytes", j.bytes}});
  if (j.state == JobState::Done) {
    out["directory"] = j.name + "/";
    out["files"] = j.files;
  }
  return out;
}

bool SurfaceJobs::isJobId(const std::string& id) { return isNumberedJobId(id, 'x'); }

SurfaceJobs::SurfaceJobs(int threads) : threads_(std::max(1, threads)), worker_([this] { run(); }) {}

SurfaceJobs::~SurfaceJobs() {
  {
    std::lock_guard lk(mutex_);
    stopping_ = true;
    for (auto& [n, j] : jobs_) j->info.cancelRequested = true;
  }
  wake_.notify_all();
  worker_.join();
}

SurfaceJobInfo SurfaceJobs::start(SurfaceJobRequest request) {
  std::unique_lock lk(mutex_);
  auto job = std::make_shared<Job>();
  job->info.id = "x" + std::to_string(next_);
  job->info.session = request.session;
  job->info.name = request.name;
  job->info.formats = request.formats;
  job->request = std::move(request);
  jobs_[next_++] = job;
  pruneFinishedJobs(jobs_, kMaxFinishedJobs);  // the newest finished jobs only
  // Reported as queued before the worker can take it, so that no later state is overwritten.
  changed(*job, lk);
  queue_.push_back(job);
  const SurfaceJobInfo info = job->info;
  wake_.notify_all();
  return info;
}

std::shared_ptr<SurfaceJobs::Job> SurfaceJobs::find(const std::string& id) const {
  if (!isJobId(id)) throw RecipeJobError(400, "\"" + id.substr(0, 40) + "\" is not an export job id (x1, x2, ...)", "id");
  auto it = jobs_.find(std::stoull(id.substr(1)));
  if (it == jobs_.end()) throw RecipeJobError(404, "no export job " + id + " (finished jobs are kept for a while)", "id");
  return it->second;
}

SurfaceJobInfo SurfaceJobs::job(const std::string& id) const {
  std::lock_guard lk(mutex_);
  return find(id)->info;
}

SurfaceJobInfo SurfaceJobs::cancel(const std::string& id) {
  std::unique_lock lk(mutex_);
  auto job = find(id);
  if (job->info.state == JobState::Done || job->info.state == JobState::Failed)
    throw RecipeJobError(409, "export job " + id + " has already " +
                                  (job->info.state == JobState::Done ? "finished" : "failed"),
                         "id");
  job->info.cancelRequested = true;
  if (job->info.state == JobState::Queued) {
    job->info.state = JobState::Cancelled;
    queue_.erase(std::remove(queue_.begin(), queue_.end(), job), queue_.end());
    changed(*job, lk);
  }
  return job->info;
}

void SurfaceJobs::changed(Job& job, std::unique_lock<std::mutex>& lk) {
  const SurfaceJobInfo info = job.info;
  const auto progress = job.request.progress;
  lk.unlock();
  if (progress) {
    try {
      progress(info);
    } catch (...) {
      // The job goes on whatever a listener does.
    }
  }
  lk.lock();
}

void SurfaceJobs::run() {
  std::unique_lock lk(mutex_);
  for (;;) {
    wake_.wait(lk, [&] { return stopping_ || !queue_.empty(); });
    if (stopping_) return;
    auto job = queue_.front();
    queue_.pop_front();
    job->info.state = JobState::Running;
    changed(*job, lk);
    lk.unlock();
    exportJob(*job);
    lk.lock();
  }
}

void SurfaceJobs::exportJob(Job& job) {
  const auto t0 = std::chrono::steady_clock::now();
  const auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); };
  const SurfaceJobRequest& r = job.request;
  // Written into a hidden sibling of EXPORTS/NAME, renamed into place at the end.
  const fs::path out(r.outDir);
  const fs::path staging = stagingPath(out.string());
  std::error_code ec;
  JobState end = JobState::Done;
  std::string error;
  std::vector<std::string> files;
  try {
    omp_set_num_threads(threads_);
    const FramesFile in(r.h5Path);
    const std::string createdBy = std::string("flowclip ") + FLOWCLIP_VERSION + " session " + r.session;
    SurfaceExport e(exportInfoOf(in, r.name, staging.string(), createdBy), r.formats, r.surface, r.formatParams);
    {
      std::unique_lock lk(mutex_);
      job.info.frames = int(in.frames());
      changed(job, lk);
    }
    for (size_t f = 0; f < in.frames(); ++f) {
      {
        std::lock_guard lk(mutex_);
        if (job.info.cancelRequested) {
          end = JobState::Cancelled;
          break;
        }
      }
      e.writeFrame(in.frame(f));
      std::unique_lock lk(mutex_);
      job.info.framesDone = int(f + 1);
      job.info.bytes = e.bytesWritten();
      job.info.elapsedSeconds = elapsed();
      changed(job, lk);
    }
    if (end == JobState::Done) {
      e.close();
      // The directory appears whole: an older one is exchanged with it in
      // one step (renameat2), then removed; never a moment without either.
      if (fs::exists(out)) {
        if (::renameat2(AT_FDCWD, staging.c_str(), AT_FDCWD, out.c_str(), RENAME_EXCHANGE) != 0)
          throw std::system_error(errno, std::generic_category(), "cannot replace '" + out.string() + "'");
      } else {
        fs::rename(staging, out);
      }
      files.push_back(fs::path(e.manifestPath()).filename().string());
      for (const auto& entry : fs::directory_iterator(out))
        if (entry.path().filename() != files.front()) files.push_back(entry.path().filename().string());
      std::sort(files.begin() + 1, files.end());
    }
  } catch (const std::exception& ex) {
    end = JobState::Failed;
    error = ex.what();
  }
  fs::remove_all(staging, ec);  // a failed job's files, or the export it replaced
  std::unique_lock lk(mutex_);
  job.info.state = end;
  job.info.error = error;
  job.info.files = std::move(files);
  job.info.elapsedSeconds = elapsed();
  changed(job, lk);
}

}  // namespace fc::service
