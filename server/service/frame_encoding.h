#pragma once
// The WebSocket wire format (proto/flowclip.fbs, generated into
// flowclip_generated.h at build time): encoding frames and server messages,
// verifying and parsing what clients send. No networking here.
//
// Every function writes one finished Envelope buffer (file identifier
// "FCW1") into the builder it is given, after clearing it: keep one builder
// per connection or per session and its memory is reused from frame to
// frame; send fbb.GetBufferPointer() / fbb.GetSize().
//
// Decoding a Frame, which only clients do, is tests/support/frame_decoding.h.
#include "control/control.h"
#include "sph/simulation.h"

#include "flowclip_generated.h"

#include <array>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace fc::wire {

namespace fb = flowclip::wire;

// 16-bit quantization: q = round((x − min) / (max − min) · 65535).
constexpr double kQuantizationLevels = 65535.0;

// Which optional layers a client wants (Subscribe) or a frame carries.
struct LayerFlags {
  bool control = false;    // control particles of the active instances, with α
  bool repulsion = false;  // repulsion particles of the active instances
  bool boundary = false;   // boundary particles appended to the particles (kind 2)
  bool instances = true;   // instance records (matrix, box, falloff, fidelity)
  bool speed = false;      // |v| per liquid particle, 8 bits against the frame's largest

  fb::Layer bits() const;
  static LayerFlags fromBits(fb::Layer bits);
  bool operator==(const LayerFlags&) const = default;
};

// Thrown by the encoders when the input cannot be encoded (a non-finite
// position, matrix or α; a malformed quantized frame). The builder is left
// cleared; nothing partial is ever sent.
struct EncodeError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// ---- frames ------------------------------------------------------------------

// Encodes the simulation's current state as Envelope{Frame}. The frame
// number and scene time are `stats.frame` and `stats.time` (the session's
// scene clock); timings and per-instance results come from `stats`, counts
// by kind from the particles themselves. `control` (nullable) supplies the
// instance records and the control / repulsion layers: the instances'
// template frames and α are those of the last frame control prepared, their
// world matrices are evaluated at the frame's start, stats.time − 1 /
// frame_rate (when control selected the template frame). Layers that cannot
// be provided (control layers without `control`) are left out and not set
// in Frame.layers.
//
// Throws EncodeError, naming the particle or instance, if any position,
// world matrix or α is not finite; check before calling if that is an
// expected state (FrameStats::finite). Allocates nothing per particle: the
// quantized arrays are written straight into the builder.
template <int D>
void encodeFrame(const Simulation<D>& sim, const FrameStats& stats, const Control<D>* control,
                 const std::string& sessionId, const LayerFlags& layers, flatbuffers::FlatBufferBuilder& fbb);

// One instance record, for frames encoded from already-quantized data.
struct InstanceRecord {
  std::string_view name, templateName;
  bool active = false;
  int templateFrame = -1;
  int phase = 0;
  // Template → world, homogeneous, row-major: the first (D+1)² entries
  // (9 in 2D, 16 in 3D).
  std::array<double, 16> worldRowMajor{};
  std::array<double, 3> templateMin{}, templateMax{};  // template space, m (z = 0 in 2D)
  double falloffWidth = 0;    // m, world
  double fidelity = -1;
  uint64_t controlled = 0;
  // Fills worldRowMajor from a homogeneous 4×4 column-major matrix (three.js
  // Matrix4.elements; a 2D scene's x/y block, z as identity).
  void setWorldFromColumnMajor4x4(const std::array<double, 16>& m, int dimension);
};

// A frame quantized ahead of time (the session's replay history) against the
// domain: positions[i·dimension + d] as in the schema, box = domain.
struct QuantizedFrame {
  std::string_view sessionId;
  int dimension = 3;
  std::array<double, 3> domainMin{}, domainMax{};  // m (z = 0 in 2D)
  std::span<const uint16_t> positions;             // particles × dimension
  std::span<const uint8_t> kind, phase;            // one per particle
  // Optional (Layer.Speed): 16-bit velocities in a symmetric box per axis,
  // as FrameSnapshot stores them (particles × dimension; empty: no speed).
  std::span<const uint16_t> velocities;
  std::array<double, 3> velocityMax{};
  const FrameStats* stats = nullptr;               // frame, time, timings (required)
  std::span<const InstanceRecord> instances;       // sent when layers.instances
};

// Encodes a QuantizedFrame as Envelope{Frame}: particles and instance
// records only (no control, repulsion or boundary layer: Frame.layers says
// so). Counts by kind come from `kind`, the boundary count from stats.
// Throws EncodeError on inconsistent sizes or a non-finite box.
void encodeQuantizedFrame(const QuantizedFrame& frame, const LayerFlags& layers, flatbuffers::FlatBufferBuilder& fbb);

// ---- other server → client messages ------------------------------------------

void buildAck(flatbuffers::FlatBufferBuilder& fbb, uint32_t editId, int32_t frame);
void buildError(flatbuffers::FlatBufferBuilder& fbb, fb::ErrorCode code, std::string_view message,
                uint32_t requestId = 0);

struct StateChangeInfo {
  std::string sessionId;
  fb::SessionStatus status = fb::SessionStatus::Paused;
  int32_t frame = 0;
  double time = 0;                 // s
  int32_t shownFrame = 0;
  bool live = true;
  double playbackSpeed = 0;        // frames per wall s (0: as fast as possible)
  int32_t historyFirstFrame = 0, historyLastFrame = 0;
  uint32_t historyDroppedFrames = 0;
  std::string message;             // the error in status Error
  uint32_t requestId = 0;
  std::string stateJson;           // optional: the REST state object, serialised
};
void buildStateChange(flatbuffers::FlatBufferBuilder& fbb, const StateChangeInfo& info);

// ---- verification --------------------------------------------------------------

// Limits of the verifier: nesting depth and table count (a Frame with n
// instances has n + 7 tables; client messages 2).
constexpr unsigned kVerifyMaxDepth = 16;
constexpr unsigned kVerifyMaxTables = 100000;

// Empty when `data` is a well-formed Envelope (identifier "FCW1", every
// offset, vector and string inside the buffer, depth and table limits),
// otherwise what is wrong. Never reads outside [data, data + size).
std::string verifyEnvelope(const uint8_t* data, size_t size);

// ---- client → server messages ------------------------------------------------

struct EditRequest {
  uint32_t editId = 0;
  std::string json;   // the edit object (service/session.h, Edit::fromJson)
};
struct TransportRequest {
  uint32_t requestId = 0;
  fb::TransportCommand command = fb::TransportCommand::Play;
  uint32_t steps = 1;         // Step
  int32_t frame = -1;         // Seek
  double speed = 0;           // SetSpeed: frames per wall s
  int32_t until = -1;         // Play: the frame play stops at (-1: the scene's end)
};
struct SubscribeRequest {
  uint32_t requestId = 0;
  double maxFrameRate = 0;    // frames per wall s (0: no limit)
  LayerFlags layers;
};
// Why a client message was refused: send it back with
// buildError(fbb, f.code, f.message, f.requestId).
struct ParseFailure {
  fb::ErrorCode code = fb::ErrorCode::InvalidMessage;
  std::string message;
  uint32_t requestId = 0;     // the message's id when it could be read
};
using ClientMessage = std::variant<EditRequest, TransportRequest, SubscribeRequest, ParseFailure>;

// Verifies and parses a client message. Every failure is a ParseFailure
// with a message naming the field: buffer rejected by the verifier or wrong
// identifier (InvalidMessage), no / unknown union type or a server → client
// message (UnsupportedMessage), a required field missing (MissingField), a
// value out of range or a field the command does not use (InvalidArgument).
ClientMessage parseClientMessage(const uint8_t* data, size_t size);

// Client-side builders (tests, C++ clients): fields the command does not use
// are not written.
void buildEdit(flatbuffers::FlatBufferBuilder& fbb, const EditRequest& edit);
void buildTransport(flatbuffers::FlatBufferBuilder& fbb, const TransportRequest& transport);
void buildSubscribe(flatbuffers::FlatBufferBuilder& fbb, const SubscribeRequest& subscribe);

}  // namespace fc::wire
