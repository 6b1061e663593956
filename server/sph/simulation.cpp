// The simulation's set-up and its step (sph/simulation.h). Long because the
// step's order of stages, time-step control and boundary handling read best
// as one sequence, as in the papers; methods live in the family folders.
#include "sph/simulation.h"

#include "sph/emitters/nozzle.h"
#include "sph/sampling/boundary.h"
#include "sph/sampling/lattice.h"
#include "sph/settings.h"
#include <omp.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <stdexcept>

namespace fc {

namespace {
using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

namespace {
// A registered part from its name and the scene's values over its defaults.
template <class Registry>
auto makeNamed(const Registry& registry, const std::string& name, const ParamValues& values, const char* what) {
  const auto* entry = registry.find(name);
  if (!entry) throw std::invalid_argument(std::string("unknown ") + what + " '" + name + "'");
  ParamValues v(entry->params);
  for (const auto& [k, x] : values.all()) v.set(k, x);
  return entry->make(v);
}
}  // namespace

template <int D>
Simulation<D>::Simulation(const SimulationSetup<D>& setup) : setup_(setup) {
  registerBuiltinSolversAndEffects();
  radius_ = setup_.particleRadius;
  if (!(radius_ > 0)) throw std::invalid_argument("particle_radius must be positive");
  if (setup_.domain.empty()) throw std::invalid_argument("domain is empty");
  if (setup_.phases.empty() || setup_.phases.size() > 255) throw std::invalid_argument("need 1 to 255 phases");
  // Support radius 4r (two particle diameters), as SPlisHSPlasH.
  kernel.setRadius(Real(4) * radius_);
  gravity_ = setup_.gravity;
  for (const auto& ph : setup_.phases) restDensity_.push_back(ph.restDensity);

  // The density formulation, once: the number density where phases of
  // different rest densities meet (automatic), or as the scene says. A
  // single-phase scene keeps the mass sum, exactly as before.
  {
    const int formulation = setup_.settings.densityFormulation;
    bool contrast = false;
    for (Real r : restDensity_) contrast = contrast || r != restDensity_.front();
    numberDensity_ = formulation == 2 || (formulation == 0 && contrast);
    const Real lo = *std::min_element(restDensity_.begin(), restDensity_.end());
    const Real hi = *std::max_element(restDensity_.begin(), restDensity_.end());
    contrastStep_ = std::sqrt(lo / hi);
  }

  const std::string solverName = setup_.solver.name.empty() ? "dfsph" : setup_.solver.name;
  pressure_ = makeNamed(PressureSolverRegistry<D>::instance(), solverName, setup_.solver.values, "pressure solver");
  stageNames_.push_back("pressure:" + solverName);

  boundaryModel_ = makeNamed(BoundaryModelRegistry<D>::instance(),
                             setup_.boundary.name.empty() ? std::string(kDefaultBoundaryModel) : setup_.boundary.name,
                             setup_.boundary.values, "boundary method");
  boundaryWeight_ = boundaryModel_->pressureWeight();
  extrapolateBoundary_ = boundaryModel_->extrapolatesPressure();
  mapStaticSolids_ = boundaryModel_->mapsStaticSolids();
  mirrorInConstraint_ = boundaryWeight_ == Real(2) && boundaryModel_->mirrorsInConstraint() && !mapStaticSolids_;
  if (mirrorInConstraint_) {
    boundaryWeight_ = 1;  // the mirror's push is in boundaryGradW, beside the samples' own
    mirrorRamp_ = boundaryModel_->mirrorRamp();
  }

  for (const auto& e : setup_.effects) {
    effects_.push_back(makeNamed(EffectRegistry<D>::instance(), e.name, e.values, "effect"));
    addStages(effects_.back().get());
    stageNames_.push_back("effect:" + e.name);
  }

  search.setGrid(setup_.domain, kernel.radius());
  latticeVolume_ = latticeParticleVolume(kernel, 2 * radius_);
  if (mirrorInConstraint_)
    mirrorScale_ = radius_ * std::abs(Real(flatWallMissingPush(kernel, 2 * radius_, latticeVolume_))) /
                   Real(flatWallMissingVolume(kernel, 2 * radius_, latticeVolume_));
  buildBoundary();
  {
    const auto t0 = std::chrono::steady_clock::now();
    boundaryModel_->setUp(*this, latticeVolume_);
    boundarySetupMs_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  buildFluid();
  if (fluid.size() > setup_.maxParticles)
    throw std::invalid_argument("scene has " + std::to_string(fluid.size()) + " particles, more than max_particles " +
                                std::to_string(setup_.maxParticles));
  nextId_ = uint32_t(fluid.size());
  if (!setup_.emitters.empty()) {
    effects_.push_back(makeEmitters<D>(setup_.emitters));
    addStages(effects_.back().get());
    stageNames_.push_back("emitters");
  }
  pressure_->resize(fluid.size());
  for (auto& e : effects_) e->resize(fluid.size());
  pressure_->init(*this);
  for (auto& e : effects_) e->init(*this);
  lastDt_ = Real(setup_.settings.dtMax);
  relaxInitialState();
}

template <int D>
Simulation<D>::~Simulation() = default;

template <int D>
void Simulation<D>::addEffect(std::unique_ptr<Effect<D>> effect, const std::string& name) {
  Effect<D>* eff = effect.get();
  effects_.push_back(std::move(effect));
  addStages(eff);
  stageNames_.push_back(name);
  eff->resize(fluid.size());
  eff->init(*this);
}

template <int D>
void Simulation<D>::archiveState(StateArchive& a) {
  a.section("simulation");
  a.io(time_);
  a.io(frame_);
  a.io(lastDt_);
  a.io(totalSubsteps_);
  a.io(stepsSinceReorder_);
  a.io(nextId_);
  a.io(stepScale_);
  a.section("fluid");
  a.io(fluid.x);
  a.io(fluid.v);
  a.io(fluid.mass);
  a.io(fluid.density);
  a.io(fluid.pressure);
  a.io(fluid.meanPressure);
  a.io(fluid.phase);
  a.io(fluid.kind);
  a.io(fluid.id);
  const size_t n = fluid.x.size();
  if (a.loading()) {
    if (fluid.v.size() != n || fluid.mass.size() != n || fluid.density.size() != n || fluid.pressure.size() != n ||
        fluid.meanPressure.size() != n || fluid.phase.size() != n || fluid.kind.size() != n || fluid.id.size() != n)
      throw StateArchiveError("checkpoint particle arrays differ in length");
    if (n > setup_.maxParticles) throw StateArchiveError("checkpoint holds more particles than max_particles");
    fluid.a.assign(n, Vec<D>::Zero());  // every substep starts it from gravity
  }
  uint8_t hasBodies = bodies_ != nullptr;
  a.io(hasBodies);
  if (bool(hasBodies) != (bodies_ != nullptr)) throw StateArchiveError("checkpoint and scene differ in moving bodies");
  if (bodies_) {
    bodies_->archiveState(a);
    const size_t nb = boundary.x.size();
    a.io(boundary.x);
    a.io(boundary.v);
    if (a.loading() && (boundary.x.size() != nb || boundary.v.size() != nb))
      throw StateArchiveError("checkpoint and scene differ in boundary particles");
  }

  // Stages by name: a checkpoint saved before a stage existed restores it as new.
  a.section("stages");
  std::vector<std::pair<std::string, PressureSolver<D>*>> solver{{stageNames_.at(0), pressure_.get()}};
  std::vector<std::pair<std::string, Effect<D>*>> effects;
  for (size_t k = 0; k < effects_.size(); ++k) effects.emplace_back(stageNames_.at(k + 1), effects_[k].get());
  if (a.saving()) {
    uint64_t count = 1 + effects.size();
    a.io(count);
    auto save = [&](std::string name, auto* stage) {
      StateArchive inner;
      stage->archiveState(inner);
      a.io(name);
      a.blob(inner.bytes());
    };
    save(solver[0].first, solver[0].second);
    for (auto& [name, e] : effects) save(name, e);
    return;
  }
  uint64_t count = 0;
  a.io(count);
  std::vector<std::pair<std::string, std::vector<uint8_t>>> saved;
  for (uint64_t k = 0; k < count; ++k) {
    std::string name;
    std::vector<uint8_t> bytes;
    a.io(name);
    a.blob(bytes);
    saved.emplace_back(std::move(name), std::move(bytes));
  }
  auto restore = [&](const std::string& name, auto* stage) {
    stage->resize(n);
    for (auto& [savedName, bytes] : saved)
      if (savedName == name) {
        StateArchive inner(bytes);
        stage->archiveState(inner);
        if (!inner.atEnd()) throw StateArchiveError("checkpoint of stage '" + name + "' not read to its end");
        return;
      }
    stage->init(*this);
  };
  restore(solver[0].first, solver[0].second);
  for (auto& [name, e] : effects) restore(name, e);
  if (bodies_) search.setStaticPoints(boundary.x);
  neighborsFresh_ = false;
}

template <int D>
void Simulation<D>::addStages(Effect<D>* eff) {
  if (eff->stages() & AddAccelerations) accelerationStages_.push_back(eff);
  if (eff->stages() & ImplicitVelocities) implicitStages_.push_back(eff);
  if (eff->stages() & CorrectVelocities) velocityStages_.push_back(eff);
  if (eff->stages() & FrameBoundary) frameStages_.push_back(eff);
}

template <int D>
void Simulation<D>::continueBodiesFrom(const Simulation& old, double timeOffset) {
  if (!bodies_ || !old.bodies_) return;
  bodies_->continueFrom(*old.bodies_, timeOffset);
  bodies_->place(time_, boundary);
  search.setStaticPoints(boundary.x);
  neighborsFresh_ = false;
}

template <int D>
void Simulation<D>::refreshNeighbors() {
  const auto t0 = Clock::now();
  search.update(fluid.x);
  refreshNeighborMs_ = msSince(t0);
  const auto t1 = Clock::now();
  computeDensities();
  refreshDensityMs_ = msSince(t1);
  neighborsFresh_ = true;
}

template <int D>
void Simulation<D>::appendParticles(const std::vector<NewParticle<D>>& add) {
  if (add.empty()) return;
  if (fluid.size() + add.size() > setup_.maxParticles)
    throw std::runtime_error("adding " + std::to_string(add.size()) + " particles would exceed max_particles " +
                             std::to_string(setup_.maxParticles));
  for (const auto& p : add) {
    fluid.add(p.x, p.v, p.mass, p.phase, p.kind);
    fluid.id.back() = nextId_++;
  }
  pressure_->resize(fluid.size());
  for (auto& e : effects_) e->resize(fluid.size());
  neighborsFresh_ = false;
}

template <int D>
void Simulation<D>::removeParticles(const std::vector<uint32_t>& indices) {
  if (indices.empty()) return;
  const size_t n = fluid.size();
  // Kept particles first, in order, then the removed ones; then truncate.
  perm_.clear();
  perm_.reserve(n);
  size_t r = 0;
  for (uint32_t i = 0; i < n; ++i) {
    if (r < indices.size() && indices[r] == i) {
      ++r;
      continue;
    }
    perm_.push_back(i);
  }
  const size_t kept = perm_.size();
  for (uint32_t i : indices) perm_.push_back(i);
  fluid.reorder(perm_, reorderScratch_);
  pressure_->reorder(perm_);
  for (auto& e : effects_) e->reorder(perm_);
  fluid.truncate(kept);
  pressure_->resize(kept);
  for (auto& e : effects_) e->resize(kept);
  neighborsFresh_ = false;
}

template <int D>
void Simulation<D>::buildBoundary() {
  const Real spacing = 2 * radius_;
  const int layers = setup_.settings.boundaryLayers;
  std::vector<Vec<D>> pts;
  // Sample centres sit one particle radius behind the solid surface, where
  // the fluid lattice would continue: a fluid particle resting against the
  // surface then sees the same neighbourhood as one inside the fluid.
  sampleBoxShell<D>(setup_.domain.grown(radius_), spacing, layers, true, pts);
  for (const auto& o : setup_.obstacles) {
    if (o.shape == ObstacleShape::Box) sampleBoxShell<D>(o.box.grown(-radius_), spacing, layers, false, pts);
    else if (o.shape == ObstacleShape::Sphere) sampleSphereShell<D>(o.center, o.radius - radius_, spacing, layers, pts);
    else if constexpr (D == 3) {
      if (!o.mesh) throw std::invalid_argument("mesh obstacle without its mesh");
      sampleMeshShell(*o.mesh, radius_, spacing, layers, pts);
    } else {
      throw std::invalid_argument("mesh obstacles are 3D only");
    }
  }
  boundary.x = pts;
  staticSamples_ = pts.size();
  boundary.v.assign(pts.size(), Vec<D>::Zero());
  boundary.volume.assign(pts.size(), 0);
  search.setStaticPoints(boundary.x);
  // Boundary samples fill the solid `boundary_layers` deep like the fluid
  // lattice continued, so each stands for the lattice volume. Where
  // samples crowd (box edges, curved or touching solids) the volume of Akinci
  // et al. 2012 [AIA*12], eq. (4), V_b = 1 / Σ_k W(x_b - x_k), is smaller and taken
  // instead, so that no solid counts twice. Akinci's volume alone is meant for
  // a single layer; on several layers it would overstate the wall's density.
#pragma omp parallel for schedule(static)
  for (size_t b = 0; b < pts.size(); ++b) {
    Real sum = 0;
    search.forEachStaticNear(pts[b], kernel.radius(), [&](uint32_t, const Vec<D>& q) { sum += kernel.W(Vec<D>(pts[b] - q)); });
    boundary.volume[b] = sum > 0 ? std::min(latticeVolume_, Real(1) / sum) : latticeVolume_;
  }
  // With the mirror in the constraint: each static sample's stretch of solid
  // surface, from the signed distance Φ to the solids (positive in the
  // liquid): the outward normal ∇Φ and the depth -Φ.
  if (mirrorInConstraint_) {
    surfaceNormal_.assign(pts.size(), Vec<D>::Zero());
    surfaceDepth_.assign(pts.size(), 0);
#pragma omp parallel for schedule(static)
    for (size_t b = 0; b < pts.size(); ++b) {
      const Vec<D> n = solidDistanceGradient(setup_.domain, setup_.obstacles, pts[b], Real(0.1) * radius_);
      const Real len = n.norm();
      if (!(len > Real(1e-6))) continue;  // no side to push from: the sample adds no mirror
      surfaceNormal_[b] = n / len;
      surfaceDepth_[b] = -solidDistance(setup_.domain, setup_.obstacles, pts[b]);
    }
  }
  // Moving bodies follow the static solids in the boundary arrays.
  if (!setup_.bodies.empty()) {
    bodies_ = std::make_unique<RigidBodies<D>>(setup_.bodies, radius_, layers, kernel, latticeVolume_, boundary, gravity_);
    search.setStaticPoints(boundary.x);
  }
}

template <int D>
void Simulation<D>::buildFluid() {
  const Real spacing = 2 * radius_;
  for (const auto& blk : setup_.fluidBlocks) {
    const Real m = restDensity_.at(blk.phase) * latticeVolume_;
    forEachLatticePoint<D>(blk.box, spacing, [&](const Vec<D>& p) {
      for (const auto& o : setup_.obstacles)
        if (o.signedDistance(p) < radius_) return;  // never start inside a solid
      if (bodies_)
        for (const auto& b : bodies_->states())
          if (b.signedDistance(p) < radius_) return;
      fluid.add(p, blk.velocity, m, uint8_t(blk.phase));
    });
  }
}

// Mass sum (default): ρ_i = Σ_j m_j W_ij + Σ_b Ψ_b W_ib with Ψ_b = ρ0_i V_b
// (Akinci et al. 2012 [AIA*12], eq. (6)).
//
// Number density (Solenthaler & Pajarola 2008, "Density Contrast SPH
// Interfaces" [SP08]): where phases of different rest densities meet, the
// mass sum counts a heavy neighbour as extra compression of a light particle
// (and a light one as a deficit of a heavy particle), so the pressure solve
// pushes the phases apart: a gap and a spurious interface tension that grow
// with the density ratio. [SP08] lets every particle count its neighbours as
// particles of its own kind: the particle number density δ_i = Σ_j W_ij and
// ρ_i = m_i δ_i. A boundary sample stands for V_b / V_i of particle i's
// kind (V_i = m_i / ρ0_i its rest volume), which gives the same Akinci term
// ρ0_i Σ_b V_b W_ib as before. With one phase (equal masses) both are the
// same sum. The pair gradients m_j ∇W_ij (as m_j F_ij, massGradScale) and
// the boundary sums are cached for the solvers and effects of this substep
// in both, and under the number density also F_ij alone (gradScale), for the
// pressure solvers' volume form.
// ([SP08] is cited by section and formula: its equation numbers could not be
// checked against the paper's text here.)
template <int D>
void Simulation<D>::computeDensities() {
  splitWork();
  if (numberDensity_) computeDensitiesWith<true>();
  else computeDensitiesWith<false>();
}

template <int D>
void Simulation<D>::splitWork() {
  const auto& offsets = search.dynamicNeighbors().offsets;
  const long n = long(fluid.size());
  const int threads = omp_get_max_threads();
  workSplit_.assign(size_t(threads) + 1, n);
  workSplit_[0] = 0;
  if (offsets.size() != size_t(n) + 1) {
    for (int t = 1; t < threads; ++t) workSplit_[size_t(t)] = n * t / threads;
    return;
  }
  const long total = long(offsets[size_t(n)]) + kParticleWorkInPairs * n;
  for (int t = 1; t < threads; ++t) {
    const long target = total * t / threads;
    long lo = workSplit_[size_t(t) - 1], hi = n;  // first i with work(i) >= target
    while (lo < hi) {
      const long mid = (lo + hi) / 2;
      if (long(offsets[size_t(mid)]) + kParticleWorkInPairs * mid < target) lo = mid + 1;
      else hi = mid;
    }
    workSplit_[size_t(t)] = lo;
  }
}

template <int D>
std::pair<long, long> Simulation<D>::threadParticles() const {
  const long n = long(fluid.size());
  const int t = omp_get_thread_num(), threads = omp_get_num_threads();
  if (workSplit_.size() == size_t(threads) + 1 && workSplit_.back() == n)
    return {workSplit_[size_t(t)], workSplit_[size_t(t) + 1]};
  return {n * t / threads, n * (t + 1) / threads};
}

// Always inlined: it is the body of the density pass's per-particle loop.
template <int D>
[[gnu::always_inline]] inline typename Simulation<D>::StaticSums Simulation<D>::staticSumsAt(
    const Vec<D>& xi) const {
  const Real h = kernel.radius();
  const Real ramp = mirrorRamp_;
  StaticSums out;
  Real w;
  Vec<D> g;
  search.forEachStaticNear(xi, h, [&](uint32_t b, const Vec<D>& xb) {
    if (mapStaticSolids_ && b < staticSamples_) return;  // the map's terms below stand for them
    kernel.evaluate(xi - xb, w, g);
    const Real vb = boundary.volume[b];
    out.volume += vb * w;
    out.grad += vb * g;
    out.flux += vb * boundary.v[b].dot(g);
    if (mirrorInConstraint_ && b < staticSamples_) {
      // The mirror's part: c V_b W_ib s((r - d_ib)/r), zero beyond the rest distance, and its gradient.
      const Real d = (xi - xb).dot(surfaceNormal_[b]) - surfaceDepth_[b];
      if (d < radius_) {
        // s(t) = t²/(2τ) up to τ, then t - τ/2: the push sets in smoothly over the first τ r.
        const Real t = (radius_ - d) / radius_, cv = mirrorScale_ * vb;
        const Real st = t < ramp ? t * t / (2 * ramp) : t - ramp / 2;
        const Real ds = std::min(t / ramp, Real(1));
        out.excess += cv * w * st;
        out.grad += cv * (st * g - (w * ds / radius_) * surfaceNormal_[b]);
      }
    }
    // [AHA12]'s wall pressure, per pair: Δp_ib / ρ0_i = g·(x_b - x_i) (sph/boundary/adami2012.cpp).
    if (extrapolateBoundary_) out.extrapolated += (vb * gravity_.dot(xb - xi)) * g;
    ++out.count;
  });
  if (mapStaticSolids_) {
    StaticBoundaryTerms<D> t;
    if (boundaryModel_->staticTerms(xi, gravity_, t)) {
      out.volume += t.volume;
      out.grad += t.grad;
      if (extrapolateBoundary_) out.extrapolated += t.extrapolation;
      out.count += t.samples;  // DFSPH's neighbour-deficiency test
    }
  }
  return out;
}

template <int D>
Vec<D> Simulation<D>::boundaryGradientAt(const Vec<D>& x) const {
  return staticSumsAt(x).grad;
}

template <int D>
template <bool NumberDensity>
void Simulation<D>::computeDensitiesWith() {
  const auto& nf = search.dynamicNeighbors();
  const long n = long(fluid.size());
  // Every pair's term is written below: a list that must grow is freed, not
  // copied (which would hold both), and gets an eighth to spare, as the
  // neighbour lists, where resize() would double it.
  const auto fit = [](std::vector<Real>& v, size_t size) {
    if (size > v.capacity()) {
      v = {};
      v.reserve(size + size / 8);
    }
    v.resize(size);
  };
  fit(massGradScale, nf.pairs());
  fit(gradScale, NumberDensity ? nf.pairs() : 0);
  boundaryGradW.resize(size_t(n));
  boundaryFlux.resize(size_t(n));
  boundaryNeighbors.resize(size_t(n));
  boundaryExtrapolation.resize(extrapolateBoundary_ ? size_t(n) : 0);
  boundaryExcess.resize(mirrorInConstraint_ ? size_t(n) : 0);
  const Real w0 = kernel.W0();
  const uint32_t* nbr = nf.indices.data();
  const Real* xs = fluid.x.data()->data();  // Vec<D> is D packed Reals
  const Real* mass = fluid.mass.data();
  Real* grad = massGradScale.data();
  Real* plain = NumberDensity ? gradScale.data() : nullptr;
#pragma omp parallel
  {
    const auto [first, last] = threadParticles();
    for (long i = first; i < last; ++i) {
      const Vec<D> xi = fluid.x[i];
      // Mass sum: Σ_j m_j W_ij; number density: δ_i = Σ_j W_ij, the particle number density of [SP08] §4.
      Real rho = NumberDensity ? w0 : fluid.mass[i] * w0;
      const uint32_t kb = nf.offsets[i], ke = nf.offsets[i + 1];
#pragma omp simd reduction(+ : rho)
      for (uint32_t k = kb; k < ke; ++k) {
        const Real* xj = xs + size_t(D) * nbr[k];
        Real r[D], r2 = 0;
        for (int d = 0; d < D; ++d) {
          r[d] = xi[d] - xj[d];
          r2 += r[d] * r[d];
        }
        Real w, fac;
        kernel.evaluateSquared(r2, w, fac);
        const Real mj = mass[nbr[k]];
        if constexpr (NumberDensity) rho += w;
        else rho += mj * w;
        grad[k] = mj * fac;
        if constexpr (NumberDensity) plain[k] = fac;
      }
      // ρ_i = m_i δ_i, [SP08] §4 (its "adapted density").
      if constexpr (NumberDensity) rho *= fluid.mass[i];
      const StaticSums t = staticSumsAt(xi);
      if (extrapolateBoundary_) boundaryExtrapolation[i] = t.extrapolated;
      if (mirrorInConstraint_) boundaryExcess[i] = restDensity_[fluid.phase[i]] * t.excess;
      fluid.density[i] = rho + restDensity_[fluid.phase[i]] * t.volume;
      boundaryGradW[i] = t.grad;
      boundaryFlux[i] = t.flux;
      boundaryNeighbors[i] = uint16_t(std::min(t.count, 65535u));
    }
  }
}

template <int D>
std::optional<Real> Simulation<D>::cflTimeStep() const {
  Real vmax2 = 0;
  const Real h = lastDt_;
  int nonFinite = 0;
  constexpr Real inf = std::numeric_limits<Real>::infinity();
#pragma omp parallel reduction(max : vmax2) reduction(+ : nonFinite)
  {
    const auto [first, last] = threadParticles();
    for (long i = first; i < last; ++i) {
      const Real s = (fluid.v[i] + h * fluid.a[i]).squaredNorm();
      vmax2 = std::max(vmax2, s);
      nonFinite += s < inf ? 0 : 1;  // NaN too: max() would drop it
    }
  }
  if (nonFinite > 0) return std::nullopt;
  const Real cfl = Real(setup_.settings.cflFactor);
  const Real vmax = std::sqrt(vmax2);
  Real dtMax = Real(setup_.settings.dtMax);
  // Moving bodies: their fastest material point counts as a particle's speed.
  const Real vfast = bodies_ ? std::max(vmax, Real(bodies_->maxPointSpeed())) : vmax;
  Real dt = vfast > 0 ? cfl * Real(0.4) * (2 * radius_) / vfast : dtMax;
  // Under the number density the step (its CFL part and dt_max) is scaled by
  // sqrt(ρ0_min/ρ0_max): the pressure solve corrects a compression by moving
  // each particle in inverse proportion to its mass, so the light phase takes
  // the largest velocity corrections, particle by particle, and neighbours
  // that move by a good part of a spacing relative to each other in one step
  // break the solver's linear density prediction (measured: 0.2-0.4 ρ0 more
  // than predicted for light particles streaming along the floor under a
  // heavy layer, which fed back into 5-30 m/s bursts). At 1:3 (scale 0.58)
  // the Rayleigh-Taylor test (Multiphase.LightPhaseUnderHeavyRises) is calm
  // at r = 3, 4 and 5 mm; unscaled (cfl_factor 1, dt_max 5 ms) it burst at 3
  // and 4 mm, and at 3 mm dt_max = 2.4 ms alone still burst (1.2 ms did
  // not). Equal rest densities: scale 1, the step as before.
  if (numberDensity_) {
    dt *= contrastStep_;
    dtMax *= contrastStep_;
  }
  dt = std::min(dt, pressure_->maxTimeStep(*this));
  for (const auto& e : effects_) dt = std::min(dt, e->maxTimeStep(*this));
  // After a solve stopped at its iteration limit the step is scaled down
  // (updateStepScale): a shorter step predicts less compression for the
  // density solve to remove and conditions the implicit viscosity system
  // better, so the next solves start closer to their tolerance. dt_min stays
  // the floor.
  const Real dtMin = std::min(Real(setup_.settings.dtMin), dtMax);
  return std::max(std::clamp(dt, dtMin, dtMax) * stepScale_, dtMin);
}

// The step scale: × unconverged_step_scale after every substep in which a
// solve stopped at its iteration limit, down to kMinStepScale; × step_recovery
// after every substep whose solves all converged, up to 1. The floor keeps
// recovery short after a long unconverged stretch (from 1/64 at the default
// 1.1: 44 converged substeps).
template <int D>
void Simulation<D>::updateStepScale(bool converged) {
  constexpr Real kMinStepScale = Real(1) / 64;
  if (converged) stepScale_ = std::min(Real(1), stepScale_ * Real(setup_.settings.stepRecovery));
  else stepScale_ = std::max(kMinStepScale, stepScale_ * Real(setup_.settings.unconvergedStepScale));
}

// The pressure exports show: the solver's pressure (Pa, as it acts in the
// momentum equation over the substep) averaged exponentially over the
// settings' pressure_window τ (one frame by default), p̄ += min(1, Δt/τ)
// (p - p̄). A density solve stops at its tolerance after a varying number of
// iterations, so its pressure at rest jumps from substep to substep around
// the hydrostatic one; the average over a frame's substeps is that
// hydrostatic pressure. The first substep of a run starts it at p; a
// particle added later starts from 0.
template <int D>
void Simulation<D>::averagePressure(Real dt) {
  const double window = setup_.settings.pressureWindow > 0 ? setup_.settings.pressureWindow : frameDuration();
  const Real alpha = totalSubsteps_ == 0 ? Real(1) : Real(std::min(1.0, double(dt) / window));
#pragma omp parallel
  {
    const auto [first, last] = threadParticles();
    for (long i = first; i < last; ++i) fluid.meanPressure[i] += alpha * (fluid.pressure[i] - fluid.meanPressure[i]);
  }
}

template <int D>
void Simulation<D>::reorderParticles() {
  search.zOrder(fluid.x, perm_);
  fluid.reorder(perm_, reorderScratch_);
  pressure_->reorder(perm_);
  for (auto& e : effects_) e->reorder(perm_);
}

// Solid contact, the last part of the boundary model. Boundary particles
// push only through pressure, and DFSPH has pressure only under compression,
// so a particle below rest density (spray, the toe of a wave) gets almost no
// push from a wall and can sink into it. Particle centres are therefore kept
// at least `contact_distance` particle radii from every solid surface, and
// velocity into the solid is removed (inelastic contact). Contacts are
// counted per frame: they measure how often the SPH boundary alone would not
// have kept a particle off the wall. Those whose centre had crossed the
// surface itself within the step are counted apart (`crossedSurface`).
template <int D>
void Simulation<D>::enforceSolidContact(FrameStats& fs) {
  const Real c = Real(setup_.settings.contactDistance) * radius_;
  const Vec<D> lo = setup_.domain.min.array() + c;
  const Vec<D> hi = setup_.domain.max.array() - c;
  size_t contacts = 0, crossed = 0;
  double impulse[2 * D] = {};
  const long n = long(fluid.size());
  // By whole blocks of particles: the bodies sum their contacts per block.
  const long block = RigidBodies<D>::kBlock, blocks = (n + block - 1) / block;
  if (bodies_) bodies_->beginContacts(size_t(n));
#pragma omp parallel for schedule(static, block) reduction(+ : contacts, crossed, impulse[:2 * D])
  for (long i = 0; i < blocks * block; ++i) {
    if (i >= n) continue;
    Vec<D>& x = fluid.x[i];
    Vec<D>& v = fluid.v[i];
    bool touched = false, through = false;
    for (int d = 0; d < D; ++d) {
      if (x[d] < lo[d]) {
        through = through || x[d] < setup_.domain.min[d];
        x[d] = lo[d];
        if (v[d] < 0) impulse[2 * d] -= double(fluid.mass[i]) * v[d], v[d] = 0;
        touched = true;
      } else if (x[d] > hi[d]) {
        through = through || x[d] > setup_.domain.max[d];
        x[d] = hi[d];
        if (v[d] > 0) impulse[2 * d + 1] += double(fluid.mass[i]) * v[d], v[d] = 0;
        touched = true;
      }
    }
    if (bodies_) bodies_->contact(x, v, fluid.mass[i], c, touched, through, size_t(i));
    for (const auto& o : setup_.obstacles) {
      const Real sd = o.signedDistance(x);
      if (sd >= c) continue;
      through = through || sd < 0;
      Vec<D> g;
      const Real eps = Real(1e-3) * radius_;
      for (int d = 0; d < D; ++d) {
        Vec<D> e = Vec<D>::Zero();
        e[d] = eps;
        g[d] = o.signedDistance(x + e) - o.signedDistance(x - e);
      }
      if (g.norm() > 0) {
        g.normalize();
        x += (c - sd) * g;
        const Real vn = v.dot(g);
        if (vn < 0) v -= vn * g;
      }
      touched = true;
    }
    contacts += touched ? 1 : 0;
    crossed += through ? 1 : 0;
  }
  if (bodies_) bodies_->endContacts();
  fs.wallContacts += contacts;
  fs.crossedSurface += crossed;
  for (int k = 0; k < 2 * D; ++k) fs.contactImpulse[k] += impulse[k];
}

// The initial state, once when the simulation is built: particles that
// start inside a solid or overlapping each other (fluid blocks built in
// code; scene files reject both) carry a compression that no motion
// produced. The density solve would remove it within one step, as
// velocity (overlap / Δt: 71 m/s for a lattice laid over another at 0.94 r
// and rows projected out of the walls, r = 5 mm), which the liquid then
// keeps. Instead the error is removed at the position level, velocities
// untouched (the pre-stabilisation of position-based solvers, Macklin et al.
// 2014 [MMCK14]): centres are put out of the solids, then the scene's pressure solver
// is run on zero velocities with Δt = dt_max and the particles moved by
// Δt·Δv (at most half a radius per pass), until no particle is compressed
// by more than kRelaxAbovePct. A state built from scene-file blocks, at
// rest density by construction, is left exactly as it is. Particles appended
// later (temporary particles, a session carrying its state into a rebuilt
// simulation) are not moved: they come from a running liquid.
template <int D>
void Simulation<D>::relaxInitialState() {
  constexpr double kRelaxAbovePct = 1;  // well above a lattice's own error (< 0.01 %)
  constexpr int kMaxPasses = 50;
  const long n = long(fluid.size());
  FrameStats ignored;
  enforceSolidContact(ignored);
  const Real tau = Real(setup_.settings.dtMax);
  const Real maxMove = Real(0.5) * radius_;
  std::vector<Vec<D>> velocities;
  for (relaxationPasses_ = 0; relaxationPasses_ < kMaxPasses; ++relaxationPasses_) {
    search.update(fluid.x);
    computeDensities();
    // Crowding, in the number density's terms whatever the formulation
    // (V_i Σ_j W_ij + Σ_b V_b W_ib − 1, V_i = m_i/ρ0_i): the mass sum reads
    // a heavy neighbour as compression of a light particle, which is no
    // overlap (a 1:3 lattice at rest reads light particles 32 % compressed
    // at the interface).
    const auto& nf = search.dynamicNeighbors();
    double worst = 0;
#pragma omp parallel for schedule(static) reduction(max : worst)
    for (long i = 0; i < n; ++i) {
      Real sum = kernel.W0();
      for (uint32_t k = nf.offsets[i]; k < nf.offsets[i + 1]; ++k)
        sum += kernel.W(Vec<D>(fluid.x[i] - fluid.x[nf.indices[k]]));
      Real walls = 0;
      search.forEachStaticNear(fluid.x[i], kernel.radius(), [&](uint32_t b, const Vec<D>& xb) {
        walls += boundary.volume[b] * kernel.W(Vec<D>(fluid.x[i] - xb));
      });
      worst = std::max(worst, double(fluid.mass[i] / restDensity(size_t(i)) * sum + walls) - 1);
    }
    if (100 * worst <= kRelaxAbovePct) break;
    if (velocities.empty()) velocities = fluid.v;
    std::fill(fluid.v.begin(), fluid.v.end(), Vec<D>::Zero());
    pressure_->prepare(*this);
    pressure_->correctDensity(*this, tau);
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) {
      Vec<D> dx = tau * fluid.v[i];
      const Real len = dx.norm();
      if (len > maxMove) dx *= maxMove / len;
      fluid.x[i] += dx;
    }
    fluid.v = velocities;
    enforceSolidContact(ignored);
  }
  if (relaxationPasses_ > 0) {
    // Forget the stiffness the passes accumulated: the first step's warm
    // start must not replay it as a push.
    pressure_->resize(0);
    pressure_->resize(fluid.size());
    std::fill(fluid.pressure.begin(), fluid.pressure.end(), Real(0));
  }
  neighborsFresh_ = false;
}

template <int D>
FrameStats Simulation<D>::advanceFrame() {
  const auto t0 = Clock::now();
  try {
    return advanceFrameSteps();
  } catch (const NeighborCollapse& e) {
    return stoppedFrame(FrameStats{}, e.what(), t0);
  }
}

template <int D>
FrameStats Simulation<D>::stoppedFrame(FrameStats fs, std::string why, Clock::time_point t0) const {
  fs.finite = false;
  fs.failure = std::move(why);
  fs.frame = frame_ + 1;
  fs.time = time_;
  fs.particles = fluid.size();
  fs.wallMs = msSince(t0);
  return fs;
}

template <int D>
FrameStats Simulation<D>::advanceFrameSteps() {
  const auto t0 = Clock::now();
  FrameStats fs;
  const double frameEnd = double(frame_ + 1) * frameDuration();
  const int reorderInterval = setup_.settings.reorderInterval;
  fs.minDt = 1e30;
  refreshNeighborMs_ = refreshDensityMs_ = reusedRefreshMs_ = 0;
  for (Effect<D>* e : frameStages_) e->beginFrame(*this, fs);
  const long n = long(fluid.size());
  const int maxSubsteps = setup_.settings.maxSubstepsPerFrame;
  auto stop = [&](std::string why) { return stoppedFrame(fs, std::move(why), t0); };

  while (time_ < frameEnd - 1e-9) {
    if (frameLimits_.cancel && frameLimits_.cancel->load(std::memory_order_relaxed)) {
      fs.cancelled = true;
      return stop("the frame was cancelled");
    }
    if (fs.substeps >= maxSubsteps)
      return stop("the frame needed more than " + std::to_string(maxSubsteps) +
                  " substeps (settings.max_substeps_per_frame; the time step fell to " + std::to_string(lastDt_) +
                  " s): the simulation has become unstable");
    if (Clock::now() > frameLimits_.deadline)
      return stop("the frame ran past the watchdog's time limit after " + std::to_string(fs.substeps) + " substeps");
    auto lap = Clock::now();
    auto took = [&lap]() {
      const auto now = Clock::now();
      const double ms = std::chrono::duration<double, std::milli>(now - lap).count();
      lap = now;
      return ms;
    };
    if (reorderInterval > 0 && stepsSinceReorder_ >= size_t(reorderInterval)) {
      reorderParticles();
      stepsSinceReorder_ = 0;
      neighborsFresh_ = false;
    }
    if (!neighborsFresh_) search.update(fluid.x);
    fs.neighborMs += took();
    if (!neighborsFresh_) computeDensities();
    if (neighborsFresh_) {  // the frame-start refresh, reused: this substep's own work
      fs.neighborMs += refreshNeighborMs_;
      fs.densityMs += refreshDensityMs_;
      reusedRefreshMs_ += refreshNeighborMs_ + refreshDensityMs_;
    }
    refreshNeighborMs_ = refreshDensityMs_ = 0;
    neighborsFresh_ = false;
    pressure_->prepare(*this);
    fs.densityMs += took();

    const SolverReport div = pressure_->correctDivergence(*this, lastDt_);
    fs.divergenceIterations += div.iterations;
    for (int d = 0; d < 3; ++d) fs.boundaryImpulse[d] += div.boundaryImpulse[d];
    fs.converged = fs.converged && div.converged;
    fs.divergenceMs += took();

    // Non-pressure accelerations: gravity, then the scene's effects in order.
#pragma omp parallel
    {
      const auto [first, last] = threadParticles();
      for (long i = first; i < last; ++i) fluid.a[i] = gravity_;
      // The samples' extrapolated hydrostatic pressure pushes like a body force.
      if (extrapolateBoundary_)
        for (long i = first; i < last; ++i) fluid.a[i] -= boundaryExtrapolation[i];
    }
    for (Effect<D>* e : accelerationStages_) e->addAccelerations(*this);
    fs.nonPressureMs += took();

    // Fit the substeps exactly into the frame, without a tiny last step.
    const std::optional<Real> step = cflTimeStep();
    if (!step) return stop("non-finite velocity or acceleration");
    Real dt = *step;
    fs.stepScale = std::min(fs.stepScale, double(stepScale_));
    const double remaining = frameEnd - time_;
    if (remaining <= dt) dt = Real(remaining);
    else if (remaining < 2.0 * dt) dt = Real(0.5 * remaining);

#pragma omp parallel
    {
      const auto [first, last] = threadParticles();
      for (long i = first; i < last; ++i) fluid.v[i] += dt * fluid.a[i];
    }
    if (extrapolateBoundary_) {
      // What the walls gave the liquid through the extrapolated pressure.
      double ix = 0, iy = 0, iz = 0;
#pragma omp parallel for reduction(+ : ix, iy, iz)
      for (long i = 0; i < long(fluid.size()); ++i) {
        const double m = -double(dt) * double(fluid.mass[i]);
        ix += m * boundaryExtrapolation[i][0];
        iy += m * boundaryExtrapolation[i][1];
        if constexpr (D == 3) iz += m * boundaryExtrapolation[i][2];
      }
      fs.boundaryImpulse[0] += ix;
      fs.boundaryImpulse[1] += iy;
      fs.boundaryImpulse[2] += iz;
    }

    bool substepConverged = div.converged;
    // Implicit solves on v* (implicit viscosity), before the pressure solve.
    if (!implicitStages_.empty()) {
      for (Effect<D>* e : implicitStages_) {
        const SolverReport rep = e->solveVelocities(*this, dt);
        fs.viscosityIterations += rep.iterations;
        fs.viscosityConverged = fs.viscosityConverged && rep.converged;
        substepConverged = substepConverged && rep.converged;
        fs.converged = fs.converged && rep.converged;
        for (int d = 0; d < 3; ++d) fs.boundaryImpulse[d] += rep.boundaryImpulse[d];
      }
      fs.nonPressureMs += took();
    }

    const SolverReport dens = pressure_->correctDensity(*this, dt);
    averagePressure(dt);
    fs.pressureMs += took();
    fs.densityIterations += dens.iterations;
    for (int d = 0; d < 3; ++d) fs.boundaryImpulse[d] += dens.boundaryImpulse[d];
    fs.converged = fs.converged && dens.converged;
    fs.avgDensityErrorPct = std::max(fs.avgDensityErrorPct, dens.avgErrorPct);
    fs.maxDensityErrorPct = std::max(fs.maxDensityErrorPct, dens.maxErrorPct);
    substepConverged = substepConverged && dens.converged;
    fs.unconvergedSubsteps += substepConverged ? 0 : 1;
    updateStepScale(substepConverged);

    for (Effect<D>* e : velocityStages_) e->correctVelocities(*this, dt);
    if (bodies_) bodies_->integrate(*this, dt, setup_.domain, radius_);

#pragma omp parallel
    {
      const auto [first, last] = threadParticles();
      for (long i = first; i < last; ++i) fluid.x[i] += dt * fluid.v[i];
    }
    time_ += double(dt);
    // Keep time exact at frame boundaries despite rounding.
    if (time_ >= frameEnd - 1e-9) time_ = frameEnd;
    if (bodies_) {
      // Bodies at the step's end, before the liquid's contact with them.
      bodies_->place(time_, boundary);
      search.setStaticPoints(boundary.x);
    }
    enforceSolidContact(fs);
    lastDt_ = dt;
    fs.minDt = std::min(fs.minDt, double(dt));
    fs.maxDt = std::max(fs.maxDt, double(dt));
    ++fs.substeps;
    ++totalSubsteps_;
    ++stepsSinceReorder_;
  }
  ++frame_;
  for (Effect<D>* e : frameStages_) e->endFrame(*this, fs);

  double vmax2 = 0, energy = 0;
  bool finite = true;
  size_t outside = 0, temporary = 0;
#pragma omp parallel for schedule(static) reduction(max : vmax2) reduction(+ : energy, outside, temporary) reduction(&& : finite)
  for (long i = 0; i < n; ++i) {
    temporary += fluid.kind[i] == uint8_t(ParticleKind::Temporary) ? 1 : 0;
    bool out = !setup_.domain.contains(fluid.x[i]);
    for (const auto& o : setup_.obstacles) out = out || o.signedDistance(fluid.x[i]) < 0;
    if (bodies_) out = out || bodies_->inside(fluid.x[i]);
    outside += out ? 1 : 0;
    const double v2 = double(fluid.v[i].squaredNorm());
    vmax2 = std::max(vmax2, v2);
    energy += 0.5 * double(fluid.mass[i]) * v2;
    finite = finite && fluid.x[i].allFinite() && fluid.v[i].allFinite() && std::isfinite(fluid.density[i]);
  }
  fs.finite = finite && (!bodies_ || bodies_->finite());
  if (!fs.finite) fs.failure = "non-finite position or velocity";
  fs.escapedParticles = outside;
  fs.temporaryParticles = temporary;
  fs.maxSpeed = std::sqrt(vmax2);
  fs.kineticEnergy = energy;
  fs.frame = frame_;
  fs.time = time_;
  fs.particles = fluid.size();
  fs.boundaryParticles = boundary.size();
  size_t boundaryPairs = 0;
  for (uint16_t c : boundaryNeighbors) boundaryPairs += c;
  fs.avgNeighbors = n ? double(search.dynamicNeighbors().pairs() + boundaryPairs) / double(n) : 0;
  if (fs.substeps == 0) fs.minDt = 0;
  if (bodies_) bodies_->reportFrame(fs);
  fs.wallMs = msSince(t0);
  return fs;
}

std::string failureText(const FrameStats& s) {
  char t[48];
  std::snprintf(t, sizeof t, " (t = %.6g s): ", s.time);
  return "frame " + std::to_string(s.frame) + t + s.failure;
}

FC_INSTANTIATE_DIMS(Simulation)

}  // namespace fc
