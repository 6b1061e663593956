// Export of a session's replay history: see history_export.h.
#include "service/history_export.h"

#include "io/hdf5_util.h"
#include "io/staged_files.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <system_error>

namespace fc::service {

namespace fs = std::filesystem;

std::string xdmfPathFor(const std::string& h5Path) {
  fs::path p(h5Path);
  p.replace_extension(".xdmf");
  return p.string();
}

namespace {

// XML attribute and text escaping (the HDF5 file's name goes into the text).
std::string xmlEscaped(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

struct FrameRows {
  int frame = 0;
  double time = 0;
  uint64_t offset = 0, count = 0;
};

// One HyperSlab selection of rows offset..offset+count of an HDF5 dataset of
// `total` rows and `cols` columns (0: one-dimensional).
void hyperSlab(std::string& x, const FrameRows& r, uint64_t total, int cols, const char* type, int precision,
               const std::string& dataset, const char* indent) {
  const std::string n = std::to_string(r.count), off = std::to_string(r.offset);
  const std::string c = std::to_string(cols);
  x += indent;
  x += "<DataItem ItemType=\"HyperSlab\" Type=\"HyperSlab\" Dimensions=\"" + n + (cols ? " " + c : "") + "\">\n";
  x += indent;
  if (cols)
    x += "  <DataItem Dimensions=\"3 2\" Format=\"XML\">" + off + " 0 1 1 " + n + " " + c + "</DataItem>\n";
  else
    x += "  <DataItem Dimensions=\"3 1\" Format=\"XML\">" + off + " 1 " + n + "</DataItem>\n";
  x += indent;
  x += "  <DataItem Dimensions=\"" + std::to_string(total) + (cols ? " " + c : "") + "\" NumberType=\"" + type +
       "\" Precision=\"" + std::to_string(precision) + "\" Format=\"HDF\">" + dataset + "</DataItem>\n";
  x += indent;
  x += "</DataItem>\n";
}

// XDMF 2: a temporal collection of one Polyvertex grid per frame.
std::string xdmfText(const std::string& h5Name, int dimension, const std::vector<FrameRows>& frames, uint64_t total) {
  const std::string file = xmlEscaped(h5Name);
  std::string x =
      "<?xml version=\"1.0\" ?>\n"
      "<!DOCTYPE Xdmf SYSTEM \"Xdmf.dtd\" []>\n"
      "<!-- FlowClip session history: the frames of " + file + " (docs/export-format.md) -->\n"
      "<Xdmf Version=\"2.0\">\n"
      " <Domain>\n"
      "  <Grid Name=\"history\" GridType=\"Collection\" CollectionType=\"Temporal\">\n";
  x.reserve(x.size() + frames.size() * 2200);
  char time[40];
  for (const FrameRows& r : frames) {
    if (r.count == 0) continue;  // nothing to show; readers reject empty grids
    std::snprintf(time, sizeof time, "%.10g", r.time);
    x += "   <Grid Name=\"frame_" + std::to_string(r.frame) + "\" GridType=\"Uniform\">\n";
    x += "    <Time Value=\"" + std::string(time) + "\"/>\n";
    x += "    <Topology TopologyType=\"Polyvertex\" NumberOfElements=\"" + std::to_string(r.count) +
         "\" NodesPerElement=\"1\"/>\n";
    x += std::string("    <Geometry GeometryType=\"") + (dimension == 2 ? "XY" : "XYZ") + "\">\n";
    hyperSlab(x, r, total, dimension, "Float", 4, file + ":/particles/position", "     ");
    x += "    </Geometry>\n";
    x += "    <Attribute Name=\"velocity\" AttributeType=\"Vector\" Center=\"Node\">\n";
    hyperSlab(x, r, total, dimension, "Float", 4, file + ":/particles/velocity", "     ");
    x += "    </Attribute>\n";
    for (const char* name : {"phase", "kind"}) {
      x += std::string("    <Attribute Name=\"") + name + "\" AttributeType=\"Scalar\" Center=\"Node\">\n";
      hyperSlab(x, r, total, 0, "UChar", 1, file + ":/particles/" + name, "     ");
      x += "    </Attribute>\n";
    }
    x += "   </Grid>\n";
  }
  x += "  </Grid>\n </Domain>\n</Xdmf>\n";
  return x;
}

void writeTextFile(const std::string& path, const std::string& text) {
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    if (!out) throw std::runtime_error("cannot create '" + path + "'");
    out.write(text.data(), std::streamsize(text.size()));
    out.flush();
    if (!out) throw std::runtime_error("cannot write '" + path + "'");
  }
  try {
    hdf5::syncPath(path, false);
  } catch (const std::system_error& e) {
    throw std::runtime_error("cannot flush '" + path + "' to disk: " + e.code().message());
  }
}

template <int D>
HistoryExport writeFrames(const std::string& h5Path, const std::vector<FramePtr>& frames, const ExportHeader& header) {
  const std::string xdmfPath = xdmfPathFor(h5Path);
  size_t largest = 0;
  for (const FramePtr& f : frames) {
    const size_t n = f->particles();
    if (f->dimension != D || f->positions.size() != n * D || f->velocities.size() != n * D || f->phase.size() != n)
      throw std::invalid_argument("history frame " + std::to_string(f->frame) + " is not a complete " +
                                  std::to_string(D) + "D snapshot");
    largest = std::max(largest, n);
  }

  // Both files staged next to their names; removed unless both are published,
  // also after a crash (recoverPublishing).
  StagedFiles publish(/*replace=*/true);
  const std::string h5Staged = stagingPath(h5Path);
  const std::string xdmfStaged = stagingPath(xdmfPath);
  publish.stage(h5Staged, h5Path);
  publish.stage(xdmfStaged, xdmfPath);

  HistoryExport res;
  res.h5Path = h5Path;
  res.xdmfPath = xdmfPath;
  std::vector<FrameRows> rows;
  rows.reserve(frames.size());
  {
    FrameExporter<D> exporter(h5Staged, header);
    std::vector<float> pos(largest * D), vel(largest * D);
    for (const FramePtr& fp : frames) {
      const FrameSnapshot& f = *fp;
      const long n = long(f.particles());
      // x = min + q · (max − min) / 65535 and v = (q · 2 / 65535 − 1) · vmax,
      // as FrameSnapshot::position / velocity, per axis factors hoisted.
      double lo[D], step[D], vmax[D];
      for (int d = 0; d < D; ++d) {
        lo[d] = f.domainMin[size_t(d)];
        step[d] = (f.domainMax[size_t(d)] - f.domainMin[size_t(d)]) / FrameSnapshot::kQuantizationLevels;
        vmax[d] = f.velocityMax[size_t(d)];
      }
      const uint16_t* qx = f.positions.data();
      const uint16_t* qv = f.velocities.data();
      float* px = pos.data();
      float* pv = vel.data();
#pragma omp parallel for schedule(static) if (n >= 16384)
      for (long i = 0; i < n; ++i)
        for (int d = 0; d < D; ++d) {
          const size_t k = size_t(i) * D + size_t(d);
          px[k] = float(lo[d] + double(qx[k]) * step[d]);
          pv[k] = float((double(qv[k]) * (2 / FrameSnapshot::kQuantizationLevels) - 1) * vmax[d]);
        }
      ExportColumns c;
      c.count = size_t(n);
      c.position = px;
      c.velocity = pv;
      c.phase = f.phase.data();
      c.kind = f.kind.data();
      rows.push_back({f.frame, f.time, exporter.particleRowCount(), uint64_t(n)});
      exporter.writeFrame(f.frame, f.time, c);
    }
    exporter.close();
    res.frames = exporter.frameCount();
    res.particleRows = exporter.particleRowCount();
  }
  writeTextFile(xdmfStaged, xdmfText(fs::path(h5Path).filename().string(), D, rows, res.particleRows));
  publish.commit();
  auto sizeOf = [](const std::string& path) {
    std::error_code ec;
    const auto size = fs::file_size(path, ec);
    return ec ? uint64_t(0) : uint64_t(size);
  };
  res.bytes = sizeOf(h5Path) + sizeOf(xdmfPath);
  return res;
}

}  // namespace

HistoryExport writeHistoryExport(const std::string& h5Path, const std::vector<FramePtr>& frames,
                                 ExportHeader header) {
  if (frames.empty()) throw std::invalid_argument("no frames to export to '" + h5Path + "'");
  if (header.dimension != 2 && header.dimension != 3)
    throw std::invalid_argument("cannot export a history of dimension " + std::to_string(header.dimension));
  header.source = kHistorySource;
  header.solverColumns = false;
  try {
    return header.dimension == 2 ? writeFrames<2>(h5Path, frames, header) : writeFrames<3>(h5Path, frames, header);
  } catch (const std::invalid_argument&) {
    throw;
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot export the session history to '" + h5Path + "': " + e.what());
  }
}

}  // namespace fc::service
