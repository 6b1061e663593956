// The WebSocket wire format: see frame_encoding.h and proto/flowclip.fbs.
// Long because every table of the wire format is encoded here, beside the
// flatbuffers builder calls that must follow the schema's order.
#include "service/frame_encoding.h"

#include "core/text.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

namespace fc::wire {

namespace {

using flatbuffers::FlatBufferBuilder;
using flatbuffers::Offset;

// ---- quantization ---------------------------------------------------------------

// A box in float (what the wire stores) that encloses [lo, hi] given in
// double: the quantizer uses the float values, so encoder and decoder agree
// exactly on the box.
struct FloatBox {
  std::array<float, 3> lo{0, 0, 0}, hi{0, 0, 0};
};

float floatBelow(double v) {
  float f = float(v);
  if (double(f) > v) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}
float floatAbove(double v) {
  float f = float(v);
  if (double(f) < v) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

FloatBox enclosing(const double lo[3], const double hi[3], int dim) {
  FloatBox b;
  for (int d = 0; d < dim; ++d) {
    b.lo[size_t(d)] = floatBelow(lo[d]);
    b.hi[size_t(d)] = floatAbove(hi[d]);
  }
  return b;
}

bool finiteBox(const FloatBox& b) {
  for (int d = 0; d < 3; ++d)
    if (!std::isfinite(b.lo[size_t(d)]) || !std::isfinite(b.hi[size_t(d)])) return false;
  return true;
}

struct Quantizer {
  double lo[3] = {0, 0, 0};
  double scale[3] = {0, 0, 0};
  explicit Quantizer(const FloatBox& b) {
    for (int d = 0; d < 3; ++d) {
      lo[d] = double(b.lo[size_t(d)]);
      const double extent = double(b.hi[size_t(d)]) - lo[d];
      scale[d] = extent > 0 ? kQuantizationLevels / extent : 0.0;
    }
  }
  // Rounds half up; values outside the box clamp to its faces.
  uint16_t operator()(int d, double x) const {
    double v = (x - lo[d]) * scale[d];
    v = v < 0 ? 0 : (v > kQuantizationLevels ? kQuantizationLevels : v);
    return flatbuffers::EndianScalar(uint16_t(v + 0.5));
  }
};

fb::Vec3 toVec3(const std::array<float, 3>& v) { return fb::Vec3(v[0], v[1], v[2]); }

uint32_t u32(uint64_t v) { return uint32_t(std::min<uint64_t>(v, std::numeric_limits<uint32_t>::max())); }

// Points table whose q vector `fill(uint16_t* q, const Quantizer&)` writes in
// place (count × dim values).
template <class Fill>
Offset<fb::Points> createPoints(FlatBufferBuilder& fbb, const FloatBox& box, size_t count, int dim, Fill&& fill) {
  uint16_t* q = nullptr;
  const auto vec = fbb.CreateUninitializedVector<uint16_t>(count * size_t(dim), &q);
  fill(q, Quantizer(box));
  const fb::Vec3 lo = toVec3(box.lo), hi = toVec3(box.hi);
  return fb::CreatePoints(fbb, &lo, &hi, u32(count), vec);
}

// ---- positions --------------------------------------------------------------------

// Extends [lo, hi] (D axes) by every position; returns the index of the first
// non-finite one, or SIZE_MAX.
template <int D>
size_t scanPositions(const std::vector<Vec<D>>& x, double lo[3], double hi[3]) {
  const long n = long(x.size());
  Real mn[3], mx[3];
  for (int d = 0; d < 3; ++d) {
    mn[d] = std::numeric_limits<Real>::max();
    mx[d] = std::numeric_limits<Real>::lowest();
  }
  long bad = 0;
#pragma omp parallel for schedule(static) reduction(min : mn[:3]) reduction(max : mx[:3]) reduction(+ : bad) if (n >= 65536)
  for (long i = 0; i < n; ++i) {
    bool ok = true;
    for (int d = 0; d < D; ++d) ok &= std::isfinite(x[size_t(i)][d]);
    if (!ok) {
      ++bad;
      continue;
    }
    for (int d = 0; d < D; ++d) {
      mn[d] = std::min(mn[d], x[size_t(i)][d]);
      mx[d] = std::max(mx[d], x[size_t(i)][d]);
    }
  }
  if (bad) {
    for (size_t i = 0; i < x.size(); ++i)
      if (!x[i].allFinite()) return i;
  }
  for (int d = 0; d < D; ++d) {
    if (n == 0) break;
    lo[d] = std::min(lo[d], double(mn[d]));
    hi[d] = std::max(hi[d], double(mx[d]));
  }
  return SIZE_MAX;
}

template <int D>
std::string describe(const Vec<D>& x) {
  std::string s = "(";
  for (int d = 0; d < D; ++d) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%s%g", d ? ", " : "", double(x[d]));
    s += buf;
  }
  return s + ")";
}

template <int D>
void quantizePositions(const std::vector<Vec<D>>& x, uint16_t* q, const Quantizer& quant) {
  const long n = long(x.size());
#pragma omp parallel for schedule(static) if (n >= 65536)
  for (long i = 0; i < n; ++i)
    for (int d = 0; d < D; ++d) q[size_t(i) * D + size_t(d)] = quant(d, double(x[size_t(i)][d]));
}

// ---- instances and stats --------------------------------------------------------

struct LayerSpan {
  uint32_t controlOffset = 0, controlCount = 0, repulsionOffset = 0, repulsionCount = 0;
};

Offset<fb::Instance> createInstance(FlatBufferBuilder& fbb, const InstanceRecord& r, int dim, bool withMatrix,
                                    const LayerSpan& span) {
  const auto name = fbb.CreateString(r.name.data(), r.name.size());
  const auto tname = fbb.CreateString(r.templateName.data(), r.templateName.size());
  Offset<flatbuffers::Vector<float>> matrix;
  if (withMatrix) {
    const size_t m = size_t(dim + 1) * size_t(dim + 1);
    float* out = nullptr;
    matrix = fbb.CreateUninitializedVector<float>(m, &out);
    for (size_t k = 0; k < m; ++k) out[k] = flatbuffers::EndianScalar(float(r.worldRowMajor[k]));
  }
  const fb::Vec3 tmin(float(r.templateMin[0]), float(r.templateMin[1]), float(r.templateMin[2]));
  const fb::Vec3 tmax(float(r.templateMax[0]), float(r.templateMax[1]), float(r.templateMax[2]));
  fb::InstanceBuilder b(fbb);
  b.add_name(name);
  b.add_template_name(tname);
  b.add_active(r.active);
  b.add_template_frame(r.templateFrame);
  b.add_phase(uint8_t(std::clamp(r.phase, 0, 255)));
  if (withMatrix) b.add_world_matrix(matrix);
  b.add_template_min(&tmin);
  b.add_template_max(&tmax);
  b.add_falloff_width(float(r.falloffWidth));
  b.add_fidelity(float(r.fidelity));
  b.add_controlled(u32(r.controlled));
  b.add_control_offset(span.controlOffset);
  b.add_control_count(span.controlCount);
  b.add_repulsion_offset(span.repulsionOffset);
  b.add_repulsion_count(span.repulsionCount);
  return b.Finish();
}

struct KindCounts {
  uint64_t liquid = 0, temporary = 0, boundary = 0;
};

Offset<fb::Stats> createStats(FlatBufferBuilder& fbb, const FrameStats& s, const KindCounts& counts) {
  fb::StatsBuilder b(fbb);
  b.add_wall_ms(float(s.wallMs));
  b.add_control_ms(float(s.controlMs));
  b.add_neighbor_ms(float(s.neighborMs));
  b.add_density_ms(float(s.densityMs));
  b.add_divergence_ms(float(s.divergenceMs));
  b.add_non_pressure_ms(float(s.nonPressureMs));
  b.add_pressure_ms(float(s.pressureMs));
  b.add_substeps(uint32_t(std::max(s.substeps, 0)));
  b.add_divergence_iterations(uint32_t(std::max(s.divergenceIterations, 0)));
  b.add_density_iterations(uint32_t(std::max(s.densityIterations, 0)));
  b.add_avg_density_error_pct(float(s.avgDensityErrorPct));
  b.add_max_density_error_pct(float(s.maxDensityErrorPct));
  b.add_converged(s.converged);
  b.add_min_dt(float(s.minDt));
  b.add_max_dt(float(s.maxDt));
  b.add_max_speed(float(s.maxSpeed));
  b.add_avg_neighbors(float(s.avgNeighbors));
  b.add_liquid_particles(u32(counts.liquid));
  b.add_temporary_particles(u32(counts.temporary));
  b.add_boundary_particles(u32(counts.boundary));
  b.add_control_particles(u32(s.controlParticles));
  b.add_repulsion_particles(u32(s.repulsionParticles));
  b.add_controlled_particles(u32(s.controlledParticles));
  b.add_seeded_particles(u32(s.seededParticles));
  b.add_removed_particles(u32(s.removedParticles));
  b.add_escaped_particles(u32(s.escapedParticles));
  return b.Finish();
}

void finishEnvelope(FlatBufferBuilder& fbb, fb::Message type, Offset<void> message) {
  fb::EnvelopeBuilder b(fbb);
  b.add_message_type(type);
  b.add_message(message);
  fb::FinishEnvelopeBuffer(fbb, b.Finish());
}

// Everything of a Frame table except what encodeFrame / encodeQuantizedFrame
// compute differently.
struct FrameParts {
  Offset<flatbuffers::String> sessionId;
  int frame = 0;
  double time = 0;
  int dimension = 3;
  FloatBox domain;
  fb::Layer layers = fb::Layer::NONE;
  Offset<fb::Points> particles;
  Offset<flatbuffers::Vector<uint8_t>> kind, phase;
  Offset<fb::ControlLayer> control;
  Offset<fb::Points> repulsion;
  Offset<flatbuffers::Vector<Offset<fb::Instance>>> instances;
  Offset<fb::Stats> stats;
  Offset<flatbuffers::Vector<uint8_t>> speed;
  float speedMax = 0;
};

void finishFrame(FlatBufferBuilder& fbb, const FrameParts& p) {
  const fb::Vec3 dmin = toVec3(p.domain.lo), dmax = toVec3(p.domain.hi);
  fb::FrameBuilder b(fbb);
  b.add_session_id(p.sessionId);
  b.add_frame(p.frame);
  b.add_time(p.time);
  b.add_dimension(uint8_t(p.dimension));
  b.add_domain_min(&dmin);
  b.add_domain_max(&dmax);
  b.add_layers(p.layers);
  b.add_particles(p.particles);
  b.add_kind(p.kind);
  b.add_phase(p.phase);
  if (!p.control.IsNull()) b.add_control(p.control);
  if (!p.repulsion.IsNull()) b.add_repulsion(p.repulsion);
  if (!p.instances.IsNull()) b.add_instances(p.instances);
  b.add_stats(p.stats);
  if (!p.speed.IsNull()) {
    b.add_speed(p.speed);
    b.add_speed_max(p.speedMax);
  }
  finishEnvelope(fbb, fb::Message::Frame, b.Finish().Union());
}

template <int D>
std::array<double, 16> rowMajor(const Affine<D>& a) {
  std::array<double, 16> m{};
  const auto h = a.homogeneous();
  for (int r = 0; r <= D; ++r)
    for (int c = 0; c <= D; ++c) m[size_t(r * (D + 1) + c)] = double(h(r, c));
  return m;
}

// Template → world in double (so that the bounds pass and the quantization
// pass compute the same world points).
template <int D>
struct WorldMap {
  Eigen::Matrix<double, D, D> linear;
  Eigen::Matrix<double, D, 1> translation;
  explicit WorldMap(const Affine<D>& a)
      : linear(a.linear.template cast<double>()), translation(a.translation.template cast<double>()) {}
  Eigen::Matrix<double, D, 1> operator()(const Vec<D>& x) const {
    return linear * x.template cast<double>() + translation;
  }
};

template <int D>
void extendMapped(const WorldMap<D>& map, const std::vector<Vec<D>>& x, double lo[3], double hi[3]) {
  for (const auto& p : x) {
    const auto w = map(p);
    for (int d = 0; d < D; ++d) {
      lo[d] = std::min(lo[d], w[d]);
      hi[d] = std::max(hi[d], w[d]);
    }
  }
}

template <int D>
void quantizeMapped(const WorldMap<D>& map, const std::vector<Vec<D>>& x, uint16_t* q, const Quantizer& quant) {
  for (size_t i = 0; i < x.size(); ++i) {
    const auto w = map(x[i]);
    for (int d = 0; d < D; ++d) q[i * D + size_t(d)] = quant(d, w[d]);
  }
}

// Layer.Speed: speeds[i] = |v_i| → round(|v| / max · 255); a non-finite
// speed (never published: the session stops first) encodes as 255.
Offset<flatbuffers::Vector<uint8_t>> createSpeed(FlatBufferBuilder& fbb, const std::vector<double>& speeds, float& maxOut) {
  double mx = 0;
  for (double v : speeds)
    if (std::isfinite(v)) mx = std::max(mx, v);
  maxOut = float(mx);
  uint8_t* q = nullptr;
  auto out = fbb.CreateUninitializedVector<uint8_t>(speeds.size(), &q);
  const double scale = mx > 0 ? 255.0 / mx : 0.0;
  for (size_t i = 0; i < speeds.size(); ++i)
    q[i] = std::isfinite(speeds[i]) ? uint8_t(std::min(255.0, speeds[i] * scale + 0.5)) : uint8_t(255);
  return out;
}

uint8_t quantizeAlpha(Real a) {
  const double v = std::clamp(double(a), 0.0, 1.0);
  return uint8_t(v * 255.0 + 0.5);
}

template <int D>
void encodeFrameImpl(const Simulation<D>& sim, const FrameStats& stats, const Control<D>* control,
                     const std::string& sessionId, const LayerFlags& layers, FlatBufferBuilder& fbb) {
  const auto& fluid = sim.fluid;
  const auto& boundary = sim.boundary;
  const AABB<D>& domain = sim.setup().domain;
  const bool withBoundary = layers.boundary;
  const size_t nLiquid = fluid.size();
  const size_t nBoundary = withBoundary ? boundary.size() : 0;
  const size_t n = nLiquid + nBoundary;
  if (fluid.kind.size() != nLiquid || fluid.phase.size() != nLiquid)
    throw EncodeError("particle arrays disagree: " + std::to_string(nLiquid) + " positions, " +
                      std::to_string(fluid.kind.size()) + " kinds, " + std::to_string(fluid.phase.size()) + " phases");

  // ---- checks and boxes first: nothing is built unless all of it encodes.
  double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
  for (int d = 0; d < D; ++d) {
    lo[d] = double(domain.min[d]);
    hi[d] = double(domain.max[d]);
  }
  const FloatBox domainBox = enclosing(lo, hi, D);
  if (!finiteBox(domainBox)) throw EncodeError("the domain box is not finite");
  if (size_t i = scanPositions<D>(fluid.x, lo, hi); i != SIZE_MAX)
    throw EncodeError("particle " + std::to_string(i) + " (id " + std::to_string(fluid.id.size() > i ? fluid.id[i] : 0) +
                      ") has a non-finite position " + describe<D>(fluid.x[i]));
  if (withBoundary)
    if (size_t i = scanPositions<D>(boundary.x, lo, hi); i != SIZE_MAX)
      throw EncodeError("boundary particle " + std::to_string(i) + " has a non-finite position " +
                        describe<D>(boundary.x[i]));
  const FloatBox particleBox = enclosing(lo, hi, D);

  // Instances: placement at the frame's start (when control selected their
  // template frames).
  const size_t nInst = control ? control->instances().size() : 0;
  const double frameStart = stats.frame > 0 ? std::max(0.0, stats.time - sim.frameDuration()) : stats.time;
  std::vector<Affine<D>> maps(nInst);
  std::vector<LayerSpan> spans(nInst);
  const bool sendControl = layers.control && control;
  const bool sendRepulsion = layers.repulsion && control;
  double clo[3], chi[3], rlo[3], rhi[3];
  for (int d = 0; d < 3; ++d) {
    clo[d] = rlo[d] = std::numeric_limits<double>::max();
    chi[d] = rhi[d] = std::numeric_limits<double>::lowest();
  }
  size_t nControl = 0, nRepulsion = 0;
  for (size_t i = 0; i < nInst; ++i) {
    const BoundInstance<D>& inst = control->instances()[i];
    maps[i] = inst.spec.transform.templateToWorld(frameStart, inst.centre());
    if (!maps[i].linear.allFinite() || !maps[i].translation.allFinite())
      throw EncodeError("instance '" + inst.spec.name + "' has a non-finite world matrix at t = " +
                        std::to_string(frameStart) + " s");
    if (!control->isActive(i) || !inst.accel) continue;
    const size_t f = control->templateFrame(i);
    if (f >= inst.accel->frameCount()) continue;
    const auto gridsHeld = inst.accel->frame(f);  // keeps a streamed frame while it is read
    const TemplateFrameGrids<D>& grids = *gridsHeld;
    const WorldMap<D> map(maps[i]);
    if (sendControl) {
      const auto& alpha = control->coverage(i);
      for (size_t j = 0; j < alpha.size(); ++j)
        if (!std::isfinite(alpha[j]))
          throw EncodeError("instance '" + inst.spec.name + "': α of control particle " + std::to_string(j) +
                            " is not finite");
      spans[i].controlOffset = u32(nControl);
      spans[i].controlCount = u32(grids.controlCount());
      nControl += grids.controlCount();
      extendMapped<D>(map, grids.controlPositions(), clo, chi);
    }
    if (sendRepulsion && inst.spec.params.repulsion) {
      spans[i].repulsionOffset = u32(nRepulsion);
      spans[i].repulsionCount = u32(grids.repulsionCount());
      nRepulsion += grids.repulsionCount();
      extendMapped<D>(map, grids.repulsionPositions(), rlo, rhi);
    }
  }
  for (int d = 0; d < 3; ++d) {
    if (nControl == 0 || d >= D) clo[d] = chi[d] = 0;
    if (nRepulsion == 0 || d >= D) rlo[d] = rhi[d] = 0;
  }
  const FloatBox controlBox = enclosing(clo, chi, D), repulsionBox = enclosing(rlo, rhi, D);
  if (!finiteBox(controlBox) || !finiteBox(repulsionBox))
    throw EncodeError("control or repulsion particles map outside the float range");

  // ---- build (children before parents).
  FrameParts p;
  p.sessionId = fbb.CreateString(sessionId);
  p.frame = stats.frame;
  p.time = stats.time;
  p.dimension = D;
  p.domain = domainBox;

  p.particles = createPoints(fbb, particleBox, n, D, [&](uint16_t* q, const Quantizer& quant) {
    quantizePositions<D>(fluid.x, q, quant);
    if (withBoundary) quantizePositions<D>(boundary.x, q + nLiquid * D, quant);
  });
  KindCounts counts;
  {
    uint8_t* k = nullptr;
    p.kind = fbb.CreateUninitializedVector<uint8_t>(n, &k);
    if (nLiquid) std::memcpy(k, fluid.kind.data(), nLiquid);
    std::memset(k + nLiquid, uint8_t(ParticleKind::Boundary), nBoundary);
    uint64_t temporary = 0;
    const uint8_t* kinds = fluid.kind.data();
    for (size_t i = 0; i < nLiquid; ++i) temporary += kinds[i] == uint8_t(ParticleKind::Temporary);
    counts.temporary = temporary;
    counts.liquid = nLiquid - temporary;
    counts.boundary = boundary.size();
    uint8_t* ph = nullptr;
    p.phase = fbb.CreateUninitializedVector<uint8_t>(n, &ph);
    if (nLiquid) std::memcpy(ph, fluid.phase.data(), nLiquid);
    std::memset(ph + nLiquid, 255, nBoundary);
  }
  fb::Layer present = fb::Layer::NONE;
  if (withBoundary) present |= fb::Layer::Boundary;

  if (sendControl) {
    present |= fb::Layer::Control;
    const auto points = createPoints(fbb, controlBox, nControl, D, [&](uint16_t* q, const Quantizer& quant) {
      for (size_t i = 0; i < nInst; ++i) {
        if (spans[i].controlCount == 0) continue;
        const auto gridsHeld = control->instances()[i].accel->frame(control->templateFrame(i));  // keeps a streamed frame while it is read
        const auto& grids = *gridsHeld;
        quantizeMapped<D>(WorldMap<D>(maps[i]), grids.controlPositions(), q + size_t(spans[i].controlOffset) * D, quant);
      }
    });
    uint8_t* a = nullptr;
    const auto alpha = fbb.CreateUninitializedVector<uint8_t>(nControl, &a);
    for (size_t i = 0; i < nInst; ++i) {
      if (spans[i].controlCount == 0) continue;
      const auto& cov = control->coverage(i);
      uint8_t* out = a + spans[i].controlOffset;
      // α not computed for this frame (no force evaluation yet): 1, uncovered.
      if (cov.size() != spans[i].controlCount) std::memset(out, 255, spans[i].controlCount);
      else
        for (size_t j = 0; j < cov.size(); ++j) out[j] = quantizeAlpha(cov[j]);
    }
    p.control = fb::CreateControlLayer(fbb, points, alpha);
  }
  if (sendRepulsion) {
    present |= fb::Layer::Repulsion;
    p.repulsion = createPoints(fbb, repulsionBox, nRepulsion, D, [&](uint16_t* q, const Quantizer& quant) {
      for (size_t i = 0; i < nInst; ++i) {
        if (spans[i].repulsionCount == 0) continue;
        const auto gridsHeld = control->instances()[i].accel->frame(control->templateFrame(i));  // keeps a streamed frame while it is read
        const auto& grids = *gridsHeld;
        quantizeMapped<D>(WorldMap<D>(maps[i]), grids.repulsionPositions(), q + size_t(spans[i].repulsionOffset) * D,
                          quant);
      }
    });
  }

  if (layers.instances && (control || !stats.instances.empty())) {
    present |= fb::Layer::Instances;
    std::vector<Offset<fb::Instance>> records;
    if (control) {
      records.reserve(nInst);
      for (size_t i = 0; i < nInst; ++i) {
        const BoundInstance<D>& inst = control->instances()[i];
        InstanceRecord r;
        r.name = inst.spec.name;
        r.templateName = inst.spec.templateName;
        r.active = control->isActive(i);
        r.templateFrame = r.active ? int(control->templateFrame(i)) : -1;
        r.phase = inst.spec.phase;
        r.worldRowMajor = rowMajor<D>(maps[i]);
        if (inst.accel && inst.accel->source) {
          const AABB<D> region = inst.templ().region();
          for (int d = 0; d < D; ++d) {
            r.templateMin[size_t(d)] = double(region.min[d]);
            r.templateMax[size_t(d)] = double(region.max[d]);
          }
        }
        r.falloffWidth = inst.spec.params.falloffWidth;
        if (stats.instances.size() == nInst && stats.instances[i].name == inst.spec.name) {
          r.fidelity = stats.instances[i].fidelity;
          r.controlled = stats.instances[i].controlled;
        } else {
          r.fidelity = r.active ? control->fidelity(i) : -1;
        }
        records.push_back(createInstance(fbb, r, D, true, spans[i]));
      }
    } else {
      // No control stage at hand: what the stats say, without placement.
      records.reserve(stats.instances.size());
      for (const InstanceFrameStats& s : stats.instances) {
        InstanceRecord r;
        r.name = s.name;
        r.active = s.active;
        r.templateFrame = s.templateFrame;
        r.fidelity = s.fidelity;
        r.controlled = s.controlled;
        records.push_back(createInstance(fbb, r, D, false, LayerSpan{}));
      }
    }
    p.instances = fbb.CreateVector(records);
  }
  if (layers.speed) {
    std::vector<double> speeds(nLiquid);
    for (size_t i = 0; i < nLiquid; ++i) speeds[i] = double(fluid.v[i].norm());
    p.speed = createSpeed(fbb, speeds, p.speedMax);
    present |= fb::Layer::Speed;
  }
  p.layers = present;
  p.stats = createStats(fbb, stats, counts);
  finishFrame(fbb, p);
}

std::string escapeIdentifier(const uint8_t* id) {
  std::string s;
  for (int k = 0; k < 4; ++k) {
    const unsigned char c = id[k];
    if (c >= 0x20 && c < 0x7f) s += char(c);
    else {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\x%02x", c);
      s += buf;
    }
  }
  return s;
}

ParseFailure failure(fb::ErrorCode code, std::string message, uint32_t requestId = 0) {
  return ParseFailure{code, std::move(message), requestId};
}

ParseFailure unusedField(const char* field, const char* usedBy, fb::TransportCommand cmd, uint32_t requestId) {
  return failure(fb::ErrorCode::InvalidArgument,
                 std::string("Transport.") + field + " is only used by " + usedBy + " (command is " +
                     fb::EnumNameTransportCommand(cmd) + ")",
                 requestId);
}

std::string number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

}  // namespace

// ---- layer flags ----------------------------------------------------------------

fb::Layer LayerFlags::bits() const {
  fb::Layer b = fb::Layer::NONE;
  if (control) b |= fb::Layer::Control;
  if (repulsion) b |= fb::Layer::Repulsion;
  if (boundary) b |= fb::Layer::Boundary;
  if (instances) b |= fb::Layer::Instances;
  if (speed) b |= fb::Layer::Speed;
  return b;
}

LayerFlags LayerFlags::fromBits(fb::Layer bits) {
  LayerFlags f;
  f.control = (bits & fb::Layer::Control) != fb::Layer::NONE;
  f.repulsion = (bits & fb::Layer::Repulsion) != fb::Layer::NONE;
  f.boundary = (bits & fb::Layer::Boundary) != fb::Layer::NONE;
  f.instances = (bits & fb::Layer::Instances) != fb::Layer::NONE;
  f.speed = (bits & fb::Layer::Speed) != fb::Layer::NONE;
  return f;
}

// ---- frames -----------------------------------------------------------------------

template <int D>
void encodeFrame(const Simulation<D>& sim, const FrameStats& stats, const Control<D>* control,
                 const std::string& sessionId, const LayerFlags& layers, flatbuffers::FlatBufferBuilder& fbb) {
  fbb.Clear();
  try {
    encodeFrameImpl<D>(sim, stats, control, sessionId, layers, fbb);
  } catch (...) {
    fbb.Clear();
    throw;
  }
}

template void encodeFrame<2>(const Simulation<2>&, const FrameStats&, const Control<2>*, const std::string&,
                             const LayerFlags&, flatbuffers::FlatBufferBuilder&);
template void encodeFrame<3>(const Simulation<3>&, const FrameStats&, const Control<3>*, const std::string&,
                             const LayerFlags&, flatbuffers::FlatBufferBuilder&);

void InstanceRecord::setWorldFromColumnMajor4x4(const std::array<double, 16>& m, int dimension) {
  worldRowMajor.fill(0);
  const int n = dimension + 1;
  // Homogeneous row/column r of the (D+1)² matrix is row/column r of the 4×4
  // for r < D, and its row/column 3 for the last one.
  auto src = [&](int r) { return r < dimension ? r : 3; };
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) worldRowMajor[size_t(r * n + c)] = m[size_t(src(c) * 4 + src(r))];
}

void encodeQuantizedFrame(const QuantizedFrame& f, const LayerFlags& layers, flatbuffers::FlatBufferBuilder& fbb) {
  fbb.Clear();
  if (f.dimension != 2 && f.dimension != 3)
    throw EncodeError("dimension " + std::to_string(f.dimension) + " is not 2 or 3");
  if (!f.stats) throw EncodeError("a quantized frame needs its stats");
  const size_t n = f.kind.size();
  if (f.phase.size() != n || f.positions.size() != n * size_t(f.dimension))
    throw EncodeError("quantized frame arrays disagree: " + std::to_string(f.positions.size()) + " coordinates, " +
                      std::to_string(n) + " kinds, " + std::to_string(f.phase.size()) + " phases in " +
                      std::to_string(f.dimension) + "D");
  double lo[3], hi[3];
  for (int d = 0; d < 3; ++d) {
    lo[d] = d < f.dimension ? f.domainMin[size_t(d)] : 0.0;
    hi[d] = d < f.dimension ? f.domainMax[size_t(d)] : 0.0;
  }
  // The positions were quantized against these values: store them as they
  // are (rounding to float is exact for a float domain).
  FloatBox box;
  for (int d = 0; d < 3; ++d) {
    box.lo[size_t(d)] = float(lo[d]);
    box.hi[size_t(d)] = float(hi[d]);
  }
  if (!finiteBox(box)) throw EncodeError("the domain box is not finite");
  for (const InstanceRecord& r : f.instances)
    for (size_t k = 0; k < size_t((f.dimension + 1) * (f.dimension + 1)); ++k)
      if (!std::isfinite(r.worldRowMajor[k]))
        throw EncodeError("instance '" + std::string(r.name) + "' has a non-finite world matrix");
  try {
    FrameParts p;
    p.sessionId = fbb.CreateString(f.sessionId.data(), f.sessionId.size());
    p.frame = f.stats->frame;
    p.time = f.stats->time;
    p.dimension = f.dimension;
    p.domain = box;
    p.particles = createPoints(fbb, box, n, f.dimension, [&](uint16_t* q, const Quantizer&) {
      if (FLATBUFFERS_LITTLEENDIAN) {
        if (!f.positions.empty()) std::memcpy(q, f.positions.data(), f.positions.size() * sizeof(uint16_t));
      } else {
        for (size_t k = 0; k < f.positions.size(); ++k) q[k] = flatbuffers::EndianScalar(f.positions[k]);
      }
    });
    p.kind = fbb.CreateVector(f.kind.data(), n);
    p.phase = fbb.CreateVector(f.phase.data(), n);
    KindCounts counts;
    for (uint8_t k : f.kind) counts.temporary += k == uint8_t(ParticleKind::Temporary);
    counts.liquid = n - counts.temporary;
    counts.boundary = f.stats->boundaryParticles;
    fb::Layer present = fb::Layer::NONE;
    if (layers.instances && !f.instances.empty()) {
      present |= fb::Layer::Instances;
      std::vector<Offset<fb::Instance>> records;
      records.reserve(f.instances.size());
      for (const InstanceRecord& r : f.instances) records.push_back(createInstance(fbb, r, f.dimension, true, {}));
      p.instances = fbb.CreateVector(records);
    }
    const size_t dim = size_t(f.dimension);
    if (layers.speed && f.velocities.size() == n * dim) {
      std::vector<double> speeds(n);
      for (size_t i = 0; i < n; ++i) {
        double v2 = 0;
        for (size_t d = 0; d < dim; ++d) {
          const double v = (double(f.velocities[i * dim + d]) * (2.0 / 65535.0) - 1.0) * f.velocityMax[d];
          v2 += v * v;
        }
        speeds[i] = std::sqrt(v2);
      }
      p.speed = createSpeed(fbb, speeds, p.speedMax);
      present |= fb::Layer::Speed;
    }
    p.layers = present;
    p.stats = createStats(fbb, *f.stats, counts);
    finishFrame(fbb, p);
  } catch (...) {
    fbb.Clear();
    throw;
  }
}

// ---- other server → client messages --------------------------------------------

void buildAck(flatbuffers::FlatBufferBuilder& fbb, uint32_t editId, int32_t frame) {
  fbb.Clear();
  const auto ack = fb::CreateAck(fbb, editId, frame);
  finishEnvelope(fbb, fb::Message::Ack, ack.Union());
}

void buildError(flatbuffers::FlatBufferBuilder& fbb, fb::ErrorCode code, std::string_view message, uint32_t requestId) {
  fbb.Clear();
  // Messages may echo client bytes; flatbuffers strings are UTF-8.
  const std::string safe = printable(message);
  const auto text = fbb.CreateString(safe);
  const auto err = fb::CreateError(fbb, code, text, requestId);
  finishEnvelope(fbb, fb::Message::Error, err.Union());
}

void buildStateChange(flatbuffers::FlatBufferBuilder& fbb, const StateChangeInfo& s) {
  fbb.Clear();
  const auto sid = fbb.CreateString(s.sessionId);
  const auto msg = s.message.empty() ? Offset<flatbuffers::String>() : fbb.CreateString(printable(s.message));
  const auto json = s.stateJson.empty() ? Offset<flatbuffers::String>()
                                        : fbb.CreateString(isValidUtf8(s.stateJson) ? s.stateJson : printable(s.stateJson, SIZE_MAX));
  fb::StateChangeBuilder b(fbb);
  b.add_session_id(sid);
  b.add_status(s.status);
  b.add_frame(s.frame);
  b.add_time(s.time);
  b.add_shown_frame(s.shownFrame);
  b.add_live(s.live);
  b.add_playback_speed(float(s.playbackSpeed));
  b.add_history_first_frame(s.historyFirstFrame);
  b.add_history_last_frame(s.historyLastFrame);
  b.add_history_dropped_frames(s.historyDroppedFrames);
  if (!msg.IsNull()) b.add_message(msg);
  b.add_request_id(s.requestId);
  if (!json.IsNull()) b.add_state_json(json);
  finishEnvelope(fbb, fb::Message::StateChange, b.Finish().Union());
}

// ---- verification -----------------------------------------------------------------

std::string verifyEnvelope(const uint8_t* data, size_t size) {
  if (!data || size == 0) return "empty message";
  // Root offset (4 bytes) and file identifier (4 bytes).
  if (size < 8)
    return "message of " + std::to_string(size) + " bytes is too short for a flatbuffer (at least 8: root offset, file identifier)";
  if (size >= size_t(FLATBUFFERS_MAX_BUFFER_SIZE)) return "message of " + std::to_string(size) + " bytes is too large";
  if (!fb::EnvelopeBufferHasIdentifier(data))
    return "file identifier is '" + escapeIdentifier(data + 4) + "', expected '" + fb::EnvelopeIdentifier() +
           "' (not a FlowClip wire message)";
  flatbuffers::Verifier::Options options;
  options.max_depth = kVerifyMaxDepth;
  options.max_tables = kVerifyMaxTables;
  flatbuffers::Verifier verifier(data, size, options);
  if (!fb::VerifyEnvelopeBuffer(verifier))
    return "message of " + std::to_string(size) +
           " bytes failed flatbuffers verification: not a well-formed Envelope (truncated or corrupt buffer, an "
           "offset, vector or string out of bounds, or more than " +
           std::to_string(kVerifyMaxDepth) + " nesting levels / " + std::to_string(kVerifyMaxTables) + " tables)";
  return {};
}

// ---- client messages ---------------------------------------------------------------

ClientMessage parseClientMessage(const uint8_t* data, size_t size) {
  if (std::string err = verifyEnvelope(data, size); !err.empty())
    return failure(fb::ErrorCode::InvalidMessage, std::move(err));
  const fb::Envelope* env = fb::GetEnvelope(data);
  const fb::Message type = env->message_type();
  const unsigned typeValue = unsigned(type);
  if (type == fb::Message::NONE)
    return failure(fb::ErrorCode::MissingField, "Envelope.message is missing (message type NONE)");
  if (typeValue > unsigned(fb::Message::MAX))
    return failure(fb::ErrorCode::UnsupportedMessage,
                   "unknown message type " + std::to_string(typeValue) +
                       ": a client sends Edit (5), Transport (6) or Subscribe (7)");
  const char* typeName = fb::EnumNameMessage(type);
  if (type == fb::Message::Frame || type == fb::Message::StateChange || type == fb::Message::Ack ||
      type == fb::Message::Error)
    return failure(fb::ErrorCode::UnsupportedMessage,
                   std::string(typeName) + " is a server → client message; a client sends Edit, Transport or Subscribe");
  if (!env->message())
    return failure(fb::ErrorCode::MissingField,
                   std::string("Envelope.message: type is ") + typeName + " but the table is missing");

  switch (type) {
    case fb::Message::Edit: {
      const fb::Edit* e = env->message_as_Edit();
      const uint32_t id = e->edit_id();
      if (id == 0)
        return failure(fb::ErrorCode::MissingField, "Edit.edit_id is missing or 0 (must be non-zero: Ack and Error echo it)");
      if (!e->json()) return failure(fb::ErrorCode::MissingField, "Edit.json is missing", id);
      if (e->json()->size() == 0)
        return failure(fb::ErrorCode::MissingField, "Edit.json is empty (expected a JSON edit object)", id);
      return EditRequest{id, e->json()->str()};
    }
    case fb::Message::Transport: {
      const fb::Transport* t = env->message_as_Transport();
      TransportRequest r;
      r.requestId = t->request_id();
      r.command = t->command();
      if (unsigned(r.command) > unsigned(fb::TransportCommand::MAX))
        return failure(fb::ErrorCode::InvalidArgument,
                       "Transport.command " + std::to_string(unsigned(r.command)) +
                           " is not one of Play (0), Pause (1), Step (2), Reset (3), Seek (4), SetSpeed (5)",
                       r.requestId);
      const auto steps = t->steps();
      const auto frame = t->frame();
      const auto speed = t->speed();
      const auto until = t->until();
      if (steps && r.command != fb::TransportCommand::Step) return unusedField("steps", "Step", r.command, r.requestId);
      if (until && r.command != fb::TransportCommand::Play) return unusedField("until", "Play", r.command, r.requestId);
      if (frame && r.command != fb::TransportCommand::Seek) return unusedField("frame", "Seek", r.command, r.requestId);
      if (speed && r.command != fb::TransportCommand::SetSpeed)
        return unusedField("speed", "SetSpeed", r.command, r.requestId);
      switch (r.command) {
        case fb::TransportCommand::Play:
          if (until) {
            r.until = *until;
            if (r.until < 0)
              return failure(fb::ErrorCode::InvalidArgument,
                             "Transport.until is " + std::to_string(r.until) + ", must be >= 0", r.requestId);
          }
          break;
        case fb::TransportCommand::Step:
          r.steps = steps ? *steps : 1;
          if (r.steps < 1 || r.steps > 1000000)
            return failure(fb::ErrorCode::InvalidArgument,
                           "Transport.steps is " + std::to_string(r.steps) + ", must be 1..1000000", r.requestId);
          break;
        case fb::TransportCommand::Seek:
          if (!frame) return failure(fb::ErrorCode::MissingField, "Transport.frame is required by Seek", r.requestId);
          r.frame = *frame;
          if (r.frame < 0)
            return failure(fb::ErrorCode::InvalidArgument,
                           "Transport.frame is " + std::to_string(r.frame) + ", must be >= 0", r.requestId);
          break;
        case fb::TransportCommand::SetSpeed:
          if (!speed) return failure(fb::ErrorCode::MissingField, "Transport.speed is required by SetSpeed", r.requestId);
          r.speed = double(*speed);
          if (!std::isfinite(r.speed) || r.speed < 0 || r.speed > 10000)
            return failure(fb::ErrorCode::InvalidArgument,
                           "Transport.speed is " + number(r.speed) +
                               ", must be 0..10000 frames per second (0: as fast as possible)",
                           r.requestId);
          break;
        default:
          break;
      }
      return r;
    }
    case fb::Message::Subscribe: {
      const fb::Subscribe* s = env->message_as_Subscribe();
      SubscribeRequest r;
      r.requestId = s->request_id();
      r.maxFrameRate = double(s->max_frame_rate());
      if (!std::isfinite(r.maxFrameRate) || r.maxFrameRate < 0 || r.maxFrameRate > 1000)
        return failure(fb::ErrorCode::InvalidArgument,
                       "Subscribe.max_frame_rate is " + number(r.maxFrameRate) +
                           ", must be 0..1000 frames per second (0: no limit)",
                       r.requestId);
      const unsigned bits = unsigned(s->layers());
      if (bits & ~unsigned(fb::Layer::ANY)) {
        char buf[16];
        std::snprintf(buf, sizeof buf, "0x%02x", bits & ~unsigned(fb::Layer::ANY));
        return failure(fb::ErrorCode::InvalidArgument,
                       std::string("Subscribe.layers has unknown bits ") + buf +
                           " (known: Control 1, Repulsion 2, Boundary 4, Instances 8, Speed 16)",
                       r.requestId);
      }
      r.layers = LayerFlags::fromBits(s->layers());
      return r;
    }
    default:
      return failure(fb::ErrorCode::UnsupportedMessage, std::string("message type ") + typeName + " is not handled");
  }
}

void buildEdit(flatbuffers::FlatBufferBuilder& fbb, const EditRequest& edit) {
  fbb.Clear();
  const auto json = fbb.CreateString(edit.json);
  const auto e = fb::CreateEdit(fbb, edit.editId, json);
  finishEnvelope(fbb, fb::Message::Edit, e.Union());
}

void buildTransport(flatbuffers::FlatBufferBuilder& fbb, const TransportRequest& t) {
  fbb.Clear();
  fb::TransportBuilder b(fbb);
  b.add_request_id(t.requestId);
  b.add_command(t.command);
  if (t.command == fb::TransportCommand::Step) b.add_steps(t.steps);
  if (t.command == fb::TransportCommand::Seek) b.add_frame(t.frame);
  if (t.command == fb::TransportCommand::SetSpeed) b.add_speed(float(t.speed));
  if (t.command == fb::TransportCommand::Play && t.until >= 0) b.add_until(t.until);
  finishEnvelope(fbb, fb::Message::Transport, b.Finish().Union());
}

void buildSubscribe(flatbuffers::FlatBufferBuilder& fbb, const SubscribeRequest& s) {
  fbb.Clear();
  // Written even when equal to the schema defaults, so that a reader never
  // depends on them.
  fbb.ForceDefaults(true);
  const auto sub = fb::CreateSubscribe(fbb, s.requestId, float(s.maxFrameRate), s.layers.bits());
  fbb.ForceDefaults(false);
  finishEnvelope(fbb, fb::Message::Subscribe, sub.Union());
}

}  // namespace fc::wire
