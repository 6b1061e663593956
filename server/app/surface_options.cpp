#include "app/surface_options.h"

#include "cli/param_override.h"
#include "io/scene.h"

namespace fc::app {

void addSurfaceOptions(CLI::App* command, SurfaceOptions& o) {
  registerBuiltinExporters();
  std::string names;
  for (const auto& n : ExporterRegistry::instance().names()) names += (names.empty() ? "" : ", ") + n;
  command->add_option("--formats", o.formats, "comma-separated export formats (" + names + "; default vdb,ply)");
  std::string settings;
  for (const ParamSpec& p : surfaceSettingsSpecs()) settings += (settings.empty() ? "" : ", ") + p.name;
  command->add_option("--surface", o.surface,
                      "a surface setting, KEY=VALUE (" + settings + "; `flowclip params` lists them); repeatable");
  command->add_option("--format-setting", o.formatSettings,
                      "a format's setting, FORMAT.KEY=VALUE (e.g. usd.meshes=1, vdb.half=1); repeatable");
}

std::unique_ptr<SurfaceExport> makeSurfaceExport(const SurfaceOptions& o, const ExportInfo& info) {
  const std::vector<std::string> formats = parseFormats(o.formats);
  SurfaceSettings settings = surfaceSettingsTable().defaults();
  for (const auto& kv : o.surface) {
    const cli::ParamOverride p = cli::parseParamOverride(surfaceSettingsSpecs(), kv, "--surface", "surface");
    surfaceSettingsTable().assign(settings, p.spec->name, p.value);
  }
  std::map<std::string, ParamValues> params;
  for (const auto& kv : o.formatSettings) {
    const size_t dot = kv.find('.');
    const std::string format = kv.substr(0, dot);
    const auto* entry = ExporterRegistry::instance().find(format);
    if (dot == std::string::npos || !entry)
      throw SceneError("format", "--format-setting '" + kv + "': expected FORMAT.KEY=VALUE with FORMAT an export format");
    if (std::find(formats.begin(), formats.end(), format) == formats.end())
      throw SceneError("format." + format, "--format-setting '" + kv + "': format '" + format + "' is not exported (--formats)");
    const cli::ParamOverride p = cli::parseParamOverride(entry->params, kv.substr(dot + 1), "--format-setting", format);
    params.try_emplace(format, entry->params).first->second.set(p.spec->name, p.value);
  }
  return std::make_unique<SurfaceExport>(info, formats, settings, params);
}

}  // namespace fc::app
