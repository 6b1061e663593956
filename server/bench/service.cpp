// `flowclip bench service`: what the service costs. Frame encode
// time and bytes per particle; frames/s and MB/s delivered over loopback
// WebSockets to 1 and to 8 clients for a 100k-particle frame; memory per
// session and per 1000 replay frames; the idle server's RSS.
//
// Streaming is measured without the simulation in the way: a pump session
// publishes two prepared 100k-particle frames alternately as fast as the
// streams take them, so the figures are the network path's (encode, write,
// loopback, client read), not the solver's. Writes service.md and
// service.json (bench/report.h) into --out.
#include "bench/commands.h"
#include "bench/report.h"
#include "cli/exit_codes.h"
#include "cli/process.h"
#include "io/scene.h"
#include "sph/simulation.h"
#include "service/http_server.h"
#include "service/rest_api.h"

#include <malloc.h>
#include <omp.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <thread>

namespace fc::bench {

using namespace fc::cli;

namespace {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;
namespace fs = std::filesystem;
using namespace fc::service;

struct ServiceBenchOptions {
  int particles = 100000;
  double seconds = 3;
  std::vector<int> clients{1, 8};
  std::string scene = "scenes/drop2d.json";
  int frames = 300;
  std::string templates = "templates";
  std::string out = "bench/service";
  int threads = 0;  // OpenMP threads of the encoding and the session; 0: all cores
};

constexpr double kIdleTargetMb = 20;    // the idle server's RSS target
constexpr double kPaperIdleMb = 71.2;   // the paper's system, idle
constexpr int kHistoryCapMb = 4096;     // the session memory's history cap

// A 3D frame of n particles spread through a 1 m box, moving, 5 % of them
// temporary, with two instance records: what a 3D scene streams.
FramePtr syntheticFrame(int n, int frameNumber) {
  auto f = std::make_shared<FrameSnapshot>();
  f->dimension = 3;
  f->frame = frameNumber;
  f->time = frameNumber / 60.0;
  f->domainMin = {0, 0, 0};
  f->domainMax = {1, 1, 1};
  std::mt19937 rng{uint32_t(frameNumber)};
  std::uniform_int_distribution<int> q(0, 65535);
  f->positions.resize(size_t(n) * 3);
  f->velocities.resize(size_t(n) * 3);
  f->velocityMax = {2, 2, 2};
  for (auto& x : f->positions) x = uint16_t(q(rng));
  for (auto& v : f->velocities) v = uint16_t(q(rng));
  f->kind.assign(size_t(n), uint8_t(ParticleKind::Liquid));
  for (int i = 0; i < n; i += 20) f->kind[size_t(i)] = uint8_t(ParticleKind::Temporary);
  f->phase.assign(size_t(n), 0);
  f->stats.frame = frameNumber;
  f->stats.time = f->time;
  f->stats.particles = size_t(n);
  for (int i = 0; i < 2; ++i) {
    InstanceSnapshot s;
    s.name = "instance" + std::to_string(i);
    s.templateName = "letter_S";
    s.active = true;
    s.templateFrame = frameNumber % 60;
    s.toWorld = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.2 * i, 0.1, 0.3, 1};
    s.regionMax = {0.3, 0.3, 0.3};
    s.falloffWidth = 0.05;
    f->instances.push_back(s);
  }
  f->byteSize = f->bytes();
  return f;
}

// A session that only publishes prepared frames, alternating between two,
// as fast as its subscribers' streams take them (at most every 100 µs).
class PumpSession final : public Session {
 public:
  PumpSession(FramePtr a, FramePtr b) : frames_{std::move(a), std::move(b)}, latest_(frames_[0]) {}
  ~PumpSession() override { stop(); }

  void start() {
    thread_ = std::thread([this] {
      size_t i = 0;
      while (!stopping_) {
        FramePtr f = frames_[++i % 2];
        std::vector<SessionListener> listeners;
        {
          std::lock_guard lk(mutex_);
          latest_ = f;
          for (auto& [id, l] : listeners_) listeners.push_back(l);
        }
        published_.fetch_add(1);
        for (auto& l : listeners)
          if (l.frame) l.frame(f);
        std::this_thread::sleep_for(std::chrono::microseconds(100));
      }
    });
  }
  void stop() {
    stopping_ = true;
    if (thread_.joinable()) thread_.join();
  }
  uint64_t published() const { return published_.load(); }

  const std::string& id() const override { return id_; }
  const std::string& name() const override { return id_; }
  int dimension() const override { return 3; }
  void play(int) override {}
  void pause() override {}
  void step(int) override { throw SessionError("the benchmark's pump session does not simulate"); }
  void reset() override {}
  void setPlaybackSpeed(double) override {}
  FramePtr seek(int) override { throw std::out_of_range("the benchmark's pump session keeps no history"); }
  EditTicket submit(Edit) override { throw SessionError("the benchmark's pump session takes no edits"); }
  std::optional<EditResult> editResult(uint64_t) const override { return std::nullopt; }
  std::optional<EditKind> pendingEdit(uint64_t) const override { return std::nullopt; }
  FramePtr latestFrame() const override {
    std::lock_guard lk(mutex_);
    return latest_;
  }
  FramePtr frame(int) const override { return nullptr; }
  std::vector<FramePtr> history() const override { return {}; }
  json sceneJson() const override { return json::object(); }
  json state() const override { return {{"id", id_}, {"status", "playing"}, {"frame", latestFrame()->frame}}; }
  void setExportState(json) override {}
  void setJobState(json) override {}
  SessionStatus status() const override { return SessionStatus::Playing; }
  int currentFrame() const override { return latestFrame()->frame; }
  uint64_t subscribe(SessionListener l) override {
    std::lock_guard lk(mutex_);
    listeners_[++nextListener_] = std::move(l);
    return nextListener_;
  }
  void unsubscribe(uint64_t id) override {
    std::lock_guard lk(mutex_);
    listeners_.erase(id);
  }
  bool waitIdle(std::chrono::milliseconds) const override { return true; }
  bool waitForFrame(int, std::chrono::milliseconds) const override { return true; }
  void demandLayers(const wire::LayerFlags&, int) override {}
  std::shared_ptr<const LayeredFrame> layeredFrame() const override { return nullptr; }
  HistoryExport exportHistory(const std::string&, int, int) const override {
    throw std::invalid_argument("the benchmark's pump session keeps no history");
  }
  TemplateEntry recordTemplate(TemplateDatabase&, const std::string&, const std::vector<double>&,
                               const std::vector<double>&, int, int, bool) const override {
    throw std::invalid_argument("the benchmark's pump session keeps no history");
  }

 private:
  const std::string id_ = "pump";
  std::array<FramePtr, 2> frames_;
  mutable std::mutex mutex_;
  FramePtr latest_;
  std::map<uint64_t, SessionListener> listeners_;
  uint64_t nextListener_ = 0;
  std::atomic<bool> stopping_{false};
  std::atomic<uint64_t> published_{0};
  std::thread thread_;
};

double rssMbOf(pid_t pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  return 0;
}

// Runs `encode` for at least a second and 5 times: ms per call.
template <class F>
std::pair<double, int> timeRepeated(F&& encode) {
  int reps = 0;
  const auto t0 = Clock::now();
  double elapsed = 0;
  while (elapsed < 1.0 || reps < 5) {
    encode();
    ++reps;
    elapsed = std::chrono::duration<double>(Clock::now() - t0).count();
  }
  return {elapsed / reps * 1e3, reps};
}

// The live path: a 3D tank of about n particles encoded straight from the
// simulation (quantization included), plain and with the boundary layer.
json benchLiveEncode(int n) {
  // A block filling 0.93 × 0.93 × 0.46 of a 1 m tank at spacing 2r.
  const double r = 0.5 * std::cbrt(0.93 * 0.93 * 0.46 / n);
  const json scene = {{"dimension", 3},
                      {"particle_radius", r},
                      {"domain", {{"min", {0, 0, 0}}, {"max", {1, 1, 1}}}},
                      {"fluid_blocks", json::array({{{"min", {0, 0, 0}}, {"max", {0.93, 0.93, 0.46}}}})}};
  Simulation<3> sim(parseScene<3>(scene));
  FrameStats stats;
  stats.frame = 1;
  stats.time = 1 / 60.0;
  flatbuffers::FlatBufferBuilder fbb(1 << 20);
  json out = json::array();
  for (const bool boundary : {false, true}) {
    wire::LayerFlags layers;
    layers.boundary = boundary;
    wire::encodeFrame<3>(sim, stats, nullptr, "s1", layers, fbb);  // warm the builder's memory
    const auto [ms, reps] = timeRepeated([&] { wire::encodeFrame<3>(sim, stats, nullptr, "s1", layers, fbb); });
    const size_t total = sim.fluid.size() + (boundary ? sim.boundary.size() : 0);
    out.push_back({{"layers", boundary ? "liquid + boundary" : "liquid only"},
                   {"particles", total},
                   {"ms_per_frame", ms},
                   {"ns_per_particle", ms * 1e6 / double(total)},
                   {"bytes_per_particle", double(fbb.GetSize()) / double(total)},
                   {"repetitions", reps}});
  }
  return out;
}

json benchEncode(int n) {
  const FramePtr f = syntheticFrame(n, 1);
  flatbuffers::FlatBufferBuilder fbb(1 << 20);
  encodeSnapshot(*f, "s1", wire::LayerFlags{}, fbb);  // warm the builder's memory
  const auto [ms, reps] = timeRepeated([&] { encodeSnapshot(*f, "s1", wire::LayerFlags{}, fbb); });
  std::printf("encoding: %.3f ms per recorded %d-particle frame, %.2f bytes per particle\n", ms, n,
              double(fbb.GetSize()) / n);
  return {{"particles", n},
          {"instances", 2},
          {"recorded", {{"ms_per_frame", ms}, {"ns_per_particle", ms * 1e6 / n}, {"repetitions", reps}}},
          {"message", {{"bytes_per_particle", double(fbb.GetSize()) / n}, {"mb_per_frame", fbb.GetSize() / 1e6}}},
          {"history_bytes_per_particle_frame", double(FrameSnapshot::estimateBytes(3, size_t(n), 2)) / n},
          {"live", benchLiveEncode(n)}};
}

json benchStreaming(int n, const std::vector<int>& clientCounts, double seconds) {
  const fs::path tmp = fs::temp_directory_path() / ("flowclip-bench-service-" + std::to_string(::getpid()));
  ServiceOptions so;
  so.templatesDir = (tmp / "templates").string();
  so.scenesDir = (tmp / "scenes").string();
  so.exportsDir = (tmp / "exports").string();
  ServiceHub hub(so);
  auto pump = std::make_shared<PumpSession>(syntheticFrame(n, 1), syntheticFrame(n, 2));
  hub.adoptSession(pump);
  ServerOptions net;
  net.port = 0;
  HttpServer server(hub, net);
  std::thread serverThread([&] { server.run(false); });
  pump->start();

  json rows = json::array();
  for (int k : clientCounts) {
    std::vector<uint64_t> frames(size_t(k), 0), bytes(size_t(k), 0);
    std::atomic<int> ready{0};
    std::atomic<bool> go{false}, done{false};
    std::vector<std::thread> clients;
    for (int c = 0; c < k; ++c)
      clients.emplace_back([&, c] {
        StreamClient client("127.0.0.1", server.port(), "/api/sessions/pump/stream");
        std::string msg;
        ++ready;
        while (!go) std::this_thread::yield();
        while (!done && client.read(msg)) {
          const auto* env = flowclip::wire::GetEnvelope(msg.data());
          if (env->message_type() != flowclip::wire::Message::Frame) continue;
          ++frames[size_t(c)];
          bytes[size_t(c)] += msg.size();
        }
        client.close();
      });
    while (ready < k) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    std::this_thread::sleep_for(std::chrono::milliseconds(200));  // past the first frames
    const uint64_t published0 = pump->published();
    go = true;
    std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
    done = true;
    const uint64_t published = pump->published() - published0;
    for (auto& t : clients) t.join();
    uint64_t totalBytes = 0, minFrames = UINT64_MAX, totalFrames = 0;
    for (int c = 0; c < k; ++c) {
      totalBytes += bytes[size_t(c)];
      totalFrames += frames[size_t(c)];
      minFrames = std::min(minFrames, frames[size_t(c)]);
    }
    rows.push_back({{"clients", k},
                    {"frames_per_s_each", double(totalFrames) / k / seconds},
                    {"min_frames_per_s", double(minFrames) / seconds},
                    {"mb_per_s_total", double(totalBytes) / 1e6 / seconds},
                    {"published_per_s", double(published) / seconds}});
    std::printf("streaming: %d client(s), %.1f frames/s each, %.1f MB/s in all\n", k,
                rows.back()["frames_per_s_each"].get<double>(), rows.back()["mb_per_s_total"].get<double>());
  }
  pump->stop();
  server.stop();
  serverThread.join();
  std::error_code ec;
  fs::remove_all(tmp, ec);
  return {{"particles", n}, {"seconds", seconds}, {"runs", rows}};
}

json benchSessionMemory(const ServiceBenchOptions& o) {
  ServiceOptions so;
  so.templatesDir = o.templates;
  so.scenesDir = fs::path(o.scene).parent_path().string();
  so.exportsDir = (fs::temp_directory_path() / "flowclip-bench-exports").string();
  so.historyCapBytes = size_t(kHistoryCapMb) << 20;  // no frame dropped: the history's growth is measured
  ServiceHub hub(so);
  const json scene = loadSceneJson(o.scene);
  malloc_trim(0);
  const double rss0 = currentRssMb();
  HttpRequest create;
  create.method = "POST";
  create.path = "/api/sessions";
  create.body = json{{"scene", scene}, {"history_cap_mb", kHistoryCapMb}}.dump();
  HttpResponse r = hub.handle(create);
  if (r.status != 201) throw std::runtime_error("cannot create a session of " + o.scene + ": " + r.body);
  const std::string id = json::parse(r.body)["id"];
  auto session = hub.session(id);
  const double rss1 = currentRssMb();
  const json s0 = session->state();
  session->step(o.frames);
  session->waitForFrame(o.frames, std::chrono::minutes(30));
  session->waitIdle(std::chrono::minutes(1));
  const json s1 = session->state();
  const double rss2 = currentRssMb();
  const double frames = s1["history"]["frames"].get<double>() - 1;
  const double historyMb = (s1["memory"]["history_bytes"].get<double>() - s0["memory"]["history_bytes"].get<double>()) / 1e6;
  json out = {{"scene", o.scene},
              {"liquid_particles", s1["particles"]["liquid"]},
              {"frames", frames},
              {"session_rss_mb", rss1 - rss0},
              {"simulation_state_mb", s0["memory"]["simulation_bytes"].get<double>() / 1e6},
              {"history_mb_per_1000_frames", historyMb / frames * 1000},
              {"history_rss_mb_per_1000_frames", (rss2 - rss1) / frames * 1000},
              {"checkpoints_mb", s1["memory"].value("checkpoint_bytes", 0.0) / 1e6}};
  session.reset();
  HttpRequest del;
  del.method = "DELETE";
  del.path = "/api/sessions/" + id;
  hub.handle(del);
  malloc_trim(0);
  out["after_delete_rss_mb"] = currentRssMb() - rss0;
  std::printf("session memory: %.2f MB RSS at frame 0, %.2f MB history per 1000 frames\n",
              out["session_rss_mb"].get<double>(), out["history_mb_per_1000_frames"].get<double>());
  return out;
}

json benchIdleServer() {
  int out[2];
  if (pipe(out) != 0) throw std::runtime_error("pipe failed");
  const std::string exe = selfExecutable();
  const pid_t pid = fork();
  if (pid == 0) {
    dup2(out[1], 1);
    close(out[0]);
    execl(exe.c_str(), exe.c_str(), "serve", "--port", "0", nullptr);
    _exit(127);
  }
  close(out[1]);
  FILE* f = fdopen(out[0], "r");
  char line[512] = {0};
  const bool started = f && std::fgets(line, sizeof line, f) && std::strstr(line, "listening on");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const double rss = rssMbOf(pid);
  kill(pid, SIGINT);
  int status = 0;
  waitpid(pid, &status, 0);
  if (f) fclose(f);
  if (!started) throw std::runtime_error("flowclip serve did not start");
  std::printf("idle server: %.1f MB RSS\n", rss);
  return {{"rss_mb", rss}, {"target_mb", kIdleTargetMb}, {"paper_mb", kPaperIdleMb}};
}

std::string markdown(const json& idle, const json& enc, const json& stream, const json& mem) {
  std::string md = "## Idle server\n\n";
  md += markdownTable({"figure", "value"},
                      {{"RSS of `flowclip serve` without a session, MB", fmt(idle["rss_mb"], "%.1f")},
                       {"target, MB", fmt(idle["target_mb"], "%.0f")},
                       {"the paper's system, MB", fmt(idle["paper_mb"], "%.1f")}});
  md += "\n## Frame encoding\n\nA 3D frame of " + std::to_string(enc["particles"].get<int>()) +
        " particles with 2 instances: a recorded frame (already quantized: sending it is a copy) and the live "
        "path, encoded straight from a simulation of about as many particles.\n\n";
  const json& rec = enc["recorded"];
  std::vector<std::vector<std::string>> rows = {
      {"recorded frame", std::to_string(enc["particles"].get<int>()), fmt(rec["ms_per_frame"], "%.3f"),
       fmt(rec["ns_per_particle"], "%.2f"), fmt(enc["message"]["bytes_per_particle"], "%.2f"),
       std::to_string(rec["repetitions"].get<int>())}};
  for (const json& l : enc["live"])
    rows.push_back({"live, " + l["layers"].get<std::string>(), std::to_string(l["particles"].get<long>()),
                    fmt(l["ms_per_frame"], "%.3f"), fmt(l["ns_per_particle"], "%.2f"),
                    fmt(l["bytes_per_particle"], "%.2f"), std::to_string(l["repetitions"].get<int>())});
  md += markdownTable({"frame", "particles", "ms / frame", "ns / particle", "message bytes / particle", "repetitions"},
                      rows);
  md += "\nMessage: " + fmt(enc["message"]["mb_per_frame"], "%.2f") + " MB per recorded frame. History in memory: " +
        fmt(enc["history_bytes_per_particle_frame"], "%.2f") +
        " bytes per particle-frame (positions, velocities, kind, phase).\n";
  md += "\n## WebSocket streaming\n\nLoopback, " + std::to_string(stream["particles"].get<int>()) +
        "-particle 3D frames, newest frame only (no queue), " + fmt(stream["seconds"], "%g") +
        " s per client count; a pump session publishes prepared frames, so these are the network path's figures "
        "alone.\n\n";
  rows.clear();
  for (const json& s : stream["runs"])
    rows.push_back({std::to_string(s["clients"].get<int>()), fmt(s["frames_per_s_each"], "%.1f"),
                    fmt(s["min_frames_per_s"], "%.1f"), fmt(s["mb_per_s_total"], "%.1f"),
                    fmt(s["published_per_s"], "%.1f")});
  md += markdownTable({"clients", "frames/s each", "min frames/s", "MB/s in all", "published frames/s"}, rows);
  md += "\n## Session memory\n\n`" + mem["scene"].get<std::string>() + "`: " +
        std::to_string(mem["liquid_particles"].get<int>()) + " liquid particles, " + fmt(mem["frames"], "%.0f") +
        " frames simulated.\n\n";
  md += markdownTable(
      {"figure", "MB"},
      {{"session at frame 0, RSS", fmt(mem["session_rss_mb"], "%.2f")},
       {"simulation state counted by the session", fmt(mem["simulation_state_mb"], "%.2f")},
       {"history per 1000 frames, counted by the session", fmt(mem["history_mb_per_1000_frames"], "%.2f")},
       {"history per 1000 frames, RSS measured", fmt(mem["history_rss_mb_per_1000_frames"], "%.2f")},
       {"checkpoints after the last frame, counted by the session", fmt(mem["checkpoints_mb"], "%.2f")},
       {"RSS above the start after DELETE", fmt(mem["after_delete_rss_mb"], "%.2f")}});
  return md;
}

}  // namespace

void addBenchServiceCommand(CLI::App& bench) {
  auto o = std::make_shared<ServiceBenchOptions>();
  CLI::App* cmd = bench.add_subcommand(
      "service", "frame encoding, WebSocket delivery to 1 and 8 clients, memory per session, idle server RSS");
  cmd->add_option("--particles", o->particles, "particles per streamed frame (default 100000)")
      ->check(CLI::Range(1, 10000000));
  cmd->add_option("--seconds", o->seconds, "seconds per streaming measurement (default 3)")->check(CLI::PositiveNumber);
  cmd->add_option("--clients", o->clients, "client counts to measure (default 1,8)")->delimiter(',');
  cmd->add_option("--scene", o->scene, "scene for the memory figures (default scenes/drop2d.json)");
  cmd->add_option("--frames", o->frames, "frames simulated for the history figure (default 300)")
      ->check(CLI::Range(1, 100000));
  cmd->add_option("--templates", o->templates, "template directory (default: templates)");
  cmd->add_option("--threads", o->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  cmd->add_option("--out", o->out, "report folder: service.md and service.json (default: bench/service)");
  cmd->callback([o] {
    try {
      if (o->threads > 0) omp_set_num_threads(o->threads);
      const Report report("service", omp_get_max_threads());
      const json idle = benchIdleServer();
      const json encoding = benchEncode(o->particles);
      const json streaming = benchStreaming(o->particles, o->clients, o->seconds);
      const json memory = benchSessionMemory(*o);
      const json settings = {{"particles", o->particles}, {"seconds", o->seconds}, {"clients", o->clients},
                             {"scene", o->scene},         {"frames", o->frames},   {"templates", o->templates},
                             {"threads", omp_get_max_threads()}};
      report.write(o->out, "Service", markdown(idle, encoding, streaming, memory),
                   {{"settings", settings},
                    {"idle_server", idle},
                    {"encoding", encoding},
                    {"streaming", streaming},
                    {"session_memory", memory}});
    } catch (const std::exception& e) {
      std::fprintf(stderr, "error: %s\n", e.what());
      throw ExitCode(Failure);
    }
  });
}

}  // namespace fc::bench
