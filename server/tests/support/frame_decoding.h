#pragma once
// The client side of a Frame message (proto/flowclip.fbs): verifying and
// decoding what service/frame_encoding.h encodes, as a C++ client would.
// Used by the tests and the fuzz targets; the server never decodes frames.
#include "service/frame_encoding.h"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace fc::wire {

struct DecodedPoints {
  std::array<double, 3> boxMin{}, boxMax{};
  std::vector<std::array<double, 3>> x;   // dequantized, m (z = 0 in 2D)
  // The largest decoding error per axis: (max − min) / 65535 / 2.
  std::array<double, 3> maxError() const;
};

struct DecodedInstance {
  std::string name, templateName;
  bool active = false;
  int templateFrame = -1;
  int phase = 0;
  std::vector<float> worldRowMajor;       // 9 (2D) or 16 (3D)
  std::array<double, 3> templateMin{}, templateMax{};
  double falloffWidth = 0, fidelity = -1;
  uint32_t controlled = 0, controlOffset = 0, controlCount = 0, repulsionOffset = 0, repulsionCount = 0;
};

struct DecodedFrame {
  std::string sessionId;
  int frame = 0;
  double time = 0;
  int dimension = 0;
  std::array<double, 3> domainMin{}, domainMax{};
  LayerFlags layers;                      // layers present
  DecodedPoints particles;
  std::vector<uint8_t> kind, phase;
  DecodedPoints control;                  // empty unless layers.control
  std::vector<double> alpha;              // α per control point, q / 255
  DecodedPoints repulsion;                // empty unless layers.repulsion
  std::vector<DecodedInstance> instances;
  std::vector<double> speed;              // m/s per liquid particle (q / 255 · speed_max), empty unless layers.speed
  double speedMax = 0;
  // Timings and counts (float precision on the wire). `particles` is
  // liquid + temporary; the per-instance list carries name, active, template
  // frame, fidelity, controlled and the layer counts.
  FrameStats stats;
};

// Verifies and decodes an Envelope{Frame}; throws std::invalid_argument
// saying what is wrong (verifier, not a Frame, inconsistent array sizes).
DecodedFrame decodeFrame(const uint8_t* data, size_t size);

}  // namespace fc::wire
