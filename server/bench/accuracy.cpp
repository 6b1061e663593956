// `flowclip bench accuracy [--quick]`: every knob that trades accuracy for
// time, swept on reference scenes (docs/benchmarks/accuracy.md). Each point is
// the reference scene with some knobs changed, run in its own child process
// (`flowclip run --stats --export`), so that every point starts clean. Cost
// comes from the child's per-frame simulation time (export excluded);
// accuracy from its stats and from the exported particles:
//   - density error: the liquid's compression max(ρ/ρ0 - 1, 0) in the
//     exported frames (average over frames of the per-frame average, and the
//     largest), beside what the solver reported at exit;
//   - volume drift: Σ m/max(ρ,ρ0) relative to the rest volume, last frame
//     against the first simulated frame;
//   - the 2D dam break's surge front against Martin & Moyce (1952) [MM52], RMS of
//     Z = x/a over their points T = t sqrt(2g/a) (bench/data);
//   - the template scenes' control fidelity (IoU), averaged over the frames
//     where an instance plays;
//   - the resting columns' rows, closest approach, top, speed after 1 s and
//     pressure against ρ0 g h, per boundary model (measureRestingColumn).
// Writes accuracy.csv, accuracy.md, surge_fronts.csv, presets.json and the
// plots (tools/plot_accuracy.py). With --local N or --scheduler ADDR the
// children run as tasks of a Dask cluster (`flowclip-batch commands`, the
// Python package's) instead of one after the other; the figures are read the same way.
// One file: the sweep's points, their runs and the report are one benchmark.
#include "bench/accuracy_metrics.h"
#include "bench/commands.h"
#include "bench/exported_frames.h"
#include "bench/report.h"
#include "cli/exit_codes.h"
#include "cli/json_file.h"
#include "cli/process.h"
#include "control/instance.h"
#include "io/scene.h"
#include "sph/builtin.h"
#include "sph/settings.h"
#include "sph/simulation.h"
#include <nlohmann/json.hpp>
#include <omp.h>
#include <sys/resource.h>
#include <unistd.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <sstream>

namespace fc::bench {

using namespace fc::cli;

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

// ---------------------------------------------------------------------------
// Knobs: where each lives in a scene file. One table; the CSV's knob columns
// follow it.

enum class Place { Top, Solver, Settings, Control, Instances };

struct Knob {
  const char* name;    // scene key and CSV column
  Place place;
  const char* method;  // Place::Solver: the pressure solver the key belongs to
};

const std::vector<Knob>& knobs() {
  static const std::vector<Knob> k = {
      {"particle_radius", Place::Top, nullptr},
      {"density_tolerance_pct", Place::Solver, "dfsph"},
      {"divergence_tolerance_pct", Place::Solver, "dfsph"},
      {"stiffness", Place::Solver, "wcsph"},
      {"cfl_factor", Place::Settings, nullptr},
      {"forces_every_substep", Place::Control, nullptr},
      {"repulsion", Place::Instances, nullptr},
      {"temporary_particles", Place::Instances, nullptr},
      {"falloff_width", Place::Instances, nullptr},
  };
  return k;
}

const Knob& knob(const std::string& name) {
  for (const Knob& k : knobs())
    if (name == k.name) return k;
  throw std::logic_error("bench accuracy: undeclared knob '" + name + "'");
}

const ParamSpec* knobSpec(const Knob& k) {
  switch (k.place) {
    case Place::Top: return nullptr;
    case Place::Solver: {
      const auto* entry = PressureSolverRegistry<2>::instance().find(k.method);
      return entry ? findSpec(entry->params, k.name) : nullptr;
    }
    case Place::Settings: return findSpec(simulationSettingsSpecs(), k.name);
    case Place::Control: return findSpec(controlSettingsSpecs(), k.name);
    case Place::Instances: return findSpec(instanceParamSpecs(2), k.name);
  }
  return nullptr;
}

std::string sceneMethod(const json& scene) {
  return scene.contains("solver") ? scene["solver"].value("method", std::string("dfsph")) : "dfsph";
}
// The scene's boundary model (the default where the file names none) and
// the parameters the file sets, "adami2012 constraint=1".
std::string sceneBoundary(const json& scene) {
  const json* b = scene.contains("boundary") ? &scene["boundary"] : nullptr;
  std::string s = b && b->contains("method") ? (*b)["method"].get<std::string>() : std::string(kDefaultBoundaryModel);
  if (b)
    for (const auto& [key, value] : b->items())
      if (key != "method")
        s += " " + key + "=" +
             (value.is_boolean() ? fmt(double(value.get<bool>())) : value.is_number() ? fmt(value.get<double>()) : value.dump());
  return s;
}
bool hasInstances(const json& scene) { return scene.contains("instances") && !scene["instances"].empty(); }

// The knob's value in `scene` (its default where the file leaves it out), or
// nothing where it does not apply: another solver's parameter, a control
// knob in a scene without instances.
std::optional<double> knobValue(const json& scene, const Knob& k) {
  const ParamSpec* spec = knobSpec(k);
  const auto read = [&](const json& o) -> std::optional<double> {
    if (o.contains(k.name)) return o[k.name].is_boolean() ? double(o[k.name].get<bool>()) : o[k.name].get<double>();
    return spec ? std::optional<double>(spec->def) : std::nullopt;
  };
  switch (k.place) {
    case Place::Top: return read(scene);
    case Place::Solver:
      if (sceneMethod(scene) != k.method) return std::nullopt;
      return read(scene.value("solver", json::object()));
    case Place::Settings: return read(scene.value("settings", json::object()));
    case Place::Control:
      if (!hasInstances(scene)) return std::nullopt;
      return read(scene.value("control", json::object()));
    case Place::Instances:
      if (!hasInstances(scene)) return std::nullopt;
      return read(scene["instances"][0]);
  }
  return std::nullopt;
}

void setKnob(json& scene, const Knob& k, double v) {
  const ParamSpec* spec = knobSpec(k);
  const json value = spec && spec->type == ParamType::Boolean ? json(v != 0) : json(v);
  switch (k.place) {
    case Place::Top: scene[k.name] = value; break;
    case Place::Solver: scene["solver"][k.name] = value; break;
    case Place::Settings: scene["settings"][k.name] = value; break;
    case Place::Control: scene["control"][k.name] = value; break;
    case Place::Instances:
      for (json& inst : scene["instances"]) inst[k.name] = value;
      break;
  }
}

// ---------------------------------------------------------------------------
// Reference scenes: what each is measured for.

struct Reference {
  const char* scene;   // stem of scenes/<scene>.json
  bool surge;          // Martin & Moyce surge front (a column of width a, height 2a, at the left wall)
  bool fidelity;       // template instances: control fidelity IoU
  bool rest = false;   // a column resting in a box: its distance from the walls, surface, speed and pressure
};

const std::vector<Reference>& references() {
  static const std::vector<Reference> r = {
      {"dambreak2d", true, false},
      {"drop2d", false, true},
      {"zero_gravity2d", false, true},
      {"wave2d", false, true},
      {"waterjet2d", false, true},
      {"doubledam2d", false, true},
      {"blade2d", false, true},
      {"hydrostatic2d", false, false, true},
      {"hydrostatic3d", false, false, true},
  };
  return r;
}

const Reference& reference(const std::string& scene) {
  for (const Reference& r : references())
    if (scene == r.scene) return r;
  throw std::logic_error("bench accuracy: '" + scene + "' is not a reference scene");
}

// ---------------------------------------------------------------------------
// The sweep.

struct Point {
  std::string group;    // solver | boundary | resolution | precision | control | templates
  std::string scene;    // a reference scene
  std::string method;   // pressure solver; empty: the scene's
  std::string real = "float";
  std::vector<std::pair<std::string, double>> set;  // knob overrides
  double seconds = 0;  // simulated
  json boundary;         // the scene's boundary section; null: the scene's
};

// Opt-in forms of a registered boundary model, priced beside the models'
// defaults: each a boundary section of a scene.
const std::vector<json>& boundaryVariants() {
  static const std::vector<json> variants = {{{"method", "adami2012"}, {"constraint", true}}};
  return variants;
}

struct Sweep {
  double damSeconds;                 // the dam break: long enough for Martin & Moyce's last point (T = 3.33)
  double templateSeconds;            // template scenes (their instances play from 0.1-0.2 s)
  double coarseRadius, fineRadius;   // resolution levels around the scene's own
  std::vector<double> densityTolerances, divergenceTolerances, cflFactors, stiffnesses;
  bool fullGrid;                     // every tolerance pair x CFL, else one knob at a time
  double controlRadius;              // drop2d's resolution in the control sweep (0: the scene's)
  std::vector<double> falloffWidths;
  bool templateScenes;               // the other 2D template scenes at their defaults
  std::vector<std::string> restScenes;  // resting columns, each with every boundary model
};

// A resting column's run: settled over its last half second, its speed from 1 s on.
constexpr double kRestSeconds = 2.0, kRestSettledFrom = 1.5, kRestSpeedFrom = 1.0;

// Full: at the scenes' own resolutions, the tolerance x CFL grid complete.
// Quick (`make test`'s smoke run, minutes): coarse, short, one knob at a time.
Sweep sweepFor(bool quick) {
  if (quick) return {0.6, 0.8, 0.02, 0, {1, 0.1, 0.01}, {1, 0.1, 0.01}, {0.5, 1, 1.5}, {50000}, false, 0.006, {0.1},
                     false, {"hydrostatic2d"}};
  return {0.8, 1.2, 0.01, 0.0035, {1, 0.1, 0.01}, {1, 0.1, 0.01}, {0.5, 1, 1.5}, {50000}, true, 0, {0.02, 0.1},
          true, {"hydrostatic2d", "hydrostatic3d"}};
}

std::vector<Point> sweepPoints(const Sweep& s, bool quick, bool withDouble) {
  std::vector<Point> pts;
  const auto dfsph = [&](const std::string& group, double dens, double div, double cfl, double radius,
                         const std::string& real, const json& boundary = nullptr) {
    Point p{group, "dambreak2d", "dfsph", real, {{"density_tolerance_pct", dens}, {"divergence_tolerance_pct", div},
                                                {"cfl_factor", cfl}}, s.damSeconds, boundary};
    if (radius > 0) p.set.push_back({"particle_radius", radius});
    pts.push_back(p);
  };
  const auto wcsph = [&](const std::string& group, double stiffness, double cfl, double radius,
                         const std::string& real) {
    Point p{group, "dambreak2d", "wcsph", real, {{"stiffness", stiffness}, {"cfl_factor", cfl}}, s.damSeconds, nullptr};
    if (radius > 0) p.set.push_back({"particle_radius", radius});
    pts.push_back(p);
  };
  // The quick run measures at the coarse level throughout.
  const double solverRadius = quick ? 0.01 : 0;
  if (s.fullGrid) {
    for (double dens : s.densityTolerances)
      for (double div : s.divergenceTolerances)
        for (double cfl : s.cflFactors) dfsph("solver", dens, div, cfl, solverRadius, "float");
  } else {
    for (double dens : s.densityTolerances) dfsph("solver", dens, 0.1, 1, solverRadius, "float");
    for (double div : s.divergenceTolerances)
      if (div != 0.1) dfsph("solver", 0.1, div, 1, solverRadius, "float");
    for (double cfl : s.cflFactors)
      if (cfl != 1) dfsph("solver", 0.1, 0.1, cfl, solverRadius, "float");
  }
  for (double k : s.stiffnesses)
    for (double cfl : s.fullGrid ? s.cflFactors : std::vector<double>{1})
      wcsph("solver", k, cfl, solverRadius, "float");

  // Boundary models: every registered one and the opt-in variants on the
  // dam break at 0.1/0.1 %, CFL 1, then holding a column at rest at the
  // scenes' own settings.
  std::vector<json> models;
  for (const std::string& model : BoundaryModelRegistry<2>::instance().names()) models.push_back({{"method", model}});
  models.insert(models.end(), boundaryVariants().begin(), boundaryVariants().end());
  for (const json& model : models) dfsph("boundary", 0.1, 0.1, 1, solverRadius, "float", model);
  for (const std::string& scene : s.restScenes)
    for (const json& model : models) pts.push_back({"rest", scene, "", "float", {}, kRestSeconds, model});

  // Resolution and precision: the tolerance diagonal and WCSPH, at CFL 1.
  const std::vector<double> diagonal = quick ? std::vector<double>{0.1} : s.densityTolerances;
  for (double radius : {s.coarseRadius, s.fineRadius}) {
    if (radius <= 0) continue;
    for (double tol : diagonal) dfsph("resolution", tol, tol, 1, radius, "float");
    if (!quick) wcsph("resolution", s.stiffnesses.front(), 1, radius, "float");
  }
  if (withDouble) {
    for (double tol : diagonal) dfsph("precision", tol, tol, 1, solverRadius, "double");
    wcsph("precision", s.stiffnesses.front(), 1, solverRadius, "double");
  }

  // Control on the rectangular drop: each knob away from its default, and
  // the scene's solver at the ends of the tolerance range.
  const auto drop = [&](std::vector<std::pair<std::string, double>> set, const std::string& method = "") {
    if (s.controlRadius > 0) set.push_back({"particle_radius", s.controlRadius});
    pts.push_back({"control", "drop2d", method, "float", set, s.templateSeconds, nullptr});
  };
  drop({});
  drop({{"forces_every_substep", 1}});
  drop({{"repulsion", 0}});
  drop({{"temporary_particles", 0}});
  for (double w : s.falloffWidths) drop({{"falloff_width", w}});
  if (!quick) {
    drop({{"density_tolerance_pct", 1}, {"divergence_tolerance_pct", 1}}, "dfsph");
    drop({{"density_tolerance_pct", 0.01}, {"divergence_tolerance_pct", 0.01}}, "dfsph");
  }
  if (s.templateScenes) {
    for (const Reference& r : references()) {
      if (!r.fidelity || std::string(r.scene) == "drop2d") continue;
      pts.push_back({"templates", r.scene, "", "float", {}, s.templateSeconds, nullptr});
    }
  }
  return pts;
}

// ---------------------------------------------------------------------------
// Running one point.

fs::path sourceDir() {
  for (const fs::path& dir : {fs::path("."), fs::path(FLOWCLIP_SOURCE_DIR)})
    if (fs::is_regular_file(dir / "scenes" / "dambreak2d.json") && fs::is_directory(dir / "bench" / "data"))
      return dir;
  throw std::runtime_error("cannot find scenes/dambreak2d.json and bench/data (run from the repository)");
}

// CPU seconds (user + system) of the children waited for so far.
double childCpuSeconds() {
  rusage u{};
  getrusage(RUSAGE_CHILDREN, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// A number, or "n/a" where the quantity does not apply to the point.
using Cell = std::optional<double>;

struct Result {
  Point point;
  json scene;            // the scene the point ran
  std::string status = "failed";
  std::string error;
  size_t particles = 0, frames = 0, unconverged = 0;
  double simulatedS = 0, substepsPerFrame = 0;
  double wallPerSimS = 0, msPerFrame = 0, usPerParticleStep = 0;
  // The child's CPU time (all threads, setup and export included) per
  // simulated second: what the point costs whatever else runs on the machine.
  double cpuPerSimS = 0;
  double avgErr = 0, maxErr = 0, solverAvgErr = 0, solverMaxErr = 0, volumeDrift = 0;
  double maxSpeed = 0;            // m/s, largest over the frames: a run that blew up shows it here
  double iterationsPerFrame = 0;  // divergence + density solver iterations: work that does not depend on load
  Cell surgeRms, surgeBias, fidelity;
  std::optional<RestingColumnMeasure> rest;  // resting columns
  SurgeCurve surge;      // the run's Z(T) (dam break)
  double load = 0;
  std::map<std::string, bool> front;  // per error metric
  std::string preset = "none";
  bool ok() const { return status == "ok"; }
};

struct Context {
  std::string floatBinary, doubleBinary, templates;
  int threads = 0;
  int repeat = 1;
  fs::path source, work;
  SurgeCurve martinMoyce;
};

json pointScene(const Context& ctx, const Point& p) {
  json scene = loadSceneJson((ctx.source / "scenes" / (p.scene + ".json")).string());
  if (!p.method.empty() && sceneMethod(scene) != p.method) scene["solver"] = {{"method", p.method}};
  if (!p.boundary.is_null()) scene["boundary"] = p.boundary;
  for (const auto& [name, v] : p.set) setKnob(scene, knob(name), v);
  return scene;
}

// One run of a point's child: what its figures are made of.
struct Run {
  int code = -1;        // exit status (-1: it did not exit normally)
  json stats;           // its --stats file (null where it wrote none)
  double cpuS = 0;      // its CPU seconds, all threads, setup and export included
  double load = 0;      // the load average around it
  std::string message;  // the last line it printed on stderr, where it was captured
};

// The child command of a point: `flowclip run` of the scene into the stats and
// export paths (threads: OpenMP threads, 0 for all).
std::vector<std::string> pointArgs(const Context& ctx, const Point& p, const std::string& scene,
                                   const std::string& stats, const std::string& exportPath,
                                   const std::string& templates, int threads) {
  std::vector<std::string> args{p.real == "double" ? ctx.doubleBinary : ctx.floatBinary,
                                "run",         scene,     "--seconds", std::to_string(p.seconds),
                                "--stats",     stats,     "--export",  exportPath,
                                "--templates", templates, "--quiet"};
  if (threads > 0) args.insert(args.end(), {"--threads", std::to_string(threads)});
  return args;
}

void measurePoint(const Context& ctx, Result& r, const std::function<Run(int)>& runK, const fs::path& exportPath);

void runPoint(const Context& ctx, Result& r) {
  const Point& p = r.point;
  r.scene = pointScene(ctx, p);
  const fs::path scenePath = ctx.work / "scene.json", statsPath = ctx.work / "stats.json",
                 exportPath = ctx.work / "frames.h5";
  std::ofstream(scenePath) << r.scene.dump(1) << '\n';
  fs::remove(statsPath);
  fs::remove(exportPath);
  const std::vector<std::string> args =
      pointArgs(ctx, p, scenePath.string(), statsPath.string(), exportPath.string(), ctx.templates, ctx.threads);
  measurePoint(ctx, r, [&](int) {
    Run run;
    const double load0 = loadAverage(), cpu0 = childCpuSeconds();
    run.code = runChild(args);
    run.cpuS = childCpuSeconds() - cpu0;
    run.load = 0.5 * (load0 + loadAverage());
    if (run.code == Interrupted) return run;
    if (std::ifstream in(statsPath); in) run.stats = json::parse(in, nullptr, false);
    return run;
  }, exportPath);
}

// A point's figures from its runs (`runK(k)`: the k-th of ctx.repeat, made
// here or read from a cluster's task) and the particle export they wrote.
void measurePoint(const Context& ctx, Result& r, const std::function<Run(int)>& runK, const fs::path& exportPath) {
  const Point& p = r.point;
  // Repeats give the cost of the fastest run (the one least disturbed by
  // whatever else the machine runs); the simulation itself must not change.
  json stats;
  double cpuS = 0, fastestMs = 0, load = 0;
  std::string signature;
  for (int k = 0; k < ctx.repeat; ++k) {
    Run one = runK(k);
    const int code = one.code;
    const double cpu = one.cpuS;
    load += one.load / ctx.repeat;
    if (code == Interrupted) {
      r.status = "interrupted";
      return;
    }
    json run = std::move(one.stats);
    if (code != 0 || !run.is_object() || !run.contains("summary")) {
      r.error = "flowclip run exited with " + std::to_string(code);
      if (run.is_object() && run.contains("summary") && run["summary"].contains("error"))
        r.error += ": " + run["summary"]["error"].get<std::string>();
      else if (!one.message.empty())
        r.error += ": " + one.message;
      return;
    }
    double ms = 0;
    std::string sig;
    for (const json& f : run["frames"]) {
      ms += f["wall_ms"].get<double>();
      sig += f["substeps"].dump() + f["density_iterations"].dump() + f["avg_density_error_pct"].dump() + ";";
    }
    if (k == 0) signature = sig;
    else if (sig != signature) {
      r.error = "repeated runs simulated differently (substeps, iterations or density errors differ)";
      return;
    }
    if (k == 0 || ms < fastestMs) fastestMs = ms, cpuS = cpu, stats = std::move(run);
  }
  r.load = load;
  const json& summary = stats["summary"];
  if (summary.value("real", std::string()) != p.real) {
    r.error = "the binary runs Real = " + summary.value("real", std::string("?")) + ", the point needs " + p.real;
    return;
  }
  const json& frames = stats["frames"];
  double wallMs = 0, particleSteps = 0, substeps = 0, fidelity = 0;
  size_t fidelityFrames = 0;
  for (const json& f : frames) {
    wallMs += f["wall_ms"].get<double>();
    particleSteps += f["particles"].get<double>() * f["substeps"].get<double>();
    substeps += f["substeps"].get<double>();
    r.maxSpeed = std::max(r.maxSpeed, f["max_speed"].get<double>());
    r.iterationsPerFrame += f["divergence_iterations"].get<double>() + f["density_iterations"].get<double>();
    r.unconverged += f["converged"].get<bool>() ? 0 : 1;
    r.solverAvgErr += f["avg_density_error_pct"].get<double>();
    r.solverMaxErr = std::max(r.solverMaxErr, f["max_density_error_pct"].get<double>());
    for (const json& i : f.value("instances", json::array()))
      if (i.value("active", false) && i.value("fidelity", -1.0) >= 0) {
        fidelity += i["fidelity"].get<double>();
        ++fidelityFrames;
      }
  }
  r.frames = frames.size();
  if (r.frames == 0) {
    r.error = "the run simulated no frame";
    return;
  }
  r.particles = summary["liquid_particles"].get<size_t>();
  r.simulatedS = summary["simulated_s"].get<double>();
  r.substepsPerFrame = substeps / double(r.frames);
  r.wallPerSimS = wallMs / 1000 / r.simulatedS;
  r.cpuPerSimS = cpuS / r.simulatedS;
  r.msPerFrame = wallMs / double(r.frames);
  r.usPerParticleStep = particleSteps > 0 ? wallMs * 1000 / particleSteps : 0;
  r.solverAvgErr /= double(r.frames);
  r.iterationsPerFrame /= double(r.frames);

  const Reference& ref = reference(p.scene);
  if (ref.fidelity) {
    if (fidelityFrames == 0) {
      r.error = "no frame with an active instance (is the template in '" + ctx.templates + "'?)";
      return;
    }
    r.fidelity = fidelity / double(fidelityFrames);
  }

  // Frame 0 is the initial state (densities not yet computed): the
  // compression and volume are measured from frame 1 on.
  const ExportedFrames e = readExportedFrames(exportPath.string());
  const double wallX = r.scene["domain"]["min"][0].get<double>();
  double a = 0, g = 0;
  if (ref.surge) {
    // Martin & Moyce's setup: one column of width a and height 2a (their
    // n² = 2) standing on the floor against the left wall.
    const json& column = r.scene["fluid_blocks"][0];
    const double floorY = r.scene["domain"]["min"][1].get<double>();
    a = column["max"][0].get<double>() - wallX;
    const double height = column["max"][1].get<double>() - floorY;
    if (r.scene["fluid_blocks"].size() != 1 || column["min"][0].get<double>() != wallX ||
        column["min"][1].get<double>() != floorY || std::abs(height - 2 * a) > 1e-9 * a)
      throw std::runtime_error(p.scene + ": not Martin & Moyce's setup (one column a wide, 2a high, at the left wall)");
    g = std::hypot(r.scene["gravity"][0].get<double>(), r.scene["gravity"][1].get<double>());
  }
  double first = 0, last = 0;
  for (size_t f = 0; f < e.frames(); ++f) {
    const LiquidFrame m = measureLiquidFrame(e, f, wallX);
    if (ref.surge) {
      r.surge.T.push_back(m.time * std::sqrt(2 * g / a));
      r.surge.Z.push_back(m.front / a);
    }
    if (f == 0) continue;
    if (f == 1) first = m.volumeRatio;
    last = m.volumeRatio;
    r.avgErr += m.avgCompressionPct;
    r.maxErr = std::max(r.maxErr, m.maxCompressionPct);
  }
  if (e.frames() < 2) {
    r.error = "the export has no simulated frame";
    return;
  }
  r.avgErr /= double(e.frames() - 1);
  r.volumeDrift = 100 * (last / first - 1);
  if (ref.rest) {
    const json& dom = r.scene["domain"];
    const std::vector<double> lo = dom["min"].get<std::vector<double>>(), hi = dom["max"].get<std::vector<double>>();
    const std::vector<double> gravity = r.scene["gravity"].get<std::vector<double>>();
    for (size_t d = 0; d < gravity.size(); ++d)
      if (d != 1 && gravity[d] != 0) throw std::runtime_error(p.scene + ": a resting column needs gravity along -y");
    try {
      r.rest = measureRestingColumn(e, lo.data(), hi.data(), -gravity[1], kRestSettledFrom, kRestSpeedFrom);
    } catch (const std::invalid_argument& ex) {
      r.error = std::string("resting column not measurable: ") + ex.what();
      return;
    }
  }
  if (ref.surge) {
    try {
      r.surgeRms = surgeRms(r.surge, ctx.martinMoyce);
      r.surgeBias = surgeBias(r.surge, ctx.martinMoyce);
    } catch (const std::invalid_argument& ex) {
      r.error = std::string("surge front not comparable with Martin & Moyce: ") + ex.what();
      return;
    }
  }
  r.status = "ok";
}

// ---------------------------------------------------------------------------
// Fronts and presets.

// The error metrics a Pareto front is drawn for (cost: wall s per
// simulated s), with the scenes they apply to.
struct ErrorMetric {
  const char* column;  // CSV column of the front flag: front_<name>
  const char* label;
  double (*value)(const Result&);  // nullopt-free: only called where it applies
  bool (*applies)(const Result&);
};

const std::vector<ErrorMetric>& errorMetrics() {
  static const std::vector<ErrorMetric> m = {
      {"avg_density_error", "average density error (%)", [](const Result& r) { return r.avgErr; },
       [](const Result& r) { return reference(r.point.scene).surge; }},
      {"max_density_error", "largest density error (%)", [](const Result& r) { return r.maxErr; },
       [](const Result& r) { return reference(r.point.scene).surge; }},
      {"volume_drift", "|volume drift| (%)", [](const Result& r) { return std::abs(r.volumeDrift); },
       [](const Result& r) { return reference(r.point.scene).surge; }},
      {"surge_front_rms", "surge front RMS vs Martin & Moyce (Z)", [](const Result& r) { return *r.surgeRms; },
       [](const Result& r) { return r.surgeRms.has_value(); }},
      {"fidelity", "1 - control fidelity IoU", [](const Result& r) { return 1 - *r.fidelity; },
       [](const Result& r) { return r.fidelity.has_value() && r.point.scene == "drop2d"; }},
  };
  return m;
}

// One front per scene and resolution: resolution is a knob of its own (a
// coarser liquid is cheaper and differently wrong), and the presets keep the
// scene's resolution, so the fronts that matter are the ones at a given
// resolution. Float and double compete on the same front.
void markFronts(std::vector<Result>& results) {
  std::map<std::pair<std::string, double>, std::vector<size_t>> families;
  for (size_t i = 0; i < results.size(); ++i)
    if (results[i].ok())
      families[{results[i].point.scene, *knobValue(results[i].scene, knob("particle_radius"))}].push_back(i);
  for (const ErrorMetric& m : errorMetrics())
    for (const auto& [family, members] : families) {
      std::vector<double> cost, error;
      std::vector<bool> eligible;
      for (size_t i : members) {
        const bool in = m.applies(results[i]);
        eligible.push_back(in);
        cost.push_back(in ? results[i].wallPerSimS : 0);
        error.push_back(in ? m.value(results[i]) : 0);
      }
      const std::vector<bool> on = paretoFront(cost, error, eligible);
      for (size_t k = 0; k < members.size(); ++k)
        if (eligible[k]) results[members[k]].front[m.column] = on[k];
    }
}

// Presets come from the solver sweep (the dam break at its own resolution,
// float): they carry solver and settings only, the resolution stays the
// scene's. Candidates reached their tolerance in every frame, kept the
// volume within 1 % and the surge front within half a column width (RMS of
// Z) of Martin & Moyce's: a run that blew up can show little compression
// (its liquid flew apart) but not the experiment's front. The front is drawn
// on cost against the measured average density error.
constexpr double kPresetMaxVolumeDriftPct = 1.0;
constexpr double kPresetMaxSurgeRms = 0.5;

PresetPick choosePresets(std::vector<Result>& results) {
  std::vector<double> cost, error;
  std::vector<bool> eligible;
  for (const Result& r : results) {
    const bool in = r.ok() && r.point.group == "solver" && r.unconverged == 0 &&
                    std::abs(r.volumeDrift) <= kPresetMaxVolumeDriftPct && r.surgeRms &&
                    *r.surgeRms <= kPresetMaxSurgeRms;
    eligible.push_back(in);
    cost.push_back(r.wallPerSimS);
    error.push_back(r.avgErr);
  }
  const PresetPick pick = pickPresets(cost, error, paretoFront(cost, error, eligible));
  // A row two presets share (a short front) is tagged with both names.
  const std::pair<long, const char*> tags[] = {{pick.draft, "draft"}, {pick.preview, "preview"}, {pick.final, "final"}};
  for (const auto& [row, name] : tags) {
    if (row < 0) continue;
    std::string& tag = results[size_t(row)].preset;
    tag = tag == "none" ? std::string(name) : tag + "+" + name;
  }
  return pick;
}

// ---------------------------------------------------------------------------
// Output.

std::string cell(const Cell& c, const char* f = "%.6g") { return c ? fmt(*c, f) : "n/a"; }

// A resting column's measures: CSV column, markdown heading and format.
struct RestColumn {
  const char* csv;
  const char* heading;
  const char* format;
  double (*value)(const RestingColumnMeasure&);
};

const std::vector<RestColumn>& restColumns() {
  using M = RestingColumnMeasure;
  static const std::vector<RestColumn> c = {
      {"floor_row_gap_r", "floor row (r)", "%.2f", [](const M& m) { return m.floorRowGap; }},
      {"side_row_gap_r", "side rows (r)", "%.2f", [](const M& m) { return m.sideRowGap; }},
      {"closest_approach_r", "closest approach (r)", "%.2f", [](const M& m) { return m.closestApproach; }},
      {"surface_change_r", "surface change (r)", "%+.2f", [](const M& m) { return m.surfaceChange; }},
      {"max_speed_after_1s", "max speed after 1 s (m/s)", "%.3f", [](const M& m) { return m.maxSpeedAfter; }},
      {"floor_row_pressure_ratio", "floor-row p / ρ0gh", "%.3f", [](const M& m) { return m.floorRowPressure; }},
      {"band_pressure_error_pct", "worst band p vs ρ0gh (%)", "%.1f", [](const M& m) { return m.bandPressureErrorPct; }},
      {"band_pressure_std_pct", "worst band std (%)", "%.1f", [](const M& m) { return m.bandPressureStdPct; }},
  };
  return c;
}

std::vector<std::string> csvHeader() {
  std::vector<std::string> h = {"id", "group", "scene", "method", "boundary", "real"};
  for (const Knob& k : knobs()) h.push_back(k.name);
  for (const char* c : {"status", "particles", "frames", "simulated_s", "substeps_per_frame",
                        "solver_iterations_per_frame", "unconverged_frames", "wall_s_per_sim_s", "ms_per_frame", "us_per_particle_step", "cpu_s_per_sim_s", "avg_density_error_pct",
                        "max_density_error_pct", "solver_avg_density_error_pct", "solver_max_density_error_pct",
                        "volume_drift_pct", "max_speed", "surge_front_rms", "surge_front_bias", "fidelity_iou"})
    h.push_back(c);
  for (const RestColumn& c : restColumns()) h.push_back(c.csv);
  for (const ErrorMetric& m : errorMetrics()) h.push_back(std::string("front_") + m.column);
  h.push_back("preset");
  h.push_back("load_avg");
  return h;
}

std::vector<std::string> csvRow(size_t id, const Result& r) {
  std::vector<std::string> row = {std::to_string(id), r.point.group, r.point.scene, sceneMethod(r.scene),
                                  sceneBoundary(r.scene), r.point.real};
  for (const Knob& k : knobs()) row.push_back(cell(knobValue(r.scene, k)));
  const auto num = [&](double v) { return r.ok() ? fmt(v) : std::string("n/a"); };
  row.push_back(r.status);
  row.push_back(r.ok() ? std::to_string(r.particles) : "n/a");
  row.push_back(r.ok() ? std::to_string(r.frames) : "n/a");
  for (double v : {r.simulatedS, r.substepsPerFrame, r.iterationsPerFrame}) row.push_back(num(v));
  row.push_back(r.ok() ? std::to_string(r.unconverged) : "n/a");
  for (double v : {r.wallPerSimS, r.msPerFrame, r.usPerParticleStep, r.cpuPerSimS, r.avgErr, r.maxErr, r.solverAvgErr,
                   r.solverMaxErr, r.volumeDrift, r.maxSpeed})
    row.push_back(num(v));
  row.push_back(r.ok() ? cell(r.surgeRms) : "n/a");
  row.push_back(r.ok() ? cell(r.surgeBias) : "n/a");
  row.push_back(r.ok() ? cell(r.fidelity) : "n/a");
  for (const RestColumn& c : restColumns()) row.push_back(r.ok() && r.rest ? fmt(c.value(*r.rest)) : "n/a");
  for (const ErrorMetric& m : errorMetrics()) {
    const auto it = r.front.find(m.column);
    row.push_back(it == r.front.end() ? "n/a" : it->second ? "1" : "0");
  }
  row.push_back(r.preset);
  row.push_back(fmt(r.load, "%.2f"));
  return row;
}

std::string join(const std::vector<std::string>& v, const std::string& sep) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? sep : "") + v[i];
  return s;
}

// "dfsph 0.1/0.1 % cfl 1" and the like: what distinguishes a point.
std::string describe(const Result& r) {
  std::ostringstream o;
  const std::string method = sceneMethod(r.scene);
  o << r.point.scene << " " << method;
  if (!r.point.boundary.is_null()) o << " " << sceneBoundary(r.scene);
  if (method == "dfsph")
    o << " tol " << fmt(*knobValue(r.scene, knob("density_tolerance_pct"))) << "/"
      << fmt(*knobValue(r.scene, knob("divergence_tolerance_pct"))) << "%";
  if (method == "wcsph") o << " B " << fmt(*knobValue(r.scene, knob("stiffness")));
  o << " cfl " << fmt(*knobValue(r.scene, knob("cfl_factor"))) << " r "
    << fmt(*knobValue(r.scene, knob("particle_radius")))
    << " " << r.point.real;
  for (const auto& [name, v] : r.point.set)
    if (knob(name).place == Place::Control || knob(name).place == Place::Instances) o << " " << name << "=" << fmt(v);
  return o.str();
}

json presetJson(const Result& r, const std::string& name, const std::string& description) {
  json solver = {{"method", sceneMethod(r.scene)}};
  json settings = json::object();
  for (const Knob& k : knobs()) {
    const auto v = knobValue(r.scene, k);
    if (!v) continue;
    if (k.place == Place::Solver) solver[k.name] = *v;
    if (k.place == Place::Settings) settings[k.name] = *v;
  }
  return {{"name", name},
          {"description", description},
          {"solver", solver},
          {"settings", settings},
          {"cost", {{"us_per_particle_step", r.usPerParticleStep}, {"ms_per_frame", r.msPerFrame},
                    {"wall_s_per_sim_s", r.wallPerSimS}}},
          {"error", {{"avg_density_error_pct", r.avgErr}, {"max_density_error_pct", r.maxErr},
                     {"volume_drift_pct", r.volumeDrift}, {"surge_front_rms", *r.surgeRms}}}};
}

struct Options {
  bool quick = false;
  std::string out = "build/accuracy";
  std::string doubleBinary;
  std::string templates = "templates";
  int threads = 0;
  int repeat = 1;
  bool plots = true;
  int local = 0;             // > 0: the points as tasks of a Dask LocalCluster of that many workers
  std::string scheduler;     // or of the running scheduler at this address
  std::string batchCommand;  // flowclip-batch (default: $FLOWCLIP_BATCH, build/venv/bin, PATH)
  bool cluster() const { return local > 0 || !scheduler.empty(); }
};

// The `rest` group's row: its cost and how the column rests (restColumns).
void writeRestRow(std::ostream& md, size_t i, const Result& r, bool first) {
  if (first) {
    md << "\n## rest\n\nEach boundary model holding a column at rest for " << fmt(kRestSeconds)
       << " s at the scene's own settings, measured from its exported frames. Rows: the liquid within 2 r of the "
          "floor, of a side wall (rest: 1 r); closest approach: of any centre to a wall, every frame; surface change: "
          "the highest centre plus r against the first frame's; max speed from 1 s on; pressure: the exported "
          "pressure against ρ0 g (H − y), H the surface the liquid's volume defines, Σ p / Σ ρ0gh of the floor row, "
          "and the interior (over 6 r from the side walls, up to 8 r below H) in up to twelve bands from the floor: "
          "the worst band's mean error and the largest frame-to-frame standard deviation. Rows, surface and pressure "
          "settled over the last "
       << fmt(kRestSeconds - kRestSettledFrom) << " s.\n\n";
    md << "| id | point | particles | wall s / sim s | µs / particle-step | substeps / frame | solver iterations / frame "
          "| unconverged frames |";
    for (const RestColumn& c : restColumns()) md << " " << c.heading << " |";
    md << "\n|---:|---|---:|---:|---:|---:|---:|---:|";
    for (size_t k = 0; k < restColumns().size(); ++k) md << "---:|";
    md << "\n";
  }
  md << "| " << i << " | " << describe(r) << " | ";
  if (!r.ok() || !r.rest) {
    md << r.status << ": " << r.error << " |";
    for (size_t k = 0; k < 5 + restColumns().size(); ++k) md << " |";
    md << "\n";
    return;
  }
  md << r.particles << " | " << fmt(r.wallPerSimS, "%.2f") << " | " << fmt(r.usPerParticleStep, "%.3f") << " | "
     << fmt(r.substepsPerFrame, "%.1f") << " | " << fmt(r.iterationsPerFrame, "%.0f") << " | " << r.unconverged << " |";
  for (const RestColumn& c : restColumns()) md << " " << fmt(c.value(*r.rest), c.format) << " |";
  md << "\n";
}

void writeMarkdown(const fs::path& path, const Options& opt, const std::vector<Result>& results,
                   const Report& report, double meanLoad, const PresetPick& pick) {
  std::ofstream md(path);
  md << "# Accuracy and cost (" << (opt.quick ? "quick run" : "full sweep") << ")\n\n" << report.markdownHeader()
     << "\n";
  md << results.size() << " points, each in its own `flowclip run` child ("
     << (opt.threads > 0 ? std::to_string(opt.threads) : std::string("all")) << " OpenMP thread"
     << (opt.threads == 1 ? "" : "s") << " per run"
     << (opt.repeat > 1 ? ", cost of the fastest of " + std::to_string(opt.repeat) + " runs" : std::string())
     << ")"
     << (opt.local > 0 ? ", run as tasks of a Dask LocalCluster of " + std::to_string(opt.local) +
                             " worker processes (`flowclip-batch commands`)"
         : !opt.scheduler.empty() ? ", run as tasks of the Dask cluster at " + opt.scheduler +
                                        " (`flowclip-batch commands`)"
                                  : std::string())
     << "; "
     << "load average " << fmt(meanLoad, "%.2f") << " over the points (figures made under load are inflated). Real = "
     << (opt.doubleBinary.empty() ? "float only (no `--double-binary` given: a double build was not measured)"
                                  : "float and double (`--double-binary " + opt.doubleBinary + "`)")
     << ".\n\n";
  md << "Cost: simulation wall time per frame (export excluded). Density error: the liquid's compression "
        "max(ρ/ρ0 − 1, 0) in the exported frames; the solver's own figure at exit is in accuracy.csv. Volume drift: "
        "Σ m/max(ρ,ρ0) against the rest volume, last frame against the first. Surge: RMS of Z = x/a against "
        "Martin & Moyce (1952) at their 15 points T = t√(2g/a) ≤ 3.33 (bench/data/martin_moyce_1952.csv). "
        "Fidelity: mean IoU of liquid and template over the frames where the instance plays. ★: on the Pareto front "
        "of cost against that error among the points of the same scene and resolution.\n\n";
  const auto star = [](const Result& r, const char* m) {
    const auto it = r.front.find(m);
    return it != r.front.end() && it->second ? std::string(" ★") : std::string();
  };
  std::string group;
  for (size_t i = 0; i < results.size(); ++i) {
    const Result& r = results[i];
    if (r.point.group == "rest") {
      writeRestRow(md, i, r, r.point.group != group);
      group = r.point.group;
      continue;
    }
    if (r.point.group != group) {
      group = r.point.group;
      md << "\n## " << group << "\n\n";
      md << "| id | point | particles | wall s / sim s | ms / frame | µs / particle-step | CPU s / sim s | substeps / frame | "
            "solver iterations / frame | unconverged frames | avg density err % | max density err % | volume drift % "
            "| max speed m/s | surge RMS (bias) | fidelity IoU | preset |\n";
      md << "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n";
    }
    md << "| " << i << " | " << describe(r) << " | ";
    if (!r.ok()) {
      md << r.status << ": " << r.error << " | | | | | | | | | | | | | | | |\n";
      continue;
    }
    md << r.particles << " | " << fmt(r.wallPerSimS, "%.2f") << " | " << fmt(r.msPerFrame, "%.1f") << " | "
       << fmt(r.usPerParticleStep, "%.3f") << " | " << fmt(r.cpuPerSimS, "%.2f") << " | "
       << fmt(r.substepsPerFrame, "%.1f") << " | " << fmt(r.iterationsPerFrame, "%.0f") << " | " << r.unconverged
       << " | " << fmt(r.avgErr, "%.4f") << star(r, "avg_density_error") << " | " << fmt(r.maxErr, "%.3f")
       << star(r, "max_density_error") << " | " << fmt(r.volumeDrift, "%+.4f") << star(r, "volume_drift") << " | "
       << fmt(r.maxSpeed, "%.1f") << " | " << cell(r.surgeRms, "%.3f")
       << (r.surgeBias ? " (" + fmt(*r.surgeBias, "%+.3f") + ")" : std::string()) << star(r, "surge_front_rms")
       << " | " << cell(r.fidelity, "%.3f") << star(r, "fidelity") << " | " << (r.preset == "none" ? "" : r.preset)
       << " |\n";
  }
  md << "\n## Presets\n\n";
  md << "From the solver sweep (the 2D dam break at its own resolution; presets change solver and settings, not the "
        "resolution). Candidates converged in every frame, kept the volume within "
     << fmt(kPresetMaxVolumeDriftPct) << " % and the surge front within " << fmt(kPresetMaxSurgeRms)
     << " (RMS of Z) of Martin & Moyce's; on their Pareto front of cost against average density error, draft is "
        "the cheapest point, final the most accurate, preview the knee (the front point furthest below the line from "
        "draft to final in log cost against log error).\n\n";
  md << "| preset | point | wall s / sim s | ms / frame | µs / particle-step | avg density err % | max density err % | "
        "volume drift % | surge RMS |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& [name, idx] : {std::pair<const char*, long>{"draft", pick.draft}, {"preview", pick.preview},
                                  {"final", pick.final}}) {
    if (idx < 0) {
      md << "| " << name << " | none (no eligible point) | | | | | | | |\n";
      continue;
    }
    const Result& r = results[size_t(idx)];
    md << "| " << name << " | " << describe(r) << " | " << fmt(r.wallPerSimS, "%.2f") << " | "
       << fmt(r.msPerFrame, "%.1f") << " | " << fmt(r.usPerParticleStep, "%.3f") << " | " << fmt(r.avgErr, "%.4f")
       << " | " << fmt(r.maxErr, "%.3f") << " | " << fmt(r.volumeDrift, "%+.4f") << " | " << cell(r.surgeRms, "%.3f")
       << " |\n";
  }
}

// ---------------------------------------------------------------------------
// The points as tasks of a Dask cluster (--local N, --scheduler ADDR).

bool isExecutable(const fs::path& f) { return fs::is_regular_file(f) && access(f.c_str(), X_OK) == 0; }

// flowclip-batch: --batch-command, else $FLOWCLIP_BATCH, else the one beside
// the python of build/venv (make setup installs it there), else on PATH.
std::string findBatchCommand(const Options& opt, const std::string& self) {
  const auto given = [](const std::string& path, const std::string& from) {
    if (!isExecutable(path)) throw SceneError(from, "'" + path + "' is not an executable file");
    return fs::absolute(path).string();
  };
  if (!opt.batchCommand.empty()) return given(opt.batchCommand, "--batch-command");
  if (const char* env = std::getenv("FLOWCLIP_BATCH"); env && *env) return given(env, "FLOWCLIP_BATCH");
  const fs::path venv = fs::path(self).parent_path() / "venv" / "bin" / "flowclip-batch";
  if (isExecutable(venv)) return venv.string();
  if (const char* path = std::getenv("PATH")) {
    std::stringstream dirs(path);
    for (std::string dir; std::getline(dirs, dir, ':');)
      if (!dir.empty() && isExecutable(fs::path(dir) / "flowclip-batch"))
        return fs::absolute(fs::path(dir) / "flowclip-batch").string();
  }
  throw SceneError(opt.local > 0 ? "--local" : "--scheduler",
                   "runs the points through flowclip-batch, which was not found: install FlowClip's Python package "
                   "with Dask (pip install \"clients/python[batch]\"; make setup puts it in build/venv), or name it "
                   "with --batch-command PATH or FLOWCLIP_BATCH");
}
// A point's line of the sweep's progress: its figures, or why it failed.
void printPoint(size_t i, size_t n, const Result& r, double wall) {
  if (r.ok())
    std::fprintf(stderr,
                 "[%zu/%zu] %s: %.1f s wall, %.2f wall s/sim s, %.3f us/p-step, density err %.4f%% (max %.3f%%), "
                 "volume %+.4f%%%s%s%s, load %.1f\n",
                 i + 1, n, describe(r).c_str(), wall, r.wallPerSimS, r.usPerParticleStep, r.avgErr, r.maxErr,
                 r.volumeDrift, r.surgeRms ? (", surge RMS " + fmt(*r.surgeRms, "%.3f")).c_str() : "",
                 r.fidelity ? (", fidelity " + fmt(*r.fidelity, "%.3f")).c_str() : "",
                 r.unconverged ? (", " + std::to_string(r.unconverged) + " frames unconverged").c_str() : "", r.load);
  else
    std::fprintf(stderr, "[%zu/%zu] %s: FAILED: %s\n", i + 1, n, describe(r).c_str(), r.error.c_str());
}


// Every point's runs (ctx.repeat each) as the commands of one `flowclip-batch
// commands` list, run on the cluster; then each point's figures are read from
// its tasks' folders as runPoint reads its own child's. Returns false when
// interrupted (the points without every run stay "interrupted").
bool runOnCluster(const Context& ctx, const Options& opt, const std::string& batch, std::vector<Result>& results) {
  const fs::path tasks = ctx.work / "tasks", scenes = ctx.work / "scenes";
  fs::create_directories(tasks);
  fs::create_directories(scenes);
  const std::string templates = fs::absolute(ctx.templates).string();
  const auto taskId = [](size_t i, int k) { return "p" + std::to_string(i) + "-r" + std::to_string(k); };
  json commands = json::array();
  for (size_t i = 0; i < results.size(); ++i) {
    Result& r = results[i];
    try {
      r.scene = pointScene(ctx, r.point);
    } catch (const std::exception& ex) {
      r.error = ex.what();
      continue;
    }
    const fs::path scene = scenes / ("p" + std::to_string(i) + ".json");
    std::ofstream(scene) << r.scene.dump(1) << '\n';
    for (int k = 0; k < ctx.repeat; ++k)
      commands.push_back({{"id", taskId(i, k)},
                          {"argv", pointArgs(ctx, r.point, scene.string(), "stats.json", "frames.h5", templates,
                                             ctx.threads)},
                          {"cwd", (tasks / taskId(i, k)).string()},
                          {"outputs", {"stats.json", "frames.h5"}},
                          {"threads", ctx.threads}});
  }
  const fs::path list = ctx.work / "commands.json", resultsFile = ctx.work / "results.json";
  writeJsonAtomically(list.string(), json({{"commands", commands}}));
  std::vector<std::string> args{batch, "commands", list.string(), "--results", resultsFile.string()};
  if (opt.local > 0) args.insert(args.end(), {"--local", std::to_string(opt.local)});
  else args.insert(args.end(), {"--scheduler", opt.scheduler});
  std::fprintf(stderr, "bench accuracy: %zu points, %zu runs as tasks of %s (%s)\n", results.size(),
               commands.size(),
               opt.local > 0 ? ("a LocalCluster of " + std::to_string(opt.local) + " workers").c_str()
                             : opt.scheduler.c_str(),
               batch.c_str());
  const int code = runChild(args);
  // 0: every command succeeded; 1: some failed (their results say why); 130: interrupted.
  if (code != 0 && code != 1 && code != Interrupted) {
    const std::string what = "flowclip-batch commands (" + batch + ") " +
                             (code == 127 || code < 0 ? "could not run" : "exited with " + std::to_string(code)) +
                             " before running the points; its message is above";
    if (code == BadInput) throw SceneError(opt.local > 0 ? "--local" : "--scheduler", what);
    throw std::runtime_error(what);
  }
  std::map<std::string, json> done;
  if (std::ifstream in(resultsFile); in) {
    const json all = json::parse(in, nullptr, false);
    if (all.is_object() && all.contains("commands"))
      for (const json& c : all["commands"])
        if (c.is_object()) done[c["id"].get<std::string>()] = c;
  }
  if (done.empty() && code != Interrupted && !commands.empty())
    throw std::runtime_error("flowclip-batch commands wrote no results into " + resultsFile.string());

  bool complete = true;
  for (size_t i = 0; i < results.size(); ++i) {
    Result& r = results[i];
    double wall = 0;
    if (!r.scene.is_null()) {
      try {
        measurePoint(ctx, r, [&](int k) {
          Run run;
          const auto it = done.find(taskId(i, k));
          if (it == done.end()) {  // not finished: the batch was interrupted
            run.code = Interrupted;
            return run;
          }
          const json& c = it->second;
          const int status = c["status"].is_number_integer() ? c["status"].get<int>() : -1;
          run.code = status < 0 ? -1 : status;  // killed by a signal: as runChild says it
          run.cpuS = c.value("cpu_s", 0.0);
          run.load = c.value("load", 0.0);
          wall += c.value("wall_s", 0.0);
          const std::string tail = c.value("stderr_tail", std::string());
          const size_t nl = tail.find_last_of('\n');
          run.message = nl == std::string::npos ? tail : tail.substr(nl + 1);
          if (c.value("ok", false)) {
            if (std::ifstream in(tasks / taskId(i, k) / "stats.json"); in) run.stats = json::parse(in, nullptr, false);
          } else if (run.code == 0) {
            run.message = "its outputs are missing";
          }
          return run;
        }, tasks / taskId(i, 0) / "frames.h5");
      } catch (const std::exception& ex) {
        r.status = "failed";
        r.error = ex.what();
      }
    }
    if (r.status == "interrupted") {
      complete = false;
      continue;
    }
    printPoint(i, results.size(), r, wall);
  }
  return complete && code != Interrupted;
}

int benchAccuracy(const Options& opt) {
  registerBuiltinSolversAndEffects();  // the knobs' declared defaults
  // On a cluster the points run side by side: one OpenMP thread each unless --threads says otherwise.
  const int threads = opt.threads > 0 ? opt.threads : opt.cluster() ? 1 : 0;
  const Report report("accuracy", threads > 0 ? threads : omp_get_max_threads());
  Context ctx;
  ctx.source = sourceDir();
  ctx.floatBinary = selfExecutable();
  ctx.templates = opt.templates;
  ctx.threads = threads;
  ctx.repeat = opt.repeat;
  ctx.martinMoyce = readSurgeCurve((ctx.source / "bench" / "data" / "martin_moyce_1952.csv").string());
  if (!opt.doubleBinary.empty()) {
    if (!fs::is_regular_file(opt.doubleBinary) || access(opt.doubleBinary.c_str(), X_OK) != 0)
      throw SceneError("--double-binary", "'" + opt.doubleBinary + "' is not an executable file");
    ctx.doubleBinary = fs::absolute(opt.doubleBinary).string();
    // Its Real, from a run of no frame, before the sweep spends time on it.
    const fs::path probe =
        fs::temp_directory_path() / ("flowclip-accuracy-probe-" + std::to_string(getpid()) + ".json");
    const int code = runChild({ctx.doubleBinary, "run", (ctx.source / "scenes" / "dambreak2d.json").string(), "--frames",
                               "0", "--stats", probe.string(), "--quiet"});
    json stats;
    if (std::ifstream in(probe); in) stats = json::parse(in, nullptr, false);
    fs::remove(probe);
    const std::string real =
        stats.is_object() && stats.contains("summary") ? stats["summary"].value("real", std::string("?")) : "?";
    if (code != 0 || real != "double")
      throw SceneError("--double-binary", "'" + opt.doubleBinary + "' " +
                                              (code != 0 ? "failed to run a scene (exit " + std::to_string(code) + ")"
                                                         : "runs Real = " + real + ", not double") +
                                              " (build one with -DFLOWCLIP_DOUBLE=ON: make bench-accuracy does)");
  }
  if (!fs::is_regular_file(fs::path(opt.templates) / "drop2d.h5"))
    throw SceneError("--templates", "'" + opt.templates +
                                        "' has no drop2d.h5, which the control sweep plays (make templates records it)");
  const std::string batch = opt.cluster() ? findBatchCommand(opt, ctx.floatBinary) : std::string();
  const fs::path out = opt.out;
  fs::create_directories(out);
  // A cluster's workers write the runs' outputs: under --out, which they see where
  // the machine's temporary folder may be their own.
  ctx.work = opt.cluster() ? fs::absolute(out) / (".accuracy-work-" + std::to_string(getpid()))
                           : fs::temp_directory_path() / ("flowclip-bench-accuracy-" + std::to_string(getpid()));
  fs::create_directories(ctx.work);

  const Sweep sweep = sweepFor(opt.quick);
  std::vector<Result> results;
  for (Point& p : sweepPoints(sweep, opt.quick, !ctx.doubleBinary.empty())) {
    const Reference& ref = reference(p.scene);
    if (ref.fidelity && p.group == "templates") {
      // Only the template scenes whose templates are in the database.
      const json scene = loadSceneJson((ctx.source / "scenes" / (p.scene + ".json")).string());
      bool present = true;
      for (const json& inst : scene["instances"])
        present = present &&
                  fs::is_regular_file(fs::path(opt.templates) / (inst["template"].get<std::string>() + ".h5"));
      if (!present) {
        std::fprintf(stderr, "bench accuracy: %s skipped: its template is not in '%s'\n", p.scene.c_str(),
                     opt.templates.c_str());
        continue;
      }
    }
    Result r;
    r.point = p;
    results.push_back(r);
  }

  int status = Ok;
  std::optional<InterruptGuard> interrupt(std::in_place);
  const auto t0 = std::chrono::steady_clock::now();
  size_t done = 0;
  bool clusterInterrupted = false;
  if (opt.cluster()) {
    try {
      clusterInterrupted = !runOnCluster(ctx, opt, batch, results);
    } catch (...) {
      fs::remove_all(ctx.work);
      throw;
    }
    // The points every run of which finished, in the sweep's order.
    std::erase_if(results, [](const Result& r) { return r.status == "interrupted"; });
    done = results.size();
    for (const Result& r : results)
      if (!r.ok()) status = Failure;
  }
  for (size_t i = 0; !opt.cluster() && i < results.size() && !InterruptGuard::requested(); ++i) {
    Result& r = results[i];
    const auto tp = std::chrono::steady_clock::now();
    try {
      runPoint(ctx, r);
    } catch (const std::exception& ex) {
      r.status = "failed";
      r.error = ex.what();
    }
    if (r.status == "interrupted") break;
    ++done;
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - tp).count();
    printPoint(i, results.size(), r, wall);
    if (!r.ok()) status = Failure;
  }
  const bool interrupted = InterruptGuard::requested() || done < results.size() || clusterInterrupted;
  interrupt.reset();
  results.resize(done);
  fs::remove_all(ctx.work);
  if (interrupted) {
    std::fprintf(stderr, "interrupted after %zu points: writing what was measured\n", done);
    status = Interrupted;
  }

  markFronts(results);
  const PresetPick pick = choosePresets(results);
  double meanLoad = 0;
  for (const Result& r : results) meanLoad += r.load / double(std::max<size_t>(results.size(), 1));
  const double totalS = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  {
    std::ofstream csv(out / "accuracy.csv");
    csv << join(csvHeader(), ",") << '\n';
    for (size_t i = 0; i < results.size(); ++i) csv << join(csvRow(i, results[i]), ",") << '\n';
  }
  {
    std::ofstream surge(out / "surge_fronts.csv");
    surge << "id,T,Z\n";
    for (size_t i = 0; i < results.size(); ++i)
      for (size_t k = 0; k < results[i].surge.T.size(); ++k)
        surge << i << ',' << fmt(results[i].surge.T[k]) << ',' << fmt(results[i].surge.Z[k]) << '\n';
  }
  std::string command = "flowclip bench accuracy";
  if (opt.quick) command += " --quick";
  command += " --out " + opt.out;
  if (!opt.doubleBinary.empty()) command += " --double-binary " + opt.doubleBinary;
  if (opt.threads > 0) command += " --threads " + std::to_string(opt.threads);
  if (opt.repeat > 1) command += " --repeat " + std::to_string(opt.repeat);
  if (opt.local > 0) command += " --local " + std::to_string(opt.local);
  if (!opt.scheduler.empty()) command += " --scheduler " + opt.scheduler;
  const std::string source = command + " (" + (opt.quick ? "quick run" : "full sweep") + ", " + utcTimestamp() +
                             ", load avg " + fmt(meanLoad, "%.1f") + ")";
  Options shown = opt;
  shown.threads = threads;
  writeMarkdown(out / "accuracy.md", shown, results, report, meanLoad, pick);
  {
    json presets = json::array();
    const std::map<std::string, std::string> descriptions = {
        {"draft", "cheapest point of the front: blocking out timing and layout, fast previews"},
        {"preview", "the front's knee: most accuracy per cost, for reviewing motion"},
        {"final", "most accurate point of the front: final exports"}};
    for (const auto& [name, idx] : {std::pair<const char*, long>{"draft", pick.draft}, {"preview", pick.preview},
                                    {"final", pick.final}})
      if (idx >= 0) presets.push_back(presetJson(results[size_t(idx)], name, descriptions.at(name)));
    writeJsonAtomically((out / "presets.json").string(), json({{"source", source}, {"presets", presets}}));
  }
  std::fprintf(stderr, "bench accuracy: %zu points in %.0f s (mean load %.1f): %s/accuracy.csv, accuracy.md, "
                       "presets.json\n", results.size(), totalS, meanLoad, opt.out.c_str());

  if (opt.plots) {
    const fs::path python = fs::path(ctx.floatBinary).parent_path() / "venv" / "bin" / "python";
    const fs::path script = ctx.source / "tools" / "plot_accuracy.py";
    if (!fs::exists(python)) {
      std::fprintf(stderr, "error: no plots: %s is missing (make setup creates it; --no-plots skips the plots)\n",
                   python.c_str());
      return status == Ok ? Failure : status;
    }
    const int code = runChild({python.string(), script.string(), out.string(),
                               "--martin-moyce", (ctx.source / "bench" / "data" / "martin_moyce_1952.csv").string()});
    if (code != 0) {
      std::fprintf(stderr, "error: %s exited with %d\n", script.c_str(), code);
      return status == Ok ? Failure : status;
    }
  }
  return status;
}

}  // namespace

void addBenchAccuracyCommand(CLI::App& bench) {
  auto opt = std::make_shared<Options>();
  CLI::App* acc = bench.add_subcommand(
      "accuracy",
      "accuracy against cost for every solver and control knob, on reference scenes (docs/benchmarks/accuracy.md)");
  acc->add_flag("--quick", opt->quick, "a small coarse sweep in minutes (make test's smoke run)");
  acc->add_option("--out", opt->out, "output directory (default: build/accuracy)");
  acc->add_option("--double-binary", opt->doubleBinary,
                  "a flowclip built with -DFLOWCLIP_DOUBLE=ON: adds Real = double points");
  acc->add_option("--templates", opt->templates, "template database (default: templates; needs drop2d.h5)");
  acc->add_option("--threads", opt->threads, "OpenMP threads per run (default: all cores; 1 with --local/--scheduler)")
      ->check(CLI::PositiveNumber);
  acc->add_option("--repeat", opt->repeat, "runs per point; the cost is the fastest run's (default: 1)")
      ->check(CLI::PositiveNumber);
  acc->add_flag("!--no-plots", opt->plots, "skip the plots (tools/plot_accuracy.py)");
  auto* local = acc->add_option("--local", opt->local,
                                "run the points as tasks of a Dask LocalCluster of N worker processes "
                                "(flowclip-batch; one OpenMP thread per point unless --threads)")
                    ->check(CLI::PositiveNumber);
  acc->add_option("--scheduler", opt->scheduler,
                  "run the points as tasks of a running Dask scheduler, tcp://HOST:8786 (workers see the same paths)")
      ->excludes(local);
  acc->add_option("--batch-command", opt->batchCommand,
                  "flowclip-batch for --local/--scheduler (default: $FLOWCLIP_BATCH, build/venv/bin, PATH)");
  acc->callback([opt] {
    int code = Ok;
    try {
      code = benchAccuracy(*opt);
    } catch (...) {
      code = reportError("bench accuracy", Failure);
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::bench
