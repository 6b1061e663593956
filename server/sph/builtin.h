#pragma once
// Factories of the built-in solvers and effects; sph/registry.cpp puts them
// in the registries. Each is defined in the file named after its method, in
// the folder of its family: sph/pressure/dfsph.cpp, sph/viscosity/xsph.cpp,
// sph/surface_tension/akinci2013.cpp, sph/boundary/adami2012.cpp.
#include "sph/pipeline.h"

namespace fc {

const ParamSpecs& dfsphParams();
template <int D> std::unique_ptr<PressureSolver<D>> makeDFSPH(const ParamValues&);

const ParamSpecs& wcsphParams();
template <int D> std::unique_ptr<PressureSolver<D>> makeWCSPH(const ParamValues&);

const ParamSpecs& viscosityStandardParams();
template <int D> std::unique_ptr<Effect<D>> makeViscosityStandard(const ParamValues&);

const ParamSpecs& viscosityWeiler2018Params();
template <int D> std::unique_ptr<Effect<D>> makeViscosityWeiler2018(const ParamValues&);

const ParamSpecs& viscosityXSPHParams();
template <int D> std::unique_ptr<Effect<D>> makeViscosityXSPH(const ParamValues&);

const ParamSpecs& surfaceTensionAkinci2013Params();
template <int D> std::unique_ptr<Effect<D>> makeSurfaceTensionAkinci2013(const ParamValues&);

const ParamSpecs& boundaryAkinci2012Params();
template <int D> std::unique_ptr<BoundaryModel<D>> makeBoundaryAkinci2012(const ParamValues&);

const ParamSpecs& boundaryAdami2012Params();
template <int D> std::unique_ptr<BoundaryModel<D>> makeBoundaryAdami2012(const ParamValues&);

const ParamSpecs& boundaryBender2019Params();
template <int D> std::unique_ptr<BoundaryModel<D>> makeBoundaryBender2019(const ParamValues&);

const ParamSpecs& boundaryKoschier2017Params();
template <int D> std::unique_ptr<BoundaryModel<D>> makeBoundaryKoschier2017(const ParamValues&);

}  // namespace fc
