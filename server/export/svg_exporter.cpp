// `svg`: a 2D liquid's outline per frame as an SVG path, for motion design
// and compositing tools that take vector shapes: the zero level of the
// level set in the plane z = 0 (marching squares), closed loops, holes
// wound the other way. Coordinates are the scene's metres (y flipped, as
// SVG's y points down), so that every frame of a sequence lines up.
#include "export/builtin.h"
#include "export/surface_export.h"
#include "surface/volumes.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <unordered_map>

namespace fc {

namespace {

using Loop = std::vector<std::array<double, 2>>;

// Marching squares over the grid's slice k = 0: each cell's segments keep
// the liquid on their left (the two inside corners of a saddle apart), and
// chain through the edges they share into closed loops, counter-clockwise
// around the liquid, clockwise around a hole.
std::vector<Loop> outline(const openvdb::FloatGrid& grid) {
  auto acc = grid.getConstAccessor();
  const auto at = [&](int i, int j) { return acc.getValue(openvdb::Coord(i, j, 0)); };
  // Edge ids: (i, j) and the axis (0: along x, 1: along y) packed in 64 bits.
  constexpr int64_t off = int64_t(1) << 30;
  const auto edge = [](int i, int j, int axis) {
    return int64_t((uint64_t(int64_t(i) + off) << 33) | (uint64_t(int64_t(j) + off) << 1) | uint64_t(axis));
  };
  std::unordered_map<int64_t, int64_t> next;
  const auto cell = [&](int i, int j) {
    // Corners counter-clockwise, and the edge from each to the next.
    const int ci[4] = {i, i + 1, i + 1, i}, cj[4] = {j, j, j + 1, j + 1};
    const int64_t e[4] = {edge(i, j, 0), edge(i + 1, j, 1), edge(i, j + 1, 0), edge(i, j, 1)};
    bool in[4];
    for (int c = 0; c < 4; ++c) in[c] = at(ci[c], cj[c]) < 0;
    for (int k = 0; k < 4; ++k) {
      if (!(in[k] && !in[(k + 1) % 4])) continue;  // the liquid ends across edge k
      for (int back = 1; back < 4; ++back) {       // and begins across the edge before it
        const int m = (k + 4 - back) % 4;
        if (!in[m] && in[(m + 1) % 4]) {
          next[e[k]] = e[m];
          break;
        }
      }
    }
  };
  // Only the cells at the narrow band's voxels of the slice: the outline is there, and a
  // sparse liquid (a long sheet, far droplets) costs its band, not its bounding box.
  for (auto leaf = grid.tree().cbeginLeaf(); leaf; ++leaf) {
    const openvdb::Coord o = leaf->origin();
    if (o.z() > 0 || o.z() + int(leaf->dim()) <= 0) continue;
    for (auto v = leaf->cbeginValueOn(); v; ++v) {
      const openvdb::Coord c = v.getCoord();
      if (c.z() != 0) continue;
      for (int di = -1; di <= 0; ++di)
        for (int dj = -1; dj <= 0; ++dj) cell(c.x() + di, c.y() + dj);
    }
  }
  const double voxel = grid.voxelSize()[0];
  const auto point = [&](int64_t id) {
    const int axis = int(id & 1);
    const int i = int(int64_t(uint64_t(id) >> 33) - off), j = int(int64_t((uint64_t(id) >> 1) & ((uint64_t(1) << 32) - 1)) - off);
    const float a = at(i, j), b = axis ? at(i, j + 1) : at(i + 1, j);
    const double t = std::clamp(double(a) / (double(a) - double(b)), 0.0, 1.0);
    return std::array<double, 2>{(i + (axis ? 0.0 : t)) * voxel, (j + (axis ? t : 0.0)) * voxel};
  };
  std::vector<Loop> loops;
  std::unordered_map<int64_t, bool> used;
  std::vector<int64_t> starts;
  for (const auto& entry : next) starts.push_back(entry.first);
  std::sort(starts.begin(), starts.end());  // the same file whatever the hash order
  for (const int64_t start : starts) {
    if (used[start]) continue;
    Loop loop;
    for (int64_t id = start; !used[id];) {
      used[id] = true;
      loop.push_back(point(id));
      auto it = next.find(id);
      if (it == next.end()) break;  // an outline that leaves the band: not closed here
      id = it->second;
    }
    if (loop.size() >= 3) loops.push_back(std::move(loop));
  }
  return loops;
}

class SvgExporter : public Exporter {
 public:
  bool needsGrids() const override { return true; }
  void begin(const ExportInfo& info) override {
    if (info.dimension != 2)
      throw ExportSetupError("svg export: the outline of a 2D liquid; '" + info.name + "' is a 3D scene");
    Exporter::begin(info);
  }
  void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles& files) override {
    const std::vector<Loop> loops = surface && surface->volumes ? outline(*surface->volumes->surface) : std::vector<Loop>{};
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (const Loop& l : loops)
      for (const auto& p : l)
        for (int d = 0; d < 2; ++d) lo[d] = std::min(lo[d], p[d]), hi[d] = std::max(hi[d], p[d]);
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
    for (const Loop& l : loops) {
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
