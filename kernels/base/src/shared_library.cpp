#include "palp/base/shared_library.h"

#include <dlfcn.h>

#include "palp/base/error.h"

namespace palp {

std::filesystem::path loadedFileDir(const void* anchor) {
    Dl_info info{};
    if (dladdr(anchor, &info) == 0 || info.dli_fname == nullptr) return {};
    return std::filesystem::path(info.dli_fname).parent_path();
}

void* openLibrarySymbol(const std::filesystem::path& path, const char* symbol,
                        const std::string& what) {
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
        const char* why = dlerror();
        throw IoError(path.string() + ": expected " + what + ", found it cannot be loaded (" +
                      (why ? why : "no reason given") + ")");
    }
    void* address = dlsym(handle, symbol);
    if (address == nullptr) {
        throw IoError(path.string() + ": expected " + what + " with " + symbol +
                      ", found no such symbol");
    }
    return address;
}

}  // namespace palp
