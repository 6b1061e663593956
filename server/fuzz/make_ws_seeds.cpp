// Writes the seed corpus of fuzz_ws_message with the project's own encoder
// (service/frame_encoding.h): one file per client message kind, the server
// messages a client must refuse (and the frame decoder reads), and the
// regression inputs of known bugs (regress-*). Usage:
//   build-fuzz/fuzz/make_ws_seeds server/fuzz/corpus/ws_message
// The output is committed; rerun after a change of proto/flowclip.fbs.
#include "service/frame_encoding.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace {

namespace wire = fc::wire;
namespace fb = flowclip::wire;

std::filesystem::path outDir;

void write(const std::string& name, const uint8_t* data, size_t size) {
  std::ofstream f(outDir / name, std::ios::binary);
  f.write(reinterpret_cast<const char*>(data), std::streamsize(size));
  if (!f) {
    std::fprintf(stderr, "cannot write %s\n", (outDir / name).c_str());
    std::exit(1);
  }
}

void write(const std::string& name, const flatbuffers::FlatBufferBuilder& fbb) {
  write(name, fbb.GetBufferPointer(), fbb.GetSize());
}

void edit(const std::string& name, uint32_t id, const std::string& json) {
  flatbuffers::FlatBufferBuilder fbb;
  wire::buildEdit(fbb, {id, json});
  write(name, fbb);
}

void transport(const std::string& name, fb::TransportCommand command, uint32_t steps = 1, int32_t frame = -1,
               double speed = 0) {
  flatbuffers::FlatBufferBuilder fbb;
  wire::TransportRequest t;
  t.requestId = 7;
  t.command = command;
  t.steps = steps;
  t.frame = frame;
  t.speed = speed;
  wire::buildTransport(fbb, t);
  write(name, fbb);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUTPUT_DIR\n", argv[0]);
    return 2;
  }
  outDir = argv[1];
  std::filesystem::create_directories(outDir);

  // Edits (service/session.h, Edit::fromJson), one per kind.
  edit("edit-add-instance", 1,
       R"({"type":"add_instance","instance":{"name":"drop2","template":"tiny","start":0.1,)"
       R"("transform":[{"time":0,"translation":[0.05,0.02],"rotation":0,"scale":[1,1]}]}})");
  edit("edit-update-instance", 2, R"({"type":"update_instance","name":"drop","patch":{"start":0.5,"speed":null}})");
  edit("edit-remove-instance", 3, R"({"type":"remove_instance","name":"drop"})");
  edit("edit-settings", 4,
       R"({"type":"settings","settings":{"frame_rate":30},"solver":{"method":"dfsph","density_tolerance_pct":0.1},)"
       R"("control":{"forces_every_substep":true}})");
  edit("edit-unknown-type", 5, R"({"type":"explode"})");

  transport("transport-play", fb::TransportCommand::Play);
  transport("transport-pause", fb::TransportCommand::Pause);
  transport("transport-step", fb::TransportCommand::Step, 12);
  transport("transport-reset", fb::TransportCommand::Reset);
  transport("transport-seek", fb::TransportCommand::Seek, 1, 3);
  transport("transport-speed", fb::TransportCommand::SetSpeed, 1, -1, 24);

  {
    flatbuffers::FlatBufferBuilder fbb;
    wire::SubscribeRequest s;
    s.requestId = 9;
    s.maxFrameRate = 30;
    s.layers = {true, true, true, true, true};
    wire::buildSubscribe(fbb, s);
    write("subscribe-all-layers", fbb);
    wire::buildSubscribe(fbb, wire::SubscribeRequest{});
    write("subscribe-default", fbb);
  }

  // Server -> client messages: refused by parseClientMessage, read by the
  // frame decoder (a quantized frame with two particles and one instance).
  {
    flatbuffers::FlatBufferBuilder fbb;
    wire::buildAck(fbb, 1, 3);
    write("server-ack", fbb);
    wire::buildError(fbb, fb::ErrorCode::InvalidEdit, "instances[0].start: must be >= 0", 4);
    write("server-error", fbb);
    wire::StateChangeInfo info;
    info.sessionId = "s1";
    info.frame = 3;
    info.stateJson = R"({"id":"s1","status":"paused"})";
    wire::buildStateChange(fbb, info);
    write("server-state-change", fbb);

    fc::FrameStats stats;
    stats.frame = 3;
    stats.time = 0.05;
    stats.particles = 2;
    const std::vector<uint16_t> positions = {0, 0, 65535, 32768};
    const std::vector<uint16_t> velocities = {32768, 32768, 40000, 20000};
    const std::vector<uint8_t> kind = {0, 1}, phase = {0, 0};
    wire::InstanceRecord inst;
    inst.name = "drop";
    inst.templateName = "tiny";
    inst.active = true;
    inst.templateFrame = 2;
    inst.worldRowMajor = {1, 0, 0.1, 0, 1, 0.2, 0, 0, 1};
    inst.templateMax = {0.1, 0.1, 0};
    inst.falloffWidth = 0.02;
    inst.fidelity = 0.9;
    inst.controlled = 2;
    wire::QuantizedFrame q;
    q.sessionId = "s1";
    q.dimension = 2;
    q.domainMax = {0.2, 0.2, 0};
    q.positions = positions;
    q.kind = kind;
    q.phase = phase;
    q.velocities = velocities;
    q.velocityMax = {1, 1, 0};
    q.stats = &stats;
    q.instances = {&inst, 1};
    wire::LayerFlags layers;
    layers.speed = true;
    wire::encodeQuantizedFrame(q, layers, fbb);
    write("server-frame-2d", fbb);
  }

  // Known bugs (docs/fuzzing.md, "Regression inputs").
  edit("regress-edit-invalid-utf8-name", 10, "{\"type\":\"remove_instance\",\"name\":\"dr\xff" "op\"}");
  edit("regress-edit-invalid-utf8-update", 11, "{\"type\":\"update_instance\",\"name\":\"\xc0\xae\",\"patch\":{}}");
  edit("regress-edit-invalid-utf8-add", 12,
       "{\"type\":\"add_instance\",\"instance\":{\"name\":\"dr\xff" "op\",\"template\":\"tiny\"}}");
  edit("regress-edit-number-overflow", 13, R"({"type":"settings","settings":{"frame_rate":1e999}})");
  edit("regress-edit-deep-nesting", 14,
       "{\"type\":\"add_instance\",\"instance\":" + std::string(100000, '[') + std::string(100000, ']') + "}");
  std::printf("wrote the seeds of fuzz_ws_message to %s\n", outDir.c_str());
  return 0;
}
