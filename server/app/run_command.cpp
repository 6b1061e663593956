// `flowclip run SCENE.json`: simulate a scene headless, with a progress line,
// optional HDF5 export of every frame and a JSON stats file.
#include "app/commands.h"
#include "app/memory_breakdown.h"
#include "app/surface_options.h"
#include "export/from_simulation.h"
#include "cli/param_override.h"
#include "core/large_allocations.h"
#include "io/frame_export.h"
#include "io/instance_binding.h"
#include "io/scene.h"
#include "io/stats_json.h"
#include "sph/simulation.h"
#include <nlohmann/json.hpp>
#include <omp.h>
#include <unistd.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

namespace fc::app {

using namespace fc::cli;

namespace {

struct RunOptions {
  std::string scene;
  std::optional<int> frames;
  std::optional<double> seconds;
  std::string exportPath;
  std::string surfacePath;  // --export-surface DIR
  SurfaceOptions surface;
  std::string statsPath;
  int threads = 0;
  double particleRadius = 0;
  std::string scale;  // --scale NAME: the scene's named resolution
  std::string solver;
  std::string boundary;
  std::string templates = "templates";
  double templateMemoryMB = kDefaultTemplateMemoryMB;
  std::vector<std::string> controlSettings;  // KEY=VALUE, over the scene's "control" object
  std::vector<std::string> boundarySettings;  // KEY=VALUE, over the boundary model's parameters
  std::vector<std::string> solverSettings;    // KEY=VALUE, over the pressure solver's parameters
  double frameTimeout = 0;                    // s of wall time per frame (0: no limit)
  bool quiet = false;
};

// --control-setting KEY=VALUE: one of the scene's control settings
// (controlSettingsSpecs) replaced, checked as the scene file's would be
// (booleans as 0/1/true/false). `flowclip bench control` uses it to time
// forces_every_substep.
void overrideControlSettings(const std::vector<std::string>& overrides, ControlSettings& settings) {
  for (const auto& kv : overrides) {
    const ParamOverride o = parseParamOverride(controlSettingsSpecs(), kv, "--control-setting", "control");
    controlSettingsTable().assign(settings, o.spec->name, o.value);
  }
}

template <int D>
int runScene(const RunOptions& opt, const nlohmann::json& sceneJson) {
  SimulationSetup<D> setup = parseScene<D>(sceneJson, opt.particleRadius);
  std::string solverName = setup.solver.name.empty() ? "dfsph" : setup.solver.name;
  if (!opt.solver.empty()) {
    if (!PressureSolverRegistry<D>::instance().find(opt.solver))
      throw SceneError("solver.method", "unknown solver '" + opt.solver + "' given by --solver");
    // The scene's own solver keeps the scene's tolerances (the reference
    // benchmarks name theirs); another solver starts from its defaults, as
    // the scene's parameters belong to the solver it names.
    if (opt.solver != solverName) {
      setup.solver.name = solverName = opt.solver;
      setup.solver.values = ParamValues();
    }
  }
  const auto* solverEntry = PressureSolverRegistry<D>::instance().find(solverName);
  for (const auto& kv : opt.solverSettings) {
    if (!solverEntry) throw SceneError("solver.method", "unknown solver '" + solverName + "'");
    const ParamOverride o = parseParamOverride(solverEntry->params, kv, "--solver-setting", "solver");
    setup.solver.values.set(o.spec->name, o.value);
  }
  std::string boundaryName = setup.boundary.name.empty() ? std::string(kDefaultBoundaryModel) : setup.boundary.name;
  if (!opt.boundary.empty()) {
    if (!BoundaryModelRegistry<D>::instance().find(opt.boundary))
      throw SceneError("boundary.method", "unknown boundary method '" + opt.boundary + "' given by --boundary");
    if (opt.boundary != boundaryName) {
      setup.boundary.name = boundaryName = opt.boundary;
      setup.boundary.values = ParamValues();
    }
  }
  const auto* boundaryEntry = BoundaryModelRegistry<D>::instance().find(boundaryName);
  for (const auto& kv : opt.boundarySettings) {
    if (!boundaryEntry) throw SceneError("boundary.method", "unknown boundary method '" + boundaryName + "'");
    const ParamOverride o = parseParamOverride(boundaryEntry->params, kv, "--boundary-setting", "boundary");
    setup.boundary.values.set(o.spec->name, o.value);
  }
  SceneControl<D> control = parseSceneControl<D>(sceneJson, setup.phases);
  overrideControlSettings(opt.controlSettings, control.settings);
  Simulation<D> sim(setup);
  TemplateDatabase database(opt.templates, templateMemoryBytes(opt.templateMemoryMB));
  const auto tBind = std::chrono::steady_clock::now();
  const size_t instances = attachControl<D>(sim, control, database);
  const double bindS = std::chrono::duration<double>(std::chrono::steady_clock::now() - tBind).count();
  const double frameDt = sim.frameDuration();
  int frames = 0;
  if (opt.frames) frames = *opt.frames;
  else frames = int(std::lround((opt.seconds ? *opt.seconds : setup.duration) / frameDt));
  frames = std::max(frames, 0);

  std::unique_ptr<FrameExporter<D>> exporter;
  if (!opt.exportPath.empty()) {
    ExportHeader h;
    h.sceneName = setup.name;
    h.dimension = D;
    h.particleRadius = setup.particleRadius;
    h.frameRate = 1.0 / frameDt;
    h.phases = setup.phases;
    for (int d = 0; d < D; ++d) {
      h.domainMin.push_back(setup.domain.min[d]);
      h.domainMax.push_back(setup.domain.max[d]);
    }
    h.createdBy = std::string("flowclip ") + FLOWCLIP_VERSION;
    exporter = std::make_unique<FrameExporter<D>>(opt.exportPath, h);
    exporter->writeFrame(0, 0.0, sim.fluid);
  }
  std::unique_ptr<SurfaceExport> surfaces;
  if (!opt.surfacePath.empty()) {
    reuseLargeAllocations();
    ExportInfo info;
    info.name = std::filesystem::path(opt.scene).stem().string();
    info.directory = opt.surfacePath;
    info.dimension = D;
    info.particleRadius = setup.particleRadius;
    info.frameRate = 1.0 / frameDt;
    info.phases = setup.phases;
    info.createdBy = std::string("flowclip ") + FLOWCLIP_VERSION;
    surfaces = makeSurfaceExport(opt.surface, info);
    surfaces->writeFrame(particleFrame(sim.fluid, 0, 0.0));
  }

  // The solver's parameters as the run uses them (declared defaults, then
  // the scene's): a benchmark's figures mean little without its tolerances.
  // The same for the boundary model.
  const auto describe = [](const ParamSpecs* specs, const ParamValues& values, nlohmann::json& asJson) {
    std::string text;
    asJson = nlohmann::json::object();
    if (specs)
      for (const auto& spec : *specs) {
        const double v = values.has(spec.name) ? values.get(spec.name) : spec.def;
        asJson[spec.name] = v;
        char buf[96];
        std::snprintf(buf, sizeof buf, "%s%s=%g", text.empty() ? "" : " ", spec.name.c_str(), v);
        text += buf;
      }
    return text;
  };
  nlohmann::json solverParameters, boundaryParameters;
  const std::string solverText = describe(solverEntry ? &solverEntry->params : nullptr, setup.solver.values, solverParameters);
  const std::string boundaryText =
      describe(boundaryEntry ? &boundaryEntry->params : nullptr, setup.boundary.values, boundaryParameters);
  if (!opt.quiet)
    std::fprintf(stderr, "%s: %dD, %zu liquid + %zu boundary particles, solver %s (%s), boundary %s%s%s%s, %d threads, Real=%s\n",
                 setup.name.c_str(), D, sim.fluid.size(), sim.boundary.size(), solverName.c_str(), solverText.c_str(),
                 boundaryName.c_str(), boundaryText.empty() ? "" : " (", boundaryText.c_str(),
                 boundaryText.empty() ? "" : ")", omp_get_max_threads(), realName());
  if (!opt.quiet)
    for (size_t i = 0; i < setup.obstacles.size(); ++i)
      if (const auto& m = setup.obstacles[i].mesh)
        std::fprintf(stderr, "obstacles[%zu]: mesh %s, %zu triangles, signed-distance grid %dx%dx%d (%.1f MB) built in %.0f ms\n",
                     i, setup.obstacles[i].placement.file.c_str(), m->mesh().triangles.size(), m->dims()[0], m->dims()[1],
                     m->dims()[2], double(m->nodes() * sizeof(Real)) / 1e6, m->buildMs());
  if (!opt.quiet && instances)
    std::fprintf(stderr, "%zu template instances, templates loaded with their repulsion layers in %.2f s\n", instances,
                 bindS);

  nlohmann::json framesJson = nlohmann::json::array();
  const auto t0 = std::chrono::steady_clock::now();
  auto lastLine = t0;  // the last progress line
  double particleSteps = 0;
  size_t substeps = 0, unconverged = 0, unconvergedSubsteps = 0, escaped = 0, contacts = 0;
  double controlMs = 0;
  int status = Ok;
  std::string failure;
  const bool tty = isatty(fileno(stderr));
  // Ctrl-C stops the run after the current frame; what was simulated is
  // still exported and summarised.
  std::optional<InterruptGuard> interrupt(std::in_place);
  for (int f = 0; f < frames && !InterruptGuard::requested(); ++f) {
    if (opt.frameTimeout > 0)
      sim.setFrameLimits({std::chrono::steady_clock::now() +
                              std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                  std::chrono::duration<double>(opt.frameTimeout)),
                          nullptr});
    const FrameStats s = sim.advanceFrame();
    particleSteps += double(s.particles) * s.substeps;
    substeps += size_t(s.substeps);
    unconverged += s.converged ? 0 : 1;
    unconvergedSubsteps += size_t(s.unconvergedSubsteps);
    escaped += s.escapedParticles;
    contacts += s.wallContacts;
    controlMs += s.controlMs;
    if (!s.finite) {
      // A non-finite frame is never published: stop before exporting it.
      status = SimulationFailed;
      failure = failureText(s) + "; simulation stopped";
      break;
    }
    framesJson.push_back(frameStatsToJson(s, instances > 0));
    if (exporter) exporter->writeFrame(s.frame, s.time, sim.fluid);
    if (surfaces) surfaces->writeFrame(particleFrame(sim.fluid, s.frame, s.time));
    // Not on a terminal (a log, a batch task): every 5 % of the frames, and at least every 2 s.
    const bool due = std::chrono::steady_clock::now() - lastLine > std::chrono::seconds(2);
    if (!opt.quiet && (tty || f + 1 == frames || (f + 1) % std::max(1, frames / 20) == 0 || due)) {
      lastLine = std::chrono::steady_clock::now();
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const double eta = wall / (f + 1) * (frames - f - 1);
      const std::string ctrl =
          instances ? "  control " + std::to_string(int(std::lround(s.controlMs))) + " ms, " +
                          std::to_string(s.temporaryParticles) + " temporary"
                    : std::string();
      const std::string surface =
          surfaces ? "  surface " + std::to_string(int(std::lround(surfaces->surfaceMs() / surfaces->frames()))) + " ms"
                   : std::string();
      std::fprintf(stderr,
                   "%sframe %d/%d  t=%.3f s  %d substeps  iter %d/%d  err %.3f%%  %.1f ms/frame%s%s  ETA %.0f s%s",
                   tty ? "\r" : "", f + 1, frames, s.time, s.substeps, s.divergenceIterations, s.densityIterations,
                   s.avgDensityErrorPct, s.wallMs, ctrl.c_str(), surface.c_str(), eta, tty ? "   " : "\n");
      std::fflush(stderr);
    }
  }
  const bool interrupted = InterruptGuard::requested();
  interrupt.reset();
  if (!opt.quiet && tty) std::fprintf(stderr, "\n");
  if (interrupted) {
    std::fprintf(stderr, "interrupted after %zu frames: keeping what was simulated\n", framesJson.size());
    status = Interrupted;
  }
  if (exporter) exporter->close();
  // A surface export is complete (has its manifest) only when every frame asked for was simulated.
  if (surfaces && status == Ok) surfaces->close();

  const double wallS = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const double simS = double(framesJson.size()) * frameDt;
  nlohmann::json summary = {
      {"scene", setup.name},
      {"dimension", D},
      {"solver", solverName},
      {"solver_parameters", solverParameters},
      {"boundary", boundaryName},
      {"boundary_parameters", boundaryParameters},
      {"boundary_setup_ms", sim.boundarySetupMs()},
      {"boundary_model_bytes", sim.boundaryModelBytes()},
      {"real", realName()},
      {"threads", omp_get_max_threads()},
      {"frames", framesJson.size()},
      {"simulated_s", simS},
      {"wall_s", wallS},
      {"wall_s_per_simulated_s", simS > 0 ? wallS / simS : 0},
      {"substeps", substeps},
      {"substeps_per_frame", framesJson.empty() ? 0.0 : double(substeps) / double(framesJson.size())},
      {"ms_per_frame", framesJson.empty() ? 0.0 : wallS * 1000.0 / double(framesJson.size())},
      {"us_per_particle_step", particleSteps > 0 ? wallS * 1e6 / particleSteps : 0},
      {"liquid_particles", sim.fluid.size()},
      {"boundary_particles", sim.boundary.size()},
      {"unconverged_frames", unconverged},
      {"unconverged_substeps", unconvergedSubsteps},
      {"escaped_particles", escaped},
      {"wall_contacts", contacts},
      {"peak_rss_mb", peakRssMb()},
      {"memory_bytes", memoryBreakdown(sim)},
      {"pipeline", sim.pipelineStages()},
      {"status", status == Ok ? "ok" : status == Interrupted ? "interrupted" : "failed"}};
  if (instances) {
    summary["instances"] = instances;
    summary["control_ms_per_frame"] = framesJson.empty() ? 0.0 : controlMs / double(framesJson.size());
    // Control's share next to the simulation's, as the paper's Table 1.
    summary["control_overhead_pct"] = wallS * 1000 > controlMs ? 100.0 * controlMs / (wallS * 1000 - controlMs) : 0.0;
    summary["template_bind_s"] = bindS;
    nlohmann::json streamed = nlohmann::json::array();
    for (const auto& t : database.streamedTemplates()) {
      streamed.push_back({{"name", t.name}, {"frames", t.frames}, {"cache_mb", double(t.cacheBytes) / 1048576.0},
                          {"peak_mb", double(t.peakBytes) / 1048576.0}, {"frames_read", t.loads},
                          {"frames_reused", t.hits}, {"read_s", t.loadSeconds}});
      if (!opt.quiet)
        std::fprintf(stderr,
                     "template %s streamed from its file: %zu of its frames read (%zu reused), at most %.0f MB of "
                     "its %.0f MB cache held, %.2f s reading and building\n",
                     t.name.c_str(), t.loads, t.hits, double(t.peakBytes) / 1048576.0,
                     double(t.cacheBytes) / 1048576.0, t.loadSeconds);
    }
    if (!streamed.empty()) summary["templates_streamed"] = streamed;
  }
  if (surfaces) {
    summary["surface_ms_per_frame"] = surfaces->frames() ? surfaces->surfaceMs() / surfaces->frames() : 0.0;
    summary["surface_export_bytes"] = surfaces->bytesWritten();
  }
  if (!failure.empty()) summary["error"] = failure;
  if (!opt.statsPath.empty()) writeJsonAtomically(opt.statsPath, {{"frames", framesJson}, {"summary", summary}});
  if (!opt.quiet) {
    std::fprintf(stderr,
                 "summary: %zu frames (%.2f simulated s) in %.2f s wall = %.2f wall s per simulated s; %.3f us per "
                 "particle-step; %.1f substeps/frame; peak RSS %.0f MB%s\n",
                 framesJson.size(), simS, wallS, simS > 0 ? wallS / simS : 0.0,
                 particleSteps > 0 ? wallS * 1e6 / particleSteps : 0.0,
                 framesJson.empty() ? 0.0 : double(substeps) / double(framesJson.size()), peakRssMb(),
                 unconverged ? (", " + std::to_string(unconverged) + " frames did not converge").c_str() : "");
  }
  if (!failure.empty()) std::fprintf(stderr, "error: %s\n", failure.c_str());
  return status;
}

}  // namespace

void addRunCommand(CLI::App& app) {
  auto opt = std::make_shared<RunOptions>();
  CLI::App* run = app.add_subcommand("run", "simulate a scene headless");
  run->add_option("scene", opt->scene, "scene file (JSON)")->required();
  auto* fr = run->add_option("--frames", opt->frames, "number of frames to simulate")->check(CLI::NonNegativeNumber);
  run->add_option("--seconds", opt->seconds, "simulated seconds (default: the scene's duration)")
      ->check(CLI::NonNegativeNumber)
      ->excludes(fr);
  run->add_option("--export", opt->exportPath, "write every frame's particles to this HDF5 file");
  run->add_option("--export-surface", opt->surfacePath,
                  "write every frame's surface, meshes or point caches into this directory (--formats; "
                  "docs/surfaces.md)");
  run->add_option("--stats", opt->statsPath, "write per-frame statistics and a summary to this JSON file");
  run->add_option("--threads", opt->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  auto* radius = run->add_option("--particle-radius", opt->particleRadius,
                                 "override the scene's particle radius (resolution), m")
                     ->check(CLI::PositiveNumber);
  run->add_option("--scale", opt->scale,
                  "run at one of the scene's named resolutions (\"scales\", e.g. paper); templates then come from "
                  "TEMPLATES/NAME")
      ->excludes(radius);
  run->add_option("--solver", opt->solver, "override the scene's pressure solver (a different one runs with its default parameters)");
  run->add_option("--solver-setting", opt->solverSettings,
                  "set a parameter of the pressure solver, KEY=VALUE (e.g. density_tolerance_pct=0.02); repeatable");
  run->add_option("--boundary", opt->boundary,
                  "override the scene's boundary model (a different one runs with its default parameters)");
  run->add_option("--boundary-setting", opt->boundarySettings,
                  "set a parameter of the boundary model, KEY=VALUE (e.g. constraint=1); repeatable");
  run->add_option("--templates", opt->templates,
                  "template database directory (default: templates, or templates/NAME with --scale NAME)");
  addTemplateMemoryOption(run, opt->templateMemoryMB);
  run->add_option("--frame-timeout", opt->frameTimeout,
                  "stop with exit status 3 if one frame takes longer than this many wall seconds (default: no limit)")
      ->check(CLI::NonNegativeNumber);
  run->add_option("--control-setting", opt->controlSettings,
                  "override a control setting of the scene, KEY=VALUE (e.g. forces_every_substep=1); repeatable");
  run->add_flag("--quiet", opt->quiet, "no progress line or summary");
  addSurfaceOptions(run, opt->surface);
  run->callback([opt, run] {
    if (opt->threads > 0) omp_set_num_threads(opt->threads);
    int code = Ok;
    try {
      nlohmann::json j = loadSceneJson(opt->scene);
      RunOptions o = *opt;
      if (!o.scale.empty()) {
        if (!run->count("--templates")) o.templates = scaledTemplatesDir(o.templates, j, o.scale);
        j = applySceneScale(j, o.scale);
      }
      code = sceneDimension(j) == 2 ? runScene<2>(o, j) : runScene<3>(o, j);
    } catch (...) {
      code = reportError(opt->scene, Failure);
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::app
