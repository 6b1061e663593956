#include "service/recipe_jobs.h"

#include "io/scene.h"
#include "io/template_database.h"

#include <omp.h>

#include <algorithm>
#include <filesystem>

namespace fc::service {

namespace fs = std::filesystem;
using json = nlohmann::json;

const char* jobStateName(JobState s) {
  switch (s) {
    case JobState::Queued: return "queued";
    case JobState::Running: return "running";
    case JobState::Done: return "done";
    case JobState::Failed: return "failed";
    case JobState::Cancelled: return "cancelled";
  }
  return "failed";
}

json jobProgressJson(const JobProgress& j) {
  json out = {{"state", jobStateName(j.state)},
              {"progress", j.progress()},
              {"frames_done", j.framesDone},
              {"frames", j.frames},
              {"cancel_requested", j.cancelRequested},
              {"elapsed_s", j.elapsedSeconds}};
  if (!j.error.empty()) out["error"] = j.error;
  return out;
}

bool isNumberedJobId(const std::string& id, char prefix) {
  if (id.size() < 2 || id.size() > 20 || id[0] != prefix || id[1] == '0') return false;
  return std::all_of(id.begin() + 1, id.end(), [](char c) { return c >= '0' && c <= '9'; });
}

json jobJson(const JobInfo& j) {
  json out = jobProgressJson(j);
  out.update({{"id", j.id}, {"recipe", j.recipe}, {"templates", j.templates}, {"dimension", j.dimension}, {"force", j.force}});
  return out;
}

bool RecipeJobs::isJobId(const std::string& id) { return isNumberedJobId(id, 'r'); }

RecipeJobs::RecipeJobs(RecipeJobsOptions options) : options_(std::move(options)) {
  worker_ = std::thread([this] { run(); });
}

RecipeJobs::~RecipeJobs() {
  {
    std::lock_guard lk(mutex_);
    stopping_ = true;
    for (auto& job : queue_) job->info.state = JobState::Cancelled;
    queue_.clear();
    for (auto& [n, job] : jobs_)
      if (job->info.state == JobState::Running) job->info.cancelRequested = true;
  }
  changed_.notify_all();
  worker_.join();
}

std::string RecipeJobs::recipePath(const std::string& name) const {
  if (options_.recipesDir.empty())
    throw RecipeJobError(404, "the server has no recipe directory (serve --recipes DIR)", "name");
  if (!isValidTemplateName(name))
    throw RecipeJobError(400, "recipe name \"" + name.substr(0, 80) +
                                  "\" is invalid: names are 1 to 64 characters from A-Z a-z 0-9 _ -",
                         "name");
  const fs::path file = fs::path(options_.recipesDir) / (name + ".json");
  std::error_code ec;
  if (!fs::is_regular_file(file, ec))
    throw RecipeJobError(404, "no recipe \"" + name + "\" in " + options_.recipesDir, "name");
  return file.string();
}

json RecipeJobs::list(const std::function<bool(const std::string&)>& isRecorded) {
  std::vector<fs::path> files;
  std::error_code ec;
  if (!options_.recipesDir.empty())
    for (const auto& entry : fs::directory_iterator(options_.recipesDir, ec))
      if (entry.is_regular_file() && entry.path().extension() == ".json" &&
          isValidTemplateName(entry.path().stem().string()))
        files.push_back(entry.path());
  std::sort(files.begin(), files.end());

  std::vector<json> summaries;
  {
    std::lock_guard lk(listMutex_);
    for (const fs::path& f : files) {
      const uint64_t size = fs::file_size(f, ec);
      const int64_t mtime = ec ? 0 : int64_t(fs::last_write_time(f, ec).time_since_epoch().count());
      ListedRecipe& cached = listed_[f.stem().string()];
      if (cached.summary.is_null() || cached.size != size || cached.mtime != mtime) {
        json s = {{"name", f.stem().string()}};
        // A recipe is parsed and its scene validated once per file version (3D scenes take a moment).
        try {
          const Recipe r = loadRecipe(f.string());
          json names = json::array();
          for (const CaptureSpec& c : r.captures) names.push_back(c.name);
          s.update({{"dimension", r.dimension}, {"templates", names}, {"frames", recipeSimulationFrames(r)}});
        } catch (const std::exception& e) {
          s["error"] = e.what();
        }
        cached = {size, mtime, s};
      }
      summaries.push_back(cached.summary);
    }
  }

  json list = json::array();
  std::lock_guard lk(mutex_);
  for (json s : summaries) {
    const std::string name = s["name"];
    if (!s.contains("error")) {
      json templates = json::array();
      bool all = true;
      for (const json& t : s["templates"]) {
        const bool recorded = isRecorded(t.get<std::string>());
        all = all && recorded;
        templates.push_back({{"name", t}, {"recorded", recorded}});
      }
      s["templates"] = templates;
      s["recorded"] = all;
      if (auto it = lastSeconds_.find(name); it != lastSeconds_.end()) s["last_seconds"] = it->second;
      for (const auto& [n, job] : jobs_)
        if (job->info.recipe == name && !job->info.finished()) s["job"] = job->info.id;
    }
    list.push_back(std::move(s));
  }
  return {{"directory", options_.recipesDir}, {"recipes", list}};
}

JobInfo RecipeJobs::start(const std::string& name, bool force, bool& created) {
  const std::string file = recipePath(name);
  {
    // Answered before parsing: a client that asks again while it records gets the job at once.
    std::lock_guard lk(mutex_);
    for (const auto& [n, job] : jobs_)
      if (job->info.recipe == name && !job->info.finished()) {
        created = false;
        return job->info;
      }
  }
  Recipe recipe;
  try {
    recipe = loadRecipe(file);
  } catch (const SceneError& e) {
    throw RecipeJobError(422, name + ".json: " + e.what(), e.path);
  }
  const TemplateDatabase db(options_.templatesDir);
  if (!force)
    for (const CaptureSpec& c : recipe.captures)
      if (db.contains(c.name))
        throw RecipeJobError(409, "template \"" + c.name + "\" of recipe \"" + name +
                                      "\" is already recorded (send \"force\": true to record it again)",
                             "force");
  auto job = std::make_shared<Job>();
  job->info.recipe = name;
  job->info.dimension = recipe.dimension;
  job->info.force = force;
  for (const CaptureSpec& c : recipe.captures) job->info.templates.push_back(c.name);
  job->info.frames = recipeSimulationFrames(recipe);
  job->recipe = std::move(recipe);

  std::lock_guard lk(mutex_);
  // Checked again: another request may have queued it while this one parsed.
  for (const auto& [n, other] : jobs_)
    if (other->info.recipe == name && !other->info.finished()) {
      created = false;
      return other->info;
    }
  if (stopping_) throw RecipeJobError(503, "the server is stopping");
  const uint64_t number = next_++;
  job->info.id = "r" + std::to_string(number);
  jobs_[number] = job;
  queue_.push_back(job);
  prune();
  created = true;
  changed_.notify_all();
  return job->info;
}

std::shared_ptr<RecipeJobs::Job> RecipeJobs::find(const std::string& id) const {
  if (!isJobId(id))
    throw RecipeJobError(400, "job id \"" + id.substr(0, 40) + "\" is malformed: job ids are r1, r2, ...", "id");
  auto it = jobs_.find(std::stoull(id.substr(1)));
  if (it == jobs_.end()) throw RecipeJobError(404, "no recording job \"" + id + "\"", "id");
  return it->second;
}

namespace {

JobInfo snapshot(const JobInfo& info, std::chrono::steady_clock::time_point started) {
  JobInfo out = info;
  if (out.state == JobState::Running)
    out.elapsedSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return out;
}

}  // namespace

JobInfo RecipeJobs::job(const std::string& id) const {
  std::lock_guard lk(mutex_);
  const auto j = find(id);
  return snapshot(j->info, j->started);
}

std::vector<JobInfo> RecipeJobs::jobs() const {
  std::lock_guard lk(mutex_);
  std::vector<JobInfo> out;
  for (const auto& [n, j] : jobs_) out.push_back(snapshot(j->info, j->started));
  return out;
}

JobInfo RecipeJobs::cancel(const std::string& id) {
  std::lock_guard lk(mutex_);
  const auto job = find(id);
  Job& j = *job;
  switch (j.info.state) {
    case JobState::Queued:
      j.info.state = JobState::Cancelled;
      queue_.erase(std::remove_if(queue_.begin(), queue_.end(), [&](const auto& q) { return q.get() == &j; }),
                   queue_.end());
      changed_.notify_all();
      break;
    case JobState::Running: j.info.cancelRequested = true; break;
    case JobState::Cancelled: break;
    case JobState::Done:
    case JobState::Failed:
      throw RecipeJobError(409, "job " + id + " has already " +
                                    (j.info.state == JobState::Done ? "recorded its templates" : "failed") +
                                    ": nothing to cancel",
                           "id");
  }
  return snapshot(j.info, j.started);
}

JobInfo RecipeJobs::wait(const std::string& id, std::chrono::milliseconds timeout,
                         const std::function<bool(const JobInfo&)>& until) const {
  std::unique_lock lk(mutex_);
  const auto j = find(id);  // held: pruning cannot free it while waiting
  changed_.wait_for(lk, timeout, [&] { return until ? until(snapshot(j->info, j->started)) : j->info.finished(); });
  return snapshot(j->info, j->started);
}

void RecipeJobs::prune() { pruneFinishedJobs(jobs_, kMaxFinishedJobs); }

void RecipeJobs::run() {
  if (options_.threads > 0) omp_set_num_threads(options_.threads);
  std::unique_lock lk(mutex_);
  while (true) {
    changed_.wait(lk, [&] { return stopping_ || !queue_.empty(); });
    if (stopping_) return;
    std::shared_ptr<Job> job = queue_.front();
    queue_.pop_front();
    job->info.state = JobState::Running;
    job->started = std::chrono::steady_clock::now();
    changed_.notify_all();
    lk.unlock();
    record(*job);
    lk.lock();
    job->recipe = Recipe{};  // the scene JSON is not needed any more
    prune();
    changed_.notify_all();
  }
}

// Runs without the lock, taking it once per simulation frame to publish the
// progress and read a cancellation.
void RecipeJobs::record(Job& job) {
  RecordOptions ro;
  ro.templatesDir = options_.templatesDir;
  ro.force = job.info.force;
  ro.simulationProgress = [&](const RecordProgress& p) {
    std::lock_guard lk(mutex_);
    job.info.framesDone = p.simFrame;
    job.info.frames = p.simFrames;
    changed_.notify_all();
    return !job.info.cancelRequested && !stopping_;
  };
  JobState state = JobState::Done;
  std::string error;
  try {
    (void)recordRecipe(job.recipe, ro);
  } catch (const RecordAborted&) {
    state = JobState::Cancelled;
  } catch (const std::exception& e) {
    state = JobState::Failed;
    error = e.what();
  }
  std::lock_guard lk(mutex_);
  job.info.state = state;
  job.info.error = error;
  job.info.elapsedSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - job.started).count();
  if (state == JobState::Done) {
    job.info.framesDone = job.info.frames;
    lastSeconds_[job.info.recipe] = job.info.elapsedSeconds;
  }
}

}  // namespace fc::service
