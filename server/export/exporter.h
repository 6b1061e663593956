#pragma once
// Exporters of frames to the files renderers and DCCs import (vdb, ply,
// obj, usd, ...), registered by name in one table like the solvers and
// effects (export/exporters.cpp) and chosen by name from the CLI, REST and
// the editor. SurfaceExport (export/surface_export.h) drives them: it
// reconstructs the surface once per frame for those that need it, and
// publishes each frame's files together.
#include "sph/phase.h"
#include "sph/pipeline.h"
#include "surface/surface.h"
#include <functional>
#include <string>
#include <vector>

namespace fc {

// What every exporter of one export knows.
struct ExportInfo {
  std::string name;           // file stem: NAME.0001.vdb, NAME.usda, ...
  std::string directory;      // where the files go (exists)
  int dimension = 3;          // of the scene; a 2D scene's frames lie at z = 0
  double particleRadius = 0;  // m
  double frameRate = 0;       // frames per simulated second
  std::vector<Phase> phases;
  std::string createdBy;      // e.g. "flowclip 0.1.0"
};

// The files of one frame (or of the end of an export), written under staged
// names and published together by SurfaceExport.
class FrameFiles {
 public:
  explicit FrameFiles(std::string directory) : directory_(std::move(directory)) {}
  // The staged path to write `fileName` (a bare name) to; it becomes
  // DIRECTORY/fileName when the frame is published.
  std::string add(const std::string& fileName);
  struct File {
    std::string staged, final;
  };
  const std::vector<File>& files() const { return files_; }

 private:
  std::string directory_;
  std::vector<File> files_;
};

// The frame number in file names: NAME.0007.ext (four digits at least).
std::string frameFileName(const std::string& name, int frame, const std::string& extension);

class Exporter {
 public:
  virtual ~Exporter() = default;
  // Whether frame() needs the surface's grids, its mesh or a 2D liquid's outline.
  virtual bool needsGrids() const { return false; }
  virtual bool needsMesh() const { return false; }
  virtual bool needsOutline() const { return false; }
  virtual void begin(const ExportInfo& info) { info_ = info; }
  // One frame: `surface` is set when the exporter needs any of them.
  virtual void frame(const ParticleFrame& frame, const Surface* surface, FrameFiles& files) = 0;
  // After the last frame: the files that span every frame (a USD stage).
  virtual void finish(FrameFiles& files) {}

 protected:
  ExportInfo info_;
};

using ExporterRegistry = Registry<Exporter>;

// Registration happens in one place (export/exporters.cpp).
void registerBuiltinExporters();

}  // namespace fc
