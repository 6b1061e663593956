// `flowclip export FRAMES.h5 --formats vdb,ply,usd --out DIR`: surfaces,
// meshes and point caches from an existing particle export (a run's or a
// session's), with a progress line.
#include "app/commands.h"
#include "app/surface_options.h"
#include "core/large_allocations.h"
#include "io/frames_file.h"
#include <omp.h>
#include <unistd.h>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <optional>

namespace fc::app {

using namespace fc::cli;

namespace {

struct ExportOptions {
  std::string input;
  std::string out;
  std::string name;
  SurfaceOptions surface;
  int first = 0;
  int last = -1;
  int threads = 0;
  bool quiet = false;
};

int runExport(const ExportOptions& opt) {
  reuseLargeAllocations();
  const FramesFile in(opt.input);
  const ExportInfo info =
      exportInfoOf(in, opt.name.empty() ? std::filesystem::path(opt.input).stem().string() : opt.name, opt.out,
                   std::string("flowclip ") + FLOWCLIP_VERSION);
  auto exporter = makeSurfaceExport(opt.surface, info);

  // Frames by their number (as in the file's /frames/index), first..last.
  std::vector<size_t> frames;
  for (size_t f = 0; f < in.frames(); ++f)
    if (int(in.indices()[f]) >= opt.first && (opt.last < 0 || int(in.indices()[f]) <= opt.last)) frames.push_back(f);
  if (frames.empty())
    throw std::invalid_argument("no frame of '" + opt.input + "' is in the range asked (the file has frames " +
                                (in.frames() ? std::to_string(in.indices().front()) + ".." + std::to_string(in.indices().back())
                                             : std::string("none")) +
                                ")");
  if (!opt.quiet)
    std::fprintf(stderr, "%s: %dD, %zu frames, particle radius %g m -> %s (%s), %d threads\n", opt.input.c_str(),
                 in.dimension(), frames.size(), in.particleRadius(), opt.out.c_str(), opt.surface.formats.c_str(),
                 omp_get_max_threads());
  const bool tty = isatty(fileno(stderr));
  const auto t0 = std::chrono::steady_clock::now();
  std::optional<InterruptGuard> interrupt(std::in_place);
  size_t done = 0;
  for (size_t f : frames) {
    if (InterruptGuard::requested()) break;
    exporter->writeFrame(in.frame(f));
    ++done;
    if (!opt.quiet && (tty || done == frames.size() || done % std::max<size_t>(1, frames.size() / 20) == 0)) {
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const int width = 30, filled = int(double(width) * double(done) / double(frames.size()));
      std::fprintf(stderr, "%s[%s%s] %zu/%zu frames  %.1f MB  surface %.0f ms/frame  ETA %.0f s%s", tty ? "\r" : "",
                   std::string(size_t(filled), '#').c_str(), std::string(size_t(width - filled), '.').c_str(), done,
                   frames.size(), double(exporter->bytesWritten()) / 1e6,
                   exporter->surfaceMs() / double(done), wall / double(done) * double(frames.size() - done),
                   tty ? "   " : "\n");
      std::fflush(stderr);
    }
  }
  const bool interrupted = InterruptGuard::requested();
  interrupt.reset();
  if (!opt.quiet && tty) std::fprintf(stderr, "\n");
  if (interrupted) {
    // The manifest is written only for a complete export.
    std::fprintf(stderr, "interrupted after %zu of %zu frames: those frames' files are in place, no manifest\n", done,
                 frames.size());
    return Interrupted;
  }
  exporter->close();
  if (!opt.quiet)
    std::fprintf(stderr, "exported %zu frames, %.1f MB, manifest %s\n", done, double(exporter->bytesWritten()) / 1e6,
                 exporter->manifestPath().c_str());
  return Ok;
}

}  // namespace

void addExportCommand(CLI::App& app) {
  auto opt = std::make_shared<ExportOptions>();
  CLI::App* cmd = app.add_subcommand("export", "surfaces, meshes and point caches from a particle export (HDF5)");
  cmd->add_option("frames", opt->input, "frames file written by `run --export` or a session's export (.h5)")->required();
  cmd->add_option("--out", opt->out, "output directory (created if missing)")->required();
  cmd->add_option("--name", opt->name, "file stem of the outputs (default: the input's)");
  cmd->add_option("--first", opt->first, "first frame number to export (default 0)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--last", opt->last, "last frame number to export (default: the last)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--threads", opt->threads, "OpenMP threads (default: all cores)")->check(CLI::PositiveNumber);
  cmd->add_flag("--quiet", opt->quiet, "no progress line or summary");
  addSurfaceOptions(cmd, opt->surface);
  cmd->callback([opt] {
    if (opt->threads > 0) omp_set_num_threads(opt->threads);
    int code = Ok;
    try {
      code = runExport(*opt);
    } catch (...) {
      code = reportError(opt->input, Failure);
    }
    if (code != Ok) throw ExitCode(code);
  });
}

}  // namespace fc::app
