// XSPH velocity smoothing (Monaghan 1989 [Mon89]):
//   v_i ← v_i + c Σ_j 2 m_j/(ρ_i + ρ_j) (v_j - v_i) W_ij,
// applied after the pressure solve. Damps noise; c is dimensionless. The
// symmetric weight conserves momentum (m_j/ρ_j alone does not where
// densities differ, as at a free surface).
#include "sph/builtin.h"
#include "sph/simulation.h"

namespace fc {

struct XsphParams {
  double coefficient;
};

const ParamTable<XsphParams>& xsphTable() {
  using P = XsphParams;
  static const ParamTable<P> table = {
      {.name = "coefficient", .min = 0, .max = 1, .def = 0.05, .help = "XSPH smoothing factor c",
       .member = &P::coefficient},
  };
  return table;
}

const ParamSpecs& viscosityXSPHParams() { return xsphTable().specs(); }

template <int D>
class ViscosityXSPH final : public Effect<D> {
 public:
  explicit ViscosityXSPH(const XsphParams& p) : c_(Real(p.coefficient)) {}
  unsigned stages() const override { return CorrectVelocities; }
  void resize(size_t n) override { old_.resize(n); }

  void correctVelocities(Simulation<D>& sim, Real) override {
    auto& f = sim.fluid;
    const uint32_t* off = sim.pairOffsets();
    const long n = long(f.size());
    old_.resize(f.size());
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) old_[i] = f.v[i];
#pragma omp parallel for schedule(static)
    for (long i = 0; i < n; ++i) {
      const Vec<D> xi = f.x[i], vi = old_[i];
      Vec<D> dv = Vec<D>::Zero();
      for (uint32_t k = off[i], e = off[i + 1]; k < e; ++k) {
        const uint32_t j = sim.pairNeighbors()[k];
        dv += (Real(2) * f.mass[j] / (f.density[i] + f.density[j]) * sim.kernel.W(xi - f.x[j])) * (old_[j] - vi);
      }
      f.v[i] = vi + c_ * dv;
    }
  }

 private:
  Real c_;
  std::vector<Vec<D>> old_;
};

template <int D>
std::unique_ptr<Effect<D>> makeViscosityXSPH(const ParamValues& p) {
  return std::make_unique<ViscosityXSPH<D>>(xsphTable().bind(p));
}
template std::unique_ptr<Effect<2>> makeViscosityXSPH<2>(const ParamValues&);
template std::unique_ptr<Effect<3>> makeViscosityXSPH<3>(const ParamValues&);

}  // namespace fc
