// palp phantom: the thesis scenes as CT-like volumes (filled in with the phantom work).
#include "commands.h"
#include "palp/error.h"

namespace palp::tool {

Command addPhantom(CLI::App& root) {
    CLI::App* app = root.add_subcommand("phantom", "Generate a thesis scene as a CT-like volume");
    return {app, []() -> int { throw Error("phantom: not implemented yet"); }};
}

}  // namespace palp::tool
