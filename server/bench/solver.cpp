// `flowclip bench solver`: the pressure solvers on the reference dam breaks
// (scenes/bench). Each (scene, solver) pair runs in its own child process
// (`flowclip run --stats`), so that peak RSS is that run's alone.
#include "bench/commands.h"
#include "cli/exit_codes.h"
#include "cli/json_file.h"
#include "cli/process.h"
#include <nlohmann/json.hpp>
#include <unistd.h>
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

namespace fc::bench {

using namespace fc::cli;

namespace {

namespace fs = std::filesystem;

// SPlisHSPlasH DFSPH figures read once, on one machine (single precision,
// AVX2, -O3 -march=native, OpenMP, 2 threads, volume-map boundaries): µs per
// particle-step and wall s per simulated s. Figures from another machine do
// not divide; tools/bench_reference.py times SPlisHSPlasH on this one
// (docs/benchmarks/solver.md).
struct Reference {
  double usPerParticleStep;
  double wallPerSimS;
};
const std::map<std::string, Reference>& splishsplashReference() {
  static const std::map<std::string, Reference> ref = {
      {"dambreak3d_r010", {1.73, 127.0}},
      {"dambreak3d_r0125", {1.41, 43.5}},
      {"dambreak2d_r010", {0.90, 3.5}},
      {"dambreak2d_r005", {0.89, 30.0}},
  };
  return ref;
}

struct BenchOptions {
  std::vector<std::string> scenes;
  std::vector<std::string> solvers{"dfsph", "wcsph"};
  double seconds = 2;
  int threads = 0;
  std::string out;
};

int benchSolver(const BenchOptions& opt) {
  const std::vector<std::string> scenes = opt.scenes.empty() ? sceneFilesIn("scenes/bench") : opt.scenes;
  if (scenes.empty()) {
    std::fprintf(stderr, "error: no bench scenes found (scenes/bench/*.json)\n");
    return BadInput;
  }
  const std::string self = selfExecutable();
  const std::string tmp = (fs::temp_directory_path() / ("flowclip-bench-" + std::to_string(getpid()) + ".json")).string();
  nlohmann::json results = nlohmann::json::array();

  std::printf("%-18s %-6s %9s %8s %10s %10s %9s %10s %9s %9s %8s %8s  %s\n", "scene", "solver", "particles",
              "steps", "us/p-step", "substep/fr", "ms/frame", "wall/sim-s", "avg err%", "max err%", "tol %", "RSS MB",
              "SPlisHSPlasH DFSPH (us/p-step, wall/sim-s)");
  std::fflush(stdout);
  int worst = Ok;
  for (const auto& scene : scenes) {
    const std::string stem = fs::path(scene).stem().string();
    for (const auto& solver : opt.solvers) {
      std::vector<std::string> args{self,      "run",   scene, "--seconds", std::to_string(opt.seconds),
                                    "--solver", solver, "--stats", tmp,     "--quiet"};
      if (opt.threads > 0) {
        args.push_back("--threads");
        args.push_back(std::to_string(opt.threads));
      }
      std::fprintf(stderr, "bench: %s with %s ...\n", stem.c_str(), solver.c_str());
      const int code = runChild(args);
      nlohmann::json stats;
      std::ifstream f(tmp);
      if (code != 0 || !f) {
        std::printf("%-18s %-6s failed (exit %d)\n", stem.c_str(), solver.c_str(), code);
        worst = Failure;
        continue;
      }
      f >> stats;
      fs::remove(tmp);
      const auto& s = stats["summary"];
      double avgErr = 0, maxErr = 0;
      for (const auto& fr : stats["frames"]) {
        avgErr += fr["avg_density_error_pct"].get<double>();
        maxErr = std::max(maxErr, fr["max_density_error_pct"].get<double>());
      }
      if (!stats["frames"].empty()) avgErr /= double(stats["frames"].size());
      std::string ref = "-";
      const auto it = splishsplashReference().find(stem);
      if (it != splishsplashReference().end() && solver == "dfsph") {
        std::ostringstream o;
        o.precision(3);
        o << it->second.usPerParticleStep << ", " << it->second.wallPerSimS << "  (ours: "
          << s["us_per_particle_step"].get<double>() / it->second.usPerParticleStep * 100 << "%, "
          << s["wall_s_per_simulated_s"].get<double>() / it->second.wallPerSimS * 100 << "%)";
        ref = o.str();
      }
      // The density tolerance the run held (a solver without one: "-").
      std::string tol = "-";
      if (s.contains("solver_parameters") && s["solver_parameters"].contains("density_tolerance_pct")) {
        std::ostringstream o;
        o << s["solver_parameters"]["density_tolerance_pct"].get<double>();
        tol = o.str();
      }
      std::printf("%-18s %-6s %9zu %8zu %10.3f %10.1f %9.1f %10.2f %9.4f %9.3f %8s %8.0f  %s\n", stem.c_str(),
                  solver.c_str(), s["liquid_particles"].get<size_t>(), s["substeps"].get<size_t>(),
                  s["us_per_particle_step"].get<double>(), s["substeps_per_frame"].get<double>(),
                  s["ms_per_frame"].get<double>(), s["wall_s_per_simulated_s"].get<double>(), avgErr, maxErr,
                  tol.c_str(), s["peak_rss_mb"].get<double>(), ref.c_str());
      std::fflush(stdout);
      nlohmann::json row = s;
      row["scene_file"] = scene;
      row["mean_avg_density_error_pct"] = avgErr;
      row["max_density_error_pct"] = maxErr;
      results.push_back(row);
    }
  }
  if (!opt.out.empty()) writeJsonAtomically(opt.out, results);
  return worst;
}

}  // namespace

void addBenchSolverCommand(CLI::App& bench) {
  auto opt = std::make_shared<BenchOptions>();
  CLI::App* solver = bench.add_subcommand("solver", "pressure solvers on the reference dam breaks (scenes/bench)");
  solver->add_option("--scenes", opt->scenes, "scene files (default: scenes/bench/*.json)")->delimiter(',');
  solver->add_option("--solvers", opt->solvers, "solvers to compare")->delimiter(',');
  solver->add_option("--seconds", opt->seconds, "simulated seconds per run")->check(CLI::PositiveNumber);
  solver->add_option("--threads", opt->threads, "OpenMP threads")->check(CLI::PositiveNumber);
  solver->add_option("--out", opt->out, "also write the results as JSON");
  solver->callback([opt] {
    const int code = benchSolver(*opt);
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::bench
