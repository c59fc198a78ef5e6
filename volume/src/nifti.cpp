#include "palp/error.h"
#include "palp/volume/formats.h"

namespace palp::volume {
SliceStack readNifti(const std::filesystem::path&, const LoadOptions&) { throw Error("readNifti: not implemented yet"); }
SliceStack readNrrd(const std::filesystem::path&, const LoadOptions&) { throw Error("readNrrd: not implemented yet"); }
SliceStack readMetaImage(const std::filesystem::path&, const LoadOptions&) { throw Error("readMetaImage: not implemented yet"); }
}  // namespace palp::volume
