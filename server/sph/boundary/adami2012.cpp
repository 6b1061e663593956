// Boundary particles that carry a pressure: Adami, Hu & Adams, "A
// generalized wall boundary condition for smoothed particle hydrodynamics",
// J. Comput. Phys. 2012 [AHA12]. A wall sample b takes the pressure of the
// liquid beside it, extrapolated into the wall by the local force balance
// between wall and liquid ([AHA12], its wall pressure),
//   p_b = p_f + ρ_f (g - a_b)·(x_b - x_f),
// and acts in the symmetric pair term of the pressure force,
//   F_i = -m_i Ψ_b (p_i/ρ_i² + p_b/ρ0_i²) ∇W_ib,  Ψ_b = ρ0_i V_b.
// [AHA12] averages p_f over the sample's liquid neighbours (Shepard); here
// each pair extrapolates from its own particle i, p_b = p_i + Δp_ib, so
// that the term splits into 2 p_i/ρ_i² Σ_b Ψ_b ∇W_ib, which the pressure
// solvers take with the weight 2 in the sums they already have, and the
// hydrostatic part Σ_b V_b (g - a_b)·(x_b - x_i) ∇W_ib, which is
// independent of the pressure and acts with gravity
// (Simulation::boundaryExtrapolation). `hydrostatic` off leaves the
// mirror alone, p_b = p_i: twice Akinci's push, without the gradient that
// carries the weight of the liquid above a wall row.
// `constraint`: the doubled push alone moves a compressed particle along a
// direction its density does not change along, which can add energy every
// time the solver acts. With it on, the mirror's second half is a term of
// the density the solver corrects, E_i = c Σ_b V_b W_ib s((r - d_ib)/r)
// over the static samples (d_ib the particle's distance from sample b's own
// stretch of surface, s a ramp over `ramp` r; Simulation::boundaryExcess),
// and its push is E_i's gradient: one function of the positions, so the
// pressure solve stays a projection. c: at the rest distance from a flat
// wall that push equals the samples' own, as the mirror's does. Moving
// bodies keep their samples' own term.
// Band et al. [BGI*18] compare such approximations in IISPH and solve for
// the boundary pressure within the pressure system instead.
#include "sph/builtin.h"

namespace fc {

namespace {
struct Adami2012Params {
  bool hydrostatic{};
  bool constraint{};
  double ramp{};
};

const ParamTable<Adami2012Params>& adami2012Table() {
  using P = Adami2012Params;
  static const ParamTable<P> table = {
      {.name = "hydrostatic", .min = 0, .max = 1, .def = 1,
       .help = "extrapolate the wall pressure with depth, p_b = p_i + rho0 (g - a_b)·(x_b - x_i); off: p_b = p_i",
       .member = &P::hydrostatic},
      {.name = "constraint", .min = 0, .max = 1, .def = 0,
       .help = "the mirror enters the density the solver corrects, as a term that grows nearer a wall than the rest "
               "distance, instead of doubling the push alone: keeps the liquid's energy and its distance from the "
               "walls; the row at a wall then reads a higher pressure",
       .member = &P::constraint},
      {.name = "ramp", .unit = "r", .min = 0.001, .max = 1, .def = 0.1,
       .help = "with constraint: the depth over which the mirror's push sets in (shorter: nearer the rest "
               "distance, but a resting pool rings)",
       .member = &P::ramp},
  };
  return table;
}

template <int D>
class Adami2012 final : public BoundaryModel<D> {
 public:
  explicit Adami2012(const Adami2012Params& p)
      : hydrostatic_(p.hydrostatic), constraint_(p.constraint), ramp_(Real(p.ramp)) {}
  Real pressureWeight() const override { return Real(2); }
  bool extrapolatesPressure() const override { return hydrostatic_; }
  bool mirrorsInConstraint() const override { return constraint_; }
  Real mirrorRamp() const override { return ramp_; }

 private:
  bool hydrostatic_, constraint_;
  Real ramp_;
};
}  // namespace

const ParamSpecs& boundaryAdami2012Params() { return adami2012Table().specs(); }

template <int D>
std::unique_ptr<BoundaryModel<D>> makeBoundaryAdami2012(const ParamValues& p) {
  return std::make_unique<Adami2012<D>>(adami2012Table().bind(p));
}
template std::unique_ptr<BoundaryModel<2>> makeBoundaryAdami2012<2>(const ParamValues&);
template std::unique_ptr<BoundaryModel<3>> makeBoundaryAdami2012<3>(const ParamValues&);

}  // namespace fc
