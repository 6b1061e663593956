// `obj`: the surface mesh per frame as Wavefront OBJ text (positions and
// triangles; OBJ has no per-vertex velocity: use `ply` or `usd` for motion blur).
#include "export/builtin.h"

#include <charconv>
#include <cstdio>
#include <fstream>

namespace fc {

namespace {

class ObjExporter : public Exporter {
 public:
  bool needsMesh() const override { return true; }
  void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles& files) override {
    const SurfaceMesh& m = surface->mesh;
    const std::string path = files.add(frameFileName(info_.name, frame.index, "obj"));
    std::ofstream out(path, std::ios::binary);
    if (!out) throw std::runtime_error("obj export: cannot create '" + path + "'");
    out << "# " << info_.createdBy << ", frame " << frame.index << ", time " << frame.time << " s\n"
        << "o " << info_.name << "\n";
    std::string buf;
    buf.reserve(1 << 20);
    char num[32];
    const auto put = [&](auto value) {
      auto [end, ec] = std::to_chars(num, num + sizeof num, value);
      buf.append(num, end);
    };
    for (const auto& p : m.points) {
      buf += "v ";
      put(p[0]), buf += ' ', put(p[1]), buf += ' ', put(p[2]), buf += '\n';
      if (buf.size() > (1 << 20) - 128) out.write(buf.data(), std::streamsize(buf.size())), buf.clear();
    }
    for (const auto& t : m.triangles) {
      buf += "f ";
      put(t[0] + 1), buf += ' ', put(t[1] + 1), buf += ' ', put(t[2] + 1), buf += '\n';
      if (buf.size() > (1 << 20) - 128) out.write(buf.data(), std::streamsize(buf.size())), buf.clear();
    }
    out.write(buf.data(), std::streamsize(buf.size()));
    out.flush();
    if (!out) throw std::runtime_error("obj export: cannot write '" + path + "'");
  }
};

}  // namespace

ParamSpecs objExporterParams() { return {}; }
std::unique_ptr<Exporter> makeObjExporter(const ParamValues&) { return std::make_unique<ObjExporter>(); }

}  // namespace fc
