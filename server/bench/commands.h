#pragma once
// `flowclip bench ...`: benchmarks that print their figures and write the
// reports docs/benchmarks/ shows. app/main.cpp adds the group; nothing else
// in the server depends on bench/.
#include <CLI/CLI.hpp>

#include <string>
#include <vector>

namespace fc::bench {

// The `bench` group with all its sub-commands (bench.cpp).
void addBenchCommand(CLI::App& app);

// Its sub-commands, one file each.
void addBenchSolverCommand(CLI::App& bench);     // bench solver (solver.cpp)
void addBenchTemplatesCommand(CLI::App& bench);  // bench templates (templates.cpp)
void addBenchControlCommand(CLI::App& bench);    // bench control (control.cpp)
void addBenchServiceCommand(CLI::App& bench);    // bench service (service.cpp)
void addBenchScenesCommand(CLI::App& bench);     // bench scenes (scenes.cpp)
void addBenchAccuracyCommand(CLI::App& bench);   // bench accuracy (accuracy.cpp)
void addBenchSurfaceCommand(CLI::App& bench);    // bench surface (surface.cpp)

// The scene files (*.json, sorted) of `folder` under the working directory,
// else under the source tree: the benchmarks' default scenes (bench.cpp).
std::vector<std::string> sceneFilesIn(const std::string& folder);

}  // namespace fc::bench
