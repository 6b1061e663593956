#include "service/render_jobs.h"

#include "service/child_process.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fc::service {

namespace fs = std::filesystem;
using json = nlohmann::json;

json renderJobJson(const RenderJobInfo& j) {
  json out = jobProgressJson(j);
  json tasks = json::array();
  int done = 0;
  for (const RenderTaskInfo& t : j.tasks) {
    json task = {{"id", t.id}, {"overrides", t.overrides}, {"state", t.state},
                 {"frame", t.frame}, {"frames", t.frames}, {"wall_s", t.wallSeconds}};
    if (t.state == "done") ++done;
    if (j.state == JobState::Done) task["files"] = t.files;
    tasks.push_back(std::move(task));
  }
  out.update({{"id", j.id}, {"name", j.name}, {"session", j.session}, {"request", j.request},
              {"tasks", tasks}, {"tasks_done", done}});
  if (j.state == JobState::Done) out["directory"] = j.id + "/";
  return out;
}

bool RenderJobs::isJobId(const std::string& id) { return isNumberedJobId(id, 'j'); }

RenderJobs::RenderJobs(RenderJobsOptions options) : options_(std::move(options)) {
  std::error_code ec;
  // Staged jobs are a dead server's only when no live server holds the directory's lock
  // (made with the directory, by the first job, when there is none yet).
  if (fs::is_directory(options_.jobsDir, ec))
    lock_ = ::open((fs::path(options_.jobsDir) / ".lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  const bool owner = lock_ >= 0 && ::flock(lock_, LOCK_EX | LOCK_NB) == 0;
  // Numbered after the jobs already in the directory; a dead server's staged jobs are never complete.
  for (const auto& entry : fs::directory_iterator(options_.jobsDir, ec)) {
    const std::string name = entry.path().filename().string();
    if (isJobId(name)) next_ = std::max<uint64_t>(next_, std::stoull(name.substr(1)) + 1);
    const size_t stage = name.rfind(".stage");
    if (name.size() > 7 && name[0] == '.' && stage != std::string::npos && stage + 6 == name.size() &&
        isJobId(name.substr(1, stage - 1))) {
      next_ = std::max<uint64_t>(next_, std::stoull(name.substr(2, stage - 2)) + 1);
      if (owner) fs::remove_all(entry.path(), ec);
    }
  }
  worker_ = std::thread([this] { run(); });
}

RenderJobs::~RenderJobs() {
  {
    std::lock_guard lk(mutex_);
    stopping_ = true;
    for (auto& [n, j] : jobs_) {
      j->info.cancelRequested = true;
      if (j->process) j->process->signalGroup(SIGKILL);
    }
  }
  wake_.notify_all();
  worker_.join();
  if (lock_ >= 0) ::close(lock_);
}

std::string RenderJobs::where() const {
  if (!options_.scheduler.empty()) return options_.scheduler;
  return "local (" + std::to_string(options_.localWorkers) + " worker" + (options_.localWorkers == 1 ? "" : "s") + ")";
}

RenderJobInfo RenderJobs::start(RenderJobRequest request) {
  std::unique_lock lk(mutex_);
  // Past any id another server sharing the directory has taken since.
  std::error_code ec;
  while (fs::exists(fs::path(options_.jobsDir) / ("j" + std::to_string(next_)), ec) ||
         fs::exists(fs::path(options_.jobsDir) / (".j" + std::to_string(next_) + ".stage"), ec))
    ++next_;
  auto job = std::make_shared<Job>();
  job->info.id = "j" + std::to_string(next_);
  job->info.name = request.name;
  job->info.session = request.session;
  job->info.request = request.request;
  for (const json& v : request.variants) {
    RenderTaskInfo t;
    t.overrides = v;
    job->info.tasks.push_back(std::move(t));
  }
  job->request = std::move(request);
  jobs_[next_++] = job;
  pruneFinishedJobs(jobs_, kMaxFinishedJobs);
  // Reported as queued before the job thread can take it, so that no later state is overwritten.
  changed(*job, lk);
  queue_.push_back(job);
  const RenderJobInfo info = job->info;
  wake_.notify_all();
  return info;
}

std::shared_ptr<RenderJobs::Job> RenderJobs::find(const std::string& id) const {
  if (!isJobId(id)) throw RecipeJobError(400, "\"" + id.substr(0, 40) + "\" is not a render job id (j1, j2, ...)", "id");
  auto it = jobs_.find(std::stoull(id.substr(1)));
  if (it == jobs_.end()) throw RecipeJobError(404, "no render job " + id + " (finished jobs are kept for a while)", "id");
  return it->second;
}

RenderJobInfo RenderJobs::job(const std::string& id) const {
  std::lock_guard lk(mutex_);
  return find(id)->info;
}

std::vector<RenderJobInfo> RenderJobs::jobs() const {
  std::lock_guard lk(mutex_);
  std::vector<RenderJobInfo> out;
  for (const auto& [n, j] : jobs_) out.push_back(j->info);
  return out;
}

RenderJobInfo RenderJobs::cancel(const std::string& id) {
  std::unique_lock lk(mutex_);
  auto job = find(id);
  if (job->info.state == JobState::Done || job->info.state == JobState::Failed)
    throw RecipeJobError(409, "render job " + id + " has already " +
                                  (job->info.state == JobState::Done ? "finished" : "failed"),
                         "id");
  job->info.cancelRequested = true;
  if (job->info.state == JobState::Queued) {
    job->info.state = JobState::Cancelled;
    queue_.erase(std::remove(queue_.begin(), queue_.end(), job), queue_.end());
  } else if (job->process) {
    job->process->signalGroup(SIGKILL);  // the batch, its LocalCluster and their flowclip runs
  }
  changed(*job, lk);
  return job->info;
}

void RenderJobs::changed(Job& job, std::unique_lock<std::mutex>& lk) {
  const RenderJobInfo info = job.info;
  const auto progress = job.request.progress;
  std::unique_lock reporting(job.reporting);  // before mutex_ is released: reports keep their order
  lk.unlock();
  if (progress) {
    try {
      progress(info);
    } catch (...) {
      // The job goes on whatever a listener does.
    }
  }
  reporting.unlock();
  lk.lock();
}

void RenderJobs::run() {
  std::unique_lock lk(mutex_);
  for (;;) {
    wake_.wait(lk, [&] { return stopping_ || !queue_.empty(); });
    if (stopping_) return;
    auto job = queue_.front();
    queue_.pop_front();
    if (job->info.state != JobState::Queued) continue;  // cancelled while it was being queued
    job->info.state = JobState::Running;
    changed(*job, lk);
    lk.unlock();
    runJob(*job);
    lk.lock();
  }
}

namespace {

// A field of a progress line, or `fallback` when absent or of another type.
int intField(const json& e, const char* key, int fallback) {
  const auto it = e.find(key);
  return it != e.end() && it->is_number() ? int(std::clamp(it->get<double>(), 0.0, 1e7)) : fallback;
}
double numberField(const json& e, const char* key) {
  const auto it = e.find(key);
  return it != e.end() && it->is_number() ? it->get<double>() : 0.0;
}
std::string stringField(const json& e, const char* key) {
  const auto it = e.find(key);
  return it != e.end() && it->is_string() ? it->get<std::string>() : std::string();
}

// Frames in all: a task not yet started counts as many as one that has.
void countFrames(RenderJobInfo& info) {
  int known = 0;
  for (const RenderTaskInfo& t : info.tasks) known = std::max(known, t.frames);
  info.frames = info.framesDone = 0;
  // In the int range: a task's frames are at most 1e7, a job's tasks at most 64.
  for (const RenderTaskInfo& t : info.tasks) {
    const int frames = t.frames > 0 ? t.frames : known;
    info.frames += frames;
    info.framesDone += t.state == "done" ? frames : std::min(t.frame, frames);
  }
}

}  // namespace

void RenderJobs::follow(Job& job, const json& e) {
  RenderJobInfo& info = job.info;
  const std::string kind = stringField(e, "event");
  const auto task = [&](const std::string& id) -> RenderTaskInfo* {
    for (RenderTaskInfo& t : info.tasks)
      if (!id.empty() && t.id == id) return &t;
    return nullptr;
  };
  if (kind == "plan" && e.contains("tasks") && e["tasks"].is_array()) {
    // The batch's tasks come in the spec's order: the ids of ours.
    for (size_t i = 0; i < e["tasks"].size() && i < info.tasks.size(); ++i)
      if (e["tasks"][i].is_object() && e["tasks"][i].contains("id") && e["tasks"][i]["id"].is_string())
        info.tasks[i].id = e["tasks"][i]["id"].get<std::string>();
  } else if (kind == "task") {
    if (RenderTaskInfo* t = task(stringField(e, "id")); t && t->state != "done") {
      t->state = "running";
      t->frames = intField(e, "frames", t->frames);
      t->frame = std::min(intField(e, "frame", t->frame), t->frames);
    }
  } else if (kind == "done") {
    if (RenderTaskInfo* t = task(stringField(e, "id"))) {
      t->state = "done";
      t->frame = t->frames;
      t->wallSeconds = numberField(e, "wall_s");
    }
  } else if (kind == "error") {
    info.error = stringField(e, "message");
    if (info.error.empty()) info.error = "the batch failed";
  }
  countFrames(info);
}

namespace {

std::string tail(const fs::path& file, size_t lines) {
  std::ifstream in(file);
  std::deque<std::string> kept;
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("task ", 0) == 0 || line.rfind("batch: ", 0) == 0) continue;  // progress, not the cause
    kept.push_back(line);
    if (kept.size() > lines) kept.pop_front();
  }
  std::string out;
  for (const std::string& l : kept) out += (out.empty() ? "" : "\n") + l;
  return out;
}

}  // namespace

void RenderJobs::runJob(Job& job) {
  const auto t0 = std::chrono::steady_clock::now();
  const auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); };
  const fs::path out = fs::path(options_.jobsDir) / job.info.id;
  const fs::path staging = fs::path(options_.jobsDir) / ("." + job.info.id + ".stage");
  std::error_code ec;
  JobState end = JobState::Done;
  std::string error;
  bool keepStaging = false;  // finished results the rename could not publish
  bool ownStaging = false;
  try {
    if (fs::create_directories(options_.jobsDir)) {
      std::lock_guard lk(mutex_);
      if (lock_ < 0) {
        lock_ = ::open((fs::path(options_.jobsDir) / ".lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
        if (lock_ >= 0) ::flock(lock_, LOCK_EX | LOCK_NB);
      }
    }
    if (!fs::create_directory(staging))
      throw std::runtime_error(staging.string() + " exists: another server is using " + options_.jobsDir);
    ownStaging = true;
    json spec = job.request.spec;
    spec["name"] = job.info.name;
    spec["scene"] = "scene.json";
    spec["templates"] = fs::absolute(options_.templatesDir).lexically_normal().string();
    spec["out"] = ".";
    spec["list"] = job.request.variants;
    std::ofstream(staging / "scene.json") << job.request.scene.dump(1) << "\n";
    std::ofstream(staging / "spec.json") << spec.dump(1) << "\n";
    std::vector<std::string> argv = {options_.batchCommand, "run", "spec.json", "--progress", "json",
                                     "--binary", options_.binary};
    if (!options_.scheduler.empty()) argv.insert(argv.end(), {"--scheduler", options_.scheduler});
    else argv.insert(argv.end(), {"--local", std::to_string(options_.localWorkers)});
    argv.push_back("--watch-stdin");  // it stops with this server
    ChildProcess child(argv, staging.string(), (staging / "batch.log").string());
    // Whichever way this block ends, no one signals the child once it is gone.
    struct Unpublish {
      RenderJobs& jobs;
      Job& job;
      ~Unpublish() {
        std::lock_guard lk(jobs.mutex_);
        job.process = nullptr;
      }
    } unpublish{*this, job};
    {
      std::lock_guard lk(mutex_);
      job.process = &child;
      if (job.info.cancelRequested) child.signalGroup(SIGKILL);
    }
    std::string line;
    while (child.readLine(line)) {
      json e;
      try {
        e = json::parse(line);
      } catch (const json::exception&) {
        continue;  // a stray print: not ours
      }
      if (!e.is_object()) continue;
      std::unique_lock lk(mutex_);
      follow(job, e);
      job.info.elapsedSeconds = elapsed();
      changed(job, lk);
    }
    {
      std::lock_guard lk(mutex_);
      job.process = nullptr;  // before it is reaped: its group id is never signalled once free
    }
    const int status = child.wait();
    {
      std::lock_guard lk(mutex_);
      if (job.info.cancelRequested) end = JobState::Cancelled;
      else if (status != 0) {
        end = JobState::Failed;
        error = !job.info.error.empty() ? job.info.error : tail(staging / "batch.log", 8);
        if (error.empty()) error = "flowclip-batch exited with status " + std::to_string(status);
      }
    }
    if (end == JobState::Done) {
      fs::rename(staging, out, ec);
      if (ec) {
        keepStaging = true;
        throw std::runtime_error("the results are complete in " + staging.string() + " but could not become " +
                                 out.string() + ": " + ec.message());
      }
      std::lock_guard lk(mutex_);
      for (RenderTaskInfo& t : job.info.tasks) {
        // Its exit status says every task is complete, whatever progress lines were missed.
        t.state = "done";
        t.frame = t.frames;
        t.files.clear();
        if (t.id.empty()) continue;  // never planned: no folder of its own
        for (const auto& f : fs::recursive_directory_iterator(out / t.id, ec))
          if (f.symlink_status().type() == fs::file_type::regular)
            t.files.push_back(fs::relative(f.path(), out / t.id).string());
        std::sort(t.files.begin(), t.files.end());
      }
      countFrames(job.info);
    }
  } catch (const std::exception& ex) {
    end = JobState::Failed;
    error = ex.what();
  }
  if (end != JobState::Done && ownStaging && !keepStaging) fs::remove_all(staging, ec);
  std::unique_lock lk(mutex_);
  job.process = nullptr;
  job.info.state = end;
  job.info.error = end == JobState::Failed ? error : std::string();
  job.info.elapsedSeconds = elapsed();
  changed(job, lk);
}

}  // namespace fc::service
