// `flowclip bench ...`: the benchmark commands, one file each (solver.cpp,
// templates.cpp, control.cpp, service.cpp, scenes.cpp, accuracy.cpp).
#include "bench/commands.h"

#include <algorithm>
#include <filesystem>

namespace fc::bench {

std::vector<std::string> sceneFilesIn(const std::string& folder) {
  namespace fs = std::filesystem;
  std::vector<std::string> found;
  for (const fs::path& dir : {fs::path(folder), fs::path(FLOWCLIP_SOURCE_DIR) / folder}) {
    if (!fs::is_directory(dir)) continue;
    for (const auto& e : fs::directory_iterator(dir))
      if (e.path().extension() == ".json") found.push_back(e.path().string());
    break;
  }
  std::sort(found.begin(), found.end());
  return found;
}

void addBenchCommand(CLI::App& app) {
  CLI::App* bench = app.add_subcommand("bench", "benchmarks: figures printed, reports written (bench/)");
  bench->require_subcommand(1);
  addBenchSolverCommand(*bench);
  addBenchTemplatesCommand(*bench);
  addBenchControlCommand(*bench);
  addBenchServiceCommand(*bench);
  addBenchScenesCommand(*bench);
  addBenchAccuracyCommand(*bench);
  addBenchSurfaceCommand(*bench);
}

}  // namespace fc::bench
