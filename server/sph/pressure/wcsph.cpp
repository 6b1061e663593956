// Weakly compressible SPH: Becker & Teschner, "Weakly compressible SPH for
// free surface flows", SCA 2007 [BT07].
#include "sph/builtin.h"
#include "sph/simulation.h"
#include <cmath>

namespace fc {

struct WcsphParams {
  double stiffness;
  double exponent;
};

const ParamTable<WcsphParams>& wcsphTable() {
  using P = WcsphParams;
  static const ParamTable<P> table = {
      {.name = "stiffness", .unit = "Pa", .min = 1, .max = 1e9, .def = 50000, .help = "B in p = B((ρ/ρ0)^γ - 1)",
       .member = &P::stiffness},
      {.name = "exponent", .min = 1, .max = 7, .def = 7, .help = "γ in p = B((ρ/ρ0)^γ - 1)", .member = &P::exponent},
  };
  return table;
}

const ParamSpecs& wcsphParams() { return wcsphTable().specs(); }

template <int D>
class WCSPH final : public PressureSolver<D> {
 public:
  explicit WCSPH(const WcsphParams& p) : stiffness_(Real(p.stiffness)), exponent_(Real(p.exponent)) {}

  // Sound speed c = sqrt(B γ / ρ0); the step must resolve it (acoustic CFL).
  Real maxTimeStep(const Simulation<D>& sim) const override {
    Real rho0 = sim.restDensity_[0];
    for (Real r : sim.restDensity_) rho0 = std::min(rho0, r);
    const Real c = std::sqrt(stiffness_ * exponent_ / rho0);
    return Real(sim.setup().settings.cflFactor) * Real(0.4) * 2 * sim.particleRadius() / c;
  }

  SolverReport correctDensity(Simulation<D>& sim, Real dt) override {
    auto& f = sim.fluid;
    const long n = long(f.size());
    double sum = 0;
    Real mx = 0;
    // Equation of state, eq. (7) in [BT07], clamped at zero to avoid tensile
    // instability at the free surface.
#pragma omp parallel for schedule(static) reduction(+ : sum) reduction(max : mx)
    for (long i = 0; i < n; ++i) {
      const Real rho0 = sim.restDensity_[f.phase[i]];
      const Real ratio = std::max(sim.constrainedDensity(size_t(i)) / rho0, Real(1));
      f.pressure[i] = stiffness_ * (std::pow(ratio, exponent_) - Real(1));
      const Real err = ratio - Real(1);
      sum += double(err);
      mx = std::max(mx, err);
    }
    if (sim.numberDensity()) accelerate<true>(sim, dt);
    else accelerate<false>(sim, dt);
    SolverReport rep;
    for (long i = 0; i < n; ++i) {
      const Real pi = f.pressure[i] / (f.density[i] * f.density[i]);
      const Vec<D> j =
          (-double(dt) * f.mass[i] * sim.boundaryPressureWeight() * sim.restDensity_[f.phase[i]] * pi) * sim.boundaryGradW[i];
      for (int d = 0; d < D; ++d) rep.boundaryImpulse[d] += double(j[d]);
    }
    rep.avgErrorPct = n ? sum / double(n) * 100.0 : 0;
    rep.maxErrorPct = double(mx) * 100.0;
    return rep;
  }

 private:
  // Mass sum: symmetric pressure acceleration, eq. (6) in [BT07]; boundaries
  // act with the particle's own pressure term (Akinci et al. 2012 [AIA*12],
  // eq. (10)), times the boundary model's weight w (pipeline.h).
  // Number density (Solenthaler & Pajarola 2008 [SP08], see dfsph.cpp): the
  // pressure from the equation of state of ρ_i = m_i δ_i, and the force of
  // [SP08] Section 4, a_i = -(1/m_i) Σ_j (p_i/δ_i² + p_j/δ_j²) ∇W_ij, the
  // boundary mirroring p_i/δ_i² with the weight V_b/V_i (the same Akinci
  // term -ρ0_i p_i/ρ_i² Σ_b V_b ∇W_ib as above).
  template <bool ND>
  void accelerate(Simulation<D>& sim, Real dt) {
    auto& f = sim.fluid;
    const uint32_t* off = sim.pairOffsets();
    const long n = long(f.size());
    if constexpr (ND) {
      scaled_.resize(f.size());
#pragma omp parallel for schedule(static)
      for (long i = 0; i < n; ++i) {
        const Real delta = f.density[i] / f.mass[i];
        scaled_[i] = f.pressure[i] / (delta * delta);
      }
    }
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) {
      const Real rho0 = sim.restDensity_[f.phase[i]];
      const Real pi = f.pressure[i] / (f.density[i] * f.density[i]);
      Vec<D> a = -(sim.boundaryPressureWeight() * rho0 * pi) * sim.boundaryGradW[i];
      if constexpr (!ND) {
        for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
          const uint32_t j = sim.pairNeighbors()[k];
          a -= (pi + f.pressure[j] / (f.density[j] * f.density[j])) * sim.massGradWAt(i, k);
        }
      } else {
        Vec<D> sum = Vec<D>::Zero();
        for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
          const uint32_t j = sim.pairNeighbors()[k];
          sum += (scaled_[i] + scaled_[j]) * sim.gradWAt(i, k);
        }
        a -= sum / f.mass[i];
      }
      f.v[i] += dt * a;
    }
  }

  Real stiffness_, exponent_;
  std::vector<Real> scaled_;  // number density only: p_i / δ_i²
};

template <int D>
std::unique_ptr<PressureSolver<D>> makeWCSPH(const ParamValues& p) {
  return std::make_unique<WCSPH<D>>(wcsphTable().bind(p));
}
template std::unique_ptr<PressureSolver<2>> makeWCSPH<2>(const ParamValues&);
template std::unique_ptr<PressureSolver<3>> makeWCSPH<3>(const ParamValues&);

}  // namespace fc
