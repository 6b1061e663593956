#pragma once
// An export of frames to files by format name (`vdb,ply,usd`): the driver of
// the exporters of export/exporter.h, used by `flowclip run --export-surface`,
// `flowclip export` and the server.
//
// Files land in one directory, named NAME.0001.vdb, NAME.0001.ply,
// NAME_points.0001.ply, NAME.0001.obj, NAME.usda (docs/surfaces.md). Each
// frame's files are published together (io/staged_files.h): a frame is
// either complete or absent, never half-written under its final name. At
// close() the files spanning every frame (the USD stage) and the manifest
// NAME.export.json are published together; a failed or abandoned export has
// no manifest, so an export is complete exactly when its manifest exists.
#include "export/exporter.h"
#include "io/frames_file.h"
#include "surface/surface.h"
#include <nlohmann/json.hpp>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace fc {

// A format list or a directory that cannot be used: the message says which
// and why (unknown name with the known ones, unwritable directory).
struct ExportSetupError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// "vdb,ply" -> {"vdb", "ply"}: every name known, none repeated, at least one.
// Throws ExportSetupError.
std::vector<std::string> parseFormats(const std::string& list);

// What an export of the frames file `in` knows: its dimension, particle
// radius, frame rate and phases, with the given stem, directory and author.
ExportInfo exportInfoOf(const FramesFile& in, const std::string& name, const std::string& directory,
                        const std::string& createdBy);

class SurfaceExport {
 public:
  // Creates the directory if needed and checks that it is writable; throws
  // ExportSetupError. `formatParams` may hold values for the formats'
  // declared parameters (by format name).
  SurfaceExport(const ExportInfo& info, const std::vector<std::string>& formats, const SurfaceSettings& surface,
                const std::map<std::string, ParamValues>& formatParams = {});
  ~SurfaceExport();
  SurfaceExport(const SurfaceExport&) = delete;
  SurfaceExport& operator=(const SurfaceExport&) = delete;

  // Reconstructs the surface if a format needs it, writes and publishes the
  // frame's files. Throws std::runtime_error naming the file on failure (the
  // frame's files are then absent).
  void writeFrame(const ParticleFrame& frame);
  // Publishes the files spanning every frame and the manifest. Idempotent.
  void close();

  int frames() const { return int(frameIndices_.size()); }
  double surfaceMs() const { return surfaceMs_; }  // total reconstruction time
  size_t bytesWritten() const { return bytes_; }
  const std::string& manifestPath() const { return manifest_; }

 private:
  ExportInfo info_;
  std::vector<std::string> formats_;
  SurfaceSettings surface_;
  std::vector<std::unique_ptr<Exporter>> exporters_;
  bool grids_ = false, mesh_ = false, outline_ = false, closed_ = false;
  std::vector<int> frameIndices_;
  std::vector<double> frameTimes_;
  nlohmann::json frameFiles_ = nlohmann::json::array();
  double surfaceMs_ = 0;
  size_t bytes_ = 0;
  std::string manifest_;
};

}  // namespace fc
