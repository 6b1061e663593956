// Density maps: Koschier & Bender, "Density Maps for Improved SPH Boundary
// Handling", SCA 2017 [KB17]. The static solids (the domain's walls and the
// obstacles) add their density contribution B(x) and its gradient ∇B to a
// particle's sums, read from a grid integrated once
// (sph/boundary/volume_map.h, Options::density); the walls' samples stay for
// viscosity, adhesion, contact and display, and moving bodies keep their
// samples in every term. With `extrapolate`, the solids carry the
// particle's pressure extrapolated into them as adami2012's samples do
// (Adami, Hu & Adams 2012 [AHA12]): weight 2 and the hydrostatic part.
#include "sph/boundary/map_model.h"
#include "sph/builtin.h"

namespace fc {

namespace {
const ParamTable<MapModelParams>& koschier2017Table() {
  static const ParamTable<MapModelParams> table = mapModelTable("density map");
  return table;
}

template <int D>
class Koschier2017 final : public MapBoundaryModel<D> {
 public:
  explicit Koschier2017(const MapModelParams& p) : MapBoundaryModel<D>(p, true) {}

  bool staticTerms(const Vec<D>& x, const Vec<D>& gravity, StaticBoundaryTerms<D>& t) const override {
    return this->map_->densityTerms(x, gravity, t);
  }
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
