#include "dicom_plugin.h"

#include <dlfcn.h>

#include <string>

#include "palp/base/error.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace detail {

namespace {

/// An object of this library, whose address dladdr() maps to the library's file.
const int kAnchor = 0;

/// The DICOM library beside this one (as loaded: the build tree's volume/ folder, or the
/// installed library folder).
fs::path pluginPath() {
    Dl_info info{};
    if (dladdr(&kAnchor, &info) == 0 || info.dli_fname == nullptr) return kDicomPluginFile;
    return fs::path(info.dli_fname).parent_path() / kDicomPluginFile;
}

const DicomPlugin* loadPlugin() {
    const fs::path path = pluginPath();
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (handle == nullptr) {
        const char* why = dlerror();
        throw IoError(path.string() +
                      ": expected palp's DICOM library, found it cannot be loaded (" +
                      (why ? why : "no reason given") + ")");
    }
    using Entry = const DicomPlugin* (*)();
    void* symbol = dlsym(handle, kDicomPluginSymbol);
    if (symbol == nullptr) {
        throw IoError(path.string() + ": expected palp's DICOM library with " + kDicomPluginSymbol +
                      ", found no such symbol");
    }
    return reinterpret_cast<Entry>(symbol)();
}

}  // namespace

const DicomPlugin& dicomPlugin() {
    static const DicomPlugin* const plugin = loadPlugin();  // a throw leaves it for the next call
    return *plugin;
}

LazySliceStack openDicom(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    return dicomPlugin().open(inputs, options);
}

}  // namespace detail

std::vector<DicomSeriesInfo> scanDicom(const std::vector<fs::path>& inputs) {
    return detail::dicomPlugin().scan(inputs);
}

SliceStack readDicom(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    return detail::dicomPlugin().read(inputs, options);
}

void writeDicomSeries(const SliceStack& stack, const fs::path& dir,
                      const DicomWriteOptions& options) {
    detail::dicomPlugin().write(stack, dir, options);
}

}  // namespace palp::volume
