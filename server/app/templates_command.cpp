// `flowclip record RECIPE.json`: simulate a recipe and store the captured
// templates (one per capture) in the database. `flowclip templates
// list|inspect|remove`: the database.
#include "app/commands.h"
#include "io/recipe.h"
#include "io/scene.h"
#include "io/template_database.h"
#include "io/template_file.h"

#include <omp.h>
#include <unistd.h>
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <cstdio>
#include <limits>
#include <memory>

namespace fc::app {

using namespace fc::cli;

namespace {

struct RecordCliOptions {
  std::string recipe;
  std::string templatesDir = "templates";
  bool force = false;
  bool skipExisting = false;  // nothing to do when every captured template is there
  bool quiet = false;
  int threads = 0;
  double particleRadius = 0;
  std::string scale;  // --scale NAME: the recipe's named resolution
  bool templatesGiven = false;  // --templates: used as it is, also with --scale
};

struct TemplatesCliOptions {
  std::string templatesDir = "templates";
  std::string name;
};

std::string vecText(const std::vector<double>& v) {
  std::string s = "[";
  for (size_t i = 0; i < v.size(); ++i) {
    char b[32];
    std::snprintf(b, sizeof b, "%s%g", i ? ", " : "", v[i]);
    s += b;
  }
  return s + "]";
}

int record(const RecordCliOptions& opt) {
  Recipe recipe = loadRecipe(opt.recipe);
  std::string templatesDir = opt.templatesDir;
  if (!opt.scale.empty()) {
    if (!opt.templatesGiven) templatesDir = scaledTemplatesDir(opt.templatesDir, recipe.scene, opt.scale);
    recipe.scene = applySceneScale(recipe.scene, opt.scale);
  }
  if (opt.skipExisting) {
    const TemplateDatabase db(templatesDir);
    bool all = true;
    for (const CaptureSpec& c : recipe.captures) all = all && std::filesystem::exists(db.pathFor(c.name));
    if (all) {
      if (!opt.quiet) std::fprintf(stderr, "%s: every template it captures is in %s already\n", opt.recipe.c_str(),
                                   templatesDir.c_str());
      return Ok;
    }
  }
  RecordOptions ro;
  ro.templatesDir = templatesDir;
  ro.force = opt.force;
  ro.particleRadiusOverride = opt.particleRadius;
  const bool tty = isatty(fileno(stderr));
  const auto t0 = std::chrono::steady_clock::now();
  ro.progress = [&](const RecordProgress& p) {
    if (!opt.quiet && (tty || p.frame == p.frames || p.frame % std::max(1, p.frames / 20) == 0)) {
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const double eta = wall / p.frame * (p.frames - p.frame);
      std::fprintf(stderr,
                   "%sframe %d/%d  t=%.3f s  %zu captured  %d substeps  iter %d/%d  err %.3f%%  %.1f ms/frame  ETA "
                   "%.0f s%s",
                   tty ? "\r" : "", p.frame, p.frames, p.stats.time, p.captured, p.stats.substeps,
                   p.stats.divergenceIterations, p.stats.densityIterations, p.stats.avgDensityErrorPct,
                   p.stats.wallMs, eta, tty ? "   " : "\n");
      std::fflush(stderr);
    }
    return !InterruptGuard::requested();
  };
  if (!opt.quiet) {
    std::string names;
    for (const CaptureSpec& c : recipe.captures) names += (names.empty() ? "'" : ", '") + c.name + "'";
    std::fprintf(stderr, "recording %s (%dD) from %s, %d threads\n", names.c_str(), recipe.dimension,
                 opt.recipe.c_str(), omp_get_max_threads());
  }
  RecordResult res;
  try {
    InterruptGuard interrupt;
    res = recordRecipe(recipe, ro);
  } catch (...) {
    if (!opt.quiet && tty) std::fprintf(stderr, "\n");
    throw;
  }
  if (!opt.quiet && tty) std::fprintf(stderr, "\n");
  for (const RecordedTemplate& t : res.templates) {
    const TemplateFileStats st = templateFileStats(t.path);
    std::fprintf(stderr,
                 "wrote %s: %zu frames, %zu particle-frames (%.0f per frame), %llu bytes (%.2f B per "
                 "particle-frame); simulated in %.2f s, written in %.2f s\n",
                 t.path.c_str(), t.frames, t.particleFrames,
                 t.frames ? double(t.particleFrames) / double(t.frames) : 0.0, (unsigned long long)st.bytesOnDisk,
                 st.bytesPerParticleFrame, res.wallSeconds, t.writeSeconds);
  }
  return Ok;
}

int list(const TemplatesCliOptions& opt) {
  TemplateDatabase db(opt.templatesDir);
  const auto entries = db.list();
  if (entries.empty()) {
    std::printf("no templates in '%s'\n", db.directory().c_str());
    return Ok;
  }
  std::printf("%-24s %3s %7s %7s %9s %10s %12s  %s\n", "name", "dim", "frames", "fps", "duration", "avg parts",
              "bytes", "region");
  for (const auto& e : entries) {
    if (!e.error.empty()) {
      std::printf("%-24s unreadable: %s\n", e.name.c_str(), e.error.c_str());
      continue;
    }
    std::printf("%-24s %3d %7zu %7.2f %8.3fs %10.1f %12llu  %s - %s\n", e.name.c_str(), e.dimension, e.frames,
                e.frameRate, e.duration, e.avgParticles, (unsigned long long)e.bytesOnDisk,
                vecText(e.regionMin).c_str(), vecText(e.regionMax).c_str());
  }
  return Ok;
}

template <int D>
void printLoadStats(TemplateDatabase& db, const std::string& name) {
  const auto t0 = std::chrono::steady_clock::now();
  auto lt = db.load<D>(name);
  const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const auto& acc = lt->accel;
  if (lt->streamed()) {
    std::printf("too large to hold decoded (over %.0f MB): streamed frame by frame when played; opening it took "
                "%.3f s (the file verified, its index read)\n",
                double(db.memoryBytes()) / 1048576.0, lt->readSeconds);
    return;
  }
  size_t rmin = std::numeric_limits<size_t>::max(), rmax = 0;
  for (const auto& f : acc.frames) {
    rmin = std::min(rmin, f.repulsionCount());
    rmax = std::max(rmax, f.repulsionCount());
  }
  if (acc.frames.empty()) rmin = 0;
  const double ravg = acc.frames.empty() ? 0.0 : double(acc.repulsionParticleFrames()) / double(acc.frames.size());
  const double mpf = double(acc.particleFrames()) / 1e6;
  std::printf("repulsion particles per frame: min %zu, avg %.1f, max %zu (a = %g, thinning %g m)\n", rmin, ravg, rmax,
              double(acc.options.a), double(acc.options.thinDistance));
  std::printf("load: read %.3f s, repulsion layer + grids %.3f s, total %.3f s", lt->readSeconds, lt->buildSeconds,
              total);
  if (mpf > 0)
    std::printf(" (read %.3f s, layer %.3f s per million particle-frames)", lt->readSeconds / mpf,
                lt->buildSeconds / mpf);
  std::printf("\nmemory when loaded: particles %.2f MB, grids + repulsion layer %.2f MB\n",
              double(TemplateAccel<D>::templateBytes(lt->templ())) / 1e6, double(acc.memoryBytes()) / 1e6);
}

int inspect(const TemplatesCliOptions& opt) {
  TemplateDatabase db(opt.templatesDir);
  const std::string path = db.pathFor(opt.name);
  if (!db.contains(opt.name)) throw DatabaseError("no template '" + opt.name + "' in '" + db.directory() + "'");
  const TemplateHeader h = readTemplateHeader(path);
  const TemplateFileStats s = templateFileStats(path);
  std::printf("template %s (%s)\n", h.name.c_str(), path.c_str());
  std::printf("  dimension        %d\n", h.dimension);
  std::printf("  frames           %zu at %g fps (duration %.4f s)\n", s.frames, h.frameRate,
              s.frames > 1 ? double(s.frames - 1) / h.frameRate : 0.0);
  std::printf("  particle radius  %g m\n", h.particleRadius);
  std::printf("  support radius   %g m\n", h.supportRadius);
  std::printf("  rest density     %g kg/m^3\n", h.restDensity);
  std::printf("  region           %s - %s\n", vecText(h.regionMin).c_str(), vecText(h.regionMax).c_str());
  std::printf("  created by       %s\n", h.createdBy.c_str());
  std::printf("  recipe           %zu bytes of JSON\n", h.recipe.size());
  std::printf("particles per frame: min %zu, avg %.1f, max %zu\n", s.minParticles, s.avgParticles, s.maxParticles);
  std::printf("on disk: %llu bytes, %.3f bytes per particle-frame\n", (unsigned long long)s.bytesOnDisk,
              s.bytesPerParticleFrame);
  std::fflush(stdout);
  if (h.dimension == 2) printLoadStats<2>(db, opt.name);
  else printLoadStats<3>(db, opt.name);
  return Ok;
}

}  // namespace

void addTemplatesCommands(CLI::App& app) {
  auto ro = std::make_shared<RecordCliOptions>();
  CLI::App* rec = app.add_subcommand("record", "simulate a recipe and store the captured animation template(s)");
  rec->add_option("recipe", ro->recipe, "recipe file (a scene plus a \"capture\" object or array, JSON)")->required();
  rec->add_option("--templates", ro->templatesDir,
                  "template directory (default: templates, or templates/NAME with --scale NAME)");
  rec->add_flag("--force", ro->force, "overwrite an existing template of the same name");
  rec->add_flag("--skip-existing", ro->skipExisting,
                "do nothing when every template the recipe captures exists (a stopped batch of recordings resumes)");
  rec->add_option("--threads", ro->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  auto* radius = rec->add_option("--particle-radius", ro->particleRadius, "override the recipe's particle radius, m")
                     ->check(CLI::PositiveNumber);
  rec->add_option("--scale", ro->scale,
                  "record at one of the recipe's named resolutions (\"scales\", e.g. paper) into TEMPLATES/NAME (or the "
                  "folder the scale names)")
      ->excludes(radius);
  rec->add_flag("--quiet", ro->quiet, "no progress line");
  rec->callback([ro, rec] {
    if (ro->threads > 0) omp_set_num_threads(ro->threads);
    ro->templatesGiven = rec->count("--templates") > 0;
    int code = Ok;
    try {
      code = record(*ro);
    } catch (...) {
      code = reportError(ro->recipe, SimulationFailed);
    }
    if (code != Ok) throw ExitCode(code);
  });

  auto to = std::make_shared<TemplatesCliOptions>();
  CLI::App* tpl = app.add_subcommand("templates", "list, inspect or remove templates of the database");
  tpl->require_subcommand(1);
  tpl->add_option("--templates", to->templatesDir, "template directory (default: templates)");
  auto wrap = [to](int (*fn)(const TemplatesCliOptions&)) {
    return [to, fn] {
      int code = Ok;
      try {
        code = fn(*to);
      } catch (...) {
        code = reportError(to->name, SimulationFailed);
      }
      if (code != Ok) throw ExitCode(code);
    };
  };
  CLI::App* ls = tpl->add_subcommand("list", "list the templates (name, dimension, frames, size, region)");
  ls->add_option("--templates", to->templatesDir, "template directory (default: templates)");
  ls->callback(wrap(list));
  CLI::App* in = tpl->add_subcommand("inspect", "print a template's header, statistics and load timings");
  in->add_option("name", to->name, "template name")->required();
  in->add_option("--templates", to->templatesDir, "template directory (default: templates)");
  in->callback(wrap(inspect));
  CLI::App* rm = tpl->add_subcommand("remove", "delete a template file from the database");
  rm->add_option("name", to->name, "template name")->required();
  rm->add_option("--templates", to->templatesDir, "template directory (default: templates)");
  rm->callback(wrap(+[](const TemplatesCliOptions& o) {
    TemplateDatabase(o.templatesDir).remove(o.name);
    std::printf("removed %s\n", o.name.c_str());
    return int(Ok);
  }));
}

void addTemplateMemoryOption(CLI::App* cmd, double& megabytes) {
  cmd->add_option("--template-memory", megabytes,
                  "MB a template may take decoded; a larger one is streamed from its file, at most this much of it "
                  "kept (default: " + std::to_string(int(kDefaultTemplateMemoryMB)) + ")")
      ->check(CLI::Range(1.0, 1.0e7));
}

size_t templateMemoryBytes(double megabytes) { return size_t(megabytes * 1024 * 1024); }

}  // namespace fc::app
