// The palp tool's shared library (libpalp_tool): the global flags, and where the library lies,
// for the executable to find the commands module beside it.
#include <dlfcn.h>

#include "../commands.h"

namespace palp::tool {

namespace {

/// An object of this library, whose address dladdr() maps to the library's file.
const int kAnchor = 0;

}  // namespace

Globals& globals() {
    static Globals g;
    return g;
}

std::filesystem::path toolLibraryDir() {
    Dl_info info{};
    if (dladdr(&kAnchor, &info) == 0 || info.dli_fname == nullptr) return {};
    return std::filesystem::path(info.dli_fname).parent_path();
}

}  // namespace palp::tool
