#pragma once
// Sub-commands of the flowclip executable.
#include <CLI/CLI.hpp>
#include <string>

namespace fc::app {

void addRunCommand(CLI::App& app);
void addBenchCommand(CLI::App& app);
void addTemplatesCommands(CLI::App& app);  // record, templates list|inspect|remove

// Exit codes shared by every command.
enum ExitCode { Ok = 0, Failure = 1, BadInput = 2, SimulationFailed = 3, Interrupted = 130 };

double peakRssMb();
std::string selfExecutable();

}  // namespace fc::app
