// One simulation session: see session.h. Long because SessionImpl's thread
// owns the simulation and every transition of its state (transport, edits,
// re-simulation, history) happens under one lock in one place. What does not
// need that lock lives in its own file: recorded frames (frame_snapshot.h),
// the history and its stale range (frame_history.h), listeners
// (session_listeners.h), edit parsing (edit.h), edit scopes (edit_scope.h),
// checkpoints (checkpoints.h), layers of recorded frames (replay_layers.h)
// and exports (history_export.h).
#include "service/session.h"

#include "control/control.h"
#include "io/instance_binding.h"
#include "io/recipe.h"
#include "service/checkpoints.h"
#include "service/replay_layers.h"
#include "service/edit_scope.h"
#include "service/frame_history.h"
#include "service/history_export.h"
#include "service/history_template.h"
#include "service/session_listeners.h"
#include "sph/state_archive.h"

#include <omp.h>

#include <algorithm>
#include <cstdlib>
#include <atomic>
#include <climits>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <numeric>
#include <thread>

namespace fc::service {

using nlohmann::json;

const char* statusName(SessionStatus status) {
  switch (status) {
    case SessionStatus::Paused: return "paused";
    case SessionStatus::Playing: return "playing";
    case SessionStatus::Stepping: return "stepping";
    case SessionStatus::Error: return "error";
  }
  return "?";
}

// ------------------------------------------------------------------ session ---

namespace {

using Clock = std::chrono::steady_clock;
constexpr size_t kKeptResults = 1024;

struct Op {
  bool reset = false;
  bool layers = false;  // re-encode the current frame with the demanded layers
  uint64_t id = 0;
  Edit edit;
  std::shared_ptr<std::promise<EditResult>> promise;
};

template <int D>
json canonicalScene(const SimulationSetup<D>& setup, const SceneControl<D>& control) {
  json j = sceneToJson<D>(setup);
  const json c = sceneControlToJson<D>(control, setup.phases);
  for (auto it = c.begin(); it != c.end(); ++it) j[it.key()] = *it;
  return j;
}

// The simulation's constructor reports what parseScene cannot check (it
// checks nearly everything) as std::invalid_argument.
template <int D>
std::unique_ptr<Simulation<D>> makeSimulation(const SimulationSetup<D>& setup) {
  try {
    return std::make_unique<Simulation<D>>(setup);
  } catch (const std::invalid_argument& e) {
    throw SceneError("", e.what());
  }
}

template <int D>
class SessionImpl final : public Session {
 public:
  SessionImpl(std::string id, std::string name, const json& scene, TemplateDatabase& database,
              const SessionOptions& options)
      : id_(std::move(id)),
        db_(database),
        options_(options),
        checkpoints_(options.checkpointEvery, checkpointCap(options), options.compressCheckpoints,
                     options.denseCheckpoints) {
    setup_ = parseScene<D>(scene);
    control_ = parseSceneControl<D>(scene, setup_.phases);
    if (!control_.instances.empty()) bound_ = bindInstances<D>(control_.instances, db_);
    buildSimulation();
    name_ = name.empty() ? setup_.name : std::move(name);
    scene_ = canonicalScene<D>(setup_, control_);
    speed_ = options_.playbackSpeed >= 0 && std::isfinite(options_.playbackSpeed) ? options_.playbackSpeed : 0;
    std::lock_guard lk(mutex_);
    sceneShared_ = scene_;
    endFrame_ = playUntil_ = sceneEndFrame();
    recordInitialFrame();
    thread_ = std::thread([this] { run(); });
  }

  ~SessionImpl() override {
    cancel_ = true;  // the frame in progress stops at its next substep
    {
      std::lock_guard lk(mutex_);
      stop_ = true;
    }
    cv_.notify_all();
    if (thread_.joinable()) thread_.join();
  }

  const std::string& id() const override { return id_; }
  const std::string& name() const override { return name_; }
  int dimension() const override { return D; }

  // ---- transport ----

  void play(int until) override {
    {
      std::lock_guard lk(mutex_);
      if (status_ == SessionStatus::Error) throw SessionError(errorText() + "; reset the session first");
      if (until < -1) throw SessionError("play: until must be a frame >= 0, got " + std::to_string(until));
      playUntil_ = until < 0 ? endFrame_ : until;
      // From a replayed frame: the recorded frames first, then on simulating.
      replayPlaying_ = replay_ != nullptr;
      status_ = SessionStatus::Playing;
      stepsLeft_ = 0;
      lastStart_ = Clock::time_point{};
      ++signal_;
    }
    wake();
    notifyState();
  }

  void pause() override {
    bool changed = false;
    {
      std::lock_guard lk(mutex_);
      if (status_ == SessionStatus::Playing || status_ == SessionStatus::Stepping) {
        status_ = SessionStatus::Paused;
        stepsLeft_ = 0;
        replayPlaying_ = false;
        changed = true;
      }
      ++signal_;
    }
    wake();
    if (changed) notifyState();
  }

  void step(int frames) override {
    if (frames <= 0) throw SessionError("step: the number of frames must be positive, got " + std::to_string(frames));
    bool wasReplay = false;
    {
      std::lock_guard lk(mutex_);
      if (status_ == SessionStatus::Error) throw SessionError(errorText() + "; reset the session first");
      wasReplay = replay_ != nullptr;
      replay_ = nullptr;
      replayPlaying_ = false;
      stepsLeft_ = status_ == SessionStatus::Stepping ? int(std::min<int64_t>(int64_t(stepsLeft_) + frames, INT32_MAX))
                                                      : frames;
      status_ = SessionStatus::Stepping;
      ++signal_;
    }
    wake();
    if (wasReplay) notifyFrame();
    notifyState();
  }

  void reset() override {
    cancel_ = true;  // the frame in progress is discarded by the reset anyway
    {
      std::lock_guard lk(mutex_);
      Op op;
      op.reset = true;
      ops_.push_back(std::move(op));
      ++signal_;
    }
    wake();
  }

  void setPlaybackSpeed(double fps) override {
    if (!(fps >= 0) || !std::isfinite(fps))
      throw SessionError("playback speed must be a finite number of frames per second >= 0 (0: as fast as possible)");
    {
      std::lock_guard lk(mutex_);
      speed_ = fps;
      ++signal_;
    }
    wake();
    notifyState();
  }

  FramePtr seek(int frame) override {
    FramePtr f;
    {
      std::lock_guard lk(mutex_);
      f = history_.find(frame);
      if (!f) throw std::out_of_range("frame " + std::to_string(frame) + " is not in the history (" + history_.keptText() + ")");
      if (status_ != SessionStatus::Error) status_ = SessionStatus::Paused;
      stepsLeft_ = 0;
      replayPlaying_ = false;
      // Seeking the simulation's own frame is going back to live.
      replay_ = f == live_ ? nullptr : f;
      ++signal_;
    }
    wake();
    notifyFrame();
    notifyState();
    return f;
  }

  // ---- edits ----

  EditTicket submit(Edit edit) override {
    EditTicket t;
    {
      std::lock_guard lk(mutex_);
      // A flood of edits would starve the frames (edits go first at each
      // boundary) and grow the queue without bound.
      if (pendingKinds_.size() >= kMaxPendingEdits)
        throw SessionOverloaded("the session already has " + std::to_string(kMaxPendingEdits) +
                                " edits waiting to be applied; wait for their results");
      Op op;
      op.id = t.id = ++lastEditId_;
      op.edit = std::move(edit);
      op.promise = std::make_shared<std::promise<EditResult>>();
      t.result = op.promise->get_future().share();
      if (stop_) {
        op.promise->set_value(closedResult(op));
      } else {
        pendingKinds_[op.id] = op.edit.kind;
        ops_.push_back(std::move(op));
        ++signal_;
      }
    }
    wake();
    return t;
  }

  std::optional<EditResult> editResult(uint64_t id) const override {
    std::lock_guard lk(mutex_);
    auto it = results_.find(id);
    if (it == results_.end()) return std::nullopt;
    return it->second;
  }

  std::optional<EditKind> pendingEdit(uint64_t id) const override {
    std::lock_guard lk(mutex_);
    auto it = pendingKinds_.find(id);
    if (it == pendingKinds_.end()) return std::nullopt;
    return it->second;
  }

  // ---- frames ----

  FramePtr latestFrame() const override {
    std::lock_guard lk(mutex_);
    return replay_ ? replay_ : live_;
  }

  FramePtr frame(int frame) const override {
    std::lock_guard lk(mutex_);
    return history_.find(frame);
  }

  std::vector<FramePtr> history() const override {
    std::lock_guard lk(mutex_);
    return history_.all();
  }

  HistoryExport exportHistory(const std::string& h5Path, int firstFrame, int lastFrame) const override {
    std::vector<FramePtr> frames;
    ExportHeader header;
    {
      std::lock_guard lk(mutex_);
      // Empty only when one frame exceeds the history's cap.
      if (history_.empty()) throw std::invalid_argument("no recorded frame: the history is empty");
      const int first = firstFrame < 0 ? history_.first() : firstFrame;
      const int last = lastFrame < 0 ? history_.last() : lastFrame;
      if (first > last)
        throw std::invalid_argument("the first frame (" + std::to_string(first) + ") is after the last frame (" +
                                    std::to_string(last) + ")");
      history_.throwIfStale(first, last, live_->frame);
      frames = history_.within(first, last);
      if (frames.empty())
        throw std::invalid_argument("no recorded frame in frames " + std::to_string(first) + " to " +
                                    std::to_string(last) + " (" + history_.keptText() + ")");
      header.sceneName = info_.sceneName;
      header.dimension = D;
      header.particleRadius = info_.particleRadius;
      header.frameRate = info_.frameRate;
      header.phases = info_.phases;
      header.domainMin = info_.domainMin;
      header.domainMax = info_.domainMax;
      header.createdBy = createdBy();
    }
    return writeHistoryExport(h5Path, frames, std::move(header));
  }

  TemplateEntry recordTemplate(TemplateDatabase& db, const std::string& name, const std::vector<double>& regionMin,
                               const std::vector<double>& regionMax, int firstFrame, int lastFrame,
                               bool force) const override {
    checkTemplateRequest(D, db, name, regionMin, regionMax, firstFrame, lastFrame, force);
    std::vector<FramePtr> frames;
    RecordedScene info;
    std::string recipe;
    {
      std::lock_guard lk(mutex_);
      history_.throwIfStale(firstFrame, lastFrame, live_->frame);
      frames = history_.contiguous(firstFrame, lastFrame);
      info = info_;
      recipe = sceneShared_.dump();
    }
    return recordTemplateFromFrames<D>(db, name, regionMin, regionMax, frames, info, std::move(recipe), createdBy(),
                                       force);
  }

  json sceneJson() const override {
    std::lock_guard lk(mutex_);
    return sceneShared_;
  }

  SessionStatus status() const override {
    std::lock_guard lk(mutex_);
    return status_;
  }

  int currentFrame() const override {
    std::lock_guard lk(mutex_);
    return live_->frame;
  }

  json state() const override {
    std::lock_guard lk(mutex_);
    return stateLocked();
  }

  void setExportState(json job) override {
    {
      std::lock_guard lk(mutex_);
      // The newest job wins: an older job's late report does not replace it.
      const auto number = [](const json& j) -> long long {
        const std::string id = j.is_object() && j.contains("id") && j["id"].is_string() ? j["id"].get<std::string>() : "";
        return id.size() > 1 ? std::atoll(id.c_str() + 1) : 0;
      };
      if (!exportState_.is_null() && number(job) < number(exportState_)) return;
      exportState_ = std::move(job);
    }
    notifyState();
  }

  void setJobState(json job) override {
    {
      std::lock_guard lk(mutex_);
      const auto number = [](const json& j) -> long long {
        const std::string id = j.is_object() && j.contains("id") && j["id"].is_string() ? j["id"].get<std::string>() : "";
        return id.size() > 1 ? std::atoll(id.c_str() + 1) : 0;
      };
      const long long n = number(job);  // before the move: the assignment's right side is evaluated first
      jobStates_[n] = std::move(job);
      while (jobStates_.size() > kShownJobs) jobStates_.erase(jobStates_.begin());
    }
    notifyState();
  }

  // ---- listeners ----

  uint64_t subscribe(SessionListener listener) override { return listeners_.subscribe(std::move(listener)); }

  void unsubscribe(uint64_t id) override { listeners_.unsubscribe(id); }

  bool waitIdle(std::chrono::milliseconds timeout) const override {
    std::unique_lock lk(mutex_);
    return idleCv_.wait_for(lk, timeout, [&] { return idleLocked(); });
  }

  bool waitForFrame(int frame, std::chrono::milliseconds timeout) const override {
    std::unique_lock lk(mutex_);
    idleCv_.wait_for(lk, timeout, [&] { return live_->frame >= frame || idleLocked() || stop_; });
    return live_->frame >= frame;
  }

 private:
  // ======== the session's thread (and the constructor, before it starts) ========

  // A fresh simulation of setup_ with bound_ at scene time 0; unchanged on failure.
  void buildSimulation() {
    auto sim = makeSimulation<D>(setup_);
    Control<D>* stage = controlStage_;
    controlStage_ = nullptr;
    try {
      if (!bound_.empty()) attachControlStage(*sim, control_.settings);
    } catch (...) {
      controlStage_ = stage;
      throw;
    }
    sim_ = std::move(sim);
  }

  // A control stage over bound_ on `sim` (whose clock starts at timeBase_).
  Control<D>* attachControlStage(Simulation<D>& sim, const ControlSettings& settings) {
    auto c = std::make_unique<Control<D>>(bound_, settings);
    Control<D>* stage = c.get();
    sim.addEffect(std::move(c), "control");
    return controlStage_ = stage;
  }

  int nextFrame() const { return sim_->frame() + 1; }

  std::string createdBy() const { return std::string("flowclip ") + FLOWCLIP_VERSION + " session " + id_; }

  FramePtr makeSnapshot(const FrameStats& fs) const { return snapshotOf<D>(*sim_, setup_.domain, bound_, fs); }

  FrameStats initialStats() const {
    FrameStats fs;
    fs.frame = sim_->frame();
    fs.time = sim_->time();
    fs.particles = sim_->fluid.size();
    fs.boundaryParticles = sim_->boundary.size();
    fs.temporaryParticles =
        size_t(std::count(sim_->fluid.kind.begin(), sim_->fluid.kind.end(), uint8_t(ParticleKind::Temporary)));
    return fs;
  }

  // Rough memory of the simulation: particle arrays, solver and neighbour lists.
  size_t simulationBytes() const {
    const size_t n = sim_->fluid.size();
    const size_t perFluid = 4 * sizeof(Vec<D>) + 5 * sizeof(Real) + 2 + 2 * sizeof(uint32_t) + sizeof(uint16_t);
    const size_t pairs = sim_->search.dynamicNeighbors().pairs();
    return n * perFluid + sim_->boundary.size() * (2 * sizeof(Vec<D>) + sizeof(Real)) +
           pairs * (sizeof(uint32_t) + D * sizeof(Real));
  }

  // With mutex_ held: the counters state() reads.
  void publishCountsLocked() {
    liquid_ = sim_->fluid.size();
    temporary_ =
        size_t(std::count(sim_->fluid.kind.begin(), sim_->fluid.kind.end(), uint8_t(ParticleKind::Temporary)));
    boundary_ = sim_->boundary.size();
    instances_ = bound_.size();
    hasControl_ = controlStage_ != nullptr;
    simBytes_ = simulationBytes();
  }

  // With mutex_ held: what exports and templates recorded from the history
  // need to know of the scene (read by the callers' threads).
  void publishSceneInfoLocked() {
    info_.sceneName = setup_.name;
    info_.particleRadius = double(sim_->particleRadius());
    info_.supportRadius = double(sim_->supportRadius());
    info_.frameRate = 1.0 / sim_->frameDuration();
    info_.phases = setup_.phases;
    info_.phaseMass.clear();
    for (size_t p = 0; p < setup_.phases.size(); ++p) info_.phaseMass.push_back(sim_->particleMass(int(p)));
    info_.domainMin.assign(D, 0);
    info_.domainMax.assign(D, 0);
    for (int d = 0; d < D; ++d) {
      info_.domainMin[size_t(d)] = double(setup_.domain.min[d]);
      info_.domainMax[size_t(d)] = double(setup_.domain.max[d]);
    }
  }

  // With mutex_ held: history cleared, frame 0 (or the current state) recorded and shown.
  void recordInitialFrame() {
    publishSceneInfoLocked();
    history_.clear();
    replay_ = nullptr;
    layered_.reset();  // frame numbers restart: an old layered frame 0 must not match
    layersTried_ = nullptr;
    FramePtr f = makeSnapshot(initialStats());
    live_ = f;
    recordLocked(f);
    publishCountsLocked();
  }

  void recordLocked(const FramePtr& f) {
    history_.append(f);
    fitMemoryLocked();
  }

  // With mutex_ held: the history and the checkpoints within the session's
  // cap, the oldest frames dropped first (the checkpoints hold their own
  // share, checkpointCap).
  void fitMemoryLocked() { history_.fit(options_.historyCapBytes, checkpointFigures_.bytes); }

  static size_t checkpointCap(const SessionOptions& o) { return o.checkpointsEnabled() ? o.historyCapBytes / 4 : 0; }

  void run() {
    if (options_.threads > 0) omp_set_num_threads(options_.threads);
    std::unique_lock lk(mutex_);
    while (!stop_) {
      if (!ops_.empty()) {
        Op op = std::move(ops_.front());
        ops_.pop_front();
        busy_ = true;
        lk.unlock();
        if (op.reset)
          doReset();
        else if (op.layers)
          doLayers();
        else
          doEdit(op);
        lk.lock();
        busy_ = false;
        idleCv_.notify_all();
        continue;
      }
      // Re-simulating stale frames goes first, as fast as possible,
      // whatever the transport says.
      if (resimulatingLocked()) {
        computing_ = true;
        lk.unlock();
        computeFrame(lk);
        continue;
      }
      if (layersDueLocked()) {
        busy_ = true;
        layersOfShownFrame(lk);
        busy_ = false;
        notifying_ = true;
        lk.unlock();
        notifyFrame();
        lk.lock();
        notifying_ = false;
        idleCv_.notify_all();
        continue;
      }
      if (status_ == SessionStatus::Playing && replayPlaying_) {
        replayStep(lk);
        continue;
      }
      if (status_ == SessionStatus::Playing && live_->frame >= playUntil_) {
        // The play range's end (the scene's duration by default).
        status_ = SessionStatus::Paused;
        notifyStateUnlocked(lk);
        continue;
      }
      const bool advancing = status_ == SessionStatus::Playing || status_ == SessionStatus::Stepping;
      if (!advancing) {
        idleCv_.notify_all();
        cv_.wait(lk, [&] {
          return stop_ || !ops_.empty() || status_ == SessionStatus::Playing || status_ == SessionStatus::Stepping ||
                 resimulatingLocked() || layersDueLocked();
        });
        continue;
      }
      if (status_ == SessionStatus::Playing && speed_ > 0 && !paced(lk, speed_)) continue;
      lastStart_ = Clock::now();
      computing_ = true;
      lk.unlock();
      computeFrame(lk);
    }
    // Closing: what is still queued is answered, never applied.
    std::deque<Op> left;
    left.swap(ops_);
    lk.unlock();
    for (Op& op : left)
      if (op.promise) op.promise->set_value(closedResult(op));
  }

  // With mutex_ held: waits until the next frame is due at `fps` frames per
  // wall second; false when woken earlier (re-check everything).
  bool paced(std::unique_lock<std::mutex>& lk, double fps) {
    const auto due = lastStart_ + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1 / fps));
    if (Clock::now() >= due) return true;
    const uint64_t sig = signal_;
    cv_.wait_until(lk, due, [&] { return stop_ || signal_ != sig || !ops_.empty(); });
    return false;
  }

  // With mutex_ held, released around the listeners.
  void notifyStateUnlocked(std::unique_lock<std::mutex>& lk) {
    notifying_ = true;
    lk.unlock();
    notifyState();
    lk.lock();
    notifying_ = false;
    idleCv_.notify_all();
  }

  // Playing from a replayed frame (mutex_ held): the next recorded frame at
  // the playback speed (the scene's frame rate when "as fast as possible":
  // recorded frames cost nothing to show), then live once the simulation's
  // own frame is reached. A stale frame is waited for (re-simulation goes
  // first in the loop).
  void replayStep(std::unique_lock<std::mutex>& lk) {
    const int next = replay_ ? replay_->frame + 1 : live_->frame + 1;
    if (next > playUntil_) {
      status_ = SessionStatus::Paused;
      replayPlaying_ = false;
      notifyStateUnlocked(lk);
      return;
    }
    if (!paced(lk, speed_ > 0 ? speed_ : info_.frameRate)) return;
    lastStart_ = Clock::now();
    if (next >= live_->frame) {
      // The simulation's own frame: live from here (the simulation goes on).
      replayPlaying_ = false;
      replay_ = nullptr;
    } else {
      FramePtr f = history_.find(next);
      if (!f) {
        replayPlaying_ = false;  // dropped by the memory cap: go live
        replay_ = nullptr;
      } else {
        replay_ = f == live_ ? nullptr : f;
        if (!replay_) replayPlaying_ = false;
      }
    }
    if (layersDueLocked()) layersOfShownFrame(lk);  // the frame goes out with its layers
    notifying_ = true;
    lk.unlock();
    notifyFrame();
    notifyState();
    lk.lock();
    notifying_ = false;
    idleCv_.notify_all();
  }

  // Called with mutex_ released; returns with it held.
  void computeFrame(std::unique_lock<std::mutex>& lk) {
    replayLayers_.unpark(*sim_);
    sim_->setFrameLimits({Clock::now() + options_.frameTimeout, &cancel_});
    FrameStats fs;
    try {
      fs = sim_->advanceFrame();
    } catch (const std::exception& e) {
      // A stage that cannot go on (a streamed template frame that no longer
      // reads): the frame fails like an unstable one, the session survives.
      fs = FrameStats{};
      fs.finite = false;
      fs.failure = e.what();
      fs.frame = sim_->frame() + 1;
      fs.time = sim_->time();
    }
    FramePtr snap;
    if (fs.finite) {
      snap = makeSnapshot(fs);
      encodeLayers(fs);
    }
    const bool save = fs.finite && !fs.cancelled && checkpoints_.due(fs.frame);
    lk.lock();
    computing_ = false;
    bool frameChanged = false, stateChanged = false;
    if (fs.cancelled) {
      // Stopped for a reset or for closing: the reset rebuilds the state.
      stepsLeft_ = 0;
      stateChanged = true;
    } else if (!fs.finite) {
      // Never published: the last good frame stays the newest.
      status_ = SessionStatus::Error;
      stepsLeft_ = 0;
      replayPlaying_ = false;
      resimTarget_ = -1;
      errorFrame_ = fs.frame;
      errorMessage_ = failureText(fs) + "; the simulation is paused (reset to go on)";
      stateChanged = true;
    } else {
      const bool resim = fs.frame <= resimTarget_;
      // Between the checkpoint and the first stale frame the frames come out
      // the same: the recorded snapshots stay (no viewer sees a change).
      const FramePtr kept = resim && !history_.stale(fs.frame) ? history_.find(fs.frame) : nullptr;
      if (kept) snap = kept;
      live_ = snap;
      storeLocked(snap);
      publishCountsLocked();
      if (resim) {
        if (fs.frame >= resimTarget_) resimTarget_ = -1;
        // A replaying viewer sees its frame replaced; a live one follows.
        if (kept) {
          frameChanged = false;
        } else if (replay_ && replay_->frame == fs.frame) {
          replay_ = snap;
          frameChanged = true;
        } else {
          frameChanged = replay_ == nullptr;
        }
        // State at most every 100 ms while re-simulating, and at its end.
        const auto now = Clock::now();
        if (resimTarget_ < 0 || now - lastResimState_ >= std::chrono::milliseconds(100)) {
          lastResimState_ = now;
          stateChanged = true;
        }
      } else {
        frameChanged = replay_ == nullptr;
        if (status_ == SessionStatus::Stepping && --stepsLeft_ <= 0) {
          status_ = SessionStatus::Paused;
          stepsLeft_ = 0;
          stateChanged = true;
        }
      }
    }
    if (!frameChanged && !stateChanged && !save) {
      idleCv_.notify_all();
      return;
    }
    notifying_ = true;  // idle only once the listeners have heard of it
    lk.unlock();
    if (frameChanged) notifyFrame();
    // After the frame went out (its latency does not include the save), before
    // the state that lists the checkpoints.
    if (save) {
      saveCheckpoint(fs.frame);
      std::lock_guard g(mutex_);
      publishCheckpointsLocked();
      fitMemoryLocked();
    }
    if (stateChanged) notifyState();
    lk.lock();
    notifying_ = false;
    idleCv_.notify_all();
  }

  // Session thread: the simulation's state now, as the checkpoint of `frame`.
  void saveCheckpoint(int frame) {
    {
      std::lock_guard lk(mutex_);
      checkpoints_.setFocus(replay_ ? replay_->frame : frame);
    }
    StateArchive a;
    sim_->archiveState(a);
    checkpoints_.put(frame, a.bytes());
  }

  // With mutex_ held: records a computed frame (FrameHistory::store) within the cap.
  void storeLocked(const FramePtr& f) {
    history_.store(f);
    fitMemoryLocked();
  }

  // With mutex_ held: what state() and the memory cap read of the checkpoints
  // (the store itself is the session thread's).
  void publishCheckpointsLocked() {
    checkpointFigures_ = checkpoints_.figures();
    checkpointFrames_ = checkpoints_.frames();
  }

  bool resimulatingLocked() const { return resimTarget_ >= 0 && live_->frame < resimTarget_; }

  // The first recorded frame an accepted edit changed is `first`
  // (edit_scope.h): frames from there on become stale, and the simulation,
  // if already past it, goes back to the newest checkpoint before it (frame
  // 0: a fresh build) to re-simulate up to the frame reached before.
  void invalidateFrom(int first) {
    int reached = 0, simFrame = 0;
    {
      std::lock_guard lk(mutex_);
      reached = history_.reached(live_->frame);
      simFrame = live_->frame;
    }
    if (first > reached) return;  // only frames not simulated yet change
    checkpoints_.dropFrom(first);
    if (simFrame >= first) {
      const auto t0 = Clock::now();
      std::vector<uint8_t> archive;
      const int from = checkpoints_.newestAtOrBefore(first - 1, archive);
      bool restored = false;
      if (from > 0) {
        try {
          StateArchive a(archive);
          sim_->archiveState(a);
          restored = true;
        } catch (const StateArchiveError&) {
          checkpoints_.clear();  // not this scene's: rebuild from frame 0 below
        }
      }
      if (!restored) {
        try {
          buildSimulation();
        } catch (const std::exception& e) {
          // The scene built before; should it not now, the session says so
          // and waits for a reset rather than showing frames of another scene.
          std::lock_guard lk(mutex_);
          status_ = SessionStatus::Error;
          errorFrame_ = live_->frame;
          errorMessage_ = std::string("re-simulation could not rebuild the scene: ") + e.what();
          history_.markStaleFrom(first);
          return;
        }
      }
      checkpoints_.noteRestoreMs(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      FramePtr at = makeSnapshot(initialStats());
      std::lock_guard lk(mutex_);
      // The restored frame is the live one (its recorded snapshot is the
      // same frame: before the edit's first change).
      if (FramePtr kept = history_.find(at->frame)) at = kept;
      live_ = at;
      resimFrom_ = at->frame;
    }
    std::lock_guard lk(mutex_);
    if (layered_ && layered_->frame >= first) layered_.reset();  // of the timeline before the edit
    layersTried_ = nullptr;
    history_.markStaleFrom(first);
    resimTarget_ = std::max(resimTarget_, reached);
    if (simFrame < first) resimFrom_ = std::min(resimFrom_ < 0 ? simFrame : resimFrom_, simFrame);
    lastResimState_ = Clock::time_point{};
    publishCheckpointsLocked();
    publishCountsLocked();
    ++signal_;
  }

  void doReset() {
    cancel_ = false;
    replayLayers_.unpark(*sim_);
    std::string failure;
    try {
      buildSimulation();
    } catch (const std::exception& e) {
      failure = e.what();
    }
    checkpoints_.clear();
    {
      std::lock_guard lk(mutex_);
      publishCheckpointsLocked();
      history_.setStaleFrom(INT_MAX);
      resimTarget_ = resimFrom_ = -1;
      replayPlaying_ = false;
      if (failure.empty()) {
        recordInitialFrame();
        status_ = SessionStatus::Paused;
        errorMessage_.clear();
        errorFrame_ = -1;
      } else {
        status_ = SessionStatus::Error;
        errorMessage_ = "reset failed: " + failure;
        errorFrame_ = live_->frame;
      }
      stepsLeft_ = 0;
      replay_ = nullptr;
    }
    if (failure.empty()) {
      FrameStats stats;
      {
        std::lock_guard lk(mutex_);
        stats = live_->stats;
      }
      encodeLayers(stats);
    }
    notifyFrame();
    notifyState();
  }

  // ---- optional layers ----

  void demandLayers(const wire::LayerFlags& layers, int delta) override {
    bool rose = false;
    {
      std::lock_guard lk(mutex_);
      auto change = [&](bool wanted, int& count) {
        if (!wanted) return;
        rose = rose || (delta > 0 && count == 0);
        count = std::max(0, count + delta);
      };
      change(layers.control, layerDemand_[0]);
      change(layers.repulsion, layerDemand_[1]);
      change(layers.boundary, layerDemand_[2]);
      change(layers.speed, layerDemand_[3]);
      if (rose) {
        Op op;
        op.layers = true;
        ops_.push_back(std::move(op));
        ++signal_;
      }
    }
    if (rose) wake();
  }

  std::shared_ptr<const LayeredFrame> layeredFrame() const override {
    std::lock_guard lk(mutex_);
    return layered_;
  }

  // Session thread: encodes the simulation's current state with the layers
  // wanted now, if any (the encoding is the frame's; an encode failure, a
  // non-finite α say, leaves the streams on the plain snapshot).
  void encodeLayers(const FrameStats& stats) {
    wire::LayerFlags want;
    {
      std::lock_guard lk(mutex_);
      want = wantedLayersLocked();
    }
    if (!want.control && !want.repulsion && !want.boundary && !want.speed) return;
    auto out = std::make_shared<LayeredFrame>();
    out->frame = stats.frame;
    out->layers = want;
    try {
      wire::encodeFrame<D>(*sim_, stats, controlStage_, id_, want, layerBuilder_);
    } catch (const std::exception&) {
      return;  // an encode failure, or a streamed template frame that no longer reads
    }
    out->envelope.assign(layerBuilder_.GetBufferPointer(), layerBuilder_.GetBufferPointer() + layerBuilder_.GetSize());
    std::lock_guard lk(mutex_);
    layered_ = std::move(out);
    layersTried_ = nullptr;  // a frame shown before may want its layers again
  }

  // More layers wanted: the frame shown is encoded again (the loop sees it due).
  void doLayers() {
    std::lock_guard lk(mutex_);
    layersTried_ = nullptr;
  }

  // With mutex_ held: the frame viewers see lacks layers a stream wants
  // (and they were not tried for it yet; a stale frame is being replaced).
  bool layersDueLocked() const {
    // Speed alone comes from the recorded velocities (encodeSnapshot).
    const wire::LayerFlags want = wantedLayersLocked();
    if (!want.control && !want.repulsion && !want.boundary) return false;
    const FramePtr& shown = replay_ ? replay_ : live_;
    if (!shown || shown == layersTried_ || history_.stale(shown->frame)) return false;
    if (!layered_ || layered_->frame != shown->frame) return true;
    const wire::LayerFlags& has = layered_->layers;
    return (want.control && !has.control) || (want.repulsion && !has.repulsion) || (want.boundary && !has.boundary);
  }

  wire::LayerFlags wantedLayersLocked() const {
    wire::LayerFlags want;
    want.control = layerDemand_[0] > 0;
    want.repulsion = layerDemand_[1] > 0;
    want.boundary = layerDemand_[2] > 0;
    want.speed = layerDemand_[3] > 0;
    return want;
  }

  // With mutex_ held (released meanwhile): encodes the layers of the frame
  // shown: the live one from the simulation as it is, a recorded one by
  // taking the simulation back to it (replay_layers.h).
  void layersOfShownFrame(std::unique_lock<std::mutex>& lk) {
    const FramePtr shown = replay_ ? replay_ : live_;
    const bool live = !replay_;
    layersTried_ = shown;
    lk.unlock();
    try {
      if (live) {
        replayLayers_.unpark(*sim_);
        encodeLayers(shown->stats);
      } else if (replayLayers_.goTo(
                     shown->frame, checkpoints_, [this]() -> Simulation<D>& { return *sim_; },
                     [this] { buildSimulation(); }, {Clock::now() + options_.frameTimeout, &cancel_}) ==
                 ReplayLayers<D>::Result::Ready) {
        encodeLayers(shown->stats);
      }
    } catch (const std::exception&) {
      // A checkpoint that does not load or a scene that does not build: the
      // frame is shown without its layers; the live state is still parked.
    }
    lk.lock();
  }

  void doEdit(Op& op) {
    replayLayers_.unpark(*sim_);  // edits apply to the live state
    EditResult r;
    r.id = op.id;
    r.kind = op.edit.kind;
    r.instance = op.edit.instance;
    try {
      const double oldRate = info_.frameRate;
      const int first = applyEdit(op.edit, r);
      r.accepted = true;
      r.frame = first == INT_MAX ? nextFrame() : first;
      if (first == 0)
        restartFromFrameZero(oldRate);
      else
        invalidateFrom(first);
    } catch (const SceneError& e) {
      r.path = e.path;
      r.message = e.what();
    } catch (const std::exception& e) {
      r.message = e.what();
    }
    {
      std::lock_guard lk(mutex_);
      pendingKinds_.erase(r.id);
      results_[r.id] = r;
      while (results_.size() > kKeptResults) results_.erase(results_.begin());
      if (r.accepted) {
        sceneShared_ = scene_;
        publishCountsLocked();
        publishSceneInfoLocked();
      }
    }
    op.promise->set_value(r);
    listeners_.notify([&] { return r; },
                      [](const SessionListener& l, const EditResult& result) {
                        if (l.edit) l.edit(result);
                      });
    if (r.accepted) notifyState();
  }

  size_t findInstance(const std::string& name) const {
    std::vector<std::string> names;
    for (size_t i = 0; i < control_.instances.size(); ++i) {
      if (control_.instances[i].name == name) return i;
      names.push_back(control_.instances[i].name);
    }
    throw SceneError("name", "no instance named '" + name + "' (the scene has " +
                                 json_access::joinNames(names, "none") + ")");
  }

  // Validates fully, then applies; throws (changing nothing) when invalid.
  // Returns the first frame the edit changes (0: every frame, the
  // simulation rebuilt; INT_MAX: none).
  int applyEdit(const Edit& e, EditResult& r) {
    if (e.kind == EditKind::Settings) {
      applySettings(e.payload);
      return 0;
    }
    json candidate = scene_;
    json& list = candidate["instances"];
    if (!list.is_array()) list = json::array();
    size_t index = 0;
    switch (e.kind) {
      case EditKind::AddInstance:
        if (!e.payload.is_object())
          throw SceneError("instance", std::string("must be an instance object, got ") + e.payload.type_name());
        index = list.size();
        list.push_back(e.payload);
        break;
      case EditKind::UpdateInstance:
        if (!e.payload.is_object())
          throw SceneError("patch", std::string("must be a JSON merge patch object, got ") + e.payload.type_name());
        index = findInstance(e.instance);
        list[index].merge_patch(e.payload);
        break;
      case EditKind::RemoveInstance:
        index = findInstance(e.instance);
        list.erase(list.begin() + long(index));
        break;
      case EditKind::Settings:
        break;
    }
    SceneControl<D> control = parseSceneControl<D>(candidate, setup_.phases);
    if (e.kind != EditKind::RemoveInstance) r.instance = control.instances.at(index).name;
    std::vector<BoundInstance<D>> bound;
    if (!control.instances.empty()) bound = bindInstances<D>(control.instances, db_);
    const InstanceSpec<D>* before = e.kind == EditKind::AddInstance ? nullptr : &bound_.at(index).spec;
    const InstanceSpec<D>* after = e.kind == EditKind::RemoveInstance ? nullptr : &bound.at(index).spec;
    const int first = firstAffectedFrame(firstAffectedTime<D>(before, after), sim_->frameDuration());
    // Valid: apply. Adding the first instance adds the control stage; once
    // there it stays (with no instances it only retires temporary particles).
    if (controlStage_) {
      controlStage_->setInstances(bound);
      bound_ = std::move(bound);
    } else if (!bound.empty()) {
      std::swap(bound_, bound);
      try {
        attachControlStage(*sim_, control.settings);
      } catch (...) {
        std::swap(bound_, bound);
        throw;
      }
    }
    control_ = std::move(control);
    scene_ = canonicalScene<D>(setup_, control_);
    return first;
  }

  // A new simulation from the patched settings at frame 0 (every recorded
  // frame is then stale: restartFromFrameZero).
  void applySettings(const json& payload) {
    if (!payload.is_object())
      throw SceneError("", std::string("a settings edit must be an object, got ") + payload.type_name());
    json candidate = scene_;
    for (const auto& [k, v] : payload.items()) {
      if (std::find(settingsEditKeys().begin(), settingsEditKeys().end(), k) == settingsEditKeys().end())
        throw SceneError(k, "cannot be changed by a settings edit (it may change " + json_access::joinNames(settingsEditKeys()) + ")");
      if (!v.is_object())
        throw SceneError(k, std::string("must be an object (a merge patch of the scene's \"") + k + "\"), got " +
                                v.type_name());
      json& target = candidate[k];
      const auto m = v.find("method");
      if (k == "solver" && m != v.end() && m->is_string() && target.is_object() && target.value("method", "") != *m) {
        // Another method: its own parameters, not the old method's.
        json solver = json::object();
        for (const auto& [pk, pv] : v.items())
          if (!pv.is_null()) solver[pk] = pv;
        target = solver;
      } else {
        target.merge_patch(v);
      }
    }
    SimulationSetup<D> setup = parseScene<D>(candidate);
    SceneControl<D> control = parseSceneControl<D>(candidate, setup.phases);
    std::unique_ptr<Simulation<D>> sim = makeSimulation<D>(setup);
    Control<D>* oldStage = controlStage_;
    if (oldStage) {
      try {
        attachControlStage(*sim, control.settings);
      } catch (...) {
        controlStage_ = oldStage;
        throw;
      }
    }
    sim_ = std::move(sim);
    setup_ = std::move(setup);
    control_ = std::move(control);
    scene_ = canonicalScene<D>(setup_, control_);
  }

  // After a settings edit (the simulation rebuilt at frame 0): every
  // recorded frame is stale, frame 0 replaced at once, and the frames up to
  // the one reached re-simulated (at the same scene time when the frame
  // rate changed, the history then restarting from frame 0).
  void restartFromFrameZero(double oldFrameRate) {
    checkpoints_.clear();
    FramePtr zero = makeSnapshot(initialStats());
    std::lock_guard lk(mutex_);
    publishCheckpointsLocked();
    const int reached = history_.reached(live_->frame);
    const double newRate = 1.0 / sim_->frameDuration();
    int target = reached;
    if (std::abs(newRate - oldFrameRate) > 1e-9 * oldFrameRate) {
      target = int(std::lround(double(reached) / oldFrameRate * newRate));
      history_.clear();
      replay_ = nullptr;
      replayPlaying_ = false;
      recordLocked(zero);
      endFrame_ = sceneEndFrame();
      playUntil_ = std::min(playUntil_, endFrame_);
    } else {
      storeLocked(zero);
      history_.setStaleFrom(1);
      if (replay_ && replay_->frame == 0) replay_ = zero;
    }
    layered_.reset();
    layersTried_ = nullptr;
    live_ = zero;
    resimFrom_ = 0;
    resimTarget_ = target > 0 ? target : -1;
    lastResimState_ = Clock::time_point{};
    publishCountsLocked();
    ++signal_;
  }

  // The frame playback stops at by default: the scene's duration.
  int sceneEndFrame() const {
    return std::max(1, int(std::lround(setup_.duration * (1.0 / sim_->frameDuration()))));
  }

  // ======== shared state (mutex_ held) ========

  bool idleLocked() const {
    return !computing_ && !busy_ && !notifying_ && ops_.empty() && !resimulatingLocked() && !layersDueLocked() &&
           (status_ == SessionStatus::Paused || status_ == SessionStatus::Error);
  }

  std::string errorText() const {
    return "session '" + id_ + "' is in the error state: " + errorMessage_;
  }

  EditResult closedResult(const Op& op) const {
    EditResult r;
    r.id = op.id;
    r.kind = op.edit.kind;
    r.instance = op.edit.instance;
    r.message = "the session was closed before the edit was applied";
    return r;
  }

  json stateLocked() const {
    const FramePtr shown = replay_ ? replay_ : live_;
    const size_t historyBytes = history_.bytes();
    const size_t frameBytes = live_->byteSize;
    json j = {{"id", id_},
              {"name", name_},
              {"dimension", D},
              {"status", statusName(status_)},
              {"frame", live_->frame},
              {"time", live_->time},
              {"playback_speed", speed_},
              {"shown", {{"live", replay_ == nullptr}, {"frame", shown->frame}}},
              {"history", history_.summary(options_.historyCapBytes)},
              {"stats", frameStatsToJson(live_->stats, hasControl_)},
              {"particles", {{"liquid", liquid_ - temporary_}, {"temporary", temporary_}, {"boundary", boundary_}}},
              {"instances", instances_},
              {"pending_edits", pendingKinds_.size()},
              {"steps_left", stepsLeft_},
              {"computing", computing_},
              {"memory",
               {{"history_bytes", historyBytes},
                {"frame_bytes", frameBytes},
                {"history_bytes_per_1000_frames", frameBytes * 1000},
                {"simulation_bytes", simBytes_},
                {"total_bytes", historyBytes + simBytes_}}}};
    if (status_ == SessionStatus::Error) j["error"] = {{"message", errorMessage_}, {"frame", errorFrame_}};
    j["end_frame"] = endFrame_;
    j["play_until"] = playUntil_;
    if (!exportState_.is_null()) j["export"] = exportState_;
    if (!jobStates_.empty()) {
      j["jobs"] = json::array();
      for (const auto& [n, job] : jobStates_) j["jobs"].push_back(job);
    }
    j["replaying"] = replayPlaying_;
    j["memory"]["checkpoint_bytes"] = checkpointFigures_.bytes;
    j["memory"]["total_bytes"] = historyBytes + simBytes_ + checkpointFigures_.bytes;
    j["cache"] = cacheLocked();
    return j;
  }

  // {valid: [[a, b]], stale: [[a, b]], simulating: null | {from, to, frame},
  //  reached, checkpoints: [...], checkpoint_every, checkpoint_bytes,
  //  checkpoint_raw_bytes, checkpoint_save_ms, checkpoint_restore_ms}
  json cacheLocked() const {
    const int reached = history_.reached(live_->frame);
    json simulating = nullptr;
    if (resimulatingLocked())
      simulating = {{"from", resimFrom_ < 0 ? live_->frame : resimFrom_}, {"to", resimTarget_}, {"frame", live_->frame}};
    return {{"valid", history_.validRanges()},
            {"stale", history_.staleRanges()},
            {"simulating", simulating},
            {"reached", reached},
            {"checkpoints", checkpointFrames_},
            {"checkpoint_every", checkpoints_.every()},
            {"checkpoint_dense", checkpoints_.dense()},
            {"checkpoint_bytes", checkpointFigures_.bytes},
            {"checkpoint_raw_bytes", checkpointFigures_.rawBytes},
            {"checkpoint_cap", checkpoints_.capBytes()},
            {"checkpoint_save_ms", checkpointFigures_.saveMs},
            {"checkpoint_restore_ms", checkpointFigures_.restoreMs}};
  }

  // ======== notification (no session lock held) ========

  void wake() {
    cv_.notify_all();
    idleCv_.notify_all();
  }

  // The latest slot is read under the listeners' lock, so that the last
  // notification always carries the current slot (calls may repeat a frame).
  void notifyFrame() {
    listeners_.notify([&] { return latestFrame(); },
                      [](const SessionListener& l, const FramePtr& f) {
                        if (l.frame) l.frame(f);
                      });
  }

  void notifyState() {
    listeners_.notify([&] { return state(); },
                      [](const SessionListener& l, const json& s) {
                        if (l.state) l.state(s);
                      });
  }

  // ---- immutable ----
  const std::string id_;
  std::string name_;
  TemplateDatabase& db_;
  const SessionOptions options_;

  // ---- owned by the session's thread ----
  json scene_;
  SimulationSetup<D> setup_;
  SceneControl<D> control_;
  std::vector<BoundInstance<D>> bound_;
  std::unique_ptr<Simulation<D>> sim_;
  Control<D>* controlStage_ = nullptr;
  CheckpointStore checkpoints_;
  ReplayLayers<D> replayLayers_;  // a recorded frame's layers (the live state parked meanwhile)
  Clock::time_point lastStart_{};

  // ---- shared, under mutex_ ----
  mutable std::mutex mutex_;
  std::condition_variable cv_;               // wakes the session's thread
  mutable std::condition_variable idleCv_;   // wakes waitIdle / waitForFrame
  bool stop_ = false;
  std::atomic<bool> cancel_{false};  // stops the frame in progress (Simulation::FrameLimits)
  SessionStatus status_ = SessionStatus::Paused;
  int stepsLeft_ = 0;
  double speed_ = 0;
  uint64_t signal_ = 0;      // bumped by every command (ends a paced wait)
  bool computing_ = false;   // a frame is in progress
  bool busy_ = false;        // an edit or reset is being applied (and announced)
  bool notifying_ = false;   // listeners are hearing of the last frame
  std::deque<Op> ops_;
  std::map<uint64_t, EditKind> pendingKinds_;  // submitted, not yet answered
  int layerDemand_[4] = {0, 0, 0, 0};           // streams wanting control, repulsion, boundary, speed
  std::shared_ptr<const LayeredFrame> layered_;  // the newest frame with those layers
  FramePtr layersTried_;  // the frame shown whose layers were last tried (not again)
  flatbuffers::FlatBufferBuilder layerBuilder_{1 << 16};  // session thread only
  uint64_t lastEditId_ = 0;
  std::map<uint64_t, EditResult> results_;
  FrameHistory history_;  // recorded frames and their stale range
  FramePtr live_;            // newest simulated frame
  FramePtr replay_;          // frame selected by seek (null: live)
  bool replayPlaying_ = false;  // playing through recorded frames (replay_ advances)
  int endFrame_ = 1;         // the scene's duration in frames: where play stops by default
  int playUntil_ = 1;        // where the current play stops
  // Re-simulation runs the simulation from resimFrom_ up to resimTarget_
  // (-1: not re-simulating), replacing the stale frames.
  int resimFrom_ = -1, resimTarget_ = -1;
  Clock::time_point lastResimState_{};
  CheckpointStore::Figures checkpointFigures_;
  std::vector<int> checkpointFrames_;
  json sceneShared_;
  RecordedScene info_;
  std::string errorMessage_;
  static constexpr size_t kShownJobs = 8;
  std::map<long long, json> jobStates_;  // the newest render jobs (setJobState), by number
  json exportState_;  // the newest surface export job (setExportState), null before one
  int errorFrame_ = -1;
  size_t liquid_ = 0, temporary_ = 0, boundary_ = 0, instances_ = 0, simBytes_ = 0;
  bool hasControl_ = false;

  // ---- listeners ----
  SessionListeners listeners_;

  std::thread thread_;
};

}  // namespace

std::unique_ptr<Session> createSession(const std::string& id, const std::string& name, const json& scene,
                                       TemplateDatabase& database, const SessionOptions& options) {
  const int d = sceneDimension(scene);
  if (d == 2) return std::make_unique<SessionImpl<2>>(id, name, scene, database, options);
  return std::make_unique<SessionImpl<3>>(id, name, scene, database, options);
}

}  // namespace fc::service
