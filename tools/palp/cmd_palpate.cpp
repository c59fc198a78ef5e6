// palp palpate: placeholder until the command is written (issue 4).
#include "commands.h"

namespace palp::tool {

Command addPalpate(CLI::App& root) {
    CLI::App* app = root.add_subcommand("palpate", "Not yet available");
    return {app, []() -> int { return 1; }};
}

}  // namespace palp::tool
