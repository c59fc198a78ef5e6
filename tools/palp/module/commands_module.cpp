// The palp command's volume inspection, phantom and simulation commands as a module
// (libpalp_tool_commands), opened by the executable only when one of them is asked for
// (tools/CMakeLists.txt says why).
#include <vector>

#include "../commands.h"

extern "C" __attribute__((visibility("default"))) void palp_tool_add_commands(
    CLI::App& root, std::vector<palp::tool::Command>& out) {
    using namespace palp::tool;
    for (Command (*add)(CLI::App&) : {addInfo, addPhantom, addBench, addPalpate, addServe,
                                      addBridgeSim, addSweep, addErrormap, addStudy})
        out.push_back(add(root));
}
