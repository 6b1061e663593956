// `flowclip bench scenes`: every shipped scene for a fixed number of frames,
// each in its own child process (`flowclip run --stats`, so that peak RSS is
// that run's), printed with the columns of the paper's Table 1 (Schoentgen
// et al. 2020 [SPDM20]) beside the paper's own figures: average liquid, control,
// repulsion and temporary particles per frame (over the frames with an
// active instance), simulation and control ms per frame, control share,
// memory and template storage. Writes scenes.md and scenes.json
// (bench/report.h) into --out.
#include "bench/commands.h"
#include "bench/report.h"
#include "cli/exit_codes.h"
#include "cli/process.h"
#include "io/scene.h"
#include "io/template_database.h"
#include <nlohmann/json.hpp>
#include <omp.h>
#include <unistd.h>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

namespace fc::bench {

using namespace fc::cli;

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

// Table 1 of the paper (i9-9900K, 8 cores): particles per frame, ms per
// frame, memory (GB) and template storage (MB).
struct PaperRow {
  const char* name;
  double liquid, control, repulsion, temporary, simMs, controlMs, memoryGb, storageMb;
};
const std::map<std::string, PaperRow>& paperTable() {
  static const std::map<std::string, PaperRow> t = {
      {"drop2d", {"2D Rectangular drop", 6.7e3, 1.3e3, 88, 36, 190.2, 5.6, 0.33, 3.87}},
      {"wave2d", {"2D Wave machine", 6.7e3, 2.3e3, 130, 14, 128.7, 13.7, 0.34, 7.44}},
      {"blade2d", {"2D Rotating blade", 2.2e3, 1.3e3, 79, 0, 32.4, 6.7, 0.24, 12.0}},
      {"waterjet2d", {"2D Water jet", 6.7e3, 1.3e3, 217, 138, 96.7, 3.9, 0.35, 4.19}},
      {"zero_gravity2d", {"2D Zero gravity", 6.7e3, 0.6e3, 209, 0, 116.5, 3.4, 0.46, 3.02}},
      {"doubledam2d", {"2D Double dam", 6.7e3, 1.0e3, 92, 43, 143.1, 4.0, 0.46, 3.50}},
      {"viscous3d", {"3D Viscous", 298.7e3, 1.3e3, 713, 76, 6566.5, 53.2, 5.81, 5.11}},
      {"blade3d", {"3D Rotating blade", 56.2e3, 20.0e3, 2.3e3, 0, 807.2, 135.4, 2.4, 82.7}},
      {"letters3d", {"3D Letters", 298.7e3, 39.8e3, 8.2e3, 329, 5207.5, 474.8, 7.4, 274.1}},
      {"multiphase3d", {"3D Multiphase", 106.4e3, 2.6e3, 1.4e3, 74, 2274.5, 125.7, 3.2, 5.12}},
      {"boat3d", {"3D Boat", 2.49e6, 363.3e3, 30.1e3, 994, 44585.2, 3921.6, 80.6, 3488.0}},
      {"composition3d", {"3D Composition", 298.7e3, 12.2e3, 1.7e3, 43, 4900.1, 112.4, 7.8, 90.0}},
  };
  return t;
}

// The stages of the step a frame's stats time (FrameStats' *_ms), in order.
constexpr const char* kStages[] = {"neighbor_ms", "density_ms", "divergence_ms", "non_pressure_ms", "pressure_ms"};

struct Options {
  std::vector<std::string> scenes;
  int frames = 60;
  std::string templates = "templates";
  std::string scale;  // a named resolution of every scene ("paper"); empty: as shipped
  bool templatesGiven = false;  // --templates: every scene's, also with --scale
  int threads = 0;
  std::string out;  // default bench/scenes, or bench/scenes-NAME with a scale
};

std::string count(double v) {
  char b[32];
  if (v >= 1e6) std::snprintf(b, sizeof b, "%.2fM", v / 1e6);
  else if (v >= 1e4) std::snprintf(b, sizeof b, "%.1fk", v / 1e3);
  else std::snprintf(b, sizeof b, "%.0f", v);
  return b;
}

std::string markdown(const json& rows, const json& failures, int frames) {
  std::vector<std::vector<std::string>> ours, paper;
  for (const json& r : rows) {
    ours.push_back({r["scene"], std::to_string(r["active_frames"].get<int>()) + " / " +
                                    std::to_string(r["frames"].get<int>()),
                    fmt(r["liquid"], "%.0f"), fmt(r["control"], "%.0f"), fmt(r["repulsion"], "%.0f"),
                    fmt(r["temporary"], "%.0f"), fmt(r["simulation_ms_per_frame"], "%.1f"),
                    fmt(r["control_ms_per_frame"], "%.1f"), fmt(r["control_pct"], "%.1f"),
                    fmt(r["peak_rss_mb"], "%.0f"),
                    fmt(r["template_storage_mb"], "%.2f")});
    if (!r.contains("paper")) continue;
    const json& p = r["paper"];
    paper.push_back({r["scene"], p["name"], count(p["liquid"]), count(p["control"]), count(p["repulsion"]),
                     count(p["temporary"]), fmt(p["simulation_ms_per_frame"], "%.1f"),
                     fmt(p["control_ms_per_frame"], "%.1f"), fmt(p["control_pct"], "%.1f"), fmt(p["memory_gb"], "%.2f"),
                     fmt(p["template_storage_mb"], "%.2f")});
  }
  std::string md = "Each scene for " + std::to_string(frames) + " frames (or the frames its SCENE:FRAMES names) in its own "
                   "`flowclip run`. Particles are per "
                   "frame, averaged over the frames with an active instance (frames: active / run), as the paper's; "
                   "the ms per frame over every frame; control % is of the simulation ms, as the paper's; templates "
                   "MB: the files of the templates the scene plays.\n\n## This machine\n\n";
  md += markdownTable({"scene", "frames", "liquid", "control", "repulsion", "temporary", "simulation ms / frame",
                       "control ms / frame", "control %", "peak RSS MB", "templates MB"},
                      ours);
  if (!paper.empty()) {
    md += "\n## The paper's Table 1 (i9-9900K, 8 cores)\n\n";
    md += markdownTable({"scene", "paper's scene", "liquid", "control", "repulsion", "temporary",
                         "simulation ms / frame", "control ms / frame", "control %", "memory GB", "templates MB"},
                        paper);
  }
  std::vector<std::vector<std::string>> stageRows;
  for (const json& r : rows) {
    if (!r.contains("stages_ms_per_frame")) continue;
    const json& st = r["stages_ms_per_frame"];
    std::vector<std::string> row = {r["scene"]};
    for (const char* k : kStages) row.push_back(fmt(st.value(k, 0.0), "%.1f"));
    row.push_back(fmt(r["control_ms_per_frame"], "%.1f"));
    row.push_back(fmt(r["simulation_ms_per_frame"], "%.1f"));
    stageRows.push_back(row);
  }
  md += "\n## Where the time goes\n\nms per frame in each stage of the step (the frames' `*_ms` fields); the rest "
        "of the simulation ms is integration, contacts, emitters and bodies.\n\n";
  md += markdownTable({"scene", "neighbours", "densities", "divergence solve", "viscosity and other accelerations",
                       "density solve", "control", "simulation"},
                      stageRows);
  std::vector<std::vector<std::string>> ratios;
  for (const json& r : rows) {
    if (!r.contains("paper")) continue;
    const json& p = r["paper"];
    auto ratio = [](double a, double b) { return b > 0 ? fmt(a / b, "%.2f") : std::string("-"); };
    ratios.push_back({r["scene"], ratio(r["liquid"], p["liquid"]), ratio(r["control"], p["control"]),
                      ratio(r["simulation_ms_per_frame"], p["simulation_ms_per_frame"]),
                      fmt(r["control_pct"], "%.1f") + " / " + fmt(p["control_pct"], "%.1f"),
                      ratio(r["peak_rss_mb"].get<double>() / 1024.0, p["memory_gb"]),
                      ratio(r["template_storage_mb"], p["template_storage_mb"])});
  }
  if (!ratios.empty()) {
    md += "\n## Ours over the paper's\n\nEach figure of this machine divided by the paper's (liquid and control "
          "particles, simulation ms per frame on our cores against its 8, peak RSS against its memory, template "
          "storage); the control share of each, in percent.\n\n";
    md += markdownTable({"scene", "liquid", "control", "ms / frame", "control % (ours / paper)", "memory", "templates"},
                        ratios);
  }
  if (!failures.empty()) {
    md += "\n## Failed runs\n\n";
    for (const json& f : failures)
      md += "- " + f["scene"].get<std::string>() + ": " + f["error"].get<std::string>() + "\n";
  }
  return md;
}

int benchScenes(const Options& opt) {
  std::vector<std::string> scenes = opt.scenes;
  if (scenes.empty())
    for (const std::string& f : sceneFilesIn("scenes")) {
      // With a scale, the shipped scenes that have it.
      bool has = opt.scale.empty();
      try {
        has = has || loadSceneJson(f).value("scales", json::object()).contains(opt.scale);
      } catch (const std::exception&) {
      }
      if (has) scenes.push_back(f);
    }
  if (scenes.empty()) {
    std::fprintf(stderr, "error: no scenes found (scenes/*.json%s)\n",
                 opt.scale.empty() ? "" : (" with the scale '" + opt.scale + "'").c_str());
    return BadInput;
  }
  const int threads = opt.threads > 0 ? opt.threads : omp_get_max_threads();
  const Report report("scenes", threads);
  const std::string self = selfExecutable();
  const fs::path tmp = fs::temp_directory_path() / ("flowclip-bench-scenes-" + std::to_string(getpid()));
  fs::create_directories(tmp);
  json results = json::array(), failures = json::array();
  for (size_t k = 0; k < scenes.size(); ++k) {
    // SCENE[:FRAMES]: a scene's own number of frames (the boat at the paper's scale).
    std::string scene = scenes[k];
    int sceneFrames = opt.frames;
    if (const size_t colon = scene.rfind(':'); colon != std::string::npos && !fs::exists(scene)) {
      const std::string n = scene.substr(colon + 1);
      if (n.empty() || n.size() > 6 || n.find_first_not_of("0123456789") != std::string::npos || std::stoi(n) < 1) {
        std::fprintf(stderr, "error: '%s': expected SCENE or SCENE:FRAMES with FRAMES a positive number\n",
                     scene.c_str());
        return BadInput;
      }
      sceneFrames = std::stoi(n);
      scene.resize(colon);
    }
    const std::string stem = fs::path(scene).stem().string();
    std::fprintf(stderr, "[%zu/%zu] %s: %d frames…\n", k + 1, scenes.size(), stem.c_str(), sceneFrames);
    const std::string statsPath = (tmp / (stem + ".json")).string();
    // Read once: the scale's templates folder and the templates it plays (a file it cannot read, run reports).
    json sceneJson = json::object();
    try {
      sceneJson = loadSceneJson(scene);
    } catch (const std::exception&) {
    }
    // A scale's templates: the folder it names under --templates' directory, as `run --scale` reads them.
    std::string templates = opt.templates;
    if (!opt.scale.empty() && !opt.templatesGiven) {
      try {
        templates = scaledTemplatesDir(opt.templates, sceneJson, opt.scale);
      } catch (const std::exception&) {
        templates = scaledTemplatesDir(opt.templates, json::object(), opt.scale);  // run reports the scene's error
      }
    }
    std::vector<std::string> args = {self, "run", scene, "--frames", std::to_string(sceneFrames), "--stats",
                                     statsPath, "--templates", templates, "--threads",
                                     std::to_string(threads), "--quiet"};
    if (!opt.scale.empty()) {
      args.push_back("--scale");
      args.push_back(opt.scale);
    }
    const int rc = runChild(args);
    json stats;
    try {
      std::ifstream in(statsPath);
      stats = json::parse(in);
    } catch (const std::exception&) {
    }
    if (rc != 0 || !stats.contains("summary")) {
      const std::string error = "exit " + std::to_string(rc) +
                                (stats.contains("summary") && stats["summary"].contains("error")
                                     ? ", " + stats["summary"]["error"].get<std::string>()
                                     : std::string());
      std::printf("%s: failed (%s)\n", stem.c_str(), error.c_str());
      failures.push_back({{"scene", stem}, {"error", error}});
      continue;
    }
    // Averages over the frames where an instance plays (as the paper's), or
    // over every frame where none plays in the frames run; the timings over
    // every frame.
    double liquid = 0, control = 0, repulsion = 0, temporary = 0, simMs = 0, controlMs = 0;
    std::map<std::string, double> stageMs;  // where the simulation's time goes
    size_t active = 0, frames = 0;
    std::set<std::string> templatesUsed;
    const auto playing = [](const json& f) {
      bool any = false;
      for (const json& i : f.value("instances", json::array())) any = any || i.value("active", false);
      return any || !f.contains("instances") || f["instances"].empty();
    };
    for (const json& f : stats["frames"]) {
      ++frames;
      simMs += f.value("simulation_ms", f.value("wall_ms", 0.0));
      controlMs += f.value("control_ms", 0.0);
      for (const char* k : kStages) stageMs[k] += f.value(k, 0.0);
      active += playing(f);
    }
    for (const json& f : stats["frames"]) {
      if (active > 0 && !playing(f)) continue;
      const double temp = f.value("temporary_particles", 0.0);
      liquid += f.value("particles", 0.0) - temp;
      control += f.value("control_particles", 0.0);
      repulsion += f.value("repulsion_particles", 0.0);
      temporary += temp;
    }
    const double nf = double(std::max<size_t>(frames, 1)), na = active > 0 ? double(active) : nf;
    // Template storage: the files of the templates the scene names.
    double storage = 0;
    try {
      for (const json& inst : sceneJson.value("instances", json::array()))
        if (inst.contains("template") && templatesUsed.insert(inst["template"].get<std::string>()).second) {
          std::error_code ec;
          const auto bytes = fs::file_size(fs::path(templates) / (inst["template"].get<std::string>() + ".h5"), ec);
          if (!ec) storage += double(bytes) / 1e6;
        }
    } catch (const std::exception&) {
    }
    const double rss = stats["summary"].value("peak_rss_mb", 0.0);
    const double sim = simMs / nf, ctl = controlMs / nf;
    const double pct = sim > 0 ? 100.0 * ctl / sim : 0;
    std::printf("%s: %.0f liquid, %.0f control particles; %.1f simulation ms and %.1f control ms per frame (%.1f %%); "
                "peak RSS %.0f MB\n",
                stem.c_str(), liquid / na, control / na, sim, ctl, pct, rss);
    std::fflush(stdout);
    json row = {{"scene", stem},
                {"scene_file", scene},
                {"frames", frames},
                {"active_frames", active},
                {"liquid", liquid / na},
                {"control", control / na},
                {"repulsion", repulsion / na},
                {"temporary", temporary / na},
                {"simulation_ms_per_frame", sim},
                {"control_ms_per_frame", ctl},
                {"control_pct", pct},
                {"peak_rss_mb", rss},
                {"template_storage_mb", storage}};
    json stages = json::object();
    for (const char* k : kStages) stages[k] = stageMs[k] / nf;
    row["stages_ms_per_frame"] = stages;
    const auto it = paperTable().find(stem);
    if (it != paperTable().end()) {
      const PaperRow& p = it->second;
      row["paper"] = {{"name", p.name},
                      {"liquid", p.liquid},
                      {"control", p.control},
                      {"repulsion", p.repulsion},
                      {"temporary", p.temporary},
                      {"simulation_ms_per_frame", p.simMs},
                      {"control_ms_per_frame", p.controlMs},
                      {"control_pct", 100.0 * p.controlMs / p.simMs},
                      {"memory_gb", p.memoryGb},
                      {"template_storage_mb", p.storageMb}};
    }
    results.push_back(row);
  }
  std::error_code ec;
  fs::remove_all(tmp, ec);
  const json settings = {{"scenes", scenes}, {"frames", opt.frames}, {"templates", opt.templates},
                         {"scale", opt.scale.empty() ? json() : json(opt.scale)}, {"threads", threads}};
  report.write(opt.out, opt.scale.empty() ? "The paper's scenes" : "The paper's scenes at scale '" + opt.scale + "'", markdown(results, failures, opt.frames),
               {{"settings", settings}, {"scenes", results}, {"failures", failures}});
  return failures.empty() ? Ok : SimulationFailed;
}

}  // namespace

void addBenchScenesCommand(CLI::App& bench) {
  auto opt = std::make_shared<Options>();
  CLI::App* cmd = bench.add_subcommand("scenes", "every shipped scene, with the columns of the paper's Table 1 beside its figures");
  cmd->add_option("scenes", opt->scenes, "scene files, each SCENE or SCENE:FRAMES (default: every scenes/*.json)");
  cmd->add_option("--frames", opt->frames, "frames per scene (default 60)")->check(CLI::PositiveNumber);
  cmd->add_option("--templates", opt->templates,
                  "template database directory (default: templates, or templates/NAME with --scale NAME)");
  cmd->add_option("--scale", opt->scale,
                  "run every scene at its named resolution (\"scales\", e.g. paper; a scene without it fails)");
  cmd->add_option("--threads", opt->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  cmd->add_option("--out", opt->out, "report folder: scenes.md and scenes.json (default: bench/scenes, or bench/scenes-NAME with --scale NAME)");
  cmd->callback([opt, cmd] {
    int code = Ok;
    try {
      Options o = *opt;
      o.templatesGiven = cmd->count("--templates") > 0;
      if (o.out.empty()) o.out = o.scale.empty() ? "bench/scenes" : "bench/scenes-" + o.scale;
      code = benchScenes(o);
    } catch (...) {
      code = reportError("bench scenes", Failure);
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::bench
