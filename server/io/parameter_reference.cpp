#include "io/parameter_reference.h"

#include "control/instance.h"
#include "export/exporter.h"
#include "sph/limits.h"
#include "sph/pipeline.h"
#include "sph/settings.h"

namespace fc {

using json = nlohmann::json;

namespace {

json specsJson(const ParamSpecs& specs) {
  json list = json::array();
  for (const ParamSpec& s : specs) {
    const char* type = s.type == ParamType::Boolean ? "boolean" : s.type == ParamType::Integer ? "integer" : "number";
    json j = {{"name", s.name}, {"unit", s.unit}, {"min", s.min}, {"max", s.max}, {"type", type}, {"help", s.help}};
    if (s.type == ParamType::Boolean) j["default"] = s.def != 0;
    else j["default"] = s.def;
    list.push_back(j);
  }
  return list;
}

template <class R>
json registryJson(const R& registry) {
  json out = json::object();
  for (const std::string& name : registry.names()) {
    const auto* e = registry.find(name);
    out[name] = {{"help", e->help}, {"params", specsJson(e->params)}};
  }
  return out;
}

json limitsJson() {
  json list = json::array();
  for (const PhysicalRange& r : physicalRanges())
    list.push_back({{"name", r.name}, {"unit", r.unit}, {"min", r.min}, {"max", r.max}, {"help", r.help}});
  return list;
}

}  // namespace

template <int D>
json parameterReference() {
  registerBuiltinSolversAndEffects();
  registerBuiltinExporters();
  return {{"dimension", D},
          {"instance", specsJson(instanceParamSpecs(D))},
          {"control", specsJson(controlSettingsSpecs())},
          {"settings", specsJson(simulationSettingsSpecs())},
          {"solvers", registryJson(PressureSolverRegistry<D>::instance())},
          {"effects", registryJson(EffectRegistry<D>::instance())},
          {"boundaries", registryJson(BoundaryModelRegistry<D>::instance())},
          {"surface", specsJson(surfaceSettingsSpecs())},
          {"exporters", registryJson(ExporterRegistry::instance())},
          {"limits", limitsJson()}};
}

template json parameterReference<2>();
template json parameterReference<3>();

}  // namespace fc
