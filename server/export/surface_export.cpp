#include "export/surface_export.h"

#include "io/staged_files.h"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <system_error>

namespace fc {

namespace fs = std::filesystem;

std::string FrameFiles::add(const std::string& fileName) {
  const std::string final = (fs::path(directory_) / fileName).string();
  files_.push_back({stagingPath(final), final});
  return files_.back().staged;
}

std::string frameFileName(const std::string& name, int frame, const std::string& extension) {
  char digits[16];
  std::snprintf(digits, sizeof digits, "%04d", frame);
  return name + "." + digits + "." + extension;
}

std::vector<std::string> parseFormats(const std::string& list) {
  registerBuiltinExporters();
  const auto& registry = ExporterRegistry::instance();
  std::vector<std::string> out;
  std::stringstream in(list);
  std::string name;
  while (std::getline(in, name, ',')) {
    while (!name.empty() && name.front() == ' ') name.erase(name.begin());
    while (!name.empty() && name.back() == ' ') name.pop_back();
    if (name.empty()) continue;
    if (!registry.find(name)) {
      std::string known;
      for (const auto& n : registry.names()) known += (known.empty() ? "" : ", ") + n;
      throw ExportSetupError("unknown export format '" + name + "' (known: " + known + ")");
    }
    for (const auto& seen : out)
      if (seen == name) throw ExportSetupError("export format '" + name + "' is given twice");
    out.push_back(name);
  }
  if (out.empty()) throw ExportSetupError("no export format given (e.g. vdb,ply,usd)");
  return out;
}

ExportInfo exportInfoOf(const FramesFile& in, const std::string& name, const std::string& directory,
                        const std::string& createdBy) {
  ExportInfo info;
  info.name = name;
  info.directory = directory;
  info.dimension = in.dimension();
  info.particleRadius = in.particleRadius();
  info.frameRate = in.frameRate();
  for (size_t p = 0; p < in.phaseNames().size(); ++p) {
    Phase phase;
    phase.name = in.phaseNames()[p];
    if (p < in.phaseRestDensity().size()) phase.restDensity = Real(in.phaseRestDensity()[p]);
    info.phases.push_back(phase);
  }
  info.createdBy = createdBy;
  return info;
}

namespace {

// Publishes a frame's files together; they are removed if that fails.
size_t publish(const FrameFiles& files) {
  if (files.files().empty()) return 0;
  StagedFiles staged(/*replace=*/true);
  size_t bytes = 0;
  for (const auto& f : files.files()) {
    staged.stage(f.staged, f.final);
    std::error_code ec;
    const auto size = fs::file_size(f.staged, ec);
    if (ec) throw std::runtime_error("export: '" + f.final + "' was not written");
    bytes += size_t(size);
  }
  staged.commit();
  return bytes;
}

// Removes the staged files of a frame that failed.
void discard(const FrameFiles& files) noexcept {
  for (const auto& f : files.files()) {
    std::error_code ec;
    fs::remove(f.staged, ec);
  }
}

}  // namespace

SurfaceExport::SurfaceExport(const ExportInfo& info, const std::vector<std::string>& formats,
                             const SurfaceSettings& surface, const std::map<std::string, ParamValues>& formatParams)
    : info_(info), formats_(formats), surface_(surface) {
  registerBuiltinExporters();
  if (formats_.empty()) throw ExportSetupError("no export format given (e.g. vdb,ply,usd)");
  if (info_.name.empty() || info_.name.find('/') != std::string::npos || info_.name.front() == '.')
    throw ExportSetupError("export name '" + info_.name + "' must be a plain file name");
  if (const std::string problem = surfaceSettingsProblem(surface_); !problem.empty()) throw ExportSetupError(problem);
  if (!(info_.particleRadius > 0) || !(info_.frameRate > 0))
    throw ExportSetupError("export of '" + info_.name + "': the particle radius and frame rate must be positive");
  std::error_code ec;
  fs::create_directories(info_.directory, ec);
  if (ec || !fs::is_directory(info_.directory))
    throw ExportSetupError("export directory '" + info_.directory + "' cannot be created: " +
                           (ec ? ec.message() : std::string("not a directory")));
  // A probe, so that an unwritable directory fails before any simulation.
  const std::string probe = stagingPath((fs::path(info_.directory) / (info_.name + ".probe")).string());
  {
    std::ofstream out(probe);
    if (!out) throw ExportSetupError("export directory '" + info_.directory + "' is not writable");
  }
  fs::remove(probe, ec);
  recoverPublishing(info_.directory);
  for (const auto& name : formats_) {
    const auto* entry = ExporterRegistry::instance().find(name);
    if (!entry) throw ExportSetupError("unknown export format '" + name + "'");
    auto it = formatParams.find(name);
    exporters_.push_back(entry->make(it == formatParams.end() ? ParamValues(entry->params) : it->second));
    exporters_.back()->begin(info_);
    grids_ = grids_ || exporters_.back()->needsGrids();
    mesh_ = mesh_ || exporters_.back()->needsMesh();
    outline_ = outline_ || exporters_.back()->needsOutline();
  }
  manifest_ = (fs::path(info_.directory) / (info_.name + ".export.json")).string();
  // Until this export closes, the directory does not claim a complete one.
  fs::remove(manifest_, ec);
  if (ec) throw ExportSetupError("cannot remove the previous manifest '" + manifest_ + "': " + ec.message());
}

SurfaceExport::~SurfaceExport() = default;

void SurfaceExport::writeFrame(const ParticleFrame& frame) {
  if (closed_) throw std::runtime_error("export of '" + info_.name + "': already closed");
  Surface surface;
  const bool reconstruct = grids_ || mesh_ || outline_;
  if (reconstruct) {
    surface = reconstructSurface(frame, info_.particleRadius, surface_, mesh_, info_.dimension, grids_);
    surfaceMs_ += surface.ms;
  }
  FrameFiles files(info_.directory);
  try {
    for (auto& e : exporters_) e->frame(frame, reconstruct ? &surface : nullptr, files);
    bytes_ += publish(files);
  } catch (...) {
    discard(files);
    throw;
  }
  nlohmann::json names = nlohmann::json::array();
  for (const auto& f : files.files()) names.push_back(fs::path(f.final).filename().string());
  frameIndices_.push_back(frame.index);
  frameTimes_.push_back(frame.time);
  frameFiles_.push_back({{"frame", frame.index},
                         {"time", frame.time},
                         {"particles", frame.count()},
                         {"triangles", surface.mesh.triangles.size()},
                         {"files", names}});
}

void SurfaceExport::close() {
  if (closed_) return;
  closed_ = true;
  FrameFiles files(info_.directory);
  try {
    for (auto& e : exporters_) e->finish(files);
    nlohmann::json settings = nlohmann::json::object();
    const ParamValues values = surfaceSettingsTable().values(surface_);
    for (const auto& [k, v] : values.all()) settings[k] = v;
    nlohmann::json spanning = nlohmann::json::array();
    for (const auto& f : files.files()) spanning.push_back(fs::path(f.final).filename().string());
    const nlohmann::json manifest = {{"format", "flowclip-surface-export"},
                                     {"format_version", 1},
                                     {"name", info_.name},
                                     {"created_by", info_.createdBy},
                                     {"dimension", info_.dimension},
                                     {"particle_radius", info_.particleRadius},
                                     {"frame_rate", info_.frameRate},
                                     {"formats", formats_},
                                     {"surface", settings},
                                     {"frames", frameFiles_},
                                     {"files", spanning}};
    const std::string staged = files.add(fs::path(manifest_).filename().string());
    {
      std::ofstream out(staged);
      out << manifest.dump(1) << "\n";
      if (!out.flush()) throw std::runtime_error("export: cannot write '" + manifest_ + "'");
    }
    bytes_ += publish(files);
  } catch (...) {
    discard(files);
    throw;
  }
}

}  // namespace fc
