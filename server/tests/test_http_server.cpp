// The network side of `flowclip serve` (service/http_server.h) on loopback:
// the WebSocket stream's first messages, optional layers encoded by the
// session (a paused session re-sends its frame with them), edits answered
// with the client's id and the frame they took effect in, a message that
// fails the verifier answered with an Error on a connection that stays
// usable, and the token. The Python tests (tests/test_service_*.py) drive
// the REST side and the scripted-client scenarios.
#include "service/http_server.h"

#include "service/frame_encoding.h"
#include "tests/hdf5_test_util.h"
#include "tests/support/frame_decoding.h"
#include "tests/test_fixtures.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <thread>

namespace fc::service {
namespace {

using nlohmann::json;
using fc::test::TempDir;
namespace fb = wire::fb;

using fc::test::smallTankScene;

struct Served {
  TempDir tmp;
  ServiceHub hub;
  HttpServer server;
  std::thread thread;
  std::string id;
  explicit Served(const std::string& token = "")
      : hub(hubOptions(tmp)), server(hub, serverOptions(token)), thread([this] { server.run(false); }) {
    HttpRequest r;
    r.method = "POST";
    r.path = "/api/sessions";
    json scene = smallTankScene();
    scene["instances"] = json::array({{{"name", "drop"}, {"template", "blob"}}});
    r.body = json{{"scene", scene}}.dump();
    const HttpResponse res = hub.handle(r);
    EXPECT_EQ(res.status, 201) << res.body;
    id = json::parse(res.body).value("id", "");
  }
  ~Served() {
    server.stop();
    thread.join();
  }
  static ServiceOptions hubOptions(TempDir& tmp) {
    fc::test::writeSmallTemplate<2>(tmp.file("templates"), "blob", 13, {0.05, 0.05}, {0.35, 0.35});
    ServiceOptions o;
    o.templatesDir = tmp.file("templates");
    o.scenesDir = tmp.file("scenes");
    o.exportsDir = tmp.file("exports");
    return o;
  }
  static ServerOptions serverOptions(const std::string& token) {
    ServerOptions o;
    o.port = 0;
    o.token = token;
    return o;
  }
  std::unique_ptr<StreamClient> connect(const std::string& token = "") {
    return std::make_unique<StreamClient>("127.0.0.1", server.port(), "/api/sessions/" + id + "/stream", token);
  }
};

const fb::Envelope* envelope(const std::string& m) {
  EXPECT_TRUE(wire::verifyEnvelope(reinterpret_cast<const uint8_t*>(m.data()), m.size()).empty());
  return fb::GetEnvelope(m.data());
}

// Reads until a message of `type` arrives (at most 50 messages).
std::string readUntil(StreamClient& c, fb::Message type) {
  std::string m;
  for (int i = 0; i < 50 && c.read(m); ++i)
    if (envelope(m)->message_type() == type) return m;
  ADD_FAILURE() << "no message of type " << fb::EnumNameMessage(type);
  return {};
}

wire::DecodedFrame decode(const std::string& m) {
  return wire::decodeFrame(reinterpret_cast<const uint8_t*>(m.data()), m.size());
}

void send(StreamClient& c, const flatbuffers::FlatBufferBuilder& fbb) { c.send(fbb.GetBufferPointer(), fbb.GetSize()); }

TEST(HttpServer, StreamStartsWithStateAndFrameAndAddsLayersOnRequest) {
  Served s;
  auto c = s.connect();
  std::string m;
  ASSERT_TRUE(c->read(m));
  EXPECT_EQ(envelope(m)->message_type(), fb::Message::StateChange);
  const wire::DecodedFrame first = decode(readUntil(*c, fb::Message::Frame));
  EXPECT_EQ(first.frame, 0);
  EXPECT_EQ(first.particles.x.size(), 100u);
  EXPECT_FALSE(first.layers.boundary);

  // Paused at frame 0: asking for boundary and control re-sends frame 0 with them.
  flatbuffers::FlatBufferBuilder fbb;
  wire::SubscribeRequest sub;
  sub.layers.boundary = sub.layers.control = true;
  wire::buildSubscribe(fbb, sub);
  send(*c, fbb);
  const wire::DecodedFrame layered = decode(readUntil(*c, fb::Message::Frame));
  EXPECT_EQ(layered.frame, 0);
  ASSERT_TRUE(layered.layers.boundary);
  const size_t boundary = size_t(std::count(layered.kind.begin(), layered.kind.end(), uint8_t(ParticleKind::Boundary)));
  EXPECT_GT(boundary, 0u);
  EXPECT_EQ(boundary, layered.stats.boundaryParticles);

  // Playing frames carry the control layer while the instance is active, with α per point.
  wire::TransportRequest step;
  step.command = fb::TransportCommand::Step;
  step.steps = 3;
  wire::buildTransport(fbb, step);
  send(*c, fbb);
  wire::DecodedFrame f;
  for (int i = 0; i < 20 && f.frame < 3; ++i) f = decode(readUntil(*c, fb::Message::Frame));
  ASSERT_EQ(f.frame, 3);
  ASSERT_TRUE(f.layers.control);
  ASSERT_EQ(f.instances.size(), 1u);
  EXPECT_TRUE(f.instances[0].active);
  EXPECT_EQ(f.instances[0].controlCount, 16u);
  EXPECT_EQ(f.alpha.size(), 16u);
  EXPECT_EQ(f.control.x.size(), 16u);
}

TEST(HttpServer, BadMessagesGetErrorsAndTheConnectionStaysUsable) {
  Served s;
  auto c = s.connect();
  readUntil(*c, fb::Message::Frame);
  const std::string garbage = "this is not a flatbuffer at all";
  c->send(reinterpret_cast<const uint8_t*>(garbage.data()), garbage.size());
  const std::string e = readUntil(*c, fb::Message::Error);
  EXPECT_EQ(envelope(e)->message_as_Error()->code(), fb::ErrorCode::InvalidMessage);

  // An edit the session rejects: an Error carrying the client's edit id.
  flatbuffers::FlatBufferBuilder fbb;
  wire::buildEdit(fbb, {7, R"({"type": "update_instance", "name": "drop", "patch": {"speed": -1}})"});
  send(*c, fbb);
  const std::string rejected = readUntil(*c, fb::Message::Error);
  EXPECT_EQ(envelope(rejected)->message_as_Error()->code(), fb::ErrorCode::InvalidEdit);
  EXPECT_EQ(envelope(rejected)->message_as_Error()->request_id(), 7u);

  // A valid edit on the same connection: acknowledged with the frame it takes effect in.
  wire::buildEdit(fbb, {8, R"({"type": "update_instance", "name": "drop", "patch": {"speed": 2}})"});
  send(*c, fbb);
  const std::string ack = readUntil(*c, fb::Message::Ack);
  EXPECT_EQ(envelope(ack)->message_as_Ack()->edit_id(), 8u);
  EXPECT_EQ(envelope(ack)->message_as_Ack()->frame(), 1);
  EXPECT_EQ(s.hub.session(s.id)->sceneJson()["instances"][0]["speed"], 2.0);
}

TEST(HttpServer, TokenIsRequiredWhenSet) {
  Served s("secret");
  EXPECT_THROW(s.connect(), std::runtime_error);
  EXPECT_THROW(s.connect("wrong"), std::runtime_error);
  auto c = s.connect("secret");
  std::string m;
  ASSERT_TRUE(c->read(m));
  EXPECT_EQ(envelope(m)->message_type(), fb::Message::StateChange);
}

TEST(HttpServer, DeletingTheSessionClosesItsStreamsAndFreesIt) {
  Served s;
  auto c = s.connect();
  readUntil(*c, fb::Message::Frame);
  std::weak_ptr<Session> weak = s.hub.session(s.id);
  HttpRequest del;
  del.method = "DELETE";
  del.path = "/api/sessions/" + s.id;
  EXPECT_EQ(s.hub.handle(del).status, 200);
  std::string m;
  while (c->read(m)) {
  }
  for (int i = 0; i < 100 && !weak.expired(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_TRUE(weak.expired()) << "the stream must let go of a deleted session";
}

TEST(HttpServer, TransportIsAnsweredWithItsRequestIdEvenWhenNothingChanges) {
  Served s;
  auto c = s.connect();
  readUntil(*c, fb::Message::Frame);
  flatbuffers::FlatBufferBuilder fbb;
  wire::TransportRequest pause;
  pause.command = fb::TransportCommand::Pause;  // already paused
  pause.requestId = 5;
  wire::buildTransport(fbb, pause);
  send(*c, fbb);
  bool answered = false;
  for (int i = 0; i < 10 && !answered; ++i) {
    const std::string m = readUntil(*c, fb::Message::StateChange);
    answered = envelope(m)->message_as_StateChange()->request_id() == 5;
  }
  EXPECT_TRUE(answered);
}

TEST(HttpServer, DeeplyNestedEditJsonIsAnErrorNotACrash) {
  Served s;
  auto c = s.connect();
  readUntil(*c, fb::Message::Frame);
  std::string deep = R"({"type": "update_instance", "name": "drop", "patch": {"x": )";
  deep += std::string(200000, '[') + std::string(200000, ']') + "}}";
  flatbuffers::FlatBufferBuilder fbb;
  wire::buildEdit(fbb, {3, deep});
  send(*c, fbb);
  const std::string e = readUntil(*c, fb::Message::Error);
  EXPECT_EQ(envelope(e)->message_as_Error()->request_id(), 3u);
  EXPECT_NE(envelope(e)->message_as_Error()->message()->str().find("nested"), std::string::npos);
}

// Stopping the server while sessions play and streams read must not let a
// session thread reach a connection or the dead event loop (the hub, and
// its sessions, outlive the server).
TEST(HttpServer, StopsCleanlyWhileSessionsPlayToReadingStreams) {
  Served s;
  for (int round = 0; round < 20; ++round) {
    // Declared first, closed last: a client's close waits for the server's
    // answer, which a stopped server only gives by closing the socket.
    std::vector<std::unique_ptr<StreamClient>> clients;
    HttpServer server(s.hub, Served::serverOptions(""));
    std::thread thread([&] { server.run(false); });
    for (int k = 0; k < 4; ++k)
      clients.push_back(
          std::make_unique<StreamClient>("127.0.0.1", server.port(), "/api/sessions/" + s.id + "/stream"));
    s.hub.session(s.id)->play();
    std::string m;
    for (auto& c : clients) c->read(m);
    server.stop();
    thread.join();
  }
  s.hub.session(s.id)->pause();
  EXPECT_TRUE(s.hub.session(s.id)->waitIdle(std::chrono::seconds(10)));
}

}  // namespace
}  // namespace fc::service
