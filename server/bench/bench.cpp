// `flowclip bench ...`: the benchmark commands, one file each (solver.cpp,
// templates.cpp, control.cpp, service.cpp, scenes.cpp, accuracy.cpp).
#include "bench/commands.h"

namespace fc::bench {

void addBenchCommand(CLI::App& app) {
  CLI::App* bench = app.add_subcommand("bench", "benchmarks that print their figures");
  bench->require_subcommand(1);
  addBenchSolverCommand(*bench);
  addBenchTemplatesCommand(*bench);
  addBenchControlCommand(*bench);
  addBenchServiceCommand(*bench);
  addBenchScenesCommand(*bench);
  addBenchAccuracyCommand(*bench);
}

}  // namespace fc::bench
