// `flowclip params`: every declared parameter as JSON (what GET
// /api/parameters answers), for both dimensions unless one is asked for.
// The docs' parameter reference is generated from it.
#include "app/commands.h"
#include "io/parameter_reference.h"

#include <cstdio>

namespace fc::app {

void addParamsCommand(CLI::App& app) {
  auto dimension = std::make_shared<int>(0);
  CLI::App* cmd = app.add_subcommand("params", "Print every declared parameter (name, unit, range, default, help) as JSON");
  cmd->add_option("--dimension", *dimension, "2 or 3 (default: both, as {\"2\": ..., \"3\": ...})")->check(CLI::IsMember({2, 3}));
  cmd->callback([dimension] {
    nlohmann::json out;
    if (*dimension == 2) out = parameterReference<2>();
    else if (*dimension == 3) out = parameterReference<3>();
    else out = {{"2", parameterReference<2>()}, {"3", parameterReference<3>()}};
    std::printf("%s\n", out.dump(2).c_str());
  });
}

}  // namespace fc::app
