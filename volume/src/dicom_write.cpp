#include "palp/error.h"
#include "palp/volume/dicom.h"

namespace palp::volume {
void writeDicomSeries(const SliceStack&, const std::filesystem::path&, const DicomWriteOptions&) {
    throw Error("writeDicomSeries: not implemented yet");
}
}  // namespace palp::volume
