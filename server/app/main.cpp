#include "app/commands.h"
#include "io/recipe.h"
#include "io/scene.h"
#include "io/template_database.h"
#include "io/template_file.h"
#include <atomic>
#include <csignal>
#include <unistd.h>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <string>

namespace fc::app {

double peakRssMb() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;
  return 0;
}

std::string selfExecutable() {
  char buf[4096];
  const ssize_t n = readlink("/proc/self/exe", buf, sizeof(buf) - 1);
  if (n <= 0) return "flowclip";
  buf[n] = 0;
  return buf;
}

namespace {
std::atomic<bool> interruptFlag{false};
extern "C" void onInterrupt(int) { interruptFlag = true; }
}  // namespace

InterruptGuard::InterruptGuard() {
  interruptFlag = false;
  previous_ = std::signal(SIGINT, onInterrupt);
}
InterruptGuard::~InterruptGuard() { std::signal(SIGINT, previous_); }
bool InterruptGuard::requested() { return interruptFlag.load(); }

int reportError(const std::string& origin, ExitCode otherwise) {
  try {
    throw;
  } catch (const SceneError& e) {
    // File-level errors already name the file (and line, column).
    if (e.path.empty()) std::fprintf(stderr, "error: %s\n", e.what());
    else std::fprintf(stderr, "error: %s: %s\n", origin.c_str(), e.what());
    return BadInput;
  } catch (const DatabaseError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return BadInput;
  } catch (const TemplateError& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return BadInput;
  } catch (const RecordAborted& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return Interrupted;
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "error: %s: %s\n", origin.c_str(), e.what());
    return BadInput;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return otherwise;
  }
}

}  // namespace fc::app

int main(int argc, char** argv) {
  CLI::App app{"FlowClip: art-directable SPH liquid with animation templates"};
  app.require_subcommand(1);
  app.set_version_flag("--version", FLOWCLIP_VERSION);
  fc::app::addRunCommand(app);
  fc::app::addBenchCommand(app);
  fc::app::addTemplatesCommands(app);
  fc::app::addServeCommand(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : fc::app::BadInput;
  } catch (const fc::app::ExitCode& code) {
    return code;
  }
  return 0;
}
