// `flowclip bench control`: what template control costs (the paper's
// Table 1) on every scene with template instances, with the control forces
// evaluated once per frame (the paper) and at every substep
// (control.forces_every_substep). Each run is a child `flowclip run --stats`
// process, so that peak RSS is that run's alone. Writes control.md and
// control.json (bench/report.h) into --out.
#include "bench/commands.h"
#include "bench/report.h"
#include "cli/exit_codes.h"
#include "cli/process.h"
#include "io/scene.h"
#include "io/template_database.h"
#include <nlohmann/json.hpp>
#include <omp.h>
#include <unistd.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace fc::bench {

using namespace fc::cli;

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr double kTargetPct = 5;      // control under 5 % of the simulation's time
constexpr int kMaxDefaultFrames = 300;

// The paper's Table 1 row of the scene ours reproduces (i9-9900K, 8 cores),
// as printed there.
struct PaperRow {
  const char* scene;
  const char* liquid;
  const char* control;
  const char* repulsion;
  const char* temporary;
  const char* simulationMs;
  const char* controlMs;
  const char* controlPct;
  const char* memory;
  const char* storageMb;
};
const std::map<std::string, PaperRow>& paperTable1() {
  static const std::map<std::string, PaperRow> rows = {
      {"drop2d", {"2D Rectangular drop", "6.7k", "1.3k", "88", "36", "190.2", "5.6", "2.9%", "0.33 GB", "3.87"}},
      {"letters3d", {"3D Letters", "298.7k", "39.8k", "8.2k", "329", "5207.5", "474.8", "9.1%", "7.4 GB", "274.1"}},
  };
  return rows;
}

// The two ways of applying control that are timed: the label in the table
// and the setting given to the child run.
struct Mode {
  const char* label;
  const char* setting;
};
constexpr std::array<Mode, 2> kModes = {{{"per frame (paper)", "forces_every_substep=0"},
                                         {"every substep", "forces_every_substep=1"}}};

struct ControlBenchOptions {
  std::vector<std::string> scenes;
  int frames = 0;  // 0: until the last instance of each scene ends
  std::string templates = "templates";
  int threads = 0;
  int repeat = 1;  // runs per scene and mode; the one of median control share is reported
  std::string out = "bench/control";
};

// A scene file as the bench sees it before running it.
struct ScenePlan {
  std::string file, stem;
  std::vector<std::string> templates;  // distinct names its instances play
  std::vector<std::string> missing;    // of those, not in the database
  int frames = 0;                      // through the end of its last instance (capped)
  double storageMb = 0;                // bytes on disk of its templates
};

template <int D>
void planInstances(const json& scene, const TemplateDatabase& db, ScenePlan& plan) {
  const SimulationSetup<D> setup = parseScene<D>(scene);
  const SceneControl<D> control = parseSceneControl<D>(scene, setup.phases);
  std::map<std::string, double> duration;  // per template present
  for (const auto& inst : control.instances) {
    const std::string& name = inst.templateName;
    if (duration.count(name) || std::count(plan.missing.begin(), plan.missing.end(), name)) continue;
    plan.templates.push_back(name);
    if (!db.contains(name)) {
      plan.missing.push_back(name);
      continue;
    }
    const TemplateEntry e = db.entry(name);
    duration[name] = e.duration;
    plan.storageMb += double(e.bytesOnDisk) / 1e6;
  }
  double end = 0;
  for (const auto& inst : control.instances)
    if (duration.count(inst.templateName))
      end = std::max(end, inst.time.start + inst.time.sceneDuration(duration[inst.templateName]));
  const double fps = setup.settings.frameRate;
  // Through frame k = floor(end · fps) + 1, the last to start (at (k − 1) / fps) while an instance is active.
  plan.frames = std::min(kMaxDefaultFrames, int(std::floor(end * fps + 1e-6)) + 1);
}

ScenePlan planScene(const std::string& file, const TemplateDatabase& db) {
  ScenePlan plan;
  plan.file = file;
  plan.stem = fs::path(file).stem().string();
  const json scene = loadSceneJson(file);
  if (sceneDimension(scene) == 2) planInstances<2>(scene, db, plan);
  else planInstances<3>(scene, db, plan);
  return plan;
}

bool hasInstances(const json& scene) {
  const auto it = scene.find("instances");
  return it != scene.end() && it->is_array() && !it->empty();
}

fs::path sourceDir(const std::string& relative) {
  const fs::path local(relative);
  return fs::is_directory(local) ? local : fs::path(FLOWCLIP_SOURCE_DIR) / relative;
}

// scenes/*.json with a non-empty "instances" array; a file that does not
// parse (being written) is reported and left out.
std::vector<std::string> defaultControlScenes() {
  std::vector<std::string> found;
  const fs::path dir = sourceDir("scenes");
  if (!fs::is_directory(dir)) return found;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".json") continue;
    try {
      if (hasInstances(loadSceneJson(e.path().string()))) found.push_back(e.path().string());
    } catch (const std::exception& err) {
      std::fprintf(stderr, "bench: skipping %s: %s\n", e.path().string().c_str(), err.what());
    }
  }
  std::sort(found.begin(), found.end());
  return found;
}

// The recipe under templates/recipes that captures template `name`, as
// "templates/recipes/FILE.json"; empty if none records it.
std::string recipeFor(const std::string& name) {
  const fs::path dir = sourceDir("templates/recipes");
  if (!fs::is_directory(dir)) return {};
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".json") continue;
    try {
      std::ifstream f(e.path());
      const json capture = json::parse(f).at("capture");  // one capture or an array of them
      for (const json& c : capture.is_array() ? capture : json::array({capture}))
        if (c.at("name").get<std::string>() == name) return "templates/recipes/" + e.path().filename().string();
    } catch (const std::exception&) {
      // Not a readable recipe: it records nothing we can name.
    }
  }
  return {};
}

// One run's figures. Particle counts and timings are averages per frame over
// the frames with at least one active instance (the paper's definition).
struct ControlRun {
  size_t frames = 0, activeFrames = 0;
  double liquid = 0, control = 0, repulsion = 0, temporary = 0;
  double simulationMs = 0, controlMs = 0;  // simulation = wall − control
  double fidelity = -1;                    // mean IoU over active frames with a measure
  double peakRssMb = 0;
  double controlPct() const { return simulationMs > 0 ? 100 * controlMs / simulationMs : 0; }
};

ControlRun summarise(const json& stats) {
  ControlRun r;
  double fidelitySum = 0;
  size_t fidelityFrames = 0;
  for (const auto& fr : stats.at("frames")) {
    ++r.frames;
    bool active = false;
    double fidelity = 0;
    size_t measured = 0;
    for (const auto& inst : fr.value("instances", json::array())) {
      if (!inst.at("active").get<bool>()) continue;
      active = true;
      const double f = inst.at("fidelity").get<double>();
      if (f >= 0) {
        fidelity += f;
        ++measured;
      }
    }
    if (!active) continue;
    ++r.activeFrames;
    r.liquid += fr.at("liquid_particles").get<double>();
    r.control += fr.at("control_particles").get<double>();
    r.repulsion += fr.at("repulsion_particles").get<double>();
    r.temporary += fr.at("temporary_particles").get<double>();
    r.simulationMs += fr.at("simulation_ms").get<double>();
    r.controlMs += fr.at("control_ms").get<double>();
    if (measured) {
      fidelitySum += fidelity / double(measured);
      ++fidelityFrames;
    }
  }
  if (r.activeFrames) {
    for (double* v : {&r.liquid, &r.control, &r.repulsion, &r.temporary, &r.simulationMs, &r.controlMs})
      *v /= double(r.activeFrames);
  }
  if (fidelityFrames) r.fidelity = fidelitySum / double(fidelityFrames);
  r.peakRssMb = stats.at("summary").at("peak_rss_mb").get<double>();
  return r;
}

// 6.7k, 1.3k, 88: particle counts as the paper prints them.
std::string count(double n) {
  char buf[32];
  if (n < 1000) std::snprintf(buf, sizeof(buf), "%.0f", n);
  else if (n < 1e6) std::snprintf(buf, sizeof(buf), "%.1fk", n / 1e3);
  else std::snprintf(buf, sizeof(buf), "%.2fM", n / 1e6);
  return buf;
}

struct TableRow {
  std::string scene, mode, frames, liquid, control, repulsion, temporary, simulationMs, controlMs, controlPct, memory,
      storageMb, fidelity;
  std::vector<std::string> cells() const {
    return {scene,        mode,      frames,     liquid, control,   repulsion, temporary,
            simulationMs, controlMs, controlPct, memory, storageMb, fidelity};
  }
};

void printRow(const TableRow& r) {
  std::printf("%-12s %-19s %7s %7s %7s %9s %9s %9s %10s %6s %9s %8s %8s\n", r.scene.c_str(), r.mode.c_str(),
              r.frames.c_str(), r.liquid.c_str(), r.control.c_str(), r.repulsion.c_str(), r.temporary.c_str(),
              r.simulationMs.c_str(), r.controlMs.c_str(), r.controlPct.c_str(), r.memory.c_str(),
              r.storageMb.c_str(), r.fidelity.c_str());
  std::fflush(stdout);
}

TableRow ourRow(const ScenePlan& plan, const Mode& mode, const ControlRun& r) {
  const bool any = r.activeFrames > 0;
  const auto avg = [any](double v) { return any ? count(v) : std::string("-"); };
  return {plan.stem,
          mode.label,
          std::to_string(r.activeFrames) + "/" + std::to_string(r.frames),
          avg(r.liquid),
          avg(r.control),
          avg(r.repulsion),
          avg(r.temporary),
          any ? fmt(r.simulationMs, "%.1f") : "-",
          any ? fmt(r.controlMs, "%.2f") : "-",
          any ? fmt(r.controlPct(), "%.1f%%") : "-",
          fmt(r.peakRssMb, "%.0f MB"),
          fmt(plan.storageMb, "%.2f"),
          r.fidelity >= 0 ? fmt(r.fidelity, "%.3f") : "-"};
}

TableRow paperRow(const PaperRow& p) {
  return {"paper",        p.scene,     "-",          p.liquid, p.control,   p.repulsion, p.temporary,
          p.simulationMs, p.controlMs, p.controlPct, p.memory, p.storageMb, "-"};
}

// A mode's repeated runs: the one of median control share (the upper of the
// two middle ones for an even count: a noisy host never rounds the verdict
// down) and the range of the shares.
struct RepeatedRuns {
  ControlRun median;
  double lowPct = 0, highPct = 0;
  std::vector<double> pcts;  // in run order
};

RepeatedRuns medianRun(const std::vector<ControlRun>& runs) {
  RepeatedRuns out;
  if (runs.empty()) return out;
  std::vector<ControlRun> sorted = runs;
  std::sort(sorted.begin(), sorted.end(),
            [](const ControlRun& a, const ControlRun& b) { return a.controlPct() < b.controlPct(); });
  out.median = sorted[sorted.size() / 2];
  out.lowPct = sorted.front().controlPct();
  out.highPct = sorted.back().controlPct();
  for (const auto& r : runs) out.pcts.push_back(r.controlPct());
  return out;
}

std::string spread(const RepeatedRuns& r) {
  if (r.pcts.size() < 2) return "";
  return " (median of " + std::to_string(r.pcts.size()) + " runs, " + fmt(r.lowPct, "%.1f") + "-" +
         fmt(r.highPct, "%.1f") + " %)";
}

std::string verdict(const ScenePlan& plan, const std::map<std::string, RepeatedRuns>& repeated) {
  const auto paper = repeated.find(kModes[0].label);
  if (paper == repeated.end()) return plan.stem + ": no verdict (the per-frame run failed)";
  const ControlRun& r = paper->second.median;
  if (!r.activeFrames)
    return plan.stem + ": no verdict (no frame with an active instance in " + std::to_string(r.frames) + " frames)";
  std::string line = plan.stem + ": control is " + fmt(r.controlPct(), "%.1f") + " %" + spread(paper->second) +
                     " of the simulation's time with forces once per frame: " +
                     (r.controlPct() < kTargetPct ? "meets" : "misses") + " the target (under " +
                     fmt(kTargetPct, "%.0f") + " %)";
  const auto substep = repeated.find(kModes[1].label);
  if (substep != repeated.end() && substep->second.median.activeFrames) {
    const ControlRun& s = substep->second.median;
    line += "; every substep: " + fmt(s.controlPct(), "%.1f") + " %" + spread(substep->second) + " (control " +
            fmt(r.controlMs > 0 ? s.controlMs / r.controlMs : 0, "%.1f") + "x, " +
            (s.controlPct() < kTargetPct ? "within" : "over") + " the target)";
  }
  return line;
}

const TableRow kHeader{"scene",     "forces",     "frames", "liquid",   "control", "repulsion", "temporary",
                       "sim ms/fr", "ctrl ms/fr", "ctrl %", "peak RSS", "tmpl MB", "fidelity"};

std::string markdown(const std::vector<TableRow>& table, const std::vector<std::string>& skipped,
                     const std::vector<std::string>& verdicts) {
  std::vector<std::vector<std::string>> rows;
  for (const TableRow& r : table) rows.push_back(r.cells());
  std::string md = "Particles and ms are per frame, averaged over the frames with an active instance (frames: "
                   "active/run); simulation = wall - control; control % = control / simulation. Each row is the run "
                   "of median control share; the paper's rows are its Table 1 (i9-9900K, 8 cores). Target: control "
                   "under " + fmt(kTargetPct, "%.0f") + " % of the simulation's time with forces once per frame.\n\n";
  md += "## Verdict\n\n";
  for (const auto& v : verdicts) md += "- " + v + "\n";
  md += "\n## Table 1 columns\n\n" + markdownTable(kHeader.cells(), rows);
  if (!skipped.empty()) {
    md += "\n## Skipped\n\n";
    for (const auto& s : skipped) md += "- " + s + "\n";
  }
  return md;
}

int benchControl(const ControlBenchOptions& opt) {
  const std::vector<std::string> files = opt.scenes.empty() ? defaultControlScenes() : opt.scenes;
  const TemplateDatabase db(opt.templates);
  const std::string self = selfExecutable();
  const std::string tmp =
      (fs::temp_directory_path() / ("flowclip-bench-control-" + std::to_string(getpid()) + ".json")).string();
  const int threads = opt.threads > 0 ? opt.threads : omp_get_max_threads();
  const Report report("control", threads);

  std::printf("# %d threads, load average %.2f at start; particles and ms are per frame, averaged over the frames "
              "with an active instance (frames: active/run); simulation = wall - control; control %% = control / "
              "simulation\n",
              threads, loadAverage());
  printRow(kHeader);

  json results = json::array(), paperRows = json::array();
  std::vector<TableRow> table;
  std::vector<std::string> verdicts, skipped;
  const auto skip = [&](const std::string& line) {
    std::printf("%s\n", line.c_str());
    skipped.push_back(line);
  };
  int worst = Ok;
  size_t measured = 0;
  for (const auto& file : files) {
    ScenePlan plan;
    try {
      plan = planScene(file, db);
    } catch (...) {
      worst = std::max<int>(worst, reportError(file, Failure));
      continue;
    }
    if (plan.templates.empty()) {
      skip(plan.stem + ": skipped: no template instances");
      continue;
    }
    if (!plan.missing.empty()) {
      // One line per recipe, naming the templates it records.
      std::map<std::string, std::string> byRecipe;
      for (const auto& name : plan.missing) {
        const std::string recipe = recipeFor(name);
        std::string& names = byRecipe[recipe.empty() ? "templates/recipes/<recipe>.json" : recipe];
        names += (names.empty() ? "'" : ", '") + name + "'";
      }
      const std::string dirArg = opt.templates == "templates" ? "" : " --templates " + opt.templates;
      for (const auto& [recipe, names] : byRecipe)
        skip(plan.stem + ": skipped: no template " + names + " in " + db.directory() + "; record with "
             "`build/flowclip record " + recipe + dirArg + "`");
      continue;
    }
    const int frames = opt.frames > 0 ? opt.frames : plan.frames;
    // Repetitions alternate the two modes, so that a change in the host's
    // speed during the scene reaches both.
    std::map<std::string, std::vector<ControlRun>> runs;
    for (int rep = 0; rep < opt.repeat; ++rep) {
      for (const Mode& mode : kModes) {
        const std::vector<std::string> args{self, "run", plan.file,
                                            "--frames", std::to_string(frames),
                                            "--templates", opt.templates,
                                            "--control-setting", mode.setting,
                                            "--threads", std::to_string(threads),
                                            "--stats", tmp, "--quiet"};
        std::fprintf(stderr, "bench: %s, %d frames, control forces %s (run %d/%d) ...\n", plan.stem.c_str(), frames,
                     mode.label, rep + 1, opt.repeat);
        const int code = runChild(args);
        std::ifstream f(tmp);
        if (code != 0 || !f) {
          skip(plan.stem + " " + mode.label + ": failed (exit " + std::to_string(code) + ")");
          worst = Failure;
          continue;
        }
        try {
          runs[mode.label].push_back(summarise(json::parse(f)));
        } catch (const std::exception& e) {
          skip(plan.stem + " " + mode.label + ": unreadable stats: " + e.what());
          worst = Failure;
        }
        f.close();
        fs::remove(tmp);
      }
    }
    std::map<std::string, RepeatedRuns> repeated;
    for (const Mode& mode : kModes) {
      const auto it = runs.find(mode.label);
      if (it == runs.end() || it->second.empty()) continue;
      const RepeatedRuns rr = medianRun(it->second);
      repeated[mode.label] = rr;
      const ControlRun& r = rr.median;
      ++measured;
      table.push_back(ourRow(plan, mode, r));
      printRow(table.back());
      results.push_back({{"scene_file", plan.file},
                         {"scene", plan.stem},
                         {"control_setting", mode.setting},
                         {"frames", r.frames},
                         {"active_frames", r.activeFrames},
                         {"liquid_particles", r.liquid},
                         {"control_particles", r.control},
                         {"repulsion_particles", r.repulsion},
                         {"temporary_particles", r.temporary},
                         {"simulation_ms_per_frame", r.simulationMs},
                         {"control_ms_per_frame", r.controlMs},
                         {"control_pct", r.controlPct()},
                         {"control_pct_runs", rr.pcts},
                         {"peak_rss_mb", r.peakRssMb},
                         {"template_storage_mb", plan.storageMb},
                         {"templates", plan.templates},
                         {"fidelity", r.fidelity},
                         {"threads", threads}});
    }
    const auto paper = paperTable1().find(plan.stem);
    if (paper != paperTable1().end()) {
      table.push_back(paperRow(paper->second));
      printRow(table.back());
      const PaperRow& p = paper->second;
      paperRows.push_back({{"scene", plan.stem}, {"paper_scene", p.scene}, {"liquid", p.liquid},
                           {"control", p.control}, {"repulsion", p.repulsion}, {"temporary", p.temporary},
                           {"simulation_ms", p.simulationMs}, {"control_ms", p.controlMs},
                           {"control_pct", p.controlPct}, {"memory", p.memory}, {"storage_mb", p.storageMb}});
    }
    verdicts.push_back(verdict(plan, repeated));
  }
  if (!verdicts.empty()) std::printf("\n");
  for (const auto& v : verdicts) std::printf("%s\n", v.c_str());
  const json settings = {{"scenes", files},     {"frames", opt.frames},       {"templates", opt.templates},
                         {"threads", threads},  {"repeat", opt.repeat},       {"target_control_pct", kTargetPct}};
  report.write(opt.out, "Control overhead", markdown(table, skipped, verdicts),
               {{"settings", settings}, {"runs", results}, {"paper", paperRows}, {"verdicts", verdicts},
                {"skipped", skipped}});
  if (measured == 0 && worst == Ok) {
    std::fprintf(stderr, "error: nothing measured (no scene with template instances and its templates)\n");
    return BadInput;
  }
  return worst;
}

}  // namespace

void addBenchControlCommand(CLI::App& bench) {
  auto opt = std::make_shared<ControlBenchOptions>();
  CLI::App* cmd = bench.add_subcommand(
      "control", "cost of template control (paper Table 1): forces once per frame and at every substep");
  cmd->add_option("scenes", opt->scenes, "scene files (default: every scenes/*.json with template instances)");
  cmd->add_option("--frames", opt->frames,
                  "frames per run (default: through the end of the scene's last instance, at most " +
                      std::to_string(kMaxDefaultFrames) + ")")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--templates", opt->templates, "template database directory (default: templates)");
  cmd->add_option("--threads", opt->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  cmd->add_option("--repeat", opt->repeat,
                  "runs per scene and mode, alternating the modes; the run of median control share is reported "
                  "with the range")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--out", opt->out, "report folder: control.md and control.json (default: bench/control)");
  cmd->callback([opt] {
    int code = Ok;
    try {
      code = benchControl(*opt);
    } catch (...) {
      code = reportError("bench control", Failure);
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::bench
