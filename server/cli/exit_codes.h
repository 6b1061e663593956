#pragma once
// What a sub-command of the flowclip executable returns: the exit codes
// every command shares, and the one way an exception becomes one.
#include <string>

namespace fc::cli {

// Exit codes shared by every command.
enum ExitCode { Ok = 0, Failure = 1, BadInput = 2, SimulationFailed = 3, Interrupted = 130 };

// Call inside a catch block: prints the exception being handled the way
// every command does (naming `origin` where the message does not) and
// returns its exit code: BadInput for bad scenes, recipes, templates and
// names, Interrupted for an aborted recording, `otherwise` for the rest.
int reportError(const std::string& origin, ExitCode otherwise);

}  // namespace fc::cli
