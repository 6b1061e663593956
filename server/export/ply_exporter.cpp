// `ply` and `points`: binary little-endian PLY per frame, read by Houdini,
// Blender, MeshLab and plyfile. `ply` is the surface mesh with per-vertex
// velocity (vx, vy, vz); `points` is the particle cache (liquid and
// temporary particles) with its attributes.
#include "export/builtin.h"

#include <bit>
#include <cstring>
#include <fstream>

namespace fc {

namespace {

static_assert(std::endian::native == std::endian::little, "PLY files are written as binary_little_endian");

class Writer {
 public:
  explicit Writer(const std::string& path) : path_(path), out_(path, std::ios::binary) {
    if (!out_) throw std::runtime_error("ply export: cannot create '" + path + "'");
  }
  void text(const std::string& s) { out_ << s; }
  template <class T>
  void raw(const T* data, size_t n) {
    out_.write(reinterpret_cast<const char*>(data), std::streamsize(n * sizeof(T)));
  }
  void close() {
    out_.flush();
    if (!out_) throw std::runtime_error("ply export: cannot write '" + path_ + "'");
    out_.close();
  }

 private:
  std::string path_;
  std::ofstream out_;
};

class PlyMeshExporter : public Exporter {
 public:
  bool needsMesh() const override { return true; }
  void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles& files) override {
    const SurfaceMesh& m = surface->mesh;
    Writer w(files.add(frameFileName(info_.name, frame.index, "ply")));
    w.text("ply\nformat binary_little_endian 1.0\ncomment " + info_.createdBy + ", frame " +
           std::to_string(frame.index) + ", time " + std::to_string(frame.time) + " s\n");
    w.text("element vertex " + std::to_string(m.points.size()) +
           "\nproperty float x\nproperty float y\nproperty float z\nproperty float vx\nproperty float vy\nproperty "
           "float vz\n");
    w.text("element face " + std::to_string(m.triangles.size()) + "\nproperty list uchar uint vertex_indices\nend_header\n");
    std::vector<float> vertices;
    vertices.reserve(6 * m.points.size());
    for (size_t i = 0; i < m.points.size(); ++i)
      vertices.insert(vertices.end(), {m.points[i][0], m.points[i][1], m.points[i][2], m.velocities[i][0],
                                       m.velocities[i][1], m.velocities[i][2]});
    w.raw(vertices.data(), vertices.size());
    std::vector<unsigned char> faces(13 * m.triangles.size());
    for (size_t t = 0; t < m.triangles.size(); ++t) {
      faces[13 * t] = 3;
      std::memcpy(&faces[13 * t + 1], m.triangles[t].data(), 12);
    }
    w.raw(faces.data(), faces.size());
    w.close();
  }
};

class PlyPointsExporter : public Exporter {
 public:
  void frame(const ParticleFrame& frame, const Surface*, FrameFiles& files) override {
    std::vector<size_t> rows;
    for (size_t i = 0; i < frame.count(); ++i)
      if (formsSurface(frame.kind[i])) rows.push_back(i);
    const bool ids = !frame.id.empty(), density = !frame.density.empty();
    Writer w(files.add(frameFileName(info_.name + "_points", frame.index, "ply")));
    std::string header = "ply\nformat binary_little_endian 1.0\ncomment " + info_.createdBy + ", frame " +
                         std::to_string(frame.index) + ", time " + std::to_string(frame.time) +
                         " s, particle radius " + std::to_string(info_.particleRadius) + " m\n" +
                         "element vertex " + std::to_string(rows.size()) +
                         "\nproperty float x\nproperty float y\nproperty float z\nproperty float vx\nproperty float "
                         "vy\nproperty float vz\n";
    if (ids) header += "property uint id\n";
    header += "property uchar phase\nproperty uchar kind\n";
    if (density) header += "property float density\n";
    w.text(header + "end_header\n");
    const size_t stride = 24 + (ids ? 4 : 0) + 2 + (density ? 4 : 0);
    std::vector<unsigned char> bytes(stride * rows.size());
    for (size_t n = 0; n < rows.size(); ++n) {
      unsigned char* b = &bytes[n * stride];
      const size_t i = rows[n];
      std::memcpy(b, &frame.position[3 * i], 12);
      std::memcpy(b + 12, &frame.velocity[3 * i], 12);
      size_t at = 24;
      if (ids) std::memcpy(b + at, &frame.id[i], 4), at += 4;
      b[at++] = frame.phase[i];
      b[at++] = frame.kind[i];
      if (density) std::memcpy(b + at, &frame.density[i], 4);
    }
    w.raw(bytes.data(), bytes.size());
    w.close();
  }
};

}  // namespace

ParamSpecs plyMeshExporterParams() { return {}; }
std::unique_ptr<Exporter> makePlyMeshExporter(const ParamValues&) { return std::make_unique<PlyMeshExporter>(); }
ParamSpecs plyPointsExporterParams() { return {}; }
std::unique_ptr<Exporter> makePlyPointsExporter(const ParamValues&) { return std::make_unique<PlyPointsExporter>(); }

}  // namespace fc
