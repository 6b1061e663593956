// Temporary particles (paper §3.4): seeded where a template holds more liquid
// than the simulation (Algorithm 1), removed once they have left every
// instance and sit in enough original liquid (Algorithm 2).
// GCC 12 warns that the AVX-512 reductions and rsqrt14 read an uninitialised
// operand: it is _mm512_undefined_ps, by design, so the warning is false.
// The pragmas precede the includes, where the intrinsics are parsed.
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "control/control.h"
#include "core/kernel_sums.h"
#include <omp.h>
#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace fc {

namespace {
// Greedy thinning: keeps a point unless a kept one lies within `dist`
// (in the order given, so the result is deterministic).
template <int D>
class SpacingFilter {
 public:
  explicit SpacingFilter(Real dist) : dist_(dist), inv_(Real(1) / dist) {}
  bool tryKeep(const Vec<D>& x) {
    const VecI<D> c = cellOf(x);
    VecI<D> o = VecI<D>::Constant(-1);
    while (true) {
      auto it = cells_.find(key(VecI<D>(c + o)));
      if (it != cells_.end())
        for (const Vec<D>& q : it->second)
          if ((q - x).squaredNorm() < dist_ * dist_) return false;
      int d = 0;
      while (d < D && ++o[d] > 1) o[d++] = -1;
      if (d == D) break;
    }
    cells_[key(c)].push_back(x);
    return true;
  }

 private:
  VecI<D> cellOf(const Vec<D>& x) const {
    VecI<D> c;
    for (int d = 0; d < D; ++d) c[d] = int(std::floor(x[d] * inv_));
    return c;
  }
  static uint64_t key(const VecI<D>& c) {
    uint64_t k = 0;
    for (int d = 0; d < D; ++d) k = k * 2097152u + uint64_t(int64_t(c[d]) + 1048576) % 2097152u;
    return k;
  }
  Real dist_, inv_;
  std::unordered_map<uint64_t, std::vector<Vec<D>>> cells_;
};

}  // namespace

template <int D>
void Control<D>::updateTemporaryParticles(Simulation<D>& sim, FrameStats&) {
  bool seeding = false;
  Real tau = std::numeric_limits<Real>::max(), l = std::numeric_limits<Real>::max();
  const double now = sim.time() + timeOffset_;
  for (size_t i = 0; i < instances_.size(); ++i) {
    const InstanceParams& p = instances_[i].spec.params;
    // A particle outside every instance belongs to none: removal uses the
    // most eager threshold and spacing of the instances started so far (one
    // that starts later changes nothing before it: edits re-simulate from
    // an instance's start).
    if (instances_[i].spec.time.start <= now + 1e-9) {
      tau = std::min(tau, Real(p.removalThreshold));
      l = std::min(l, Real(p.seedDistance));
    }
    seeding = seeding || (state_[i].on && p.temporaryParticles);
  }
  if (tau == std::numeric_limits<Real>::max()) {
    // Only left by an instance since removed: its defaults.
    const InstanceParams defaults = instanceParamTable(D).defaults();
    tau = Real(defaults.removalThreshold);
    l = Real(defaults.seedDistance);
  }
  if (!seeding && temporaries_ == 0) return;
  // The grid of the frame's own positions (the frame then depends only on
  // the state between frames, which a checkpoint restores), and the
  // seeding sources' lists and sums. Without temporary particles a frame
  // mostly keeps its particles: every particle's, which the first substep
  // then reuses. With them, particles come or go in most frames, and the
  // first substep needs every particle's anew: the sources' alone.
  const bool everyList = temporaries_ == 0;
  if (everyList) sim.refreshNeighbors();
  else sim.search.updateGrid(sim.fluid.x);

  const auto& f = sim.fluid;
  const Real hL = sim.supportRadius();
  const Real radius = sim.particleRadius();
  const CubicSpline<D>& W = sim.kernel;
  const long n = long(f.size());

  // ---- Algorithm 2 in [SPDM20]: removing temporary particles ----
  std::vector<uint32_t> remove;
  faded_ = 0;
  if (temporaries_ > 0) {
    const uint32_t grace = uint32_t(settings_.temporaryGraceFrames);
    const Real dtp = l * hL;
    std::vector<uint32_t>& temporary = temporaryScratch_;
    temporary.clear();
    for (long i = 0; i < n; ++i)
      if (f.kind[i] == uint8_t(ParticleKind::Temporary)) temporary.push_back(uint32_t(i));
    // Per temporary particle, in parallel: 0 stays, 1 dense enough to go
    // (subject to spacing), 2 past its grace period (goes regardless).
    std::vector<uint8_t>& verdict = verdictScratch_;
    verdict.assign(temporary.size(), 0);
    const long nt = long(temporary.size());
#pragma omp parallel for schedule(dynamic, 64)
    for (long k = 0; k < nt; ++k) {
      const uint32_t i = temporary[k];
      if (insideAnyInstance(f.x[i])) {  // no removal inside a box or its falloff band
        framesOutside_[i] = 0;
        continue;
      }
      // Past the grace period it goes whatever its surroundings (bounded
      // lifetime: the liquid's mass always returns to the scene's).
      if (++framesOutside_[i] > grace) {
        verdict[k] = 2;
        continue;
      }
      Real rho = 0;  // density of the original (non-temporary) liquid
      sim.search.forEachDynamicNear(f.x[i], hL, [&](uint32_t j, const Vec<D>&) {
        if (f.kind[j] != uint8_t(ParticleKind::Temporary)) rho += f.mass[j] * W.W(Vec<D>(f.x[i] - f.x[j]));
      });
      verdict[k] = rho > tau * sim.restDensity(i) ? 1 : 0;
    }
    // No two removals within d_tp of each other, in index order.
    SpacingFilter<D> spacing(Real(0.95) * dtp);
    for (long k = 0; k < nt; ++k)
      if (verdict[k] == 1 && spacing.tryKeep(f.x[temporary[k]])) remove.push_back(temporary[k]);
    // Past the grace period: the longest outside first, at most
    // temporary_fade_share of the liquid's mass per frame (at least one
    // particle), so that a whole instance's temporary particles fade out
    // over frames instead of leaving in one (a visible loss of a layer).
    std::vector<uint32_t>& overdue = overdueScratch_;
    overdue.clear();
    for (long k = 0; k < nt; ++k)
      if (verdict[k] == 2) overdue.push_back(temporary[k]);
    if (!overdue.empty()) {
      std::stable_sort(overdue.begin(), overdue.end(),
                       [&](uint32_t a, uint32_t b) { return framesOutside_[a] > framesOutside_[b]; });
      double total = 0;
      for (long i = 0; i < n; ++i) total += double(f.mass[i]);
      const double budget = settings_.temporaryFadeShare * total;
      double gone = 0;
      for (uint32_t i : overdue) {
        if (gone > 0 && gone + double(f.mass[i]) > budget) break;
        gone += double(f.mass[i]);
        remove.push_back(i);
        ++faded_;
      }
      std::sort(remove.begin(), remove.end());
    }
  }

  // ---- Algorithm 1 in [SPDM20]: seeding temporary particles ----
  std::vector<NewParticle<D>> add;
  if (seeding) {
    const auto& dom = sim.setup().domain;
    const auto& obstacles = sim.setup().obstacles;
    std::vector<uint8_t>& emitted = emittedScratch_;
    emitted.assign(size_t(n), 0);
    for (size_t s = 0; s < instances_.size(); ++s) {
      State& st = state_[s];
      const InstanceParams& p = instances_[s].spec.params;
      if (!st.on || !p.temporaryParticles) continue;
      // Only the box seeds (not its falloff band): its liquid, from the
      // frame's grid (the box grown by a cell, as the forces' gather).
      std::vector<uint32_t>& sources = seedSources_;
      sim.search.dynamicInBox(st.regionWorldBox.grown(sim.search.radius()), sources);
      const int phase = instances_[s].spec.phase;
      const Real eta = Real(p.seedThreshold);
      const Real dtp = Real(p.seedDistance) * hL;
      const Real eps = Real(0.05) * dtp;
      const Template<D>& tpl = instances_[s].templ();
      const Real rho0T = Real(tpl.header.restDensity);
      const auto gridsHeld = instances_[s].accel->frame(st.frame);  // keeps a streamed frame while it is read
      const TemplateFrameGrids<D>& grids = *gridsHeld;
      const auto& mc = grids.controlMasses();
      // The control masses in their grid's order, for the density sums.
      const NeighborhoodSearch<D>* controlGrid = grids.controlGrid();
      if (controlGrid) {
        sortedMass_.resize(controlGrid->staticCount());
        const uint32_t* order = controlGrid->staticOrder();
        for (size_t k = 0; k < sortedMass_.size(); ++k) sortedMass_[k] = mc[order[k]];
      }
      const long m = long(sources.size());
      auto& local = seedCandidates_;
      local.resize(static_cast<size_t>(omp_get_max_threads()));
      pairGradients_.resize(static_cast<size_t>(omp_get_max_threads()));
      sourceNeighbors_.resize(static_cast<size_t>(omp_get_max_threads()));
      for (auto& v : local) v.clear();
#pragma omp parallel for schedule(dynamic, 16)
      for (long k = 0; k < m; ++k) {
        const uint32_t i = sources[k];
        if (emitted[i] || f.phase[i] != phase || !insideBox(s, st.toTemplate.point(f.x[i]))) continue;
        // ∇ρ_i = Σ_j m_j ∇W_ij + ρ0_i Σ_b V_b ∇W_ib, over i's neighbour list
        // as the substep's density sums take it.
        const int t = omp_get_thread_num();
        const uint32_t* nbr;
        size_t count;
        if (everyList) {
          nbr = sim.pairNeighbors() + sim.pairOffsets()[i];
          count = sim.pairOffsets()[i + 1] - sim.pairOffsets()[i];
        } else {
          std::vector<uint32_t>& own = sourceNeighbors_[size_t(t)];
          sim.search.dynamicNeighborsOf(f.x[i], i, own);
          nbr = own.data();
          count = own.size();
        }
        auto& rows = pairGradients_[size_t(t)];
        const Real* grads[D];
        for (int d = 0; d < D; ++d) {
          rows[size_t(d)].resize(count);
          grads[d] = rows[size_t(d)].data();
        }
        for (size_t q = 0; q < count; ++q) {
          Vec<D> gq;
          if (everyList) {
            gq = sim.massGradWAt(long(i), sim.pairOffsets()[i] + q);
          } else {
            const Vec<D> r = f.x[i] - f.x[nbr[q]];
            Real w, fac;
            W.evaluateSquared(r.squaredNorm(), w, fac);
            gq = (f.mass[nbr[q]] * fac) * r;
          }
          for (int d = 0; d < D; ++d) rows[size_t(d)][q] = gq[d];
        }
        const Vec<D> gb = everyList ? sim.boundaryGradW[i] : sim.boundaryGradientAt(f.x[i]);
        const Vec<D> g = sim.restDensity(i) * gb + sumRanges<D>(grads, 0, count);
        // A gradient this small gives no direction to seed along (a
        // symmetric neighbourhood). It is not what filters the liquid's
        // interior: the particles' disorder keeps ‖∇ρ‖ above it almost
        // everywhere (98.7 % of blade3d's sources pass; at a free surface it
        // is of order ρ0/h, fifty times this). The crowding test below
        // rejects the interior's candidates instead.
        const Real gn = g.norm();
        if (!(gn > Real(0.02) * sim.restDensity(i) / hL)) continue;
        const Vec<D> xtp = f.x[i] - (dtp / gn) * g;
        const Vec<D> ytp = st.toTemplate.point(xtp);
        if (!insideBox(s, ytp)) continue;
        // Most candidates (96 % in letters3d) land next to liquid. A particle
        // within d_tp of x_tp lies within 2 d_tp of x_i (h at l = 0.5), so i's
        // own neighbour list rejects them before any grid query; the query
        // below still checks crowding against the rest.
        const Real crowd2 = (dtp - eps) * (dtp - eps);
        bool crowded = false;
        for (size_t q = 0; q < count && !crowded; ++q) crowded = (xtp - f.x[nbr[q]]).squaredNorm() < crowd2;
        if (crowded) continue;
        // Then the cheaper half of step 1: the template must hold liquid
        // there at all (ρ_cp − ρ > η ρ0 needs ρ_cp > η ρ0, as ρ >= 0).
        const Real rho0 = sim.restDensity(i);
        // Control density, as a fraction of the template's rest density.
        const Real rhoC = controlGrid ? poly6Sum<D>(*controlGrid, st.kernel, ytp, sortedMass_.data()) * (rho0 / rho0T) : 0;
        if (!(rhoC > eta * rho0)) continue;
        // Not into or next to a solid.
        if (!dom.grown(-radius).contains(xtp)) continue;
        bool nearSolid = false;
        for (const auto& o : obstacles) nearSolid = nearSolid || o.signedDistance(xtp) < radius;
        if (const auto* bodies = sim.bodies())
          for (const auto& b : bodies->states()) nearSolid = nearSolid || b.signedDistance(xtp) < radius;
        if (nearSolid) continue;
        Real rho = 0;
        sim.search.forEachDynamicNear(xtp, hL, [&](uint32_t j, const Vec<D>&) {
          const Vec<D> r = xtp - f.x[j];
          crowded = crowded || r.squaredNorm() < crowd2;
          rho += f.mass[j] * W.W(r);
        });
        if (crowded) continue;
        Real vb = 0;
        sim.search.forEachStaticNear(xtp, hL, [&](uint32_t b, const Vec<D>& xb) {
          vb += sim.boundary.volume[b] * W.W(Vec<D>(xtp - xb));
        });
        rho += rho0 * vb;
        if (rhoC - rho > eta * rho0)
          local[size_t(omp_get_thread_num())].push_back(
              {i, NewParticle<D>{xtp, f.v[i], f.mass[i], f.phase[i], ParticleKind::Temporary}});
      }
      std::vector<std::pair<uint32_t, NewParticle<D>>> all;
      for (auto& v : local) all.insert(all.end(), v.begin(), v.end());
      std::sort(all.begin(), all.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
      // Candidates too close to another candidate go (Algorithm 1, step 3);
      // so do those too close to one kept for an earlier instance.
      SpacingFilter<D> spacing(dtp - eps);  // lattice neighbours sit at exactly d_tp
      for (const auto& c : add) spacing.tryKeep(c.x);
      for (const auto& [src, c] : all) {
        if (!spacing.tryKeep(c.x)) continue;
        emitted[src] = 1;
        add.push_back(c);
      }
    }
  }

  sim.removeParticles(remove);
  // Never past max_particles: seeding pauses instead of failing the frame.
  const size_t room = sim.setup().maxParticles > sim.fluid.size() ? sim.setup().maxParticles - sim.fluid.size() : 0;
  if (add.size() > room) add.resize(room);
  sim.appendParticles(add);
  removed_ = remove.size();
  seeded_ = add.size();

  temporaries_ = temporaries_ - removed_ + seeded_;
}

template void Control<2>::updateTemporaryParticles(Simulation<2>&, FrameStats&);
template void Control<3>::updateTemporaryParticles(Simulation<3>&, FrameStats&);

}  // namespace fc
