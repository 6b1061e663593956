// `flowclip serve`: the simulation service (REST, WebSocket stream, editor
// files) on one port. See service/http_server.h and docs/api.md.
#include "app/commands.h"
#include "io/staged_files.h"
#include "io/template_database.h"
#include "cli/process.h"
#include "service/child_process.h"
#include "service/http_server.h"
#include "service/rest_api.h"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <unistd.h>

namespace fc::app {

using namespace fc::cli;

namespace {

namespace fs = std::filesystem;

struct ServeOptions {
  std::string host = "127.0.0.1";
  int port = 8080;
  std::string templates = "templates";
  double templateMemoryMB = kDefaultTemplateMemoryMB;
  std::string scenes = "scenes";
  std::string recipes;  // "": TEMPLATES/recipes, else the source tree's
  std::string exports = "exports";
  std::string presets = "bench/accuracy/presets.json";
  std::string web = "web/dist";
  std::string token;
  std::vector<std::string> allowOrigins;
  int maxSessions = 8;
  double maxBodyMb = 8;
  double historyCapMb = 256;
  int maxThreads = 0;
  int recordThreads = 0;
  double frameTimeout = 120;
  double streamStall = 20, streamIdle = 60;
  double editWait = 3;
  int ioThreads = 2;
  std::string jobs;  // "": EXPORTS/jobs
  std::string batchCommand;  // "": $FLOWCLIP_BATCH, flowclip-batch beside the executable, then on PATH
  std::string scheduler;
  int jobWorkers = 0;  // 0: half the CPUs, at least 1
};

// flowclip-batch for render jobs, "" when none is found.
std::string findBatchCommand(const std::string& given) {
  if (given == "none") return {};
  if (!given.empty()) return fs::absolute(given).string();
  if (const char* env = std::getenv("FLOWCLIP_BATCH"); env && *env) return fs::absolute(env).string();
  const fs::path beside = fs::path(selfExecutable()).parent_path() / "flowclip-batch";
  std::error_code ec;
  if (fs::is_regular_file(beside, ec)) return beside.string();
  return service::findOnPath("flowclip-batch");
}

int serve(const ServeOptions& o, bool presetsGiven) {
  if (!service::isLoopbackHost(o.host) && o.token.empty()) {
    std::fprintf(stderr, "error: --host %s is reachable from other machines: give --token T (clients then send "
                         "\"Authorization: Bearer T\")\n", o.host.c_str());
    return BadInput;
  }
  service::ServiceOptions so;
  so.templatesDir = o.templates;
  so.templateMemoryBytes = templateMemoryBytes(o.templateMemoryMB);
  so.scenesDir = o.scenes;
  so.exportsDir = o.exports;
  so.presetsFile = o.presets;
  so.recipesDir = o.recipes;
  // Recipes live next to the database they record into; a database elsewhere records the shipped ones.
  if (so.recipesDir.empty()) {
    const fs::path beside = fs::path(o.templates) / "recipes";
    const fs::path source = fs::path(FLOWCLIP_SOURCE_DIR) / "templates/recipes";
    so.recipesDir = fs::is_directory(beside) || !fs::is_directory(source) ? beside.string() : source.string();
  }
  // The default presets path is relative to the repository: also found when serve starts elsewhere.
  if (!presetsGiven && !fs::exists(so.presetsFile)) {
    const fs::path source = fs::path(FLOWCLIP_SOURCE_DIR) / "bench/accuracy/presets.json";
    if (fs::exists(source)) so.presetsFile = source.string();
  }
  so.maxSessions = o.maxSessions;
  so.historyCapBytes = size_t(o.historyCapMb * 1024 * 1024);
  so.maxThreads = o.maxThreads;
  so.recordThreads = o.recordThreads;
  so.frameTimeout = std::chrono::milliseconds(int64_t(o.frameTimeout * 1000));
  so.streamWriteStall = std::chrono::milliseconds(int64_t(o.streamStall * 1000));
  so.streamIdleTimeout = std::chrono::milliseconds(int64_t(o.streamIdle * 1000));
  so.editWait = std::chrono::milliseconds(int64_t(o.editWait * 1000));
  so.jobsDir = o.jobs.empty() ? (fs::path(o.exports) / "jobs").string() : o.jobs;
  so.batchCommand = findBatchCommand(o.batchCommand);
  so.batchBinary = selfExecutable();
  so.scheduler = o.scheduler;
  so.jobWorkers = o.jobWorkers > 0 ? o.jobWorkers : std::max(1, int(std::thread::hardware_concurrency()) / 2);
  if (!so.batchCommand.empty() && ::access(so.batchCommand.c_str(), X_OK) != 0) {
    std::fprintf(stderr, "error: %s %s: not an executable file\n",
                 o.batchCommand.empty() ? "FLOWCLIP_BATCH" : "--batch-command", so.batchCommand.c_str());
    return BadInput;
  }
  if (so.batchCommand.empty())
    std::fprintf(stderr, "flowclip serve: no flowclip-batch found (pip install \"flowclip[batch]\" from clients/python, "
                         "or --batch-command PATH): render jobs are off\n");
  service::ServerOptions net;
  net.host = o.host;
  net.port = uint16_t(o.port);
  net.webDir = o.web;
  net.token = o.token;
  net.allowOrigins = o.allowOrigins;
  net.maxBodyBytes = size_t(o.maxBodyMb * 1024 * 1024);
  net.ioThreads = o.ioThreads;
  // Sets of files a killed process left half-published go back to their old files; its temporary files go.
  for (const std::string* dir : {&o.templates, &o.scenes, &o.exports}) {
    const PublishRecovery r = recoverPublishing(*dir);
    for (const std::string& f : r.rolledBack) std::fprintf(stderr, "flowclip serve: %s: interrupted publish undone\n", f.c_str());
    for (const std::string& e : r.errors) std::fprintf(stderr, "warning: %s\n", e.c_str());
  }
  // The hub outlives the server: streams release their sessions first.
  service::ServiceHub hub(so);
  std::unique_ptr<service::HttpServer> server;
  try {
    server = std::make_unique<service::HttpServer>(hub, net);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return Failure;
  }
  const std::string host = o.host.find(':') != std::string::npos ? "[" + o.host + "]" : o.host;
  std::printf("flowclip serve: listening on http://%s:%u\n", host.c_str(), unsigned(server->port()));
  std::fflush(stdout);
  server->run();
  server.reset();
  std::printf("flowclip serve: stopped\n");
  return Ok;
}

}  // namespace

void addServeCommand(CLI::App& app) {
  auto o = std::make_shared<ServeOptions>();
  CLI::App* cmd = app.add_subcommand("serve", "run the simulation service: REST, WebSocket streams and the editor");
  cmd->add_option("--host", o->host, "address to bind (default 127.0.0.1; another address requires --token)");
  cmd->add_option("--port", o->port, "TCP port (default 8080; 0: any free port, printed)")->check(CLI::Range(0, 65535));
  cmd->add_option("--templates", o->templates, "template directory (default: templates)");
  addTemplateMemoryOption(cmd, o->templateMemoryMB);
  cmd->add_option("--scenes", o->scenes, "scene directory (default: scenes)");
  cmd->add_option("--recipes", o->recipes,
                  "recipes the editor can record (default: TEMPLATES/recipes, else the source tree's "
                  "templates/recipes)");
  auto* presetsOption = cmd->add_option("--presets", o->presets, "accuracy presets of `bench accuracy` (default: bench/accuracy/presets.json)");
  cmd->add_option("--exports", o->exports, "directory for HDF5/XDMF exports (default: exports)");
  cmd->add_option("--web", o->web, "the built editor's files (default: web/dist)");
  cmd->add_option("--token", o->token, "require \"Authorization: Bearer T\" (or WebSocket subprotocol flowclip-token.T)");
  cmd->add_option("--allow-origin", o->allowOrigins, "a WebSocket Origin accepted besides same-origin (repeatable)");
  cmd->add_option("--max-sessions", o->maxSessions, "sessions at once (default 8)")->check(CLI::Range(1, 1024));
  cmd->add_option("--max-body-mb", o->maxBodyMb, "largest REST body or WebSocket message, MB (default 8)")
      ->check(CLI::Range(0.001, 1024.0));
  cmd->add_option("--history-cap-mb", o->historyCapMb, "replay history per session, MB (default 256)")
      ->check(CLI::Range(1.0, 1e6));
  cmd->add_option("--max-threads", o->maxThreads, "OpenMP threads per session, the ceiling of a request's \"threads\" "
                                                  "(default: the CPUs)")
      ->check(CLI::Range(1, 1024));
  cmd->add_option("--record-threads", o->recordThreads,
                  "OpenMP threads of a recording started from the editor or REST (default: half the CPUs, at least 1)")
      ->check(CLI::Range(1, 1024));
  cmd->add_option("--frame-timeout", o->frameTimeout,
                  "a session whose frame runs longer than this many seconds goes to its error state (default 120)")
      ->check(CLI::Range(0.1, 1e6));
  cmd->add_option("--stream-stall", o->streamStall,
                  "a WebSocket client that takes longer than this many seconds to accept one message is "
                  "disconnected (default 20)")
      ->check(CLI::Range(0.1, 3600.0));
  cmd->add_option("--stream-idle", o->streamIdle,
                  "a WebSocket client that answers no keep-alive ping for this many seconds is dropped (default 60)")
      ->check(CLI::Range(1.0, 86400.0));
  cmd->add_option("--edit-wait", o->editWait,
                  "how long an edit's REST answer waits for the frame boundary where it applies, seconds; longer "
                  "answers 202 (pending) with the edit's id to poll (default 3)")
      ->check(CLI::Range(0.0, 600.0));
  cmd->add_option("--io-threads", o->ioThreads, "network threads (default 2)")->check(CLI::Range(1, 64));
  cmd->add_option("--jobs", o->jobs, "directory of render jobs' results (default: EXPORTS/jobs)");
  cmd->add_option("--scheduler", o->scheduler,
                  "render jobs run on this Dask scheduler, tcp://HOST:8786 (default: a LocalCluster of --job-workers)");
  cmd->add_option("--job-workers", o->jobWorkers, "worker processes of the local cluster (default: half the CPUs)")
      ->check(CLI::Range(1, 1024));
  cmd->add_option("--batch-command", o->batchCommand,
                  "flowclip-batch, which runs render jobs (default: $FLOWCLIP_BATCH, beside flowclip, or on PATH; none: no jobs)");
  cmd->callback([o, presetsOption] { throw ExitCode(serve(*o, presetsOption->count() > 0)); });
}

}  // namespace fc::app
