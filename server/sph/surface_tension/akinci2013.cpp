// Surface tension and adhesion of Akinci, Akinci & Teschner 2013, "Versatile
// Surface Tension and Adhesion for SPH Fluids" (ACM TOG 32(6)), [AAT13], as
// SPlisHSPlasH's "Akinci et al. 2013":
//   a_i = -gamma Σ_j K_ij ( m_j C(|x_ij|) x_ij/|x_ij| + (n_i - n_j) )
//         - beta Σ_b rho0 V_b A(|x_ib|) x_ib/|x_ib|,
// with the cohesion kernel C and the adhesion kernel A of core/kernels.h
// (their 2D normalisation is derived there), the scaled normals
// n_i = h Σ_j m_j/rho_j ∇W_ij and K_ij = 2 rho0 / (rho_i + rho_j), which
// strengthens the pull where a particle lacks neighbours (the surface).
//
// Multiphase: cohesion, curvature and the normals only involve neighbours of
// the particle's own phase; two phases do not pull on each other (their
// interface gets no tension from this effect). Within a phase all masses are
// equal (sph/simulation.cpp), so every pair term is antisymmetric,
// F_ij = -F_ji, and the liquid's momentum is conserved; adhesion exchanges
// momentum with the walls only.
//
// gamma is the paper's coefficient, with SPlisHSPlasH's default (0.05) and
// its SI reading: not a physical surface tension in N/m (the paper's two
// terms do not even share a unit). The cohesion term alone corresponds to the
// continuum surface tension sigma = (21/7040) gamma rho0^2 h^2 (see
// CohesionKernel), 0.24 N/m at the default with rho0 = 1000, r = 0.01 m.
// `sigma` (N/m) sets gamma from that relation instead, per phase, so that a
// scene keeps its liquid's surface tension at any resolution.
//
// The term is explicit: a particle in the cohesion well oscillates with
// omega^2 ~ gamma rho0 / h, so the step is capped at
// dt <= c sqrt(rho0 r^3 / (2 pi sigma)) (the capillary time step of
// Brackbill et al. 1992 [BKZ92] with sigma as above), c measured in
// tests/test_surface_tension.cpp (SurfaceTension.DISABLED_MeasureStabilityLimit).
#include "sph/builtin.h"
#include <algorithm>
#include <cmath>
#include <numbers>
#include "sph/simulation.h"

namespace fc {

struct Akinci2013Params {
  double surfaceTension;
  double adhesion;
  double sigma;
};

const ParamTable<Akinci2013Params>& akinci2013Table() {
  using P = Akinci2013Params;
  static const ParamTable<P> table = {
      {.name = "surface_tension", .min = 0, .max = 100, .def = 0.05,
       .help = "gamma of Akinci et al. 2013 (SPlisHSPlasH's surfaceTension): cohesion and curvature strength, SI, "
               "not N/m (the cohesion term alone gives sigma = 0.003 gamma rho0^2 h^2 N/m, h = 4r); caps the time "
               "step at the capillary step sqrt(rho0 r^3 / (2 pi sigma))",
       .member = &P::surfaceTension},
      {.name = "adhesion", .min = 0, .max = 100, .def = 0,
       .help = "beta of Akinci et al. 2013 (SPlisHSPlasH's surfaceTensionBoundary): pull of walls and obstacles on "
               "the liquid (0: off)",
       .member = &P::adhesion},
      {.name = "sigma", .unit = "N/m", .min = 0, .max = 10, .def = 0,
       .help = "the liquid's surface tension (water: 0.0728); when set, gamma follows it at any resolution, "
               "gamma = sigma / (0.003 rho0^2 h^2) for each phase (0: surface_tension gives gamma)",
       .member = &P::sigma},
  };
  return table;
}

const ParamSpecs& surfaceTensionAkinci2013Params() { return akinci2013Table().specs(); }

// Stability of the explicit step: dt <= c sqrt(rho0 r^3 / (2 pi sigma)),
// sigma = (21/7040) gamma rho0^2 h^2. Measured at fixed steps
// (SurfaceTension.DISABLED_MeasureStabilityLimit: 2D r = 5 and 2.5 mm,
// gamma = 1, 4, 16; 3D r = 5 mm, gamma = 1, 16): stable up to c = 2 in every
// case, energy growing or particles flying off from c = 2.5 (2D, r = 5 mm)
// or c = 3 (the others). c = 1 keeps a margin of 2.
constexpr double kCapillaryStepFactor = 1.0;

template <int D>
class SurfaceTensionAkinci2013 final : public Effect<D> {
 public:
  explicit SurfaceTensionAkinci2013(const Akinci2013Params& p)
      : gamma_(Real(p.surfaceTension)), beta_(Real(p.adhesion)), sigma_(p.sigma) {}
  unsigned stages() const override { return AddAccelerations; }

  void init(Simulation<D>& sim) override {
    cohesion_.setRadius(sim.supportRadius());
    adhesion_.setRadius(sim.supportRadius());
    rho0Max_ = 0;
    gammaOfPhase_.clear();
    const double h = sim.supportRadius();
    for (const auto& ph : sim.setup().phases) {
      rho0Max_ = std::max(rho0Max_, ph.restDensity);
      const double rho0 = ph.restDensity;
      gammaOfPhase_.push_back(
          sigma_ > 0 ? Real(sigma_ / (CohesionKernel<D>::sigmaPerGammaRho2H2() * rho0 * rho0 * h * h)) : gamma_);
    }
    resize(sim.fluid.size());
  }
  void resize(size_t n) override {
    for (auto& c : normal_) c.resize(n);
    hOverRho_.resize(n);
  }
  void reorder(const std::vector<uint32_t>& perm) override {
    for (auto& c : normal_) applyPermutation(c, perm, scratch_);
  }

  // The capillary time step with the cohesion term's surface tension. The
  // adhesion term is bounded the same way with beta for gamma, which is
  // conservative (per unit coefficient its work of adhesion is a tenth of the
  // cohesion's sigma) and not measured separately; the larger of the two
  // coefficients sets the bound.
  Real maxTimeStep(const Simulation<D>& sim) const override {
    double g = std::max(beta_, gammaOfPhase_.empty() ? gamma_ : Real(0));
    for (Real gp : gammaOfPhase_) g = std::max(g, double(gp));
    if (!(g > 0) || !(rho0Max_ > 0)) return Real(1e30);
    const double r = sim.particleRadius(), h = sim.supportRadius();
    const double sigma = CohesionKernel<D>::sigmaPerGammaRho2H2() * g * double(rho0Max_) * rho0Max_ * h * h;
    return Real(kCapillaryStepFactor * std::sqrt(double(rho0Max_) * r * r * r / (2 * std::numbers::pi * sigma)));
  }

  void addAccelerations(Simulation<D>& sim) override {
    resize(sim.fluid.size());  // no-op unless a caller skipped resize()
    // One phase: no per-pair phase test (a byte gather per pair).
    if (sim.setup().phases.size() > 1) apply<true>(sim);
    else apply<false>(sim);
  }

  // The normals of the last addAccelerations, n_i = h Σ_j m_j/ρ_j ∇W_ij.
  Vec<D> normal(size_t i) const {
    Vec<D> v;
    for (int d = 0; d < D; ++d) v[d] = normal_[d][i];
    return v;
  }

 private:
  template <bool Multiphase>
  void apply(Simulation<D>& sim) {
    auto& f = sim.fluid;
    const long n = long(f.size());
    const uint32_t* off = sim.pairOffsets();
    const uint32_t* nbr = sim.pairNeighbors();
    const uint8_t* phase = f.phase.data();
    const Real* rho = f.density.data();
    const Real* mass = f.mass.data();
    const Real* xs = f.x.data()->data();  // D packed Reals per particle
    const Real h = sim.supportRadius();
    const Real* mg = sim.massGradScale.data();  // m_j ∇W_ij = mg[k] x_ij
    std::array<Real*, D> nrm;
    for (int d = 0; d < D; ++d) nrm[d] = normal_[d].data();
    auto samePhase = [phase](long i, uint32_t j) { return !Multiphase || phase[j] == phase[i]; };
    // Plain local pointers: through the arrays the compiler reloads them every pair.
    Real *n0 = nrm[0], *n1 = nrm[1], *n2 = nrm[D - 1];

    Real* hOverRho = hOverRho_.data();
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) hOverRho[i] = h / rho[i];
    // equation (3) in [AAT13]: n_i = h Σ_j m_j/ρ_j ∇W_ij, same-phase neighbours
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) {
      const Real* xi = xs + size_t(D) * size_t(i);
      Real s0 = 0, s1 = 0, s2 = 0;  // s2: 3D only
#pragma omp simd reduction(+ : s0, s1, s2)
      for (uint32_t k = off[i]; k < off[i + 1]; ++k) {
        const uint32_t j = nbr[k];
        const Real* xj = xs + size_t(D) * j;
        const Real w = samePhase(i, j) ? hOverRho[j] : Real(0);
        s0 += w * (mg[k] * (xi[0] - xj[0]));
        s1 += w * (mg[k] * (xi[1] - xj[1]));
        if constexpr (D == 3) s2 += w * (mg[k] * (xi[D - 1] - xj[D - 1]));
      }
      n0[i] = s0;
      n1[i] = s1;
      if constexpr (D == 3) n2[i] = s2;
    }

    const Real* gammaOf = gammaOfPhase_.data();
    const Real beta = beta_;
    const Real* rho0 = sim.restDensity_.data();
    const Real eps = Real(1e-6) * h;
    const CohesionKernel<D> cohesion = cohesion_;
    // equations (1), (2), (4) and (5) in [AAT13]: cohesion + curvature, times K_ij
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) {
      const Real* xi = xs + size_t(D) * size_t(i);
      Real ni[D], x0[D];
      for (int d = 0; d < D; ++d) ni[d] = nrm[d][i], x0[d] = xi[d];  // copies: not reloaded per pair
      const Real twoRho0 = Real(2) * rho0[phase[i]], rhoi = rho[i];
      Real s0 = 0, s1 = 0, s2 = 0;  // s2: 3D only
#pragma omp simd reduction(+ : s0, s1, s2)
      for (uint32_t k = off[i]; k < off[i + 1]; ++k) {
        const uint32_t j = nbr[k];
        const Real* xj = xs + size_t(D) * j;
        Real r[D], r2 = 0;
        for (int d = 0; d < D; ++d) {
          r[d] = x0[d] - xj[d];
          r2 += r[d] * r[d];
        }
        // One square root and one division per pair: q = 1 / (|x_ij| (ρ_i + ρ_j)),
        // K_ij = 2ρ0 |x_ij| q, K_ij m_j C / |x_ij| = 2ρ0 m_j C q. A pair at the
        // same position gets no cohesion.
        const Real rl = std::sqrt(std::max(r2, eps * eps));
        const Real q = samePhase(i, j) ? twoRho0 / (rl * (rhoi + rho[j])) : Real(0);
        const Real kij = rl * q;
        const Real kcoh = r2 > eps * eps ? mass[j] * cohesion.W(rl) * q : Real(0);
        s0 += kcoh * r[0] + kij * (ni[0] - n0[j]);
        s1 += kcoh * r[1] + kij * (ni[1] - n1[j]);
        if constexpr (D == 3) s2 += kcoh * r[D - 1] + kij * (ni[D - 1] - n2[j]);
      }
      const Real acc[3] = {s0, s1, s2};
      Vec<D> a;
      const Real gamma = gammaOf[phase[i]];
      for (int d = 0; d < D; ++d) a[d] = -gamma * acc[d];
      // equations (6) and (7) in [AAT13]: adhesion to the boundary particles, Ψ_b = ρ0 V_b
      if (beta > 0) {
        Vec<D> ad = Vec<D>::Zero();
        const Vec<D> x = f.x[size_t(i)];
        sim.search.forEachStaticNear(x, h, [&](uint32_t b, const Vec<D>& xb) {
          const Vec<D> rb = x - xb;
          const Real l2 = rb.squaredNorm();
          if (l2 <= eps * eps) return;
          const Real l = std::sqrt(l2);
          ad += (sim.boundary.volume[b] * adhesion_.W(l) / l) * rb;
        });
        a -= (beta * rho0[phase[i]]) * ad;
      }
      f.a[size_t(i)] += a;
    }
  }

  Real gamma_, beta_;
  double sigma_;                    // N/m; 0: gamma_ for every phase
  std::vector<Real> gammaOfPhase_;  // gamma per phase, set by init
  Real rho0Max_ = 0;
  CohesionKernel<D> cohesion_;
  AdhesionKernel<D> adhesion_;
  std::array<std::vector<Real>, D> normal_;  // SoA, one array per axis
  std::vector<Real> hOverRho_;               // h / ρ_j, per step (no state: not reordered)
  std::vector<Real> scratch_;                // reorder()'s, kept so that reordering allocates nothing
};

template <int D>
std::unique_ptr<Effect<D>> makeSurfaceTensionAkinci2013(const ParamValues& p) {
  return std::make_unique<SurfaceTensionAkinci2013<D>>(akinci2013Table().bind(p));
}
template std::unique_ptr<Effect<2>> makeSurfaceTensionAkinci2013<2>(const ParamValues&);
template std::unique_ptr<Effect<3>> makeSurfaceTensionAkinci2013<3>(const ParamValues&);

}  // namespace fc
