#pragma once
// The DICOM room's entry points (internal to libpalp_volume_dicom.so), which palp_volume reaches
// through the plugin table (dicom_plugin.h) as scanDicom(), readDicom(), detail::openDicom() and
// writeDicomSeries(): see those for what each does and throws.
#include <filesystem>
#include <vector>

#include "lazy_stack.h"
#include "palp/volume/dicom.h"

namespace palp::volume::dicom {

std::vector<DicomSeriesInfo> scanSeries(const std::vector<std::filesystem::path>& inputs);

SliceStack readSeries(const std::vector<std::filesystem::path>& inputs, const ReadOptions& options);

detail::LazySliceStack openSeries(const std::vector<std::filesystem::path>& inputs,
                                  const ReadOptions& options);

void writeSeries(const SliceStack& stack, const std::filesystem::path& dir,
                 const DicomWriteOptions& options);

}  // namespace palp::volume::dicom
