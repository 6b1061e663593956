#pragma once
// Sub-commands of the flowclip executable.
#include <CLI/CLI.hpp>
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

namespace fc::app {

void addRunCommand(CLI::App& app);
void addBenchCommand(CLI::App& app);
void addTemplatesCommands(CLI::App& app);
void addServeCommand(CLI::App& app);      // serve (serve_command.cpp)  // record, templates list|inspect|remove
void addBenchControlCommand(CLI::App& bench);  // bench control (bench_control.cpp)
void addBenchServiceCommand(CLI::App& bench);  // bench service (bench_service.cpp)
void addBenchScenesCommand(CLI::App& bench);   // bench scenes (bench_scenes.cpp)
void addBenchAccuracyCommand(CLI::App& bench); // bench accuracy (bench_accuracy.cpp)

// Exit codes shared by every command.
enum ExitCode { Ok = 0, Failure = 1, BadInput = 2, SimulationFailed = 3, Interrupted = 130 };

double peakRssMb();
// Writes j to a temporary name next to `path`, then renames: a reader never
// sees half a file, and a failed write leaves an existing file as it was.
// Throws std::runtime_error naming the path.
void writeJsonAtomically(const std::string& path, const nlohmann::json& j);
std::string selfExecutable();
// Runs args[0] (an absolute path) with args in a child process and waits:
// its exit status, -1 if it could not start or did not exit normally.
int runChild(const std::vector<std::string>& args);

// While a guard lives, Ctrl-C (SIGINT) only sets requested(), so a long
// command can stop cleanly after its current frame; the previous handler is
// restored when the guard ends.
class InterruptGuard {
 public:
  InterruptGuard();
  ~InterruptGuard();
  InterruptGuard(const InterruptGuard&) = delete;
  InterruptGuard& operator=(const InterruptGuard&) = delete;
  static bool requested();

 private:
  void (*previous_)(int);
};

// Call inside a catch block: prints the exception being handled the way
// every command does (naming `origin` where the message does not) and
// returns its exit code: BadInput for bad scenes, recipes, templates and
// names, Interrupted for an aborted recording, `otherwise` for the rest.
int reportError(const std::string& origin, ExitCode otherwise);

}  // namespace fc::app
