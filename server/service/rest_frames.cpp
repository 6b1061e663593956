#include "service/rest_api.h"

// A session's recorded frames: GET /api/sessions/{id}/frames/{frame} (JSON
// or the stream's binary message), /stats, and the encoding of a recorded
// frame and of a state change that the WebSocket stream shares.
#include "io/stats_json.h"
#include "service/rest_support.h"

namespace fc::service {

using namespace rest;

namespace {

json instanceSnapshotJson(const InstanceSnapshot& s) {
  return {{"name", s.name},
          {"template", s.templateName},
          {"phase", s.phase},
          {"active", s.active},
          {"template_frame", s.templateFrame},
          {"fidelity", s.fidelity},
          {"world_matrix", s.toWorld},
          {"region_min", s.regionMin},
          {"region_max", s.regionMax},
          {"falloff_width", s.falloffWidth}};
}

json frameStatsEntry(const FrameSnapshot& f) {
  json j = frameStatsToJson(f.stats, !f.instances.empty());
  j["frame"] = f.frame;
  j["time"] = f.time;
  return j;
}

}  // namespace

void encodeSnapshot(const FrameSnapshot& f, const std::string& sessionId, const wire::LayerFlags& layers,
                    flatbuffers::FlatBufferBuilder& fbb) {
  // Records are views into the snapshot, which outlives the call.
  std::vector<wire::InstanceRecord> records(f.instances.size());
  for (size_t i = 0; i < records.size(); ++i) {
    const InstanceSnapshot& src = f.instances[i];
    wire::InstanceRecord& r = records[i];
    r.name = src.name;
    r.templateName = src.templateName;
    r.active = src.active;
    r.templateFrame = src.templateFrame;
    r.phase = src.phase;
    r.setWorldFromColumnMajor4x4(src.toWorld, f.dimension);
    r.templateMin = src.regionMin;
    r.templateMax = src.regionMax;
    r.falloffWidth = src.falloffWidth;
    r.fidelity = src.fidelity;
    // The frame's stats hold what control did per instance (the editor tells an instance that steers nothing).
    if (f.stats.instances.size() == records.size() && f.stats.instances[i].name == src.name)
      r.controlled = f.stats.instances[i].controlled;
  }
  wire::QuantizedFrame q;
  q.sessionId = sessionId;
  q.dimension = f.dimension;
  q.domainMin = f.domainMin;
  q.domainMax = f.domainMax;
  q.positions = f.positions;
  q.kind = f.kind;
  q.phase = f.phase;
  q.velocities = f.velocities;
  q.velocityMax = f.velocityMax;
  q.stats = &f.stats;
  q.instances = records;
  wire::encodeQuantizedFrame(q, layers, fbb);
}

wire::StateChangeInfo stateChangeInfo(const json& state, uint32_t requestId) {
  static const std::map<std::string, wire::fb::SessionStatus> statuses = {
      {"paused", wire::fb::SessionStatus::Paused},
      {"playing", wire::fb::SessionStatus::Playing},
      {"stepping", wire::fb::SessionStatus::Stepping},
      {"error", wire::fb::SessionStatus::Error}};
  wire::StateChangeInfo info;
  info.sessionId = state.value("id", "");
  auto st = statuses.find(state.value("status", "paused"));
  info.status = st == statuses.end() ? wire::fb::SessionStatus::Paused : st->second;
  info.frame = state.value("frame", 0);
  info.time = state.value("time", 0.0);
  if (state.contains("shown")) {
    info.shownFrame = state["shown"].value("frame", 0);
    info.live = state["shown"].value("live", true);
  }
  info.playbackSpeed = state.value("playback_speed", 0.0);
  if (state.contains("history")) {
    const json& h = state["history"];
    info.historyFirstFrame = h["first"].is_number() ? h["first"].get<int>() : 0;
    info.historyLastFrame = h["last"].is_number() ? h["last"].get<int>() : 0;
    info.historyDroppedFrames = h.value("dropped", 0u);
  }
  if (state.contains("error")) info.message = state["error"].value("message", "");
  info.requestId = requestId;
  info.stateJson = state.dump(-1, ' ', false, json::error_handler_t::replace);
  return info;
}

HttpResponse ServiceHub::sessionStats(const HttpRequest&, const Params& p) {
  auto s = requireSession(p[0]);
  json frames = json::array();
  for (const FramePtr& f : s->history()) frames.push_back(frameStatsEntry(*f));
  return jsonResponse({{"frames", frames}});
}

HttpResponse ServiceHub::getFrame(const HttpRequest& req, const Params& p) {
  auto s = requireSession(p[0]);
  FramePtr f;
  if (p[1] == "latest") {
    f = s->latestFrame();
  } else {
    int n = -1;
    try {
      size_t used = 0;
      n = std::stoi(p[1], &used);
      if (used != p[1].size() || n < 0) throw std::invalid_argument("");
    } catch (const std::exception&) {
      throw ApiError(400, "frame \"" + p[1].substr(0, 40) + "\" must be a frame number >= 0 or \"latest\"", "frame");
    }
    f = s->frame(n);
    if (!f) {
      const json h = s->state()["history"];
      throw ApiError(404, "frame " + p[1] + " is not in session " + p[0] + "'s history (frames " + h["first"].dump() +
                              " to " + h["last"].dump() + " are kept)",
                     "frame");
    }
  }
  std::string format = queryValue(req.query, "format");
  if (format.empty()) format = req.header("accept").find("application/x-flowclip-frame") != std::string::npos ? "binary" : "json";
  if (format == "binary") {
    flatbuffers::FlatBufferBuilder fbb(f->positions.size() * 2 + f->kind.size() * 2 + 1024);
    encodeSnapshot(*f, s->id(), wire::LayerFlags{}, fbb);
    HttpResponse r;
    r.contentType = "application/x-flowclip-frame";
    r.body.assign(reinterpret_cast<const char*>(fbb.GetBufferPointer()), fbb.GetSize());
    return r;
  }
  if (format != "json") throw ApiError(400, "format must be json or binary, got \"" + format.substr(0, 40) + "\"", "format");
  const size_t n = f->particles();
  const int D = f->dimension;
  json positions = json::array(), velocities = json::array(), kind = json::array(), phase = json::array();
  for (size_t i = 0; i < n; ++i) {
    for (int d = 0; d < D; ++d) {
      positions.push_back(f->position(i, d));
      velocities.push_back(f->velocity(i, d));
    }
    kind.push_back(f->kind[i]);
    phase.push_back(f->phase[i]);
  }
  json instances = json::array();
  for (const InstanceSnapshot& inst : f->instances) instances.push_back(instanceSnapshotJson(inst));
  return jsonResponse({{"frame", f->frame},
                       {"time", f->time},
                       {"dimension", D},
                       {"domain_min", f->domainMin},
                       {"domain_max", f->domainMax},
                       {"count", n},
                       {"positions", std::move(positions)},
                       {"velocities", std::move(velocities)},
                       {"kind", std::move(kind)},
                       {"phase", std::move(phase)},
                       {"instances", std::move(instances)},
                       {"stats", frameStatsEntry(*f)}});
}

}  // namespace fc::service
