// Implicit viscosity: Weiler, Koschier, Brand, Bender, "A Physically
// Consistent Implicit Viscosity Solver for SPH Fluids", Computer Graphics
// Forum 37(2), 2018 [WKBB18].
//
// The viscous force is μ∇²v with the SPH Laplacian of [WKBB18] (Monaghan's
// form, the 2(d+2) factor, 0.01h² against r → 0), written per pair so that
// it conserves momentum:
//   F_i = 2(d+2) Σ_j μ_ij V_i V_j (v_ij·x_ij)/(|x_ij|² + 0.01h²) ∇W_ij
//       + 2(d+2) Σ_b μ_b  V_i V_b ((v_i - v_b)·x_ib)/(|x_ib|² + 0.01h²) ∇W_ib,
// V = m/ρ, μ = ν ρ0 of the phase (ν: the phase's kinematic viscosity, m²/s),
// μ_ij = (μ_i + μ_j)/2, μ_b = boundary_viscosity · ρ0_i. At ρ = ρ0 and one
// phase this is viscosity_standard's acceleration; here it is integrated
// implicitly over the substep, as [WKBB18]:
//   (M − Δt A) v = M v* + Δt f_b,
// v* the predicted velocity (every other non-pressure acceleration applied),
// A the (symmetric, negative semi-definite) viscosity operator, f_b the
// boundary velocities' part of the wall term. With ∇W_ij = F(r) x_ij (F ≤ 0)
// each pair's block is -y yᵀ with y = sqrt(2(d+2) μ_ij V_i V_j (-F)/(r² +
// 0.01h²)) x_ij, so M − Δt A is symmetric positive definite and the system
// is solved matrix-free with preconditioned conjugate gradients, the
// preconditioner being the inverse of each particle's D×D diagonal block (the
// block-diagonal preconditioner of [WKBB18] / SPlisHSPlasH), warm-started
// from the previous substep's viscous acceleration (Δv/Δt, so that it carries
// over a change of Δt). CG solves for the correction δ = v − v* (rounding
// then scales with the viscous change, not with the velocity), and stops
// when the residual is `tolerance` times the smaller of the explicit viscous
// impulse c = Δt (f_b + A v*) and the momentum M v*, in the mass norm
// (Σ |r_i|²/m_i ≤ tol² min(Σ |c_i|²/m_i, Σ m_i |v*_i|²)). Relative to M v*
// alone, a smooth flow at a small Δt, whose viscous change is far below
// 1e-3 of its velocity, would stop before the first iteration; relative to
// c alone, stiff noise at a large Δt (c ≫ M v*) would stop early.
//
// The stage is ImplicitVelocities (see pipeline.h): it needs v* and Δt of
// the substep, and must act before the pressure solve. Implicit Euler damps
// every mode, so there is no viscous time-step limit (maxTimeStep stays at
// the default): honey-like ν at the CFL step is stable.
//
// Walls: boundary samples carry v_b = 0 where a mirrored ghost would carry
// −u, which halves their drag, so boundary_viscosity = 2ν puts the no-slip
// plane on the wall surface (measured 0.01 r from it; at ν it lies 1.24 r
// behind).
//
// Accuracy: the spatial operator is the paper's, and with the project's two
// particle spacings per support radius it is anisotropic (see
// standard.cpp and docs/physics/viscosity.md): on the resting lattice it gives
// 0.65× ν∂²u/∂y² for a shear flow u(y), 1.09× for the longitudinal part;
// plane Poiseuille flow comes out with ν_eff = 0.72 ν.
// Equation numbers of [WKBB18] are not cited: the text of the paper was not
// at hand to check them; each loop names the equation it implements.
#include "sph/builtin.h"
#include "sph/simulation.h"
#include <algorithm>
#include <cmath>

namespace fc {

namespace {
// Below this many particles the solve's loops run on one thread: a CG
// iteration is three parallel loops, and for a small liquid their fork/join
// and barriers cost more than the loops themselves, far more on a shared
// machine.
constexpr long kParallelFrom = 4096;
}  // namespace

struct Weiler2018Params {
  double tolerance;
  int maxIterations;
  double boundaryViscosity;
  bool warmStart;
};

const ParamTable<Weiler2018Params>& weiler2018Table() {
  using P = Weiler2018Params;
  static const ParamTable<P> table = {
      {.name = "tolerance", .min = 1e-6, .max = 0.1, .def = 1e-3,
       .help = "conjugate gradients stop at this residual relative to the step's explicit viscous impulse or the "
               "liquid's momentum, whichever is smaller (mass-weighted norms)",
       .member = &P::tolerance},
      {.name = "max_iterations", .min = 1, .max = 10000, .def = 100,
       .help = "most conjugate-gradient iterations per substep", .member = &P::maxIterations},
      {.name = "boundary_viscosity", .unit = "m^2/s", .min = 0, .max = 1000, .def = 0,
       .help = "kinematic viscosity against walls and obstacles (0: free slip; twice the liquid's viscosity: no "
               "slip at the wall surface)",
       .member = &P::boundaryViscosity},
      {.name = "warm_start", .min = 0, .max = 1, .def = 1,
       .help = "start each solve from the previous substep's viscous acceleration", .member = &P::warmStart},
  };
  return table;
}

const ParamSpecs& viscosityWeiler2018Params() { return weiler2018Table().specs(); }

template <int D>
class ViscosityWeiler2018 final : public Effect<D> {
  using M = Mat<D>;

 public:
  explicit ViscosityWeiler2018(const Weiler2018Params& p)
      : tolerance_(p.tolerance),
        maxIterations_(p.maxIterations),
        boundaryViscosity_(Real(p.boundaryViscosity)),
        warmStart_(p.warmStart) {}

  unsigned stages() const override { return ImplicitVelocities; }

  void init(Simulation<D>& sim) override {
    mu_.clear();
    rho0_.clear();
    anyViscosity_ = boundaryViscosity_ > 0;
    for (const auto& ph : sim.setup().phases) {
      mu_.push_back(ph.viscosity * ph.restDensity);
      rho0_.push_back(ph.restDensity);
      anyViscosity_ = anyViscosity_ || ph.viscosity > 0;
    }
  }

  // Every per-particle array is sized here (and by reorder's scratch), so a
  // substep allocates nothing once the pair arrays have grown.
  void resize(size_t n) override {
    accel_.resize(n, Vec<D>::Zero());
    vstar_.resize(n);
    fb_.resize(n);
    b_.resize(n);
    x_.resize(n);
    r_.resize(n);
    z_.resize(n);
    p_.resize(n);
    q_.resize(n);
    pinv_.resize(n);
    wall_.resize(n);
  }
  void reorder(const std::vector<uint32_t>& perm) override { applyPermutation(accel_, perm, scratch_); }
  void archiveState(StateArchive& a) override { a.io(accel_); }

  SolverReport solveVelocities(Simulation<D>& sim, Real dt) override {
    SolverReport rep;
    const long n = long(sim.fluid.size());
    if (!anyViscosity_ || n == 0 || !(dt > 0)) return rep;
    assemble(sim, dt);

    // Unknown: the correction δ = v − v*, so that float rounding is relative
    // to the viscous change and not to the velocity itself. S δ = c with
    // c = b − S v* = Δt (f_b + A v*), the explicit viscous impulse of the
    // step (r = c for δ = 0).
    auto& v = sim.fluid.v;
    const Real* mass = sim.fluid.mass.data();
    const double tol2 = tolerance_ * tolerance_;
    apply(sim, Real(0), -dt, vstar_, b_);
#pragma omp parallel for schedule(static) if (n >= kParallelFrom)
    for (long i = 0; i < n; ++i) {
      b_[i] += fb_[i];
      x_[i] = warmStart_ ? Vec<D>(dt * accel_[i]) : Vec<D>::Zero();
    }
    // r = c − S δ0, z = P⁻¹ r, p = z.
    apply(sim, Real(1), dt, x_, q_);
    double cc = 0, mv = 0, rr = 0, rz = 0;
#pragma omp parallel for schedule(static) if (n >= kParallelFrom) reduction(+ : cc, mv, rr, rz)
    for (long i = 0; i < n; ++i) {
      const Real invM = Real(1) / mass[i];
      r_[i] = b_[i] - q_[i];
      z_[i] = pinv_[i] * r_[i];
      p_[i] = z_[i];
      cc += double(b_[i].squaredNorm() * invM);
      mv += double(mass[i] * vstar_[i].squaredNorm());
      rr += double(r_[i].squaredNorm() * invM);
      rz += double(r_[i].dot(z_[i]));
    }
    // Reference: the smaller of the explicit impulse c and the momentum M v*
    // (mass norm). Smooth flow at a small step: c ≪ M v*, and the viscous
    // change is solved to `tolerance` of itself. Stiff noise at a large step:
    // c ≫ M v* (the explicit step would overshoot), and the velocity is
    // solved to `tolerance` of itself.
    // (A liquid at rest beside a moving wall has M v* = 0: then c alone.)
    const double ref = mv > 0 ? std::min(cc, mv) : cc;
    if (!(cc > 0)) {
      // No shear and no wall friction anywhere: δ = 0.
#pragma omp parallel for schedule(static) if (n >= kParallelFrom)
      for (long i = 0; i < n; ++i) x_[i].setZero();
      rr = 0;
    }
    while (rr > tol2 * ref && rep.iterations < maxIterations_) {
      const double pq = apply(sim, Real(1), dt, p_, q_);
      if (!(pq > 0)) break;  // p = 0 (rounding): nothing left to do
      const Real alpha = Real(rz / pq);
      double rzNew = 0;
      rr = 0;
#pragma omp parallel for schedule(static) if (n >= kParallelFrom) reduction(+ : rr, rzNew)
      for (long i = 0; i < n; ++i) {
        x_[i] += alpha * p_[i];
        r_[i] -= alpha * q_[i];
        z_[i] = pinv_[i] * r_[i];
        rr += double(r_[i].squaredNorm() / mass[i]);
        rzNew += double(r_[i].dot(z_[i]));
      }
      const Real beta = Real(rzNew / rz);
      rz = rzNew;
#pragma omp parallel for schedule(static) if (n >= kParallelFrom)
      for (long i = 0; i < n; ++i) p_[i] = z_[i] + beta * p_[i];
      ++rep.iterations;
    }
    rep.converged = rr <= tol2 * ref;
    rep.avgErrorPct = ref > 0 ? 100.0 * std::sqrt(rr / ref) : 0.0;

    // v = v* + δ; the viscous acceleration δ/Δt (next warm start); the
    // momentum the walls gave the liquid through viscosity, Δt (f_b − B_i v_i).
    const bool walls = boundaryViscosity_ > 0;
    double imp[D] = {};
    const Real invDt = Real(1) / dt;
#pragma omp parallel for schedule(static) if (n >= kParallelFrom) reduction(+ : imp[:D])
    for (long i = 0; i < n; ++i) {
      v[i] = vstar_[i] + x_[i];
      accel_[i] = x_[i] * invDt;
      if (walls) {
        const Vec<D> j = fb_[i] - dt * (wall_[i] * v[i]);
        for (int d = 0; d < D; ++d) imp[d] += double(j[d]);
      }
    }
    for (int d = 0; d < D; ++d) rep.boundaryImpulse[d] = imp[d];
    return rep;
  }

 private:
  // Per substep: the pair vectors y_k, each particle's wall block B_i, the
  // right-hand side b and the block-diagonal preconditioner.
  void assemble(Simulation<D>& sim, Real dt) {
    const auto& f = sim.fluid;
    const long n = long(f.size());
    const uint32_t* off = sim.pairOffsets();
    const uint32_t* nbr = sim.pairNeighbors();
    const size_t pairs = off[n];
    for (auto& y : y_) {
      if (y.capacity() < pairs) y.reserve(pairs + pairs / 4);
      y.resize(pairs);
    }
    const Real h = sim.supportRadius();
    const Real eps = Real(0.01) * h * h;
    const Real dd = Real(2 * (D + 2));
    const Real muWall = boundaryViscosity_;
    std::array<Real*, D> y;
    for (int d = 0; d < D; ++d) y[d] = y_[d].data();
    const Real* xs = f.x.data()->data();
    const std::vector<Real>& mu = mu_;
    const std::vector<Real>& rho0 = rho0_;
#pragma omp parallel for schedule(static) if (n >= kParallelFrom)
    for (long i = 0; i < n; ++i) {
      const Vec<D> xi = f.x[i];
      const Real vi = f.mass[i] / f.density[i];
      const Real mui = mu[f.phase[i]];
      M diag = M::Zero();
      // [WKBB18], the SPH Laplacian 2(d+2) Σ_j (m_j/ρ_j) (v_ij·x_ij)/(|x_ij|² + 0.01h²) ∇W_ij, as pair blocks -y yᵀ.
      for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
        const uint32_t j = nbr[k];
        const Real* xj = xs + size_t(D) * j;
        Vec<D> xij;
        for (int d = 0; d < D; ++d) xij[d] = xi[d] - xj[d];
        const Real r2 = xij.squaredNorm();
        // -m_j F from the cached m_j ∇W_ij = m_j F x_ij.
        Real gx = 0;
        for (int d = 0; d < D; ++d) gx += (sim.massGradScale[k] * xij[d]) * xij[d];
        const Real c = r2 > 0 ? std::max(Real(0), -gx / r2) : Real(0);
        const Real coef = dd * Real(0.5) * (mui + mu[f.phase[j]]) * vi / f.density[j] * c / (r2 + eps);
        const Vec<D> yk = std::sqrt(coef) * xij;
        for (int d = 0; d < D; ++d) y[d][k] = yk[d];
        diag.noalias() += yk * yk.transpose();
      }
      // [WKBB18], the boundary term of the viscous force (Akinci boundary samples, coefficient boundary_viscosity):
      // its v_i part joins the diagonal block, its v_b part the right-hand side.
      M wall = M::Zero();
      Vec<D> fb = Vec<D>::Zero();
      if (muWall > 0) {
        const Real cw = dd * muWall * rho0[f.phase[i]] * vi;
        sim.search.forEachStaticNear(xi, h, [&](uint32_t bIdx, const Vec<D>& xb) {
          const Vec<D> xib = xi - xb;
          const Real r2 = xib.squaredNorm();
          const Vec<D> g = sim.kernel.gradW(xib);  // F x_ib
          const Real s = cw * sim.boundary.volume[bIdx] / (r2 + eps);
          // (v·x_ib) ∇W_ib = (∇W_ib x_ibᵀ) v; -s ∇W x_ibᵀ is positive semi-definite.
          wall.noalias() -= s * g * xib.transpose();
          fb -= (s * sim.boundary.v[bIdx].dot(xib)) * g;
        });
        // Symmetrise the rounding of g x_ibᵀ (g ∥ x_ib).
        wall = Real(0.5) * (wall + wall.transpose()).eval();
      }
      wall_[i] = wall;
      vstar_[i] = f.v[i];
      // [WKBB18], the implicit system (M − Δt A) v = M v* (+ Δt f_b for moving boundaries): the boundary
      // velocities' impulse and the block-diagonal preconditioner.
      fb_[i] = dt * fb;
      pinv_[i] = (f.mass[i] * M::Identity() + dt * (diag + wall)).inverse();
    }
  }

  // out = massScale M in + lScale (−A) in, with −A = L + B (pairs and walls);
  // returns inᵀ out. (1, Δt): the system matrix M − Δt A.
  double apply(const Simulation<D>& sim, Real massScale, Real lScale, const std::vector<Vec<D>>& in,
               std::vector<Vec<D>>& out) const {
    const long n = long(sim.fluid.size());
    const uint32_t* off = sim.pairOffsets();
    const uint32_t* nbr = sim.pairNeighbors();
    const Real* ps = in.data()->data();
    const Real* mass = sim.fluid.mass.data();
    std::array<const Real*, D> y;
    for (int d = 0; d < D; ++d) y[d] = y_[d].data();
    double dot = 0;
    // [WKBB18], the viscosity operator A applied matrix-free: −A p_i = Σ_j (y_ij·(p_i − p_j)) y_ij + B_i p_i.
#pragma omp parallel for schedule(static) if (n >= kParallelFrom) reduction(+ : dot)
    for (long i = 0; i < n; ++i) {
      Real pi[D], acc[D];
      for (int d = 0; d < D; ++d) pi[d] = ps[size_t(D) * i + d], acc[d] = 0;
      for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
        const Real* pj = ps + size_t(D) * nbr[k];
        Real s = 0;
        for (int d = 0; d < D; ++d) s += y[d][k] * (pi[d] - pj[d]);
        for (int d = 0; d < D; ++d) acc[d] += s * y[d][k];
      }
      const Vec<D> wp = wall_[i] * in[i];
      Vec<D> o;
      for (int d = 0; d < D; ++d) o[d] = massScale * mass[i] * pi[d] + lScale * (acc[d] + wp[d]);
      out[i] = o;
      dot += double(in[i].dot(o));
    }
    return dot;
  }

  double tolerance_;
  int maxIterations_;
  Real boundaryViscosity_;
  bool warmStart_;
  bool anyViscosity_ = false;
  std::vector<Real> mu_, rho0_;  // per phase: dynamic viscosity ν ρ0 (Pa·s) and rest density
  std::vector<Vec<D>> accel_;    // viscous acceleration of the previous substep (warm start), follows reorder()
  std::vector<Vec<D>> vstar_, fb_, b_, x_, r_, z_, p_, q_, scratch_;
  std::vector<M> pinv_, wall_;   // per particle: preconditioner (inverse diagonal block), wall block B_i
  std::array<std::vector<Real>, D> y_;  // per pair (CSR order): y_ij
};

template <int D>
std::unique_ptr<Effect<D>> makeViscosityWeiler2018(const ParamValues& p) {
  return std::make_unique<ViscosityWeiler2018<D>>(weiler2018Table().bind(p));
}
template std::unique_ptr<Effect<2>> makeViscosityWeiler2018<2>(const ParamValues&);
template std::unique_ptr<Effect<3>> makeViscosityWeiler2018<3>(const ParamValues&);

}  // namespace fc
