// The flowclip executable: its sub-commands (app/ and bench/) on one command line.
#include "app/commands.h"
#include "bench/commands.h"

int main(int argc, char** argv) {
  CLI::App app{"FlowClip: art-directable SPH liquid with animation templates"};
  app.require_subcommand(1);
  app.set_version_flag("--version", FLOWCLIP_VERSION);
  fc::app::addRunCommand(app);
  fc::bench::addBenchCommand(app);
  fc::app::addTemplatesCommands(app);
  fc::app::addServeCommand(app);
  fc::app::addParamsCommand(app);
  fc::app::addExportCommand(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : fc::cli::BadInput;
  } catch (const fc::cli::ExitCode& code) {
    return code;
  }
  return 0;
}
