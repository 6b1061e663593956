#pragma once
// The REST API (proto/openapi.yaml) as plain request → response functions,
// with no networking: service/http_server.cpp (Boost.Beast) feeds it parsed
// requests, tests can call it directly. rest_api.cpp holds the route table,
// the dispatch and the sessions; the handlers are in one rest_*.cpp per
// resource (named at each group below).
//
// The ServiceHub owns the sessions and the template database. Sessions are
// shared: a WebSocket stream keeps its session alive until it notices the
// deletion (onSessionDeleted), so DELETE frees a session's memory as soon as
// its streams have closed.
#include "io/template_database.h"
#include "service/frame_encoding.h"
#include "service/session.h"

#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace fc::service {

class RecipeJobs;
class RenderJobs;
class SurfaceJobs;

struct HttpRequest {
  std::string method;                          // "GET", "POST", ...
  std::string path;                            // percent-encoded, without the query
  std::string query;                           // after '?', raw
  std::map<std::string, std::string> headers;  // lower-case names
  std::string body;
  std::string header(const std::string& lowerName) const {
    auto it = headers.find(lowerName);
    return it == headers.end() ? std::string() : it->second;
  }
};

struct HttpResponse {
  int status = 200;
  std::string contentType = "application/json";
  std::string body;
  std::vector<std::pair<std::string, std::string>> headers;
};

// An error with its HTTP status and machine-readable code, answered as
// {"error": {"status", "code", "message", "path"}}.
struct ApiError : std::runtime_error {
  ApiError(int status, std::string message, std::string path = {});
  int status;
  std::string path;
};
HttpResponse errorResponse(int status, const std::string& message, const std::string& path = {}) noexcept;
const char* errorCode(int status);  // "bad_request", "not_found", ...

struct ServiceOptions {
  std::string templatesDir = "templates";
  size_t templateMemoryBytes = size_t(kDefaultTemplateMemoryMB * 1024 * 1024);  // TemplateDatabase's budget
  std::string scenesDir = "scenes";
  std::string exportsDir = "exports";
  // Recipes the editor can record (service/recipe_jobs.h); "": none.
  std::string recipesDir;
  // OpenMP threads of a recording (0: half the CPUs, at least 1), so that
  // sessions keep cores of their own while one records.
  int recordThreads = 0;
  // The accuracy presets (draft, preview, final) that `flowclip bench
  // accuracy` chose from its Pareto front, with their measured figures.
  std::string presetsFile = "bench/accuracy/presets.json";
  // Render jobs (service/render_jobs.h): their directory, flowclip-batch
  // ("": none, POST /api/jobs answers 503), the flowclip executable the
  // tasks run, and where: a Dask scheduler's address or, when "", a
  // LocalCluster of jobWorkers processes.
  std::string jobsDir;  // "": exportsDir/jobs
  std::string batchCommand;
  std::string batchBinary;
  std::string scheduler;
  int jobWorkers = 1;
  int maxSessions = 8;
  size_t historyCapBytes = size_t(256) << 20;  // per session; a create request may ask for less, never more
  int maxThreads = 0;                          // per session's step; a request may ask for fewer (0: the CPUs)
  // The watchdog's limit on one frame's wall time: a session whose frame
  // runs longer goes to its error state (SessionOptions::frameTimeout).
  std::chrono::milliseconds frameTimeout{120000};
  // How long an edit request waits for the session to apply it before
  // answering 202 (pending); short, so that a slow frame never holds the
  // REST workers.
  std::chrono::milliseconds editWait{3000};
  // WebSocket streams: a client that takes longer than streamWriteStall to
  // accept one message (it stopped reading) is disconnected; one that
  // answers no keep-alive ping within streamIdleTimeout is dropped; a close
  // handshake not completed within streamCloseGrace is cut.
  std::chrono::milliseconds streamWriteStall{20000};
  std::chrono::milliseconds streamIdleTimeout{60000};
  std::chrono::milliseconds streamCloseGrace{5000};
};

class ServiceHub {
 public:
  explicit ServiceHub(ServiceOptions options);
  ~ServiceHub();  // stops every session

  HttpResponse handle(const HttpRequest& request);

  // A live session (nullptr if none has that id).
  std::shared_ptr<Session> session(const std::string& id) const;
  // Called once when the session is deleted (or at once if it does not
  // exist); the returned id cancels it.
  uint64_t onSessionDeleted(const std::string& id, std::function<void()> callback);
  void cancelOnSessionDeleted(uint64_t hook);

  size_t sessionCount() const;
  // Takes a session made elsewhere (benchmarks, tests): listed and served
  // like the others under its id(). Throws ApiError 409 if the id is taken.
  void adoptSession(std::shared_ptr<Session> session);
  const ServiceOptions& options() const { return options_; }
  TemplateDatabase& templates() { return database_; }

  // The route table: what the server answers, for the 405 Allow header and
  // the docs. {name} segments match one percent-decoded path segment.
  struct Route {
    const char* method;
    const char* pattern;
    HttpResponse (ServiceHub::*handler)(const HttpRequest&, const std::vector<std::string>& params);
  };
  static const std::vector<Route>& routes();

 private:
  using Params = std::vector<std::string>;
  // rest_server_info.cpp
  HttpResponse health(const HttpRequest&, const Params&);
  HttpResponse parameters(const HttpRequest&, const Params&);
  HttpResponse presets(const HttpRequest&, const Params&);
  // rest_templates.cpp
  HttpResponse listTemplates(const HttpRequest&, const Params&);
  HttpResponse getTemplate(const HttpRequest&, const Params&);
  HttpResponse deleteTemplate(const HttpRequest&, const Params&);
  HttpResponse templatePreview(const HttpRequest&, const Params&);
  HttpResponse recordTemplate(const HttpRequest&, const Params&);
  // rest_scenes.cpp
  HttpResponse listScenes(const HttpRequest&, const Params&);
  HttpResponse getScene(const HttpRequest&, const Params&);
  HttpResponse saveScene(const HttpRequest&, const Params&);
  // rest_sessions.cpp
  HttpResponse listSessions(const HttpRequest&, const Params&);
  HttpResponse createSession(const HttpRequest&, const Params&);
  HttpResponse getSession(const HttpRequest&, const Params&);
  HttpResponse deleteSession(const HttpRequest&, const Params&);
  HttpResponse sessionScene(const HttpRequest&, const Params&);
  HttpResponse listInstances(const HttpRequest&, const Params&);
  HttpResponse getInstance(const HttpRequest&, const Params&);
  HttpResponse addInstance(const HttpRequest&, const Params&);
  HttpResponse patchInstance(const HttpRequest&, const Params&);
  HttpResponse removeInstance(const HttpRequest&, const Params&);
  HttpResponse patchSettings(const HttpRequest&, const Params&);
  HttpResponse getEdit(const HttpRequest&, const Params&);
  HttpResponse transport(const HttpRequest&, const Params&);
  // rest_frames.cpp
  HttpResponse sessionStats(const HttpRequest&, const Params&);
  HttpResponse getFrame(const HttpRequest&, const Params&);
  // rest_exports.cpp
  HttpResponse exportFrames(const HttpRequest&, const Params&);
  HttpResponse getExport(const HttpRequest&, const Params&);
  HttpResponse getSurfaceFile(const HttpRequest&, const Params&);
  HttpResponse getSurfaceJob(const HttpRequest&, const Params&);
  HttpResponse cancelSurfaceJob(const HttpRequest&, const Params&);
  // rest_jobs.cpp
  HttpResponse submitJob(const HttpRequest&, const Params&);
  HttpResponse listJobs(const HttpRequest&, const Params&);
  HttpResponse getJob(const HttpRequest&, const Params&);
  HttpResponse cancelJob(const HttpRequest&, const Params&);
  HttpResponse getJobFile(const HttpRequest&, const Params&);
  // rest_recipes.cpp
  HttpResponse listRecipes(const HttpRequest&, const Params&);
  HttpResponse startRecipeJob(const HttpRequest&, const Params&);
  HttpResponse getRecipeJob(const HttpRequest&, const Params&);
  HttpResponse cancelRecipeJob(const HttpRequest&, const Params&);

  std::shared_ptr<Session> requireSession(const std::string& id) const;
  // The live sessions, taken under the lock (their methods are then called without it).
  std::vector<std::shared_ptr<Session>> allSessions() const;
  // Submits an edit and waits (options_.editWait) for its result: 200/201
  // with {"edit"} (plus "instance" for instance edits), 202 while pending,
  // 422 when rejected.
  HttpResponse runEdit(Session& session, Edit edit, int okStatus);

  ServiceOptions options_;
  TemplateDatabase database_;
  std::chrono::steady_clock::time_point started_;
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<Session>> sessions_;
  std::multimap<std::string, std::pair<uint64_t, std::function<void()>>> deletionHooks_;
  uint64_t nextHook_ = 1;
  uint64_t nextSession_ = 1;
  int creating_ = 0;  // sessions being created (count against maxSessions)
  std::mutex fileMutex_;  // scene saves and exports: one writer at a time
  // Template files opened for previews, keyed by name and revalidated by
  // the file's size and modification time (a library panel asks often):
  // read frame by frame (TemplateStream), or whole if they have no checksum block.
  struct PreviewSource {
    uint64_t size = 0;
    int64_t mtime = 0;
    std::shared_ptr<const void> tpl;  // TemplateStream<D> if streamed, else Template<D>
    bool streamed = false;
    int dimension = 0;
  };
  static constexpr size_t kPreviewCacheSize = 4;
  std::mutex previewMutex_;
  std::map<std::string, PreviewSource> previews_;
  std::unique_ptr<SurfaceJobs> surfaceJobs_;  // meshes exports into exportsDir
  std::unique_ptr<RecipeJobs> recipeJobs_;  // its worker records into database_'s directory
  std::unique_ptr<RenderJobs> renderJobs_;  // batches of sessions' scenes, on a Dask cluster
};

// JSON from a client, nested at most kMaxJsonDepth levels (deeper values
// would overflow the stack when copied). Throws ApiError 400 naming what is
// wrong.
constexpr int kMaxJsonDepth = 128;
nlohmann::json parseJsonLimited(const std::string& text);

// Resident set size of this process, MB (/proc/self/statm).
double currentRssMb();

// A recorded frame as Envelope{Frame} (particles and instance records: the
// history holds no control, repulsion or boundary layer). Throws
// wire::EncodeError on an inconsistent snapshot.
void encodeSnapshot(const FrameSnapshot& frame, const std::string& sessionId, const wire::LayerFlags& layers,
                    flatbuffers::FlatBufferBuilder& fbb);
// The StateChange message for a Session::state() object.
wire::StateChangeInfo stateChangeInfo(const nlohmann::json& state, uint32_t requestId = 0);

}  // namespace fc::service
