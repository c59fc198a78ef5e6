// palp bench servo: placeholder until the command is written (issue 4).
#include "commands.h"

namespace palp::tool {

Command addBenchServo(CLI::App& bench) {
    CLI::App* app = bench.add_subcommand("servo", "Not yet available");
    return {app, []() -> int { return 1; }};
}

}  // namespace palp::tool
