// Volume maps: Bender, Kugelstadt, Weiler & Koschier, "Volume Maps: An
// Implicit Boundary Representation for SPH", MIG 2019 [BKWK19], the default
// of SPlisHSPlasH. The static solids (the domain's walls and the
// obstacles) act on a particle as one virtual sample whose volume is the
// solid in its support (sph/boundary/volume_map.h), in the same density
// and pressure terms as a sample of Akinci et al. 2012 [AIA*12], eq. (6)
// and (10); the walls' samples stay for viscosity, adhesion, contact and
// display, and moving bodies keep their samples in every term. With
// `extrapolate`, the virtual sample (and the bodies' samples) carry the
// particle's pressure extrapolated into the solid as adami2012's do
// (Adami, Hu & Adams 2012 [AHA12]): weight 2 and the hydrostatic part.
#include "sph/boundary/volume_map.h"
#include "sph/builtin.h"
#include "sph/simulation.h"

namespace fc {

namespace {
struct Bender2019Params {
  double mapSpacing{};
  int quadrature{};
  bool extrapolate{};
};

const ParamTable<Bender2019Params>& bender2019Table() {
  using P = Bender2019Params;
  static const ParamTable<P> table = {
      {.name = "map_spacing", .unit = "r", .min = 0.25, .max = 8, .def = 1,
       .help = "grid spacing of the volume map, in particle radii (finer: smoother walls, longer set-up, more memory)",
       .member = &P::mapSpacing},
      {.name = "quadrature", .min = 2, .max = 32, .def = 8,
       .help = "quadrature points per support radius along each axis when the map is built",
       .member = &P::quadrature},
      {.name = "extrapolate", .min = 0, .max = 1, .def = 1,
       .help = "the virtual sample carries the particle's pressure extrapolated into the solid (as adami2012); off: "
               "the particle's own pressure term alone, as the paper and SPlisHSPlasH",
       .member = &P::extrapolate},
  };
  return table;
}

template <int D>
class Bender2019 final : public BoundaryModel<D> {
 public:
  explicit Bender2019(const Bender2019Params& p) : params_(p) {}
  Real pressureWeight() const override { return params_.extrapolate ? Real(2) : Real(1); }
  bool extrapolatesPressure() const override { return params_.extrapolate; }
  bool mapsStaticSolids() const override { return true; }

  void setUp(const Simulation<D>& sim, Real latticeVolume) override {
    typename VolumeMap<D>::Options o;
    o.spacing = Real(params_.mapSpacing) * sim.particleRadius();
    o.quadrature = params_.quadrature;
    map_ = std::make_unique<VolumeMap<D>>(sim.setup().domain, sim.setup().obstacles, sim.kernel,
                                          sim.particleRadius(), latticeVolume, o);
    kernel_ = sim.kernel;
    latticeVolume_ = latticeVolume;
  }

  bool staticTerms(const Vec<D>& x, const Vec<D>& gravity, StaticBoundaryTerms<D>& t) const override {
    Vec<D> xb;
    const Real v = map_->virtualSample(x, xb);
    if (!(v > 0)) return false;
    Real w;
    Vec<D> g;
    kernel_.evaluate(x - xb, w, g);
    const Real k = map_->gradientScale();
    t.volume = v * w;
    t.grad = (k * v) * g;
    t.extrapolation = (k * v * gravity.dot(xb - x)) * g;
    t.samples = unsigned(std::lround(v / latticeVolume_));
    return true;
  }
  size_t memoryBytes() const override { return map_ ? map_->bytes() : 0; }

 private:
  Bender2019Params params_;
  std::unique_ptr<VolumeMap<D>> map_;
  CubicSpline<D> kernel_;
  Real latticeVolume_ = 1;
};
}  // namespace

const ParamSpecs& boundaryBender2019Params() { return bender2019Table().specs(); }

template <int D>
std::unique_ptr<BoundaryModel<D>> makeBoundaryBender2019(const ParamValues& p) {
  return std::make_unique<Bender2019<D>>(bender2019Table().bind(p));
}
template std::unique_ptr<BoundaryModel<2>> makeBoundaryBender2019<2>(const ParamValues&);
template std::unique_ptr<BoundaryModel<3>> makeBoundaryBender2019<3>(const ParamValues&);

}  // namespace fc
