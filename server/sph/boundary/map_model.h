#pragma once
// What the two maps of the static solids share (sph/boundary/bender2019.cpp,
// koschier2017.cpp): their parameters and building the grid once with the
// simulation (sph/boundary/volume_map.h); each adds its own terms.
#include "sph/boundary/volume_map.h"
#include "sph/simulation.h"

#include <memory>
#include <string>

namespace fc {

struct MapModelParams {
  double mapSpacing{};
  int quadrature{};
  bool extrapolate{};
};

// `what` names the map in the help texts ("volume map", "density map").
inline ParamTable<MapModelParams> mapModelTable(const std::string& what) {
  using P = MapModelParams;
  return {
      {.name = "map_spacing", .unit = "r", .min = 0.25, .max = 8, .def = 1,
       .help = "grid spacing of the " + what +
               ", in particle radii (finer: smoother walls, longer set-up, more memory)",
       .member = &P::mapSpacing},
      {.name = "quadrature", .min = 2, .max = 32, .def = 8,
       .help = "quadrature points per support radius along each axis when the map is built",
       .member = &P::quadrature},
      {.name = "extrapolate", .min = 0, .max = 1, .def = 1,
       .help = "the " + what +
               "'s term carries the particle's pressure extrapolated into the solid (as adami2012); off: the "
               "particle's own pressure term alone, as the paper",
       .member = &P::extrapolate},
  };
}

template <int D>
class MapBoundaryModel : public BoundaryModel<D> {
 public:
  MapBoundaryModel(const MapModelParams& p, bool density) : params_(p), density_(density) {}
  Real pressureWeight() const override { return params_.extrapolate ? Real(2) : Real(1); }
  bool extrapolatesPressure() const override { return params_.extrapolate; }
  bool mapsStaticSolids() const override { return true; }

  void setUp(const Simulation<D>& sim, Real latticeVolume) override {
    typename VolumeMap<D>::Options o;
    o.spacing = Real(params_.mapSpacing) * sim.particleRadius();
    o.quadrature = params_.quadrature;
    o.density = density_;
    map_ = std::make_unique<VolumeMap<D>>(sim.setup().domain, sim.setup().obstacles, sim.kernel,
                                          sim.particleRadius(), latticeVolume, o);
    kernel_ = sim.kernel;
    latticeVolume_ = latticeVolume;
  }
  size_t memoryBytes() const override { return map_ ? map_->bytes() : 0; }

 protected:
  MapModelParams params_;
  bool density_;
  std::unique_ptr<VolumeMap<D>> map_;
  CubicSpline<D> kernel_;
  Real latticeVolume_ = 1;
};

}  // namespace fc
