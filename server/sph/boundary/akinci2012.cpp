// Boundary particles: Akinci, Ihmsen, Akinci, Solenthaler & Teschner,
// "Versatile Rigid-Fluid Coupling for Incompressible SPH", SIGGRAPH 2012
// [AIA*12]. A boundary sample b acts on particle i with eq. (10),
//   F_i = -m_i Ψ_b (p_i/ρ_i²) ∇W_ib,  Ψ_b = ρ0_i V_b,
// the particle's own pressure term alone: the sample carries no pressure of
// its own. The samples, their volumes (eq. (4)) and the density term are
// Simulation::buildBoundary's and computeDensities'.
#include "sph/builtin.h"

namespace fc {

namespace {
template <int D>
class Akinci2012 final : public BoundaryModel<D> {
 public:
  Real pressureWeight() const override { return Real(1); }
  bool extrapolatesPressure() const override { return false; }
};
}  // namespace

const ParamSpecs& boundaryAkinci2012Params() {
  static const ParamSpecs none;
  return none;
}

template <int D>
std::unique_ptr<BoundaryModel<D>> makeBoundaryAkinci2012(const ParamValues&) {
  return std::make_unique<Akinci2012<D>>();
}
template std::unique_ptr<BoundaryModel<2>> makeBoundaryAkinci2012<2>(const ParamValues&);
template std::unique_ptr<BoundaryModel<3>> makeBoundaryAkinci2012<3>(const ParamValues&);

}  // namespace fc
