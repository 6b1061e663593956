#include "bench/exported_frames.h"

#include "io/frames_file.h"

namespace fc {

ExportedFrames readExportedFrames(const std::string& path) {
  try {
    const FramesFile file(path);
    ExportedFrames e;
    e.dimension = file.dimension();
    e.particleRadius = file.particleRadius();
    e.phaseRestDensity = file.phaseRestDensity();
    e.time = file.times();
    e.offset = file.offsets();
    const uint64_t rows = file.rows();
    if (!file.has("/particles/density")) file.fail("has no dataset /particles/density");
    e.position = file.read<float>("/particles/position", H5T_NATIVE_FLOAT, e.dimension, 0, rows);
    e.density = file.read<float>("/particles/density", H5T_NATIVE_FLOAT, 0, 0, rows);
    if (file.has("/particles/velocity"))
      e.velocity = file.read<float>("/particles/velocity", H5T_NATIVE_FLOAT, e.dimension, 0, rows);
    if (file.has("/particles/pressure"))
      e.pressure = file.read<float>("/particles/pressure", H5T_NATIVE_FLOAT, 0, 0, rows);
    e.phase = file.read<uint8_t>("/particles/phase", H5T_NATIVE_UINT8, 0, 0, rows);
    e.kind = file.read<uint8_t>("/particles/kind", H5T_NATIVE_UINT8, 0, 0, rows);
    for (uint8_t p : e.phase)
      if (p >= e.phaseRestDensity.size()) file.fail("a particle's phase has no rest density");
    return e;
  } catch (const FramesFileError& err) {
    throw ExportReadError(err.what());
  }
}

}  // namespace fc
