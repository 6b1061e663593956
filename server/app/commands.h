#pragma once
// Sub-commands of the flowclip executable (the `bench` group is bench/'s:
// bench/commands.h). What they share is in cli/.
#include "cli/exit_codes.h"
#include "cli/json_file.h"
#include "cli/process.h"
#include <CLI/CLI.hpp>

namespace fc::app {

void addRunCommand(CLI::App& app);        // run (run_command.cpp)
void addTemplatesCommands(CLI::App& app); // record, templates list|inspect|remove (templates_command.cpp)
void addServeCommand(CLI::App& app);      // serve (serve_command.cpp)
void addParamsCommand(CLI::App& app);     // params (params_command.cpp)
void addExportCommand(CLI::App& app);     // export (export_command.cpp)

// --template-memory MB (run and serve): how much of the memory a template may
// take decoded before it is streamed from its file (templates_command.cpp).
void addTemplateMemoryOption(CLI::App* cmd, double& megabytes);
size_t templateMemoryBytes(double megabytes);

}  // namespace fc::app
