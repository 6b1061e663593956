// `svg`: a 2D liquid's outline per frame as an SVG path, for motion design
// and compositing tools that take vector shapes: the surface's outline in
// the plane z = 0 (surface/planar_surface.h), closed loops, holes wound the
// other way. Coordinates are the scene's metres (y flipped, as
// SVG's y points down), so that every frame of a sequence lines up.
#include "export/builtin.h"
#include "export/surface_export.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>

namespace fc {

namespace {

class SvgExporter : public Exporter {
 public:
  bool needsOutline() const override { return true; }
  void begin(const ExportInfo& info) override {
    if (info.dimension != 2)
      throw ExportSetupError("svg export: the outline of a 2D liquid; '" + info.name + "' is a 3D scene");
    Exporter::begin(info);
  }
  void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles& files) override {
    static const std::vector<std::vector<std::array<float, 2>>> none;
    const auto& loops = surface ? surface->outline : none;
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (const auto& l : loops)
      for (const auto& p : l)
        for (int d = 0; d < 2; ++d) lo[d] = std::min(lo[d], double(p[d])), hi[d] = std::max(hi[d], double(p[d]));
    if (loops.empty()) lo[0] = lo[1] = hi[0] = hi[1] = 0;
    const double margin = 4 * info_.particleRadius;
    const double x0 = lo[0] - margin, y1 = hi[1] + margin, width = hi[0] - lo[0] + 2 * margin,
                 height = hi[1] - lo[1] + 2 * margin;
    const std::string path = files.add(frameFileName(info_.name, frame.index, "svg"));
    std::ofstream out(path, std::ios::binary);
    if (!out) throw std::runtime_error("svg export: cannot create '" + path + "'");
    char buf[256];
    out << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
    std::snprintf(buf, sizeof buf,
                  "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.6gmm\" height=\"%.6gmm\" "
                  "viewBox=\"%.9g %.9g %.9g %.9g\">\n",
                  width * 1000, height * 1000, x0, -y1, width, height);
    out << buf << "<!-- " << info_.createdBy << ", frame " << frame.index << ", time " << frame.time
        << " s: the liquid's outline at z = 0 in metres, y up (drawn flipped) -->\n"
        << "<path id=\"liquid\" fill=\"#4a90d9\" fill-rule=\"nonzero\" d=\"";
    for (const auto& l : loops) {
      for (size_t k = 0; k < l.size(); ++k) {
        std::snprintf(buf, sizeof buf, "%s%.7g %.7g ", k ? "L" : "M", l[k][0], -l[k][1]);
        out << buf;
      }
      out << "Z ";
    }
    out << "\"/>\n</svg>\n";
    out.flush();
    if (!out) throw std::runtime_error("svg export: cannot write '" + path + "'");
  }
};

}  // namespace

ParamSpecs svgExporterParams() { return {}; }
std::unique_ptr<Exporter> makeSvgExporter(const ParamValues&) { return std::make_unique<SvgExporter>(); }

}  // namespace fc
