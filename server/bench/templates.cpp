// `flowclip bench templates`: every template of the database: bytes per
// particle-frame, load and repulsion-layer time, memory.
#include "bench/commands.h"
#include "cli/exit_codes.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include <cstdio>
#include <exception>
#include <memory>
#include <string>

namespace fc::bench {

using namespace fc::cli;

namespace {

// One template: storage on disk, load (read + decode) and repulsion-layer
// time per million particle-frames, memory once loaded.
template <int D>
void benchTemplate(TemplateDatabase& db, const TemplateEntry& e) {
  const TemplateFileStats st = templateFileStats(db.pathFor(e.name));
  auto lt = db.load<D>(e.name);
  const double mpf = double(lt->accel.particleFrames()) / 1e6;
  const double particlesMb = double(TemplateAccel<D>::templateBytes(lt->templ())) / 1e6;
  const double accelMb = double(lt->accel.memoryBytes()) / 1e6;
  const double repulsionAvg =
      lt->accel.frames.empty() ? 0.0 : double(lt->accel.repulsionParticleFrames()) / double(lt->accel.frames.size());
  std::printf("%-14s %3d %7zu %10.1f %10.1f %10.2f %12.3f %12.3f %10.1f %10.1f\n", e.name.c_str(), D, st.frames,
              st.avgParticles, repulsionAvg, st.bytesPerParticleFrame, mpf > 0 ? lt->readSeconds / mpf : 0.0,
              mpf > 0 ? lt->buildSeconds / mpf : 0.0, particlesMb + accelMb,
              mpf > 0 ? (particlesMb + accelMb) / mpf : 0.0);
  std::fflush(stdout);
}

int benchTemplates(const std::string& dir) {
  TemplateDatabase db(dir);
  const auto entries = db.list();
  if (entries.empty()) {
    std::fprintf(stderr, "error: no templates in '%s' (make templates records the 2D ones)\n", db.directory().c_str());
    return BadInput;
  }
  std::printf("%-14s %3s %7s %10s %10s %10s %12s %12s %10s %10s\n", "template", "dim", "frames", "particles",
              "repulsion", "B/p-frame", "read s/Mpf", "layer s/Mpf", "memory MB", "MB/Mpf");
  int worst = Ok;
  for (const auto& e : entries) {
    if (!e.error.empty()) {
      std::printf("%-14s unreadable: %s\n", e.name.c_str(), e.error.c_str());
      worst = Failure;
      continue;
    }
    if (e.dimension == 2) benchTemplate<2>(db, e);
    else benchTemplate<3>(db, e);
  }
  return worst;
}

}  // namespace

void addBenchTemplatesCommand(CLI::App& bench) {
  auto templatesDir = std::make_shared<std::string>("templates");
  CLI::App* tpl = bench.add_subcommand(
      "templates", "every template of the database: bytes per particle-frame, load and repulsion-layer time, memory");
  tpl->add_option("--templates", *templatesDir, "template directory (default: templates)");
  tpl->callback([templatesDir] {
    int code = Ok;
    try {
      code = benchTemplates(*templatesDir);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "error: %s\n", e.what());
      code = Failure;
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::bench
