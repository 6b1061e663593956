// `flowclip bench solver`: the pressure solvers (and, with --boundaries, the
// boundary models) on the reference dam breaks (scenes/bench). Each (scene,
// solver, boundary) runs in its own child process
// (`flowclip run --stats`), so that peak RSS is that run's alone. Writes
// solver.md and solver.json (bench/report.h) into --out.
#include "bench/commands.h"
#include "bench/report.h"
#include "cli/exit_codes.h"
#include "cli/process.h"
#include <nlohmann/json.hpp>
#include <omp.h>
#include <unistd.h>
#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace fc::bench {

using namespace fc::cli;

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

// SPlisHSPlasH DFSPH figures read once, on one machine (single precision,
// AVX2, -O3 -march=native, OpenMP, kReferenceThreads threads, volume-map
// boundaries): µs per particle-step and wall s per simulated s. Figures from another machine do
// not divide; tools/bench_reference.py times SPlisHSPlasH on this one
// (docs/benchmarks/solver.md).
constexpr int kReferenceThreads = 2;
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

// The solver's stages as the frames' stats time them (wall ms per frame).
constexpr std::array<std::pair<const char*, const char*>, 5> kStages = {{
    {"neighbor_ms", "neighbour search"},
    {"density_ms", "densities and gradients"},
    {"divergence_ms", "divergence solve"},
    {"non_pressure_ms", "viscosity and other accelerations"},
    {"pressure_ms", "density solve"},
}};

struct BenchOptions {
  std::vector<std::string> scenes;
  std::vector<std::string> solvers{"dfsph", "wcsph"};
  std::vector<std::string> boundaries;  // empty: each scene's own
  double seconds = 2;
  int threads = 0;
  int rounds = 1;  // every run this many times, taking turns; the fastest is reported
  std::string out = "bench/solver";
};

// One run's row: the child's summary, with what the bench reads from its
// frames (density errors, iterations and stage times per substep) and the
// fixed SPlisHSPlasH figures where there are some.
json runRow(const std::string& scene, const std::string& solver, const json& stats) {
  const json& s = stats.at("summary");
  double avgErr = 0, maxErr = 0, divergenceIterations = 0, densityIterations = 0;
  std::map<std::string, double> stageMs;
  for (const auto& fr : stats.at("frames")) {
    avgErr += fr.at("avg_density_error_pct").get<double>();
    maxErr = std::max(maxErr, fr.at("max_density_error_pct").get<double>());
    divergenceIterations += fr.at("divergence_iterations").get<double>();
    densityIterations += fr.at("density_iterations").get<double>();
    for (const auto& [key, label] : kStages) stageMs[key] += fr.at(key).get<double>();
  }
  const auto& frames = stats.at("frames");
  if (!frames.empty()) avgErr /= double(frames.size());
  // What is still moving: the kinetic energy over the run's last quarter, the fastest particle at its end.
  const size_t late = frames.empty() ? 0 : std::max<size_t>(frames.size() / 4, 1);
  double lateKe = 0;
  for (size_t k = frames.size() - late; k < frames.size(); ++k) lateKe += frames[k].at("kinetic_energy").get<double>();
  const double substeps = std::max(1.0, s.at("substeps").get<double>());
  json row = s;
  const std::string stem = fs::path(scene).stem().string();
  row["scene_file"] = scene;
  row["bench_scene"] = stem;
  row["mean_avg_density_error_pct"] = avgErr;
  row["late_kinetic_energy"] = late ? lateKe / double(late) : 0.0;
  row["final_max_speed"] = frames.empty() ? 0.0 : frames.back().at("max_speed").get<double>();
  row["max_density_error_pct"] = maxErr;
  row["divergence_iterations_per_substep"] = divergenceIterations / substeps;
  row["density_iterations_per_substep"] = densityIterations / substeps;
  json stages = json::object();
  double total = 0;
  for (const auto& [key, ms] : stageMs) {
    stages[key] = ms / substeps;
    total += ms / substeps;
  }
  stages["total_ms"] = total;
  row["stage_ms_per_substep"] = stages;
  // The density tolerance the run held (a solver without one: null).
  const json params = s.value("solver_parameters", json::object());
  row["density_tolerance_pct"] = params.value("density_tolerance_pct", json(nullptr));
  const auto it = splishsplashReference().find(stem);
  if (it != splishsplashReference().end() && solver == "dfsph")
    row["splishsplash_fixed"] = {
        {"us_per_particle_step", it->second.usPerParticleStep},
        {"wall_s_per_simulated_s", it->second.wallPerSimS},
        {"threads", kReferenceThreads},
        {"ours_us_pct", s.at("us_per_particle_step").get<double>() / it->second.usPerParticleStep * 100},
        {"ours_wall_pct", s.at("wall_s_per_simulated_s").get<double>() / it->second.wallPerSimS * 100}};
  return row;
}

std::string markdown(const json& rows, const json& failures, int rounds) {
  std::vector<std::vector<std::string>> runs, stages, reference;
  for (const json& r : rows) {
    const std::string scene = r["bench_scene"], solver = r["solver"], boundary = r["boundary"];
    const json& tol = r["density_tolerance_pct"];
    runs.push_back({scene, solver, boundary, std::to_string(r["liquid_particles"].get<long>()),
                    std::to_string(r["substeps"].get<long>()), fmt(r["us_per_particle_step"], "%.3f"),
                    fmt(r["substeps_per_frame"], "%.1f"), fmt(r["ms_per_frame"], "%.1f"),
                    fmt(r["wall_s_per_simulated_s"], "%.2f"), fmt(r["mean_avg_density_error_pct"], "%.4f"),
                    fmt(r["max_density_error_pct"], "%.3f"), tol.is_number() ? fmt(tol) : "-",
                    fmt(r.value("late_kinetic_energy", 0.0), "%.3g"), fmt(r.value("final_max_speed", 0.0), "%.3f"),
                    fmt(r["peak_rss_mb"], "%.0f"), fmt(r["boundary_setup_ms"], "%.1f"),
                    fmt(r["boundary_model_bytes"].get<double>() / 1048576.0, "%.2f")});
    const json& st = r["stage_ms_per_substep"];
    std::vector<std::string> cells{scene, solver, boundary};
    for (const auto& [key, label] : kStages) cells.push_back(fmt(st[key], "%.2f"));
    cells.push_back(fmt(st["total_ms"], "%.2f"));
    cells.push_back(fmt(r["divergence_iterations_per_substep"], "%.2f"));
    cells.push_back(fmt(r["density_iterations_per_substep"], "%.2f"));
    stages.push_back(cells);
    if (r.contains("splishsplash_fixed")) {
      const json& ref = r["splishsplash_fixed"];
      reference.push_back({scene, fmt(r["us_per_particle_step"], "%.3f"), fmt(ref["us_per_particle_step"], "%.2f"),
                           fmt(ref["ours_us_pct"], "%.0f") + " %", fmt(r["wall_s_per_simulated_s"], "%.2f"),
                           fmt(ref["wall_s_per_simulated_s"], "%.1f"), fmt(ref["ours_wall_pct"], "%.0f") + " %"});
    }
  }
  std::string md = "## Runs\n\nPer run: particles and steps (substeps) over the run; the density errors are the "
                   "solver's own figures per frame (average over frames of the per-frame average, and the largest); "
                   "the density tolerance is the one the run held; what still moves at the end (J/m in 2D); the "
                   "boundary model's set-up (a volume map's integration) and the memory it holds beside the boundary "
                   "samples.";
  if (rounds > 1)
    md += " Each row is the fastest (wall s per simulated s) of " + std::to_string(rounds) +
          " rounds in which the runs took turns; every round's figures are in the JSON (`*_all`).";
  md += "\n\n";
  md += markdownTable({"scene", "solver", "boundary", "particles", "steps", "µs / particle-step", "substeps / frame",
                       "ms / frame", "wall s / simulated s", "avg density error %", "max density error %",
                       "density tolerance %", "kinetic energy, last quarter, J", "max speed at the end, m/s",
                       "peak RSS MB", "boundary set-up ms", "boundary map MB"},
                      runs);
  md += "\n## Where the time goes\n\nWall ms per substep in each stage of the step, and solver iterations per "
        "substep.\n\n";
  std::vector<std::string> header{"scene", "solver", "boundary"};
  for (const auto& [key, label] : kStages) header.push_back(label);
  for (const char* h : {"total", "divergence iterations", "density iterations"}) header.push_back(h);
  md += markdownTable(header, stages);
  if (!reference.empty()) {
    md += "\n## Against fixed SPlisHSPlasH figures\n\nDFSPH runs divided by SPlisHSPlasH figures compiled into the "
          "benchmark, read once on another machine with " +
          std::to_string(kReferenceThreads) +
          " threads: indicative only; tools/bench_reference.py runs both on the same machine.\n\n";
    md += markdownTable({"scene", "µs / particle-step", "SPlisHSPlasH", "ours / theirs", "wall s / simulated s",
                         "SPlisHSPlasH", "ours / theirs"},
                        reference);
  }
  if (!failures.empty()) {
    md += "\n## Failed runs\n\n";
    for (const json& f : failures)
      md += "- " + f["scene"].get<std::string>() + " with " + f["solver"].get<std::string>() + " (" +
            f["boundary"].get<std::string>() + "): exit " +
            std::to_string(f["exit_code"].get<int>()) + "\n";
  }
  return md;
}

int benchSolver(const BenchOptions& opt) {
  const std::vector<std::string> scenes = opt.scenes.empty() ? sceneFilesIn("scenes/bench") : opt.scenes;
  if (scenes.empty()) {
    std::fprintf(stderr, "error: no bench scenes found (scenes/bench/*.json)\n");
    return BadInput;
  }
  const int threads = opt.threads > 0 ? opt.threads : omp_get_max_threads();
  const Report report("solver", threads);
  const std::string self = selfExecutable();
  const std::string tmp = (fs::temp_directory_path() / ("flowclip-bench-" + std::to_string(getpid()) + ".json")).string();
  json rows = json::array(), failures = json::array();
  int worst = Ok;
  struct Run {
    std::string scene, solver, boundary;
    json best, wallAll = json::array(), usAll = json::array();
  };
  std::vector<Run> runs;
  const std::vector<std::string> boundaries = opt.boundaries.empty() ? std::vector<std::string>{""} : opt.boundaries;
  for (const auto& scene : scenes)
    for (const auto& solver : opt.solvers)
      for (const auto& boundary : boundaries) runs.push_back({scene, solver, boundary, json(), json::array(), json::array()});
  // Rounds outermost: the runs of one round take turns with the others', so the host's drift reaches all alike.
  for (int round = 1; round <= opt.rounds; ++round)
    for (Run& run : runs) {
      const std::string& scene = run.scene;
      const std::string& solver = run.solver;
      const std::string& boundary = run.boundary;
      const std::string stem = fs::path(scene).stem().string();
      std::vector<std::string> args{self, "run", scene, "--seconds", fmt(opt.seconds), "--stats", tmp,
                                    "--threads", std::to_string(threads), "--quiet"};
      // NAME or NAME:KEY=VALUE:KEY=VALUE, a solver or a model with some of its parameters set.
      const auto named = [&args](const std::string& spec, const char* nameFlag, const char* settingFlag) {
        size_t at = spec.find(':');
        args.insert(args.end(), {nameFlag, spec.substr(0, at)});
        while (at != std::string::npos) {
          const size_t next = spec.find(':', at + 1);
          args.insert(args.end(), {settingFlag, spec.substr(at + 1, next == std::string::npos ? next : next - at - 1)});
          at = next;
        }
      };
      named(solver, "--solver", "--solver-setting");
      if (!boundary.empty()) named(boundary, "--boundary", "--boundary-setting");
      const std::string label = stem + " with " + solver + (boundary.empty() ? "" : " (" + boundary + ")");
      const std::string roundText =
          opt.rounds > 1 ? " [round " + std::to_string(round) + "/" + std::to_string(opt.rounds) + "]" : "";
      std::fprintf(stderr, "bench: %s%s ...\n", label.c_str(), roundText.c_str());
      const int code = runChild(args);
      std::ifstream f(tmp);
      if (code != 0 || !f) {
        std::printf("%s%s: failed (exit %d)\n", label.c_str(), roundText.c_str(), code);
        failures.push_back({{"scene", stem}, {"solver", solver},
                            {"boundary", boundary.empty() ? "the scene's" : boundary}, {"exit_code", code},
                            {"round", round}});
        worst = Failure;
        continue;
      }
      json row = runRow(scene, solver, json::parse(f));
      row["solver"] = solver;                             // with the parameters it was given
      if (!boundary.empty()) row["boundary"] = boundary;
      f.close();
      fs::remove(tmp);
      std::printf("%s%s: %ld particles, %.3f us per particle-step, %.2f wall s per simulated s, %.2f density "
                  "iterations per substep, peak RSS %.0f MB\n",
                  label.c_str(), roundText.c_str(), row["liquid_particles"].get<long>(),
                  row["us_per_particle_step"].get<double>(), row["wall_s_per_simulated_s"].get<double>(),
                  row["density_iterations_per_substep"].get<double>(), row["peak_rss_mb"].get<double>());
      std::fflush(stdout);
      run.wallAll.push_back(row["wall_s_per_simulated_s"]);
      run.usAll.push_back(row["us_per_particle_step"]);
      if (run.best.is_null() || row["wall_s_per_simulated_s"].get<double>() < run.best["wall_s_per_simulated_s"].get<double>())
        run.best = std::move(row);
    }
  for (Run& run : runs) {
    if (run.best.is_null()) continue;  // every round failed: listed under failures
    run.best["rounds"] = run.wallAll.size();
    run.best["wall_s_per_simulated_s_all"] = run.wallAll;
    run.best["us_per_particle_step_all"] = run.usAll;
    rows.push_back(std::move(run.best));
  }
  const json settings = {{"scenes", scenes},           {"solvers", opt.solvers}, {"boundaries", opt.boundaries},
                         {"seconds", opt.seconds},       {"threads", threads},     {"rounds", opt.rounds}};
  report.write(opt.out, "Solver benchmark", markdown(rows, failures, opt.rounds),
               {{"settings", settings}, {"runs", rows}, {"failures", failures}});
  return worst;
}

}  // namespace

void addBenchSolverCommand(CLI::App& bench) {
  auto opt = std::make_shared<BenchOptions>();
  CLI::App* solver = bench.add_subcommand("solver", "pressure solvers on the reference dam breaks (scenes/bench)");
  solver->add_option("--scenes", opt->scenes, "scene files (default: scenes/bench/*.json)")->delimiter(',');
  solver->add_option("--solvers", opt->solvers,
                     "solvers to compare, each NAME or NAME:KEY=VALUE[:KEY=VALUE] (e.g. dfsph:density_tolerance_pct=0.02)")
      ->delimiter(',');
  solver->add_option("--boundaries", opt->boundaries,
                     "boundary models to compare, each NAME or NAME:KEY=VALUE[:KEY=VALUE] (default: each scene's own)")
      ->delimiter(',');
  solver->add_option("--seconds", opt->seconds, "simulated seconds per run")->check(CLI::PositiveNumber);
  solver->add_option("--threads", opt->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  solver->add_option("--rounds", opt->rounds,
                     "run every case this many times, the cases taking turns, and report each one's fastest (default 1)")
      ->check(CLI::Range(1, 100));
  solver->add_option("--out", opt->out, "report folder: solver.md and solver.json (default: bench/solver)");
  solver->callback([opt] {
    int code = Ok;
    try {
      code = benchSolver(*opt);
    } catch (...) {
      code = reportError("bench solver", Failure);
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::bench
