#pragma once
// The options `run --export-surface` and `export` share: formats, surface
// settings and the formats' own settings, and the export they set up.
#include "export/surface_export.h"
#include <CLI/CLI.hpp>
#include <memory>
#include <string>
#include <vector>

namespace fc::app {

struct SurfaceOptions {
  std::string formats = "vdb,ply";
  std::vector<std::string> surface;         // KEY=VALUE over surfaceSettingsTable()
  std::vector<std::string> formatSettings;  // FORMAT.KEY=VALUE over the format's parameters
};

void addSurfaceOptions(CLI::App* command, SurfaceOptions& options);

// The export the options describe (formats and settings checked: SceneError
// or ExportSetupError name what is wrong).
std::unique_ptr<SurfaceExport> makeSurfaceExport(const SurfaceOptions& options, const ExportInfo& info);

}  // namespace fc::app
