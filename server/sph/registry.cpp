#include "sph/builtin.h"
#include <mutex>

namespace fc {

namespace {
template <int D>
void registerDim() {
  auto& solvers = PressureSolverRegistry<D>::instance();
  solvers.add("dfsph", {"Divergence-free SPH (Bender & Koschier 2015/2017)", dfsphParams(), makeDFSPH<D>});
  solvers.add("wcsph", {"Weakly compressible SPH (Becker & Teschner 2007)", wcsphParams(), makeWCSPH<D>});
  auto& effects = EffectRegistry<D>::instance();
  effects.add("viscosity_standard",
              {"Standard SPH viscosity (Monaghan-type Laplacian)", viscosityStandardParams(), makeViscosityStandard<D>});
  effects.add("viscosity_weiler2018", {"Implicit viscosity (Weiler, Koschier, Brand & Bender 2018)",
                                       viscosityWeiler2018Params(), makeViscosityWeiler2018<D>});
  effects.add("viscosity_xsph", {"XSPH velocity smoothing", viscosityXSPHParams(), makeViscosityXSPH<D>});
  effects.add("surface_tension_akinci2013", {"Surface tension and adhesion (Akinci, Akinci & Teschner 2013)",
                                             surfaceTensionAkinci2013Params(), makeSurfaceTensionAkinci2013<D>});
  auto& boundaries = BoundaryModelRegistry<D>::instance();
  boundaries.add("akinci2012", {"Boundary particles, the particle's own pressure term (Akinci et al. 2012)",
                                boundaryAkinci2012Params(), makeBoundaryAkinci2012<D>});
  boundaries.add("adami2012", {"Boundary particles whose pressure is the liquid's, extrapolated into the wall "
                               "(Adami, Hu & Adams 2012)",
                               boundaryAdami2012Params(), makeBoundaryAdami2012<D>});
  boundaries.add("bender2019", {"Volume maps of the static solids: one virtual sample per particle "
                                "(Bender, Kugelstadt, Weiler & Koschier 2019)",
                                boundaryBender2019Params(), makeBoundaryBender2019<D>});
  boundaries.add("koschier2017", {"Density maps of the static solids: their density contribution and its gradient "
                                  "from a grid (Koschier & Bender 2017)",
                                  boundaryKoschier2017Params(), makeBoundaryKoschier2017<D>});
}
}  // namespace

void registerBuiltinSolversAndEffects() {
  static std::once_flag once;
  std::call_once(once, [] {
    registerDim<2>();
    registerDim<3>();
  });
}

}  // namespace fc
