#include "palp/error.h"
#include "palp/volume/dicom.h"

namespace palp::volume {
std::vector<DicomSeriesInfo> scanDicom(const std::vector<std::filesystem::path>&) {
    throw Error("scanDicom: not implemented yet");
}
SliceStack readDicom(const std::vector<std::filesystem::path>&, const LoadOptions&) {
    throw Error("readDicom: not implemented yet");
}
}  // namespace palp::volume
