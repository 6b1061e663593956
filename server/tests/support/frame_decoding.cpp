#include "tests/support/frame_decoding.h"

#include <stdexcept>
#include <string>

namespace fc::wire {

namespace {

std::array<double, 3> fromVec3(const fb::Vec3* v) {
  if (!v) return {0, 0, 0};
  return {double(v->x()), double(v->y()), double(v->z())};
}

void decodePoints(const fb::Points* pts, int dim, const char* what, DecodedPoints& out) {
  if (!pts) throw std::invalid_argument(std::string("Frame.") + what + " is missing");
  out.boxMin = fromVec3(pts->box_min());
  out.boxMax = fromVec3(pts->box_max());
  const size_t count = pts->count();
  const auto* q = pts->q();
  const size_t have = q ? q->size() : 0;
  if (have != count * size_t(dim))
    throw std::invalid_argument(std::string("Frame.") + what + ": " + std::to_string(have) +
                                " quantized values for " + std::to_string(count) + " points in " +
                                std::to_string(dim) + "D");
  out.x.assign(count, {0, 0, 0});
  for (size_t i = 0; i < count; ++i)
    for (int d = 0; d < dim; ++d) {
      const double lo = out.boxMin[size_t(d)], hi = out.boxMax[size_t(d)];
      out.x[i][size_t(d)] = lo + double(q->Get(flatbuffers::uoffset_t(i * size_t(dim) + size_t(d)))) /
                                     kQuantizationLevels * (hi - lo);
    }
}

}  // namespace

std::array<double, 3> DecodedPoints::maxError() const {
  std::array<double, 3> e{};
  for (size_t d = 0; d < 3; ++d) e[d] = (boxMax[d] - boxMin[d]) / kQuantizationLevels / 2;
  return e;
}

DecodedFrame decodeFrame(const uint8_t* data, size_t size) {
  if (std::string err = verifyEnvelope(data, size); !err.empty()) throw std::invalid_argument(err);
  const fb::Envelope* env = fb::GetEnvelope(data);
  const fb::Frame* f = env->message_as_Frame();
  if (!f)
    throw std::invalid_argument(std::string("not a Frame: message type ") +
                                (unsigned(env->message_type()) <= unsigned(fb::Message::MAX)
                                     ? fb::EnumNameMessage(env->message_type())
                                     : std::to_string(unsigned(env->message_type())).c_str()));
  DecodedFrame out;
  out.sessionId = f->session_id() ? f->session_id()->str() : std::string();
  out.frame = f->frame();
  out.time = f->time();
  out.dimension = f->dimension();
  if (out.dimension != 2 && out.dimension != 3)
    throw std::invalid_argument("Frame.dimension is " + std::to_string(out.dimension) + ", not 2 or 3");
  const int dim = out.dimension;
  out.domainMin = fromVec3(f->domain_min());
  out.domainMax = fromVec3(f->domain_max());
  out.layers = LayerFlags::fromBits(f->layers());
  decodePoints(f->particles(), dim, "particles", out.particles);
  const size_t n = out.particles.x.size();
  if (!f->kind() || f->kind()->size() != n || !f->phase() || f->phase()->size() != n)
    throw std::invalid_argument("Frame.kind / Frame.phase must have one value per particle (" + std::to_string(n) + ")");
  out.kind.assign(f->kind()->begin(), f->kind()->end());
  out.phase.assign(f->phase()->begin(), f->phase()->end());
  if (out.layers.speed) {
    size_t nLiquid = n;
    while (nLiquid > 0 && out.kind[nLiquid - 1] == uint8_t(ParticleKind::Boundary)) --nLiquid;
    if (!f->speed() || f->speed()->size() != nLiquid)
      throw std::invalid_argument("Frame.speed must have one value per liquid particle (" + std::to_string(nLiquid) + ")");
    out.speedMax = f->speed_max();
    out.speed.reserve(nLiquid);
    for (uint8_t q : *f->speed()) out.speed.push_back(double(q) / 255.0 * out.speedMax);
  }
  if (out.layers.control) {
    if (!f->control()) throw std::invalid_argument("Frame.layers has Control but Frame.control is missing");
    decodePoints(f->control()->points(), dim, "control.points", out.control);
    const auto* alpha = f->control()->alpha();
    if (!alpha || alpha->size() != out.control.x.size())
      throw std::invalid_argument("Frame.control.alpha must have one value per control point (" +
                                  std::to_string(out.control.x.size()) + ")");
    out.alpha.reserve(alpha->size());
    for (uint8_t a : *alpha) out.alpha.push_back(double(a) / 255.0);
  }
  if (out.layers.repulsion) decodePoints(f->repulsion(), dim, "repulsion", out.repulsion);
  if (out.layers.instances && f->instances()) {
    for (const fb::Instance* r : *f->instances()) {
      DecodedInstance d;
      d.name = r->name() ? r->name()->str() : std::string();
      d.templateName = r->template_name() ? r->template_name()->str() : std::string();
      d.active = r->active();
      d.templateFrame = r->template_frame();
      d.phase = r->phase();
      if (r->world_matrix()) {
        d.worldRowMajor.assign(r->world_matrix()->begin(), r->world_matrix()->end());
        if (d.worldRowMajor.size() != size_t((dim + 1) * (dim + 1)))
          throw std::invalid_argument("instance '" + d.name + "': world_matrix has " +
                                      std::to_string(d.worldRowMajor.size()) + " values, expected " +
                                      std::to_string((dim + 1) * (dim + 1)));
      }
      d.templateMin = fromVec3(r->template_min());
      d.templateMax = fromVec3(r->template_max());
      d.falloffWidth = r->falloff_width();
      d.fidelity = r->fidelity();
      d.controlled = r->controlled();
      d.controlOffset = r->control_offset();
      d.controlCount = r->control_count();
      d.repulsionOffset = r->repulsion_offset();
      d.repulsionCount = r->repulsion_count();
      if (uint64_t(d.controlOffset) + d.controlCount > out.control.x.size() ||
          uint64_t(d.repulsionOffset) + d.repulsionCount > out.repulsion.x.size())
        throw std::invalid_argument("instance '" + d.name + "': layer range beyond the layer's points");
      out.instances.push_back(std::move(d));
    }
  }
  FrameStats& s = out.stats;
  s.frame = out.frame;
  s.time = out.time;
  if (const fb::Stats* w = f->stats()) {
    s.wallMs = w->wall_ms();
    s.controlMs = w->control_ms();
    s.neighborMs = w->neighbor_ms();
    s.densityMs = w->density_ms();
    s.divergenceMs = w->divergence_ms();
    s.nonPressureMs = w->non_pressure_ms();
    s.pressureMs = w->pressure_ms();
    s.substeps = int(w->substeps());
    s.divergenceIterations = int(w->divergence_iterations());
    s.densityIterations = int(w->density_iterations());
    s.avgDensityErrorPct = w->avg_density_error_pct();
    s.maxDensityErrorPct = w->max_density_error_pct();
    s.converged = w->converged();
    s.minDt = w->min_dt();
    s.maxDt = w->max_dt();
    s.maxSpeed = w->max_speed();
    s.avgNeighbors = w->avg_neighbors();
    s.particles = size_t(w->liquid_particles()) + w->temporary_particles();
    s.temporaryParticles = w->temporary_particles();
    s.boundaryParticles = w->boundary_particles();
    s.controlParticles = w->control_particles();
    s.repulsionParticles = w->repulsion_particles();
    s.controlledParticles = w->controlled_particles();
    s.seededParticles = w->seeded_particles();
    s.removedParticles = w->removed_particles();
    s.escapedParticles = w->escaped_particles();
  }
  for (const DecodedInstance& d : out.instances) {
    InstanceFrameStats is;
    is.name = d.name;
    is.active = d.active;
    is.templateFrame = d.templateFrame;
    is.fidelity = d.fidelity;
    is.controlled = d.controlled;
    is.controlParticles = d.controlCount;
    is.repulsionParticles = d.repulsionCount;
    s.instances.push_back(std::move(is));
  }
  return out;
}

}  // namespace fc::wire
