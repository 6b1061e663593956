// Divergence-free SPH: Bender & Koschier, "Divergence-Free SPH for
// Incompressible and Viscous Fluids", TVCG 2017 [BK17] (SCA 2015 [BK15]).
//
// Both solves use the same Jacobi update. With K_i the stiffness of particle
// i, the velocity correction is
//   Δv_i = -Σ_j m_j (K_i + K_j) ∇W_ij - K_i Σ_b Ψ_b ∇W_ib,
// and requiring it to cancel particle i's own residual r_i (the density rate
// Dρ_i/Dt, or (ρ*_i - ρ0)/Δt) gives K_i = r_i / S_i with
//   S_i = |Σ_j m_j ∇W_ij + Σ_b Ψ_b ∇W_ib|² + Σ_j |m_j ∇W_ij|²,
// i.e. K_i = r_i · α_i with α_i = 1/S_i, the DFSPH factor (eq. (11) in [BK17]).
//
// Number density (Solenthaler & Pajarola, "Density Contrast SPH Interfaces",
// SCA 2008 [SP08]; chosen once at setup, Simulation::numberDensity()). The
// density is ρ_i = m_i δ_i + ρ0_i Σ_b V_b W_ib with δ_i = Σ_j W_ij, and the
// pressure force is [SP08]'s symmetric volume form, F_i = -Σ_j (p_i/δ_i² +
// p_j/δ_j²) ∇W_ij, the boundary mirroring p_i/δ_i² with the weight V_b/V_i
// (V_i = m_i/ρ0_i, Akinci's term as before). [SP08] gives an equation of
// state and explicit forces; DFSPH replaces the equation of state by its two
// solves, so what carries over is the density, its rate and the force. With
// K_i = Δt p_i/δ_i² the velocity correction is
//   Δv_i = -(1/m_i) [Σ_j (K_i + K_j) ∇W_ij + K_i (ρ0_i/m_i) Σ_b V_b ∇W_ib],
// and both residuals are rates of that density,
//   Dρ_i/Dt = m_i Σ_j (v_i - v_j)·∇W_ij + ρ0_i Σ_b V_b (v_i - v_b)·∇W_ib.
// K_i acts on v_i through G_i = Σ_j ∇W_ij + (ρ0_i/m_i) Σ_b V_b ∇W_ib and on
// each neighbour through Δv_j = +(K_i/m_j) ∇W_ij, so the diagonal of the
// system, the factor's inverse, is
//   S_i = |G_i|² + Σ_j (m_i/m_j) |∇W_ij|²,
// the same Jacobi update K_i = r_i/S_i as above. With equal masses m, S is
// the mass-sum one over m² and K the mass-sum one times m²: the same solve. Momentum is conserved pairwise (m_i Δv_i from j is -(K_i +
// K_j) ∇W_ij), and with J = ∂ρ/∂x the correction is Δv = -M⁻¹ Jᵀ λ with
// λ_i = K_i/m_i: the kinetic-energy-weighted projection onto the linearised
// density constraint, as the mass-sum solve is for its own density. The
// residuals stay relative to each particle's own ρ0. The light phase takes
// the largest velocity corrections (∝ 1/m), which is why the time step is
// scaled under the number density (Simulation::cflTimeStep).
#include "sph/builtin.h"
#include "sph/simulation.h"
#include <omp.h>
#include <algorithm>
#include <array>
#include <cmath>

namespace fc {

struct DfsphParams {
  double densityTolerancePct;
  double divergenceTolerancePct;
  int minIterations;
  int maxIterations;
  int maxDivergenceIterations;
  bool divergenceSolve;
  bool warmStart;
};

const ParamTable<DfsphParams>& dfsphTable() {
  using P = DfsphParams;
  static const ParamTable<P> table = {
      {.name = "density_tolerance_pct", .unit = "%", .min = 1e-4, .max = 10, .def = 0.01,
       .help = "average density error at which the density solve stops", .member = &P::densityTolerancePct},
      {.name = "divergence_tolerance_pct", .unit = "%/step", .min = 1e-4, .max = 100, .def = 0.1,
       .help = "average density-rate error (relative to rest density, per time step) at which the divergence "
               "solve stops",
       .member = &P::divergenceTolerancePct},
      {.name = "min_iterations", .min = 1, .max = 1000, .def = 2, .help = "fewest density-solve iterations",
       .member = &P::minIterations},
      {.name = "max_iterations", .min = 1, .max = 10000, .def = 100, .help = "most density-solve iterations",
       .member = &P::maxIterations},
      {.name = "max_divergence_iterations", .min = 1, .max = 10000, .def = 100,
       .help = "most divergence-solve iterations", .member = &P::maxDivergenceIterations},
      {.name = "divergence_solve", .min = 0, .max = 1, .def = 1, .help = "run the divergence-free solve",
       .member = &P::divergenceSolve},
      {.name = "warm_start", .min = 0, .max = 1, .def = 1,
       .help = "start each solve from half the previous step's stiffness where the particle is still compressed",
       .member = &P::warmStart},
  };
  return table;
}

const ParamSpecs& dfsphParams() { return dfsphTable().specs(); }

template <int D>
class DFSPH final : public PressureSolver<D> {
 public:
  explicit DFSPH(const DfsphParams& p)
      : densityTol_(Real(p.densityTolerancePct * 0.01)),
        divergenceTol_(Real(p.divergenceTolerancePct * 0.01)),
        minIterations_(p.minIterations),
        maxIterations_(p.maxIterations),
        maxDivergenceIterations_(p.maxDivergenceIterations),
        divergenceSolve_(p.divergenceSolve),
        warmStart_(p.warmStart) {}

  void resize(size_t n) override {
    factor_.resize(n, 0);
    kappaDensity_.resize(n, 0);
    kappaDivergence_.resize(n, 0);
    residual_.resize(n, 0);
    packed_.resize(n);
    deficient_.resize(n, 0);
  }
  // The stiffnesses warm-start the next substep's solves.
  void archiveState(StateArchive& a) override {
    a.io(kappaDensity_);
    a.io(kappaDivergence_);
  }
  void reorder(const std::vector<uint32_t>& perm) override {
    applyPermutation(kappaDensity_, perm, scratch_);
    applyPermutation(kappaDivergence_, perm, scratch_);
  }

  // DFSPH factor α_i = 1/S_i (eq. (11) in [BK17]).
  void prepare(Simulation<D>& sim) override {
    numberDensity_ = sim.numberDensity();
    if (numberDensity_) prepareWith<true>(sim);
    else prepareWith<false>(sim);
  }

  SolverReport correctDivergence(Simulation<D>& sim, Real dt) override {
    SolverReport rep;
    if (!divergenceSolve_) return rep;
    boundaryImpulse_ = {};
    const long n = long(sim.fluid.size());
    // Stop when the average density rate is below tol·ρ0 per time step.
    const Real eta = divergenceTol_ / dt;
    pack(sim);
    Real avg = divergenceResidual(sim);
    if (warmStart_) {
      warmStartFrom(sim, kappaDivergence_, Real(1));
      avg = divergenceResidual(sim);
    } else {
      std::fill(kappaDivergence_.begin(), kappaDivergence_.end(), Real(0));
    }
    while ((avg > eta || rep.iterations < 1) && rep.iterations < maxDivergenceIterations_) {
      applyStiffness(sim, kappaDivergence_, Real(1));
      avg = divergenceResidual(sim);
      ++rep.iterations;
    }
    rep.converged = avg <= eta || n == 0;
    rep.avgErrorPct = double(avg) * double(dt) * 100.0;
    rep.boundaryImpulse = boundaryImpulse_;
    return rep;
  }

  SolverReport correctDensity(Simulation<D>& sim, Real dt) override {
    SolverReport rep;
    const long n = long(sim.fluid.size());
    boundaryImpulse_ = {};
    Real maxErr = 0;
    pack(sim);
    Real avg = densityResidual(sim, dt, maxErr);
    if (warmStart_) {
      warmStartFrom(sim, kappaDensity_, dt);
      avg = densityResidual(sim, dt, maxErr);
    } else {
      std::fill(kappaDensity_.begin(), kappaDensity_.end(), Real(0));
    }
    while ((avg > densityTol_ || rep.iterations < minIterations_) && rep.iterations < maxIterations_) {
      applyStiffness(sim, kappaDensity_, dt);
      avg = densityResidual(sim, dt, maxErr);
      ++rep.iterations;
    }
    rep.converged = avg <= densityTol_ || n == 0;
    rep.avgErrorPct = double(avg) * 100.0;
    rep.maxErrorPct = double(maxErr) * 100.0;
    rep.boundaryImpulse = boundaryImpulse_;
    // The pressure both corrections amount to over the step: Δv = -Δt Σ_j m_j
    // (p_i/ρ_i² + p_j/ρ_j²) ∇W_ij, so p_i = ρ_i² (K_i + K_i^div)/Δt; under
    // the number density K_i = Δt p_i/δ_i², so p_i = δ_i² (K_i + K_i^div)/Δt.
    auto& f = sim.fluid;
    if (!numberDensity_) {
#pragma omp parallel
      {
        const auto [first, last] = sim.threadParticles();
        for (long i = first; i < last; ++i)
          f.pressure[i] = f.density[i] * f.density[i] * (kappaDensity_[i] + kappaDivergence_[i] / dt);
      }
    } else {
#pragma omp parallel
      {
        const auto [first, last] = sim.threadParticles();
        for (long i = first; i < last; ++i) {
          const Real delta = f.density[i] / f.mass[i];
          f.pressure[i] = delta * delta * (kappaDensity_[i] + kappaDivergence_[i] / dt);
        }
      }
    }
    return rep;
  }

 private:
  // Warm start (as SPlisHSPlasH): a particle that is compressed now starts
  // from half of its previous stiffness; one that is not starts from zero.
  // Measured: carrying over all of it converges faster in a deep column but
  // pumps energy into the liquid, because the increments are never negative
  // and a push that is no longer needed would be repeated every step. Density stiffness is
  // stored as K/Δt, an acceleration scale, so it carries over a change of Δt;
  // divergence stiffness does not depend on Δt (called with dt = 1).
  // Expects residual_ to hold the current residual.
  void warmStartFrom(Simulation<D>& sim, std::vector<Real>& kappa, Real dt) {
#pragma omp parallel
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        kappa[i] = residual_[i] > 0 ? Real(0.5) * kappa[i] : Real(0);
        packed_[i].x[3] = kappa[i] * dt;
      }
    }
    updateVelocities(sim);
  }

  template <bool ND>
  void prepareWith(Simulation<D>& sim) {
    const uint32_t* off = sim.pairOffsets();
    const uint32_t* nbr = sim.pairNeighbors();
    const auto& f = sim.fluid;
    const Real w = sim.boundaryPressureWeight();
#pragma omp parallel
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        const Real rho0 = sim.restDensity_[f.phase[i]];
        Real s, floor;
        if constexpr (!ND) {
          // With the boundary weight w (pipeline.h, BoundaryModel) K_i moves v_i along
          // G + (w - 1) Ψ_b-sum but changes ρ_i along G (sum): the diagonal is their product.
          const Vec<D> gb = rho0 * sim.boundaryGradW[i];
          Vec<D> sum = gb;
          Real sumSq = 0;
          for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
            const Vec<D> g = sim.massGradWAt(i, k);
            sum += g;
            sumSq += g.squaredNorm();
          }
          s = (w == 1 ? sum.squaredNorm() : sum.dot(sum + (w - 1) * gb)) + sumSq;
          floor = Real(1e-6) * rho0 * rho0;
        } else {
          // S_i = |Σ_j ∇W_ij + (ρ0_i/m_i) Σ_b V_b ∇W_ib|² + Σ_j (m_i/m_j)|∇W_ij|² (the diagonal; see the top).
          const Real mi = f.mass[i];
          const Vec<D> gb = (rho0 / mi) * sim.boundaryGradW[i];
          Vec<D> sum = gb;
          Real sumSq = 0;
          for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
            const Vec<D> g = sim.gradWAt(i, k);
            sum += g;
            sumSq += g.squaredNorm() / f.mass[nbr[k]];
          }
          s = (w == 1 ? sum.squaredNorm() : sum.dot(sum + (w - 1) * gb)) + mi * sumSq;
          floor = Real(1e-6) * (rho0 / mi) * (rho0 / mi);
        }
        // A negative diagonal (w > 1, the wall's term opposing the liquid's) means
        // pushing would compress the particle further: it is left to its neighbours.
        factor_[i] = s > floor ? Real(1) / s : Real(0);
        // Too few neighbours: a surface particle cannot be compressed, and its
        // divergence estimate is unreliable ([BK17], Section 4).
        deficient_[i] = (off[i + 1] - off[i] + sim.boundaryNeighbors[i]) < (D == 3 ? 20u : 7u);
      }
    }
  }

  // Adds this iteration's stiffness K_i = r_i α_i to the accumulated one and
  // corrects the velocities with it.
  void applyStiffness(Simulation<D>& sim, std::vector<Real>& kappa, Real dt) {
#pragma omp parallel
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        const Real stiffness = residual_[i] * factor_[i];
        kappa[i] += stiffness / dt;
        packed_[i].x[3] = stiffness;
      }
    }
    updateVelocities(sim);
  }

  void updateVelocities(Simulation<D>& sim) {
    if (numberDensity_) updateVelocitiesWith<true>(sim);
    else updateVelocitiesWith<false>(sim);
  }

  // Mass sum: Δv_i = -Σ_j m_j (K_i + K_j) ∇W_ij - w K_i Σ_b Ψ_b ∇W_ib (eqs. (9) and (12) in [BK17];
  // w the boundary model's weight, 1 in [BK17]).
  // Number density: Δv_i = -(1/m_i) [Σ_j (K_i + K_j) ∇W_ij + w K_i (ρ0_i/m_i) Σ_b V_b ∇W_ib],
  // the pressure force of [SP08] Section 4, F_i = -Σ_j (p_i/δ_i² + p_j/δ_j²) ∇W_ij, with K = Δt p/δ².
  template <bool ND>
  void updateVelocitiesWith(Simulation<D>& sim) {
    const uint32_t* off = sim.pairOffsets();
    const uint32_t* nbr = sim.pairNeighbors();
    const Real* scale = ND ? sim.gradScale.data() : sim.massGradScale.data();
    const Packed* packed = packed_.data();
    auto& f = sim.fluid;
    const Real w = sim.boundaryPressureWeight();
    double ix = 0, iy = 0, iz = 0;
#pragma omp parallel reduction(+ : ix, iy, iz)
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        const Lanes xi = packed[i].x;
        const Real ki = xi[3];
        const uint32_t b = off[i], e = off[i + 1];
        // Lanes 0..D-1: Σ_j (K_i + K_j) m_j F_ij (x_i - x_j).
        const Lanes sum = sumPairs(b, e, [&](uint32_t k) {
          const Lanes xj = packed[nbr[k]].x;
          return (xi - xj) * ((ki + xj[3]) * scale[k]);
        });
        Real dx = sum[0], dy = sum[1], dz = D == 3 ? sum[2] : Real(0);
        Real kb = w * ki * sim.restDensity_[f.phase[i]];
        if constexpr (ND) {
          // Both terms carry 1/m_i, the boundary one once more (its weight V_b/V_i).
          const Real inv = Real(1) / f.mass[i];
          dx *= inv;
          dy *= inv;
          dz *= inv;
          kb *= inv * inv;
        }
        const Vec<D>& gb = sim.boundaryGradW[i];
        f.v[i][0] -= dx + kb * gb[0];
        f.v[i][1] -= dy + kb * gb[1];
        if constexpr (D == 3) f.v[i][2] -= dz + kb * gb[2];
        for (int d = 0; d < D; ++d) packed_[i].v[d] = f.v[i][d];
        const double mk = -double(f.mass[i]) * double(kb);
        ix += mk * gb[0];
        iy += mk * gb[1];
        if constexpr (D == 3) iz += mk * gb[2];
      }
    }
    boundaryImpulse_[0] += ix;
    boundaryImpulse_[1] += iy;
    boundaryImpulse_[2] += iz;
  }

  // Each particle's position and velocity into its packed record, at the
  // start of a solve (the stiffness lane is written where it is set).
  void pack(const Simulation<D>& sim) {
    const auto& f = sim.fluid;
#pragma omp parallel
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        Packed& p = packed_[i];
        p.x = Lanes{};
        p.v = Lanes{};
        for (int d = 0; d < D; ++d) p.x[d] = f.x[i][d], p.v[d] = f.v[i][d];
      }
    }
  }

  Real divergenceResidual(Simulation<D>& sim) {
    return numberDensity_ ? divergenceResidualWith<true>(sim) : divergenceResidualWith<false>(sim);
  }
  Real densityResidual(Simulation<D>& sim, Real dt, Real& maxErr) {
    return numberDensity_ ? densityResidualWith<true>(sim, dt, maxErr) : densityResidualWith<false>(sim, dt, maxErr);
  }

  // Dρ_i/Dt = Σ_j m_j (v_i - v_j)·∇W_ij + Σ_b Ψ_b (v_i - v_b)·∇W_ib (eq. (8) in [BK17]),
  // only compression counts. Returns the average over particles, relative to ρ0.
  template <bool ND>
  Real divergenceResidualWith(Simulation<D>& sim) {
    const auto& f = sim.fluid;
    const long n = long(f.size());
    double sum = 0;
#pragma omp parallel reduction(+ : sum)
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        const Real rho0 = sim.restDensity_[f.phase[i]];
        Real r = rateOfDensity<ND>(sim, i, rho0);
        r = deficient_[i] ? Real(0) : std::max(r, Real(0));
        residual_[i] = r;
        sum += double(r / rho0);
      }
    }
    return n ? Real(sum / double(n)) : Real(0);
  }

  // ρ*_i = ρ_i + Δt Dρ_i/Dt (eq. (13) in [BK17]); residual (ρ*_i - ρ0)/Δt,
  // compression only. Returns the average relative error; maxErr the largest.
  // While the step is shrunk by s < 1 (Simulation::stepScale, after solves
  // that stopped at their iteration limit), only the share s of the
  // compression a particle already has is removed in this step: that
  // compression is what the capped solves left, and removed within a step s
  // times shorter it would become a push 1/s times faster (measured: a
  // resting column with 1-iteration solves gained 6 % energy and reached
  // 2.3 m/s in its first frame at s = 1/64). Spread this way it is removed
  // at the unshrunk step's rate. With s = 1, eq. (13) as it stands.
  template <bool ND>
  Real densityResidualWith(Simulation<D>& sim, Real dt, Real& maxErr) {
    const auto& f = sim.fluid;
    const long n = long(f.size());
    const Real deferred = Real(1) - sim.stepScale();
    double sum = 0;
    Real mx = 0;
#pragma omp parallel reduction(+ : sum) reduction(max : mx)
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        const Real rho0 = sim.restDensity_[f.phase[i]];
        const Real rho = sim.constrainedDensity(size_t(i));
        const Real predicted = rho - deferred * std::max(rho - rho0, Real(0)) + dt * rateOfDensity<ND>(sim, i, rho0);
        const Real err = std::max(predicted - rho0, Real(0));
        residual_[i] = err / dt;
        mx = std::max(mx, err / rho0);
        sum += double(err / rho0);
      }
    }
    maxErr = mx;
    return n ? Real(sum / double(n)) : Real(0);
  }

  // Mass sum: Σ_j m_j (v_i - v_j)·∇W_ij + ρ0_i Σ_b V_b (v_i - v_b)·∇W_ib.
  // Number density: the rate of ρ_i = m_i δ_i + ρ0_i Σ_b V_b W_ib,
  // m_i Σ_j (v_i - v_j)·∇W_ij + the same boundary term ([SP08] Section 4, differentiated).
  template <bool ND>
  Real rateOfDensity(const Simulation<D>& sim, long i, Real rho0) const {
    const auto& f = sim.fluid;
    const uint32_t* off = sim.pairOffsets();
    const uint32_t* nbr = sim.pairNeighbors();
    const Real* scale = ND ? sim.gradScale.data() : sim.massGradScale.data();
    const Packed* packed = packed_.data();
    const Lanes xi = packed[i].x, vi = packed[i].v;
    const uint32_t b = off[i], e = off[i + 1];
    // Lanes 0..D-1 of Σ_j m_j F_ij (x_i - x_j) ∘ (v_i - v_j); the other lanes
    // stay 0 (the velocity's are).
    const Lanes sum = sumPairs(b, e, [&](uint32_t k) {
      const Packed& p = packed[nbr[k]];
      return ((xi - p.x) * (vi - p.v)) * scale[k];
    });
    Real r = (sum[0] + sum[1]) + (sum[2] + sum[3]);
    const Vec<D> v = f.v[i];
    if constexpr (ND) r *= f.mass[i];
    return r + rho0 * (v.dot(sim.boundaryGradW[i]) - sim.boundaryFlux[i]);
  }

  Real densityTol_, divergenceTol_;
  int minIterations_, maxIterations_, maxDivergenceIterations_;
  bool divergenceSolve_, warmStart_;
  bool numberDensity_ = false;  // Simulation::numberDensity(), read in prepare()


  std::vector<Real> factor_, kappaDensity_, kappaDivergence_, residual_, scratch_;
  // Per particle, what the sweeps read of a neighbour, in one aligned record
  // (one or two loads of it instead of D + 1 or 2D scattered ones): x in
  // lanes 0..D-1 and this iteration's stiffness K in lane 3; v in lanes
  // 0..D-1, the rest 0. Rebuilt at each solve's start, so never permuted.
  using Lanes = Real __attribute__((vector_size(4 * sizeof(Real))));
  struct alignas(8 * sizeof(Real)) Packed {
    Lanes x, v;
  };
  std::vector<Packed> packed_;

  // Σ_k term(k) over one particle's pairs [b, e). In 3D (about 30 pairs) in
  // two chains of additions, the even pairs and the odd ones, so that each
  // addition does not wait on the last; 2D lists (about 12 pairs) keep one.
  template <class Term>
  static Lanes sumPairs(uint32_t b, uint32_t e, Term&& term) {
    Lanes sum = {};
    uint32_t k = b;
    if constexpr (D == 3) {
      Lanes odd = {};
      for (; k + 1 < e; k += 2) {
        sum += term(k);
        odd += term(k + 1);
      }
      if (k < e) sum += term(k);
      return sum + odd;
    }
    for (; k < e; ++k) sum += term(k);
    return sum;
  }

  std::vector<uint8_t> deficient_;
  std::array<double, 3> boundaryImpulse_{};
};

template <int D>
std::unique_ptr<PressureSolver<D>> makeDFSPH(const ParamValues& p) {
  return std::make_unique<DFSPH<D>>(dfsphTable().bind(p));
}
template std::unique_ptr<PressureSolver<2>> makeDFSPH<2>(const ParamValues&);
template std::unique_ptr<PressureSolver<3>> makeDFSPH<3>(const ParamValues&);

}  // namespace fc
