#include "export/builtin.h"

#include <mutex>

namespace fc {

void registerBuiltinExporters() {
  static std::once_flag once;
  std::call_once(once, [] {
    auto& r = ExporterRegistry::instance();
    r.add("vdb", {"OpenVDB volumes per frame (NAME.0001.vdb): the level set `surface` and the velocity `v`",
                  vdbExporterParams(), makeVdbExporter});
    r.add("ply", {"surface meshes per frame (NAME.0001.ply, binary), with per-vertex velocity", plyMeshExporterParams(),
                  makePlyMeshExporter});
    r.add("points", {"point caches per frame (NAME_points.0001.ply, binary): position, velocity, id, phase, kind, "
                     "density",
                     plyPointsExporterParams(), makePlyPointsExporter});
    r.add("obj", {"surface meshes per frame (NAME.0001.obj)", objExporterParams(), makeObjExporter});
    r.add("svg", {"a 2D liquid's outline per frame (NAME.0001.svg): closed paths at z = 0, in metres",
                  svgExporterParams(), makeSvgExporter});
    r.add("usd", {"one time-sampled USD stage (NAME.usda): the points with velocities, ids and widths, and the "
                  "surface mesh with `meshes`",
                  usdExporterParams(), makeUsdExporter});
  });
}

}  // namespace fc
