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
  bool subcycle;
};

const ParamTable<ViscosityStandardParams>& viscosityStandardTable() {
  using P = ViscosityStandardParams;
  static const ParamTable<P> table = {
      {.name = "boundary_viscosity", .unit = "m^2/s", .min = 0, .max = 1000, .def = 0,
       .help = "kinematic viscosity against walls and obstacles (0: free slip)", .member = &P::boundaryViscosity},
      {.name = "subcycle", .min = 0, .max = 1, .def = 0,
       .help = "let the step exceed the explicit operator's stability limit 0.4 r^2/nu and apply the operator in "
               "as many sub-steps as the limit needs, positions held (off: the step is shortened to the limit)",
       .member = &P::subcycle},
  };
  return table;
}

const ParamSpecs& viscosityStandardParams() { return viscosityStandardTable().specs(); }

template <int D>
class ViscosityStandard final : public Effect<D> {
 public:
  explicit ViscosityStandard(const ViscosityStandardParams& p)
      : boundaryViscosity_(Real(p.boundaryViscosity)), subcycle_(p.subcycle) {}
  unsigned stages() const override { return subcycle_ ? AddAccelerations | ImplicitVelocities : AddAccelerations; }
  void init(Simulation<D>& sim) override {
    nu_.clear();
    for (const auto& ph : sim.setup().phases) nu_.push_back(ph.viscosity);
  }
  void resize(size_t n) override {
    if (subcycle_) a_.resize(n);
  }

  // Explicit diffusion is stable for Δt up to about 0.8 r²/ν (measured on a
  // Taylor-Green vortex); half of that keeps a margin.
  Real stableStep(const Simulation<D>& sim) const {
    Real nuMax = boundaryViscosity_;
    for (Real v : nu_) nuMax = std::max(nuMax, v);
    if (!(nuMax > 0)) return Real(1e30);
    const Real r = sim.particleRadius();
    return Real(0.4) * r * r / nuMax;
  }
  Real maxTimeStep(const Simulation<D>& sim) const override { return subcycle_ ? Real(1e30) : stableStep(sim); }

  void addAccelerations(Simulation<D>& sim) override {
    auto& f = sim.fluid;
    if (!subcycle_) {
      accelerations(sim, [&f](long i, const Vec<D>& a) { f.a[i] += a; });
      return;
    }
    a_.resize(f.size());
    accelerations(sim, [&](long i, const Vec<D>& a) {
      a_[i] = a;
      f.a[i] += a;
    });
  }

  // A step beyond the stability limit: the explicit increment Δt·a that
  // v* = v + Δt·a took from addAccelerations is replaced by n sub-steps of
  // Δt/n, each with the operator evaluated on the current velocities
  // (positions and densities held: operator splitting, first order in Δt
  // like the explicit step itself).
  SolverReport solveVelocities(Simulation<D>& sim, Real dt) override {
    const Real limit = stableStep(sim);
    if (!(dt > limit)) return {};
    auto& f = sim.fluid;
    const long n = long(f.size());
    const int steps = int(std::ceil(double(dt) / double(limit)));
    const Real h = dt / Real(steps);
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) f.v[i] -= dt * a_[i];
    for (int s = 0; s < steps; ++s) {
      accelerations(sim, [this](long i, const Vec<D>& a) { a_[i] = a; });
#pragma omp parallel for schedule(static)
      for (long i = 0; i < n; ++i) f.v[i] += h * a_[i];
    }
    SolverReport report;
    report.iterations = steps;
    return report;
  }

 private:
  // The viscous acceleration of every particle from the current velocities,
  // handed to put(i, a).
  template <class Put>
  void accelerations(Simulation<D>& sim, Put put) const {
    const auto& f = sim.fluid;
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
        put(i, d * a);
      }
    }
  }

  Real boundaryViscosity_;
  bool subcycle_;
  std::vector<Real> nu_;      // per phase
  std::vector<Vec<D>> a_;     // this substep's viscous acceleration (sub-cycling only)
};

template <int D>
std::unique_ptr<Effect<D>> makeViscosityStandard(const ParamValues& p) {
  return std::make_unique<ViscosityStandard<D>>(viscosityStandardTable().bind(p));
}
template std::unique_ptr<Effect<2>> makeViscosityStandard<2>(const ParamValues&);
template std::unique_ptr<Effect<3>> makeViscosityStandard<3>(const ParamValues&);

}  // namespace fc
