// Fuzz target: what a WebSocket client sends (service/frame_encoding.h,
// proto/flowclip.fbs). The bytes are one binary message, handled as the
// server's stream handler handles it (service/http_server.cpp):
//   wire::parseClientMessage(data, size)
//     ParseFailure -> the Error message sent back (buildError)
//     EditRequest  -> Edit::fromJson(parseJsonLimited(json)); its documented
//                     failures (ApiError from the JSON reader, SceneError
//                     from fromJson) become an Error message too
//     Transport / Subscribe -> their fields checked against the documented
//                     ranges (no session here: the REST target drives sessions)
// Every message the server would send back must pass the server's own
// verifier and carry valid UTF-8 (clients decode flatbuffers strings as
// UTF-8). The same bytes also go through the client-side frame decoder
// (wire::decodeFrame, tests/support/frame_decoding.h), whose documented failure is
// std::invalid_argument.
#include "fuzz_support.h"
#include "service/frame_encoding.h"
#include "service/rest_api.h"
#include "service/session.h"
#include "tests/support/frame_decoding.h"

#include <cmath>
#include <cstdint>
#include <string>
#include <variant>

namespace {

namespace wire = fc::wire;
namespace fb = flowclip::wire;

// The Error message the server would send: well-formed, UTF-8.
void checkErrorReply(fb::ErrorCode code, const std::string& message, uint32_t requestId) {
  flatbuffers::FlatBufferBuilder fbb;
  wire::buildError(fbb, code, message, requestId);
  const std::string bad = wire::verifyEnvelope(fbb.GetBufferPointer(), fbb.GetSize());
  FUZZ_CHECK(bad.empty(), "the Error reply does not verify: " + bad);
  const auto* env = fb::GetEnvelope(fbb.GetBufferPointer());
  const auto* err = env->message_as_Error();
  FUZZ_CHECK(err != nullptr, "the Error reply is not an Error");
  const std::string sent = err->message() ? err->message()->str() : std::string();
  FUZZ_CHECK(fc::fuzz::validUtf8(sent), "the Error reply's message is not UTF-8: " + sent);
  FUZZ_CHECK(err->request_id() == requestId, "the Error reply lost its request id");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const wire::ClientMessage message = wire::parseClientMessage(data, size);
  if (const auto* f = std::get_if<wire::ParseFailure>(&message)) {
    FUZZ_CHECK(!f->message.empty(), "a ParseFailure without a message");
    checkErrorReply(f->code, f->message, f->requestId);
  } else if (const auto* e = std::get_if<wire::EditRequest>(&message)) {
    try {
      const fc::service::Edit edit = fc::service::Edit::fromJson(fc::service::parseJsonLimited(e->json));
      // What the session would echo in its results and state.
      fc::service::EditResult r;
      r.kind = edit.kind;
      r.instance = edit.instance;
      (void)r.toJson().dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
    } catch (const fc::service::ApiError& err) {
      checkErrorReply(fb::ErrorCode::InvalidEdit, err.what(), e->editId);
    } catch (const fc::SceneError& err) {
      checkErrorReply(fb::ErrorCode::InvalidEdit, err.what(), e->editId);
    }
  } else if (const auto* t = std::get_if<wire::TransportRequest>(&message)) {
    if (t->command == fb::TransportCommand::Step)
      FUZZ_CHECK(t->steps >= 1 && t->steps <= 1000000u, "Step accepted with " + std::to_string(t->steps) + " steps");
    if (t->command == fb::TransportCommand::SetSpeed)
      FUZZ_CHECK(std::isfinite(t->speed) && t->speed >= 0, "SetSpeed accepted with speed " + std::to_string(t->speed));
  } else if (const auto* s = std::get_if<wire::SubscribeRequest>(&message)) {
    FUZZ_CHECK(std::isfinite(s->maxFrameRate) && s->maxFrameRate >= 0,
               "Subscribe accepted with max_frame_rate " + std::to_string(s->maxFrameRate));
  }

  // The client-side decoder of frames (tests, tools) on the same bytes.
  try {
    const wire::DecodedFrame frame = wire::decodeFrame(data, size);
    FUZZ_CHECK(frame.dimension == 2 || frame.dimension == 3,
               "decodeFrame accepted dimension " + std::to_string(frame.dimension));
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
