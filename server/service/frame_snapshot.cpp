// Recorded frames: see frame_snapshot.h.
#include "service/frame_snapshot.h"

#include "core/capacity_bytes.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

namespace fc::service {

namespace {
// libstdc++ keeps strings of up to 15 characters inside the object.
size_t heapBytes(const std::string& s) { return s.capacity() > 15 ? s.capacity() + 1 : 0; }
// make_shared's control block next to the object.
constexpr size_t kSharedOverhead = 16;
}  // namespace

size_t FrameSnapshot::bytes() const {
  size_t b = sizeof(FrameSnapshot) + kSharedOverhead;
  b += capacityBytes(positions) + capacityBytes(velocities) + capacityBytes(kind) + capacityBytes(phase);
  b += capacityBytes(stats.instances);
  for (const auto& i : stats.instances) b += heapBytes(i.name);
  b += capacityBytes(instances);
  for (const auto& i : instances) b += heapBytes(i.name) + heapBytes(i.templateName);
  return b;
}

size_t FrameSnapshot::estimateBytes(int dimension, size_t particles, size_t instances) {
  return sizeof(FrameSnapshot) + kSharedOverhead + particles * (2 * size_t(dimension) * sizeof(uint16_t) + 2) +
         instances * (sizeof(InstanceFrameStats) + sizeof(InstanceSnapshot));
}

template <int D>
FramePtr snapshotOf(const Simulation<D>& sim, const AABB<D>& domain, const std::vector<BoundInstance<D>>& instances,
                    const FrameStats& fs) {
  auto s = std::make_shared<FrameSnapshot>();
  s->dimension = D;
  s->frame = fs.frame;
  s->time = fs.time;
  for (int d = 0; d < D; ++d) {
    s->domainMin[size_t(d)] = double(domain.min[d]);
    s->domainMax[size_t(d)] = double(domain.max[d]);
  }
  const auto& f = sim.fluid;
  const long n = long(f.size());
  s->positions.resize(size_t(n) * D);
  std::array<double, D> lo, scale;
  for (int d = 0; d < D; ++d) {
    lo[size_t(d)] = s->domainMin[size_t(d)];
    scale[size_t(d)] = FrameSnapshot::kQuantizationLevels / (s->domainMax[size_t(d)] - s->domainMin[size_t(d)]);
  }
  uint16_t* q = s->positions.data();
#pragma omp parallel for schedule(static) if (n >= 16384)
  for (long i = 0; i < n; ++i)
    for (int d = 0; d < D; ++d) {
      const double v = (double(f.x[size_t(i)][d]) - lo[size_t(d)]) * scale[size_t(d)];
      q[size_t(i) * D + size_t(d)] = uint16_t(std::lround(std::clamp(v, 0.0, FrameSnapshot::kQuantizationLevels)));
    }
  // Velocities: the frame's largest |v| per axis is the box (see FrameSnapshot).
  double vmax[D] = {};
#pragma omp parallel for schedule(static) reduction(max : vmax[:D]) if (n >= 16384)
  for (long i = 0; i < n; ++i)
    for (int d = 0; d < D; ++d) vmax[d] = std::max(vmax[d], std::abs(double(f.v[size_t(i)][d])));
  double vscale[D];
  for (int d = 0; d < D; ++d) {
    s->velocityMax[size_t(d)] = vmax[d];
    vscale[d] = vmax[d] > 0 ? 1 / vmax[d] : 0;  // an axis at rest: every value 32768
  }
  s->velocities.resize(size_t(n) * D);
  uint16_t* qv = s->velocities.data();
#pragma omp parallel for schedule(static) if (n >= 16384)
  for (long i = 0; i < n; ++i)
    for (int d = 0; d < D; ++d) {
      const double u = (double(f.v[size_t(i)][d]) * vscale[d] + 1) * 0.5 * FrameSnapshot::kQuantizationLevels;
      qv[size_t(i) * D + size_t(d)] = uint16_t(std::lround(std::clamp(u, 0.0, FrameSnapshot::kQuantizationLevels)));
    }
  s->kind = f.kind;
  s->phase = f.phase;
  s->stats = fs;
  s->instances.reserve(instances.size());
  const bool fromStats = fs.instances.size() == instances.size();
  for (size_t i = 0; i < instances.size(); ++i) {
    const BoundInstance<D>& b = instances[i];
    const Template<D>& tpl = b.templ();
    InstanceSnapshot is;
    is.name = b.spec.name;
    is.templateName = b.spec.templateName;
    is.phase = b.spec.phase;
    if (fromStats) {
      is.active = fs.instances[i].active;
      is.templateFrame = fs.instances[i].templateFrame;
      is.fidelity = fs.instances[i].fidelity;
    } else {
      is.active = b.spec.time.active(fs.time, tpl.duration());
      is.templateFrame = is.active ? int(b.spec.time.frameAt(fs.time, tpl.header.frameRate, tpl.frameCount())) : -1;
    }
    Eigen::Matrix<double, D, D> m;
    Eigen::Matrix<double, D, 1> t;
    b.spec.transform.evaluate(fs.time, m, t);
    const Eigen::Matrix<double, D, 1> c = b.centre().template cast<double>();
    t -= m * c;
    for (int k = 0; k < 4; ++k) is.toWorld[size_t(k * 5)] = 1;
    for (int col = 0; col < D; ++col) {
      for (int row = 0; row < D; ++row) is.toWorld[size_t(col * 4 + row)] = m(row, col);
      is.toWorld[size_t(12 + col)] = t[col];
    }
    const AABB<D> region = tpl.region();
    for (int d = 0; d < D; ++d) {
      is.regionMin[size_t(d)] = double(region.min[d]);
      is.regionMax[size_t(d)] = double(region.max[d]);
    }
    is.falloffWidth = b.spec.params.falloffWidth;
    s->instances.push_back(std::move(is));
  }
  s->byteSize = s->bytes();
  return s;
}

// Frames in parallel; counted first so that nothing allocates in a parallel region.
template <int D>
void templateFramesOf(const std::vector<FramePtr>& frames, const std::vector<double>& lo,
                      const std::vector<double>& hi, const std::vector<Real>& phaseMass,
                      std::vector<TemplateFrame<D>>& out) {
  const long nf = long(frames.size());
  auto inside = [&](const FrameSnapshot& f, size_t i) {
    if (f.kind[i] != uint8_t(ParticleKind::Liquid) && f.kind[i] != uint8_t(ParticleKind::Temporary)) return false;
    for (int d = 0; d < D; ++d) {
      const double x = f.position(i, d);
      if (x < lo[size_t(d)] || x > hi[size_t(d)]) return false;
    }
    return true;
  };
  std::vector<size_t> counts(size_t(nf), 0);
#pragma omp parallel for schedule(dynamic, 1)
  for (long k = 0; k < nf; ++k) {
    const FrameSnapshot& f = *frames[size_t(k)];
    size_t c = 0;
    for (size_t i = 0; i < f.particles(); ++i) c += inside(f, i);
    counts[size_t(k)] = c;
  }
  out.assign(size_t(nf), TemplateFrame<D>{});
  for (long k = 0; k < nf; ++k) {
    TemplateFrame<D>& t = out[size_t(k)];
    t.x.resize(counts[size_t(k)]);
    t.v.resize(counts[size_t(k)]);
    t.mass.resize(counts[size_t(k)]);
    t.phase.resize(counts[size_t(k)]);
  }
  const size_t phases = phaseMass.size();
#pragma omp parallel for schedule(dynamic, 1)
  for (long k = 0; k < nf; ++k) {
    const FrameSnapshot& f = *frames[size_t(k)];
    TemplateFrame<D>& t = out[size_t(k)];
    size_t j = 0;
    for (size_t i = 0; i < f.particles(); ++i) {
      if (!inside(f, i)) continue;
      for (int d = 0; d < D; ++d) {
        t.x[j][d] = Real(f.position(i, d));
        t.v[j][d] = Real(f.velocity(i, d));
      }
      t.phase[j] = f.phase[i];
      t.mass[j] = f.phase[i] < phases ? phaseMass[f.phase[i]] : Real(0);
      ++j;
    }
  }
}

template FramePtr snapshotOf<2>(const Simulation<2>&, const AABB<2>&, const std::vector<BoundInstance<2>>&,
                                const FrameStats&);
template FramePtr snapshotOf<3>(const Simulation<3>&, const AABB<3>&, const std::vector<BoundInstance<3>>&,
                                const FrameStats&);
template void templateFramesOf<2>(const std::vector<FramePtr>&, const std::vector<double>&, const std::vector<double>&,
                                  const std::vector<Real>&, std::vector<TemplateFrame<2>>&);
template void templateFramesOf<3>(const std::vector<FramePtr>&, const std::vector<double>&, const std::vector<double>&,
                                  const std::vector<Real>&, std::vector<TemplateFrame<3>>&);

}  // namespace fc::service
