#pragma once
/// @file
/// Internal to palp_volume: DICOM support (the dicom/ room with GDCM and OpenJPEG) is a library
/// of its own, libpalp_volume_dicom.so, which palp_volume opens (dlopen) the first time a DICOM
/// is scanned, read or written. GDCM builds its data dictionaries when it is loaded (gdcm::Global
/// is a static object of every file that includes gdcmGlobal.h), a cost `palp --version`, a
/// NIfTI conversion or a palpation of a `.vdb` need not pay.

#include <filesystem>
#include <vector>

#include "lazy_stack.h"
#include "palp/volume/dicom.h"
#include "palp/volume/find_scans.h"

namespace palp::volume::detail {

/// What the DICOM library provides: scanDicom(), readDicom(), openDicom(), writeDicomSeries()
/// and findScans()' DICOM part, each as documented where palp_volume declares it.
struct DicomPlugin {
    std::vector<DicomSeriesInfo> (*scan)(const std::vector<std::filesystem::path>& inputs);
    SliceStack (*read)(const std::vector<std::filesystem::path>& inputs,
                       const ReadOptions& options);
    LazySliceStack (*open)(const std::vector<std::filesystem::path>& inputs,
                           const ReadOptions& options);
    void (*write)(const SliceStack& stack, const std::filesystem::path& dir,
                  const DicomWriteOptions& options);
    std::vector<FoundScan> (*findScans)(const std::vector<std::filesystem::path>& files);
};

/// File name of the DICOM library, looked for beside libpalp_volume.so.
inline constexpr const char* kDicomPluginFile = "libpalp_volume_dicom.so";
/// Its one exported symbol: `extern "C" const DicomPlugin* palp_volume_dicom_plugin()`.
inline constexpr const char* kDicomPluginSymbol = "palp_volume_dicom_plugin";

/// The DICOM library's functions, loaded on the first call (thread-safe; a failed load is
/// retried on the next call).
/// @throw IoError naming the library file and dlopen's reason when it cannot be loaded.
const DicomPlugin& dicomPlugin();

}  // namespace palp::volume::detail
