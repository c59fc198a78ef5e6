#include "dicom_plugin.h"

#include <string>

#include "palp/base/shared_library.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace detail {

namespace {

/// An object of this library, whose address dladdr() maps to the library's file.
const int kAnchor = 0;

/// The DICOM library beside this one (as loaded: the build tree's volume/ folder, or the
/// installed library folder).
fs::path pluginPath() {
    const fs::path dir = loadedFileDir(&kAnchor);
    return dir.empty() ? fs::path(kDicomPluginFile) : dir / kDicomPluginFile;
}

const DicomPlugin* loadPlugin() {
    using Entry = const DicomPlugin* (*)();
    void* symbol = openLibrarySymbol(pluginPath(), kDicomPluginSymbol, "palp's DICOM library");
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
