// `usd`: one USD stage for the whole export (NAME.usda, USD's text form,
// read by usd-core, Houdini, Blender and usdview): a Points prim with
// time-sampled positions, velocities, ids and widths (the particle
// diameter) and a `phase` primvar, and with `meshes` a Mesh prim of the
// surface. Time codes are frame numbers at the export's frame rate; Y is up.
// Frames stream into one piece file per attribute, assembled at the end.
#include "export/builtin.h"

#include "io/staged_files.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

namespace fc {

namespace {

struct UsdParams {
  bool meshes = false;
};

const ParamTable<UsdParams>& usdTable() {
  static const ParamTable<UsdParams> table{
      {.name = "meshes", .unit = "", .min = 0, .max = 1, .def = 0,
       .help = "also write the surface mesh (prim /flowclip/surface) with per-vertex velocities",
       .member = &UsdParams::meshes},
  };
  return table;
}

// One time-sampled attribute, its samples streamed to a hidden piece file.
class Samples {
 public:
  Samples(std::string declaration, std::string metadata = "")
      : declaration_(std::move(declaration)), metadata_(std::move(metadata)) {}
  ~Samples() { remove(); }
  void open(const std::string& piecePath) {
    path_ = piecePath;
    out_.open(path_, std::ios::binary);
    if (!out_) throw std::runtime_error("usd export: cannot create '" + path_ + "'");
  }
  // "  F: [" ... "],\n": the caller appends values with the helpers below.
  void beginSample(int frame) {
    buf_ += "            " + std::to_string(frame) + ": [";
    first_ = true;
    sampled_ = true;
  }
  void endSample() {
    buf_ += "],\n";
    flush();
  }
  template <class T>
  void value(T v) {
    if (!first_) buf_ += ", ";
    first_ = false;
    number(v);
  }
  void tuple(float a, float b, float c) {
    if (!first_) buf_ += ", ";
    first_ = false;
    buf_ += '(';
    number(a), buf_ += ", ", number(b), buf_ += ", ", number(c);
    buf_ += ')';
    if (buf_.size() > (1 << 20)) flush();
  }
  // The attribute's text into `out`: declaration, metadata, samples; nothing
  // for an attribute never sampled.
  void writeTo(std::ostream& out) {
    flush();
    out_.close();
    if (!sampled_) return;
    if (!metadata_.empty()) out << "        " << declaration_ << " (\n            " << metadata_ << "\n        )\n";
    out << "        " << declaration_ << ".timeSamples = {\n";
    std::ifstream in(path_, std::ios::binary);
    out << in.rdbuf();
    out << "        }\n";
  }
  void remove() noexcept {
    if (path_.empty()) return;
    if (out_.is_open()) out_.close();
    std::error_code ec;
    std::filesystem::remove(path_, ec);
    path_.clear();
  }

 private:
  template <class T>
  void number(T v) {
    char num[32];
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(v)) v = 0;
    }
    auto [end, ec] = std::to_chars(num, num + sizeof num, v);
    buf_.append(num, end);
  }
  void flush() {
    out_.write(buf_.data(), std::streamsize(buf_.size()));
    if (!out_) throw std::runtime_error("usd export: cannot write '" + path_ + "'");
    buf_.clear();
  }
  std::string declaration_, metadata_, path_, buf_;
  std::ofstream out_;
  bool first_ = true;
  bool sampled_ = false;
};

class UsdExporter : public Exporter {
 public:
  explicit UsdExporter(const UsdParams& p) : p_(p) {}
  bool needsMesh() const override { return p_.meshes; }

  void begin(const ExportInfo& info) override {
    Exporter::begin(info);
    const std::string base = (std::filesystem::path(info.directory) / (info.name + ".usda")).string();
    int n = 0;
    for (Samples* s : all()) s->open(stagingPath(base + ".piece" + std::to_string(n++)));
  }

  void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles&) override {
    first_ = std::min(first_, frame.index);
    last_ = std::max(last_, frame.index);
    const int f = frame.index;
    // Ids only from a source that has them (a session's history has none).
    for (Samples* s : points())
      if (s != &ids_ || !frame.id.empty()) s->beginSample(f);
    float lo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                   std::numeric_limits<float>::max()};
    float hi[3] = {-lo[0], -lo[1], -lo[2]};
    size_t count = 0;
    for (size_t i = 0; i < frame.count(); ++i) {
      if (!formsSurface(frame.kind[i])) continue;
      const float* x = &frame.position[3 * i];
      const float* v = &frame.velocity[3 * i];
      positions_.tuple(x[0], x[1], x[2]);
      velocities_.tuple(v[0], v[1], v[2]);
      if (!frame.id.empty()) ids_.value(int64_t(frame.id[i]));
      phase_.value(int(frame.phase[i]));
      for (int d = 0; d < 3; ++d) lo[d] = std::min(lo[d], x[d]), hi[d] = std::max(hi[d], x[d]);
      ++count;
    }
    const float r = float(info_.particleRadius);
    if (count) extent_.tuple(lo[0] - r, lo[1] - r, lo[2] - r), extent_.tuple(hi[0] + r, hi[1] + r, hi[2] + r);
    for (Samples* s : points())
      if (s != &ids_ || !frame.id.empty()) s->endSample();
    if (!p_.meshes) return;
    const SurfaceMesh& m = surface->mesh;
    for (Samples* s : meshes()) s->beginSample(f);
    float mlo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                    std::numeric_limits<float>::max()};
    float mhi[3] = {-mlo[0], -mlo[1], -mlo[2]};
    for (size_t i = 0; i < m.points.size(); ++i) {
      meshPoints_.tuple(m.points[i][0], m.points[i][1], m.points[i][2]);
      meshVelocities_.tuple(m.velocities[i][0], m.velocities[i][1], m.velocities[i][2]);
      for (int d = 0; d < 3; ++d) mlo[d] = std::min(mlo[d], m.points[i][d]), mhi[d] = std::max(mhi[d], m.points[i][d]);
    }
    for (const auto& t : m.triangles) {
      faceCounts_.value(3);
      faceIndices_.value(int(t[0])), faceIndices_.value(int(t[1])), faceIndices_.value(int(t[2]));
    }
    if (!m.points.empty()) meshExtent_.tuple(mlo[0], mlo[1], mlo[2]), meshExtent_.tuple(mhi[0], mhi[1], mhi[2]);
    for (Samples* s : meshes()) s->endSample();
  }

  void finish(FrameFiles& files) override {
    const std::string path = files.add(info_.name + ".usda");
    std::ofstream out(path, std::ios::binary);
    if (!out) throw std::runtime_error("usd export: cannot create '" + path + "'");
    const int start = first_ <= last_ ? first_ : 0, end = first_ <= last_ ? last_ : 0;
    char rate[32];
    std::snprintf(rate, sizeof rate, "%.17g", info_.frameRate);
    out << "#usda 1.0\n(\n    defaultPrim = \"flowclip\"\n    doc = \"" << info_.createdBy << "\"\n"
        << "    startTimeCode = " << start << "\n    endTimeCode = " << end << "\n"
        << "    timeCodesPerSecond = " << rate << "\n    framesPerSecond = " << rate << "\n"
        << "    metersPerUnit = 1\n    upAxis = \"Y\"\n)\n\n"
        << "def Xform \"flowclip\" (\n    kind = \"component\"\n)\n{\n"
        << "    def Points \"particles\"\n    {\n";
    char width[32];
    std::snprintf(width, sizeof width, "%.9g", 2 * info_.particleRadius);
    out << "        float[] widths = [" << width << "] (\n            interpolation = \"constant\"\n        )\n";
    for (Samples* s : points()) s->writeTo(out);
    out << "    }\n";
    if (p_.meshes) {
      out << "    def Mesh \"surface\"\n    {\n        uniform token subdivisionScheme = \"none\"\n"
          << "        uniform token orientation = \"rightHanded\"\n";
      for (Samples* s : meshes()) s->writeTo(out);
      out << "    }\n";
    }
    out << "}\n";
    out.flush();
    if (!out) throw std::runtime_error("usd export: cannot write '" + path + "'");
    for (Samples* s : all()) s->remove();
  }

 private:
  std::vector<Samples*> points() { return {&positions_, &velocities_, &ids_, &phase_, &extent_}; }
  std::vector<Samples*> meshes() { return {&meshPoints_, &meshVelocities_, &faceCounts_, &faceIndices_, &meshExtent_}; }
  std::vector<Samples*> all() {
    auto a = points(), b = meshes();
    a.insert(a.end(), b.begin(), b.end());
    if (!p_.meshes) a.resize(points().size());
    return a;
  }

  UsdParams p_;
  int first_ = std::numeric_limits<int>::max(), last_ = std::numeric_limits<int>::min();
  Samples positions_{"point3f[] points"}, velocities_{"vector3f[] velocities"}, ids_{"int64[] ids"},
      phase_{"int[] primvars:phase", "interpolation = \"vertex\""}, extent_{"float3[] extent"};
  Samples meshPoints_{"point3f[] points"}, meshVelocities_{"vector3f[] velocities"},
      faceCounts_{"int[] faceVertexCounts"}, faceIndices_{"int[] faceVertexIndices"}, meshExtent_{"float3[] extent"};
};

}  // namespace

ParamSpecs usdExporterParams() { return usdTable().specs(); }
std::unique_ptr<Exporter> makeUsdExporter(const ParamValues& v) {
  return std::make_unique<UsdExporter>(usdTable().bind(v));
}

}  // namespace fc
