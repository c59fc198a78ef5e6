// The palp tool's shared library (libpalp_tool): the global flags, and where the library lies,
// for the executable to find the commands module beside it.
#include "../commands.h"
#include "palp/base/shared_library.h"

namespace palp::tool {

namespace {

/// An object of this library, whose address dladdr() maps to the library's file.
const int kAnchor = 0;

}  // namespace

Globals& globals() {
    static Globals g;
    return g;
}

std::filesystem::path toolLibraryDir() { return loadedFileDir(&kAnchor); }

}  // namespace palp::tool
