// Standard SPH viscosity: the Laplacian estimate of Monaghan 2005 [Mon05] as used by
// SPlisHSPlasH ("Standard"):
//   a_i = d Σ_j ν (m_j/ρ_j) (v_ij·x_ij)/(|x_ij|² + 0.01h²) ∇W_ij,
// with ν the kinematic viscosity of the phases (their mean for a mixed pair).
// d = 2(D+2) is the continuum value. With only two particle spacings per
// support radius the discrete operator is anisotropic: on the lattice it
// gives 0.65x ν∇²v for v = (y², 0) but 1.09x for v = (x², 0) (whose
// continuum answer includes 2∇(∇·v)), and a Taylor-Green vortex decays about
// 1.2x faster than ν predicts. A single calibration factor cannot fix that;
// the implicit viscosity solver (weiler2018.cpp) is the accurate one.
#include "sph/builtin.h"
#include <algorithm>
#include <cmath>
#include "sph/simulation.h"

namespace fc {

struct ViscosityStandardParams {
  double boundaryViscosity;
};

const ParamTable<ViscosityStandardParams>& viscosityStandardTable() {
  using P = ViscosityStandardParams;
  static const ParamTable<P> table = {
      {.name = "boundary_viscosity", .unit = "m^2/s", .min = 0, .max = 1000, .def = 0,
       .help = "kinematic viscosity against walls and obstacles (0: free slip)", .member = &P::boundaryViscosity},
  };
  return table;
}

const ParamSpecs& viscosityStandardParams() { return viscosityStandardTable().specs(); }

template <int D>
class ViscosityStandard final : public Effect<D> {
 public:
  explicit ViscosityStandard(const ViscosityStandardParams& p) : boundaryViscosity_(Real(p.boundaryViscosity)) {}
  unsigned stages() const override { return AddAccelerations; }
  void init(Simulation<D>& sim) override {
    nu_.clear();
    for (const auto& ph : sim.setup().phases) nu_.push_back(ph.viscosity);
  }

  // Explicit diffusion is stable for Δt up to about 0.8 r²/ν (measured on a
  // Taylor-Green vortex); half of that keeps a margin.
  Real maxTimeStep(const Simulation<D>& sim) const override {
    Real nuMax = boundaryViscosity_;
    for (Real v : nu_) nuMax = std::max(nuMax, v);
    if (!(nuMax > 0)) return Real(1e30);
    const Real r = sim.particleRadius();
    return Real(0.4) * r * r / nuMax;
  }

  void addAccelerations(Simulation<D>& sim) override {
    auto& f = sim.fluid;
    const uint32_t* off = sim.pairOffsets();
    const std::vector<Real>& nu = nu_;
    const Real h = sim.supportRadius();
    const Real eps = Real(0.01) * h * h;
    const Real d = Real(2 * (D + 2));
#pragma omp parallel
    {
      const auto [first, last] = sim.threadParticles();
      for (long i = first; i < last; ++i) {
        const Vec<D> xi = f.x[i], vi = f.v[i];
        const Real nui = nu[f.phase[i]];
        Vec<D> a = Vec<D>::Zero();
        for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
          const uint32_t j = sim.pairNeighbors()[k];
          const Vec<D> xij = xi - f.x[j];
          const Real nuij = Real(0.5) * (nui + nu[f.phase[j]]);
          a += (nuij / f.density[j] * (vi - f.v[j]).dot(xij) / (xij.squaredNorm() + eps)) * sim.massGradWAt(i, k);
        }
        if (boundaryViscosity_ > 0)
          sim.search.forEachStaticNear(xi, sim.supportRadius(), [&](uint32_t b, const Vec<D>& xb) {
            const Vec<D> xib = xi - xb;
            a += (boundaryViscosity_ * sim.boundary.volume[b] * (vi - sim.boundary.v[b]).dot(xib) /
                  (xib.squaredNorm() + eps)) *
                 sim.kernel.gradW(xib);
          });
        f.a[i] += d * a;
      }
    }
  }

 private:
  Real boundaryViscosity_;
  std::vector<Real> nu_;  // per phase
};

template <int D>
std::unique_ptr<Effect<D>> makeViscosityStandard(const ParamValues& p) {
  return std::make_unique<ViscosityStandard<D>>(viscosityStandardTable().bind(p));
}
template std::unique_ptr<Effect<2>> makeViscosityStandard<2>(const ParamValues&);
template std::unique_ptr<Effect<3>> makeViscosityStandard<3>(const ParamValues&);

}  // namespace fc
