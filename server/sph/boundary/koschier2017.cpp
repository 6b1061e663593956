// Density maps: Koschier & Bender, "Density Maps for Improved SPH Boundary
// Handling", SCA 2017 [KB17]. The static solids (the domain's walls and the
// obstacles) add their density contribution B(x) and its gradient ∇B to a
// particle's sums, read from a grid integrated once
// (sph/boundary/volume_map.h, Options::density); the walls' samples stay for
// viscosity, adhesion, contact and display, and moving bodies keep their
// samples in every term. With `extrapolate`, the solids carry the
// particle's pressure extrapolated into them as adami2012's samples do
// (Adami, Hu & Adams 2012 [AHA12]): weight 2 and the hydrostatic part.
#include "sph/boundary/volume_map.h"
#include "sph/builtin.h"
#include "sph/simulation.h"

namespace fc {

namespace {
struct Koschier2017Params {
  double mapSpacing{};
  int quadrature{};
  bool extrapolate{};
};

const ParamTable<Koschier2017Params>& koschier2017Table() {
  using P = Koschier2017Params;
  static const ParamTable<P> table = {
      {.name = "map_spacing", .unit = "r", .min = 0.25, .max = 8, .def = 1,
       .help = "grid spacing of the density map, in particle radii (finer: smoother walls, longer set-up, more memory)",
       .member = &P::mapSpacing},
      {.name = "quadrature", .min = 2, .max = 32, .def = 8,
       .help = "quadrature points per support radius along each axis when the map is built",
       .member = &P::quadrature},
      {.name = "extrapolate", .min = 0, .max = 1, .def = 1,
       .help = "the solids carry the particle's pressure extrapolated into them (as adami2012); off: the "
               "particle's own pressure term alone, as the paper",
       .member = &P::extrapolate},
  };
  return table;
}

template <int D>
class Koschier2017 final : public BoundaryModel<D> {
 public:
  explicit Koschier2017(const Koschier2017Params& p) : params_(p) {}
  Real pressureWeight() const override { return params_.extrapolate ? Real(2) : Real(1); }
  bool extrapolatesPressure() const override { return params_.extrapolate; }
  bool mapsStaticSolids() const override { return true; }

  void setUp(const Simulation<D>& sim, Real latticeVolume) override {
    typename VolumeMap<D>::Options o;
    o.spacing = Real(params_.mapSpacing) * sim.particleRadius();
    o.quadrature = params_.quadrature;
    o.density = true;
    map_ = std::make_unique<VolumeMap<D>>(sim.setup().domain, sim.setup().obstacles, sim.kernel,
                                          sim.particleRadius(), latticeVolume, o);
  }

  bool staticTerms(const Vec<D>& x, const Vec<D>& gravity, StaticBoundaryTerms<D>& t) const override {
    return map_->densityTerms(x, gravity, t);
  }
  size_t memoryBytes() const override { return map_ ? map_->bytes() : 0; }

 private:
  Koschier2017Params params_;
  std::unique_ptr<VolumeMap<D>> map_;
};
}  // namespace

const ParamSpecs& boundaryKoschier2017Params() { return koschier2017Table().specs(); }

template <int D>
std::unique_ptr<BoundaryModel<D>> makeBoundaryKoschier2017(const ParamValues& p) {
  return std::make_unique<Koschier2017<D>>(koschier2017Table().bind(p));
}
template std::unique_ptr<BoundaryModel<2>> makeBoundaryKoschier2017<2>(const ParamValues&);
template std::unique_ptr<BoundaryModel<3>> makeBoundaryKoschier2017<3>(const ParamValues&);

}  // namespace fc
