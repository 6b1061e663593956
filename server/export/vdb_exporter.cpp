// `vdb`: the surface's OpenVDB grids per frame, as Houdini's and Blender's
// VDB readers expect a liquid: a level set named `surface` and a velocity
// grid `v`, in one file per frame.
#include "export/builtin.h"

#include "surface/volumes.h"

#include <openvdb/io/Stream.h>

#include <fstream>

namespace fc {

namespace {

struct VdbParams {
  bool half = false;
};

const ParamTable<VdbParams>& vdbTable() {
  static const ParamTable<VdbParams> table{
      {.name = "half", .unit = "", .min = 0, .max = 1, .def = 0,
       .help = "store the grids as 16-bit floats (half the size; Houdini and Blender read them)",
       .member = &VdbParams::half},
  };
  return table;
}

class VdbExporter : public Exporter {
 public:
  explicit VdbExporter(const VdbParams& p) : p_(p) {}
  bool needsGrids() const override { return true; }
  void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles& files) override {
    openvdb::GridPtrVec grids;
    if (surface && surface->volumes) {
      grids.push_back(surface->volumes->surface->deepCopyGrid());
      grids.push_back(surface->volumes->velocity->deepCopyGrid());
    } else {
      // A frame without liquid: empty grids, so that a sequence has every frame.
      const double voxel = 0.5 * info_.particleRadius;
      const SurfaceVolumes empty = emptySurfaceVolumes(voxel, float(1.5 * voxel));
      grids.push_back(empty.surface);
      grids.push_back(empty.velocity);
    }
    for (auto& g : grids) {
      g->setSaveFloatAsHalf(p_.half);
      g->insertMeta("frame", openvdb::Int32Metadata(frame.index));
      g->insertMeta("time", openvdb::DoubleMetadata(frame.time));
    }
    const std::string path = files.add(frameFileName(info_.name, frame.index, "vdb"));
    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata(info_.createdBy));
    meta.insertMeta("particle_radius", openvdb::DoubleMetadata(info_.particleRadius));
    // Our own stream, checked after the write (io::File does not check its own).
    std::ofstream out(path, std::ios::binary);
    try {
      openvdb::io::Stream(out).write(grids, meta);
    } catch (const openvdb::Exception& e) {
      throw std::runtime_error("vdb export: cannot write '" + path + "': " + e.what());
    }
    out.flush();
    if (!out) throw std::runtime_error("vdb export: cannot write '" + path + "' (disk full?)");
  }

 private:
  VdbParams p_;
};

}  // namespace

ParamSpecs vdbExporterParams() { return vdbTable().specs(); }
std::unique_ptr<Exporter> makeVdbExporter(const ParamValues& v) {
  return std::make_unique<VdbExporter>(vdbTable().bind(v));
}

}  // namespace fc
