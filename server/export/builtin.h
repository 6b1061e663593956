#pragma once
// The built-in exporters' factories and parameters, registered by name in
// export/exporters.cpp.
#include "export/exporter.h"
#include <memory>

namespace fc {

ParamSpecs vdbExporterParams();
std::unique_ptr<Exporter> makeVdbExporter(const ParamValues&);
ParamSpecs plyMeshExporterParams();
std::unique_ptr<Exporter> makePlyMeshExporter(const ParamValues&);
ParamSpecs plyPointsExporterParams();
std::unique_ptr<Exporter> makePlyPointsExporter(const ParamValues&);
ParamSpecs objExporterParams();
std::unique_ptr<Exporter> makeObjExporter(const ParamValues&);
ParamSpecs svgExporterParams();
std::unique_ptr<Exporter> makeSvgExporter(const ParamValues&);
ParamSpecs usdExporterParams();
std::unique_ptr<Exporter> makeUsdExporter(const ParamValues&);

}  // namespace fc
