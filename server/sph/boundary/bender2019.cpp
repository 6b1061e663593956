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
#include "sph/boundary/map_model.h"
#include "sph/builtin.h"

namespace fc {

namespace {
const ParamTable<MapModelParams>& bender2019Table() {
  static const ParamTable<MapModelParams> table = mapModelTable("volume map");
  return table;
}

template <int D>
class Bender2019 final : public MapBoundaryModel<D> {
 public:
  explicit Bender2019(const MapModelParams& p) : MapBoundaryModel<D>(p, false) {}

  bool staticTerms(const Vec<D>& x, const Vec<D>& gravity, StaticBoundaryTerms<D>& t) const override {
    Vec<D> xb;
    const Real v = this->map_->virtualSample(x, xb);
    if (!(v > 0)) return false;
    Real w;
    Vec<D> g;
    this->kernel_.evaluate(x - xb, w, g);
    const Real k = this->map_->gradientScale();
    t.volume = v * w;
    t.grad = (k * v) * g;
    t.extrapolation = (k * v * gravity.dot(xb - x)) * g;
    t.samples = unsigned(std::lround(v / this->latticeVolume_));
    return true;
  }
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
