#include "sph/emitters/nozzle.h"

#include "sph/simulation.h"

#include <algorithm>
#include <cmath>

namespace fc {

template <int D>
std::vector<Vec<D>> nozzleLayer(const Emitter<D>& e, Real spacing) {
  // Two unit vectors across the jet (one in 2D).
  Vec<D> across[D - 1];
  if constexpr (D == 2) {
    across[0] = Vec<D>(-e.direction[1], e.direction[0]);
  } else {
    const Vec<D> seed = std::abs(e.direction[0]) < Real(0.9) ? Vec<D>::UnitX() : Vec<D>::UnitY();
    across[0] = e.direction.cross(seed).normalized();
    across[1] = e.direction.cross(across[0]);
  }
  // As many points across as the nozzle's width holds at the fluid lattice's
  // spacing, centred: the jet then carries the rest density.
  const int n = std::max(1, int(std::floor(2 * e.radius / spacing + Real(1e-4))));
  const Real first = -Real(0.5) * Real(n - 1) * spacing;
  std::vector<Vec<D>> pts;
  if constexpr (D == 2) {
    for (int a = 0; a < n; ++a) pts.push_back(e.center + (first + Real(a) * spacing) * across[0]);
  } else {
    // A disk: the square lattice's points within the radius, at least the centre.
    const Real r2 = std::max(e.radius * e.radius, Real(0.25) * spacing * spacing);
    for (int a = 0; a < n; ++a)
      for (int b = 0; b < n; ++b) {
        const Real u = first + Real(a) * spacing, w = first + Real(b) * spacing;
        if (u * u + w * w <= r2 + Real(1e-6) * spacing * spacing) pts.push_back(e.center + u * across[0] + w * across[1]);
      }
    if (pts.empty()) pts.push_back(e.center);
  }
  return pts;
}

namespace {

template <int D>
class Emitters final : public Effect<D> {
 public:
  explicit Emitters(std::vector<Emitter<D>> emitters) : emitters_(std::move(emitters)) {}

  unsigned stages() const override { return FrameBoundary | CorrectVelocities; }

  void init(Simulation<D>& sim) override {
    spacing_ = 2 * sim.particleRadius();
    // The nozzle's bore: the liquid in it moves at the nozzle's speed, as the
    // liquid behind a real nozzle pushes it out. Without it the jet's newest
    // layers, free under gravity and pulled by the jet below, fall away from
    // the layers that follow, and a viscous jet breaks into clumps a support
    // radius apart (measured: honey at 0.5 m/s, 2D, r = 3 mm, gaps of 5 cm
    // within 0.15 m of the nozzle). Long enough to hold every layer one frame
    // emits, and at least two spacings.
    bore_.clear();
    for (const Emitter<D>& e : emitters_)
      bore_.push_back(std::max(2 * spacing_, e.speed * Real(sim.frameDuration()) + spacing_));
    layers_.clear();
    for (const Emitter<D>& e : emitters_) layers_.push_back(nozzleLayer(e, spacing_));
    // The first layer leaves the nozzle at the window's opening.
    travelled_.assign(emitters_.size(), spacing_);
  }

  // The layers that left each open nozzle since the previous frame start,
  // each a spacing behind the one before: layer k sits (s - k·spacing) past
  // the nozzle where s is the length of jet emitted and not yet placed.
  void beginFrame(Simulation<D>& sim, FrameStats& fs) override {
    const double t = sim.time();
    const double dt = sim.frameDuration();
    fs.emitting = true;
    add_.clear();
    open_.clear();  // nozzles open for this frame: their bores are held (correctVelocities)
    for (size_t k = 0; k < emitters_.size(); ++k) {
      const Emitter<D>& e = emitters_[k];
      if (t < e.start - 1e-9 || t >= e.end - 1e-9) continue;
      open_.push_back(k);
      Real& s = travelled_[k];
      nearNozzle(sim, e);
      const Real mass = sim.particleMass(e.phase);
      while (s >= spacing_ - Real(1e-6) * spacing_) {
        s -= spacing_;
        const Vec<D> shift = std::max(s, Real(0)) * e.direction;
        for (const Vec<D>& p0 : layers_[k]) {
          const Vec<D> p = p0 + shift;
          if (occupied(p)) {
            ++fs.emissionBlocked;
            continue;
          }
          if (sim.fluid.size() + add_.size() >= sim.setup().maxParticles) {
            ++fs.emissionBlocked;
            continue;
          }
          add_.push_back({p, e.speed * e.direction, mass, uint8_t(e.phase), ParticleKind::Liquid});
        }
      }
      s += e.speed * Real(std::min(dt, e.end - t));
    }
    fs.emittedParticles += add_.size();
    sim.appendParticles(add_);
  }

  // The jet length emitted and not yet placed carries over between frames.
  void archiveState(StateArchive& a) override { a.io(travelled_); }

  // After the pressure solve, so that what leaves the bore is exactly the
  // nozzle's flux.
  void correctVelocities(Simulation<D>& sim, Real) override {
    for (size_t k : open_) {
      const Emitter<D>& e = emitters_[k];
      const Real len = bore_[k];
      const Real wide2 = (e.radius + Real(0.5) * spacing_) * (e.radius + Real(0.5) * spacing_);
      const Vec<D> v = e.speed * e.direction;
      const long n = long(sim.fluid.size());
#pragma omp parallel for schedule(static)
      for (long i = 0; i < n; ++i) {
        if (sim.fluid.phase[i] != e.phase) continue;
        const Vec<D> q = sim.fluid.x[i] - e.center;
        const Real along = q.dot(e.direction);
        if (along < -Real(0.5) * spacing_ || along > len) continue;
        if ((q - along * e.direction).squaredNorm() > wide2) continue;
        sim.fluid.v[i] = v;
      }
    }
  }

 private:
  // The liquid within a few spacings of the nozzle (a jet backed up to it,
  // a pool reaching it): a layer's point closer than 0.75 spacing to one of
  // them is left out, so no two particles start on top of each other.
  void nearNozzle(const Simulation<D>& sim, const Emitter<D>& e) {
    near_.clear();
    const Real reach = e.radius + 3 * spacing_ + e.speed * Real(sim.frameDuration());
    const Real reach2 = reach * reach;
    const auto& x = sim.fluid.x;
    for (size_t i = 0; i < x.size(); ++i)
      if ((x[i] - e.center).squaredNorm() < reach2) near_.push_back(x[i]);
  }
  bool occupied(const Vec<D>& p) const {
    const Real min2 = Real(0.5625) * spacing_ * spacing_;
    for (const Vec<D>& q : near_)
      if ((q - p).squaredNorm() < min2) return true;
    for (const auto& a : add_)
      if ((a.x - p).squaredNorm() < min2) return true;
    return false;
  }

  std::vector<Emitter<D>> emitters_;
  std::vector<std::vector<Vec<D>>> layers_;
  std::vector<Real> bore_;       // per emitter: bore length, m
  std::vector<size_t> open_;     // emitters open this frame
  std::vector<Real> travelled_;  // per emitter: jet length emitted, not yet placed (m)
  std::vector<Vec<D>> near_;
  std::vector<NewParticle<D>> add_;
  Real spacing_ = 0;
};

}  // namespace

template <int D>
std::unique_ptr<Effect<D>> makeEmitters(const std::vector<Emitter<D>>& emitters) {
  return std::make_unique<Emitters<D>>(emitters);
}

template std::unique_ptr<Effect<2>> makeEmitters<2>(const std::vector<Emitter<2>>&);
template std::unique_ptr<Effect<3>> makeEmitters<3>(const std::vector<Emitter<3>>&);
template std::vector<Vec<2>> nozzleLayer<2>(const Emitter<2>&, Real);
template std::vector<Vec<3>> nozzleLayer<3>(const Emitter<3>&, Real);

}  // namespace fc
