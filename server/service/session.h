#pragma once
// One simulation session: a scene simulated on its own
// thread, driven from any thread by transport commands and edits, recording
// every frame in a quantized replay history and publishing the newest frame
// for streaming. No networking here: REST and WebSocket sit on top.
//
// Threads. Every public method may be called from any thread. The session's
// own thread owns the simulation: it computes frames (OpenMP inside the
// step), applies queued edits and resets at frame boundaries, records and
// publishes frames. A paused session sits at a frame boundary, so edits sent
// to it are applied at once (the frame they take effect in is the next one
// computed).
//
// Listeners (subscribe) are called without any session lock held, serialised
// with each other (one call at a time per session), from the session's thread
// (frames, edit results, state changes it causes) or from the thread that
// called a transport method (play, pause, step, seek, speed). They must
// return quickly and never block: a streaming client keeps the FramePtr or
// just notes that a frame is ready and reads latestFrame() when it can send
// (a slow consumer simply gets the newest frame, there is no queue). A
// listener may call any method of the session except waitIdle/waitForFrame
// (which wait for the listeners) and destroying it.
// After unsubscribe() returns, the listener is never called again.
//
// Frame numbers are the scene's: frame 0 is the initial state, frame n ends
// at scene time n / frame_rate (while the frame rate is unchanged).
#include "io/scene.h"
#include "io/stats_json.h"
#include "io/template_database.h"
#include "service/edit.h"
#include "service/frame_encoding.h"
#include "service/frame_snapshot.h"
#include "sph/simulation.h"

#include <nlohmann/json.hpp>

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace fc::service {

// What Session::exportHistory wrote.
struct HistoryExport {
  std::string h5Path, xdmfPath;
  int frames = 0;               // frames written
  uint64_t particleRows = 0;    // particle rows over all frames
  uint64_t bytes = 0;           // size of both files on disk
};


struct EditTicket {
  uint64_t id = 0;
  std::shared_future<EditResult> result;
};

// The newest frame encoded with optional layers (Session::demandLayers).
struct LayeredFrame {
  int frame = 0;
  wire::LayerFlags layers;            // layers encoded (Frame.layers may hold fewer: none without instances)
  std::vector<uint8_t> envelope;      // a finished Envelope{Frame}
};

// ---- the session -------------------------------------------------------------

enum class SessionStatus { Paused, Playing, Stepping, Error };
const char* statusName(SessionStatus status);  // "paused", "playing", "stepping", "error"

struct SessionOptions {
  size_t historyCapBytes = size_t(512) << 20;  // replay history; oldest frames dropped beyond it
  double playbackSpeed = 0;                     // frames per wall second while playing; 0: as fast as possible
  int threads = 0;                              // OpenMP threads of this session's step (0: the default)
  // The watchdog: a frame running longer puts the session in its error
  // state (the substep limit is the scene's settings.max_substeps_per_frame).
  std::chrono::milliseconds frameTimeout{120000};
  // Checkpoints (service/checkpoints.h): the whole simulation state every
  // this many frames (0: none; an edit then re-simulates from frame 0),
  // within a quarter of historyCapBytes, compressed where that saves a tenth.
  int checkpointEvery = kDefaultCheckpointEvery;
  // Dense: the frames between the every-K checkpoints are kept too, as
  // memory allows (the farthest from the playhead dropped first), so that
  // an edit's first changed frame is one frame's compute away.
  bool denseCheckpoints = true;
  bool compressCheckpoints = true;
  static constexpr int kDefaultCheckpointEvery = 10;
  bool checkpointsEnabled() const { return checkpointEvery > 0; }
};

struct SessionListener {
  std::function<void(const FramePtr&)> frame;            // the latest-frame slot changed (new frame or seek)
  std::function<void(const EditResult&)> edit;           // an edit was accepted or rejected
  std::function<void(const nlohmann::json&)> state;      // status or shown frame changed: state()
};

// Transport that cannot run (play or step in the error state, step(0)).
struct SessionError : std::runtime_error {
  using std::runtime_error::runtime_error;
};
// The edit queue is full (kMaxPendingEdits): try again once results arrive.
struct SessionOverloaded : SessionError {
  using SessionError::SessionError;
};
// An export or a template recording asked for frames an edit made stale
// (the session is re-simulating them): try again once state "cache" has no
// stale range.
struct StaleFramesError : SessionError {
  using SessionError::SessionError;
};

class Session {
 public:
  virtual ~Session() = default;  // stops the thread (after the frame in progress)

  virtual const std::string& id() const = 0;
  virtual const std::string& name() const = 0;
  virtual int dimension() const = 0;

  // Transport. play(until): frames one after another at the playback speed
  // up to frame `until` (-1: the scene's duration, state "end_frame"), then
  // paused; from a replayed frame it plays the recorded frames first (at
  // the playback speed, the scene's frame rate when 0) and simulates on
  // from the simulation's own frame. pause(): stops after the frame in progress. step(n): n more frames as
  // fast as possible, then paused (n > 0). reset(): queued like an edit;
  // rebuilds the simulation from the scene as edited so far, clears the
  // history and any error, frame 0, paused. setPlaybackSpeed(fps): 0 = as
  // fast as possible, else at most fps frames per wall second (>= 0). play
  // and step throw SessionError in the error state (reset first).
  virtual void play(int until = -1) = 0;
  virtual void pause() = 0;
  virtual void step(int frames) = 0;
  virtual void reset() = 0;
  virtual void setPlaybackSpeed(double framesPerSecond) = 0;
  // Replay: pauses and shows the recorded frame (latestFrame() returns it,
  // frame listeners get it) without touching the simulation, which goes on
  // from its newest frame at the next play or step. Throws std::out_of_range
  // if the frame is not in the history.
  virtual FramePtr seek(int frame) = 0;

  // Edits: queued, validated and applied by the session's thread at the next
  // frame boundary, in order. A rejected edit changes nothing. An accepted
  // one makes the recorded frames it changes stale (from the first frame
  // whose simulation reads a scene time it changed: edit_scope.h; a
  // settings edit: every frame) and the session re-simulates them by
  // itself from the newest checkpoint before them, up to the frame reached,
  // whatever the transport says (paused stays paused, playing goes on
  // after). A live viewer sees the re-simulated frames as they come; a
  // replaying one its frame replaced. state()["cache"] says which frames
  // are valid, stale and being simulated. At most
  // kMaxPendingEdits wait at once; submit throws SessionOverloaded beyond.
  static constexpr size_t kMaxPendingEdits = 256;
  virtual EditTicket submit(Edit edit) = 0;
  // The result of an edit, once known (the last 1024 are kept).
  virtual std::optional<EditResult> editResult(uint64_t id) const = 0;
  // The kind of an edit submitted and not yet answered (queued or being
  // applied); nothing for an id never handed out or already answered.
  virtual std::optional<EditKind> pendingEdit(uint64_t id) const = 0;

  // The frame to show: the simulation's own frame (during a re-simulation
  // the frame it has reached), or the recorded frame a seek selected while
  // replaying.
  virtual FramePtr latestFrame() const = 0;
  // A recorded frame (nullptr when not, or no longer, in the history).
  virtual FramePtr frame(int frame) const = 0;
  // The whole history, oldest first (shared snapshots, no copies).
  virtual std::vector<FramePtr> history() const = 0;

  // Writes the recorded frames firstFrame..lastFrame (-1: the oldest / the
  // newest kept; frames of the range no longer kept are skipped) to h5Path
  // in the frame-export layout of `flowclip run --export`
  // (docs/export-format.md) without density, pressure and id, which the
  // history does not hold, with positions and velocities as recorded
  // (16-bit quantized); plus an XDMF sidecar (h5Path with the extension
  // .xdmf) that opens the frames in ParaView as a time series. Both files
  // are written under temporary names and moved to their names together
  // (replacing existing ones) only when complete: a failure leaves neither
  // a partial file nor a changed one. Runs on the caller's thread; the
  // session goes on meanwhile. Throws std::invalid_argument if
  // firstFrame > lastFrame or the range holds no recorded frame,
  // StaleFramesError if the range holds stale frames (an edit changed them,
  // the session is re-simulating them), and std::runtime_error naming the
  // path if a file cannot be written.
  virtual HistoryExport exportHistory(const std::string& h5Path, int firstFrame = -1, int lastFrame = -1) const = 0;

  // Records a template from a region of the history over a frame range:
  // template frame k is history frame firstFrame + k; it holds the liquid
  // particles (kinds Liquid and Temporary) whose recorded position lies in the closed box
  // [regionMin, regionMax] (world coordinates, which become the template's
  // own space), with their recorded positions, velocities and phases and the
  // mass the scene gives their phase. The header is the recipe capture's
  // (io/recipe.h): frame rate, particle and support radius of the scene,
  // rest density of its first phase, the region; the recipe is the session's
  // scene (sceneJson()). Written into db's directory as NAME.h5 as
  // recordRecipe writes templates (publishTemplate). Runs on the caller's
  // thread. Throws DatabaseError (invalid name; the template exists and
  // !force), std::invalid_argument (region: D finite values each with min <
  // max, the message naming region_min or region_max; firstFrame >
  // lastFrame; no liquid in the region; frames recorded at another frame
  // rate than the scene's current one), std::out_of_range naming the first
  // frame of the range not in the history, StaleFramesError if the range
  // holds stale frames, TemplateError on write failures
  // (no file left behind). Returns db.entry(name).
  virtual TemplateEntry recordTemplate(TemplateDatabase& db, const std::string& name,
                                       const std::vector<double>& regionMin, const std::vector<double>& regionMax,
                                       int firstFrame, int lastFrame, bool force) const = 0;

  // Optional frame layers (control particles with α, repulsion particles,
  // boundary particles) exist only while the simulation is at that frame,
  // so they are never in the history. While any stream wants a layer
  // (demandLayers(+1)), the session's thread encodes each new frame once,
  // with the union of the wanted layers, as a complete Envelope{Frame}
  // (wire::encodeFrame); streams send those bytes instead of encoding the
  // snapshot. A rise in demand re-encodes the current frame at once (a
  // paused session shows the layer without stepping). Replayed frames have
  // no layers.
  virtual void demandLayers(const wire::LayerFlags& layers, int delta) = 0;
  // The newest frame with the demanded layers (nullptr: none demanded yet).
  virtual std::shared_ptr<const LayeredFrame> layeredFrame() const = 0;

  // The scene with every accepted edit: sceneToJson + sceneControlToJson,
  // every key written; parseScene/parseSceneControl read it back.
  virtual nlohmann::json sceneJson() const = 0;
  // {id, name, dimension, status, frame, time, playback_speed,
  //  shown: {live, frame}, history: {first, last, frames, bytes, cap, dropped},
  //  stats (last frame's), error: {message, frame} (error state only),
  //  particles: {liquid, temporary, boundary}, instances, pending_edits,
  //  steps_left, computing (a frame is being simulated: after pause() until
  //  it ends), memory: {history_bytes, frame_bytes, history_bytes_per_1000_frames,
  //  simulation_bytes, checkpoint_bytes, total_bytes}, end_frame, play_until,
  //  replaying, cache: {valid, stale (inclusive frame ranges), simulating:
  //  null | {from, to, frame}, reached, checkpoints, checkpoint_every,
  //  checkpoint_bytes, checkpoint_raw_bytes, checkpoint_cap,
  //  checkpoint_save_ms, checkpoint_restore_ms}}
  virtual nlohmann::json state() const = 0;
  // The newest surface export job of this session's history
  // (service/surface_jobs.h), shown as state "export" and sent to the
  // stream's clients with every change.
  virtual void setExportState(nlohmann::json job) = 0;
  // A render job of this session's scene (service/render_jobs.h): the
  // newest few are shown as state "jobs" (oldest first) and sent to the
  // stream's clients with every change.
  virtual void setJobState(nlohmann::json job) = 0;
  virtual SessionStatus status() const = 0;
  // The simulation's frame number (not the shown one; during a
  // re-simulation the frame it has reached, state "cache.reached" the newest).
  virtual int currentFrame() const = 0;

  virtual uint64_t subscribe(SessionListener listener) = 0;
  virtual void unsubscribe(uint64_t id) = 0;

  // Waits until the session is paused (or in error) with no edit or reset
  // pending, no re-simulation running, no frame in progress and the listeners told of the last frame
  // computed (its own calls; transport calls notify on the caller's thread).
  // false on timeout.
  virtual bool waitIdle(std::chrono::milliseconds timeout) const = 0;
  // Waits until frame `frame` has been simulated, or the session stops
  // advancing (paused with nothing pending, or error). true iff reached.
  virtual bool waitForFrame(int frame, std::chrono::milliseconds timeout) const = 0;
};

// Validates the scene (parseScene, parseSceneControl, bindInstances against
// `database`), builds the simulation, records frame 0 and starts the
// session's thread, paused. Throws SceneError naming the key path of what is
// wrong. `database` must outlive the session. An empty name takes the
// scene's.
std::unique_ptr<Session> createSession(const std::string& id, const std::string& name, const nlohmann::json& scene,
                                       TemplateDatabase& database, const SessionOptions& options = {});

}  // namespace fc::service
