// NIfTI-1/NIfTI-2 reader through nifticlib: header first, checks, then the data.
#include <nifti2_io.h>

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>

#include "formats/formats.h"
#include "formats/raw_data.h"
#include "formats/raw_slices.h"
#include "formats/reader_util.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "time_point.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

struct NiftiDeleter {
    void operator()(nifti_image* nim) const { nifti_image_free(nim); }
};
using NiftiPtr = std::unique_ptr<nifti_image, NiftiDeleter>;

std::optional<ElementType> niftiType(int datatype) {
    switch (datatype) {
        case DT_INT8:
            return ElementType::Int8;
        case DT_UINT8:
            return ElementType::UInt8;
        case DT_INT16:
            return ElementType::Int16;
        case DT_UINT16:
            return ElementType::UInt16;
        case DT_INT32:
            return ElementType::Int32;
        case DT_UINT32:
            return ElementType::UInt32;
        case DT_INT64:
            return ElementType::Int64;
        case DT_UINT64:
            return ElementType::UInt64;
        case DT_FLOAT32:
            return ElementType::Float32;
        case DT_FLOAT64:
            return ElementType::Float64;
        default:
            return std::nullopt;
    }
}

bool isGzipName(const std::string& s) {
    return s.size() >= 3 &&
           (s.compare(s.size() - 3, 3, ".gz") == 0 || s.compare(s.size() - 3, 3, ".GZ") == 0);
}

/// nifticlib keeps global options; serialise our calls into it.
std::mutex& niftiMutex() {
    static std::mutex m;
    return m;
}

/// pixdim[1..3] as the file stores them (nifti_image holds them after nifticlib's repairs);
/// @p nim's values when the raw header cannot be read again; @p version is set to the header's
/// NIfTI version (1 or 2; nifticlib's nifti_type says NIfTI-1 for a NIfTI-2 file it converted).
/// Called with niftiMutex held.
std::array<double, 3> rawPixdim(const std::string& name, const nifti_image& nim, int& version) {
    std::array<double, 3> out{nim.pixdim[1], nim.pixdim[2], nim.pixdim[3]};
    version = 0;
    void* raw = nifti_read_header(name.c_str(), &version, 0);
    if (!raw) return out;
    if (version == 1) {
        const auto* h = static_cast<const nifti_1_header*>(raw);
        for (std::size_t a = 0; a < 3; ++a) out[a] = h->pixdim[a + 1];
    } else if (version == 2) {
        const auto* h = static_cast<const nifti_2_header*>(raw);
        for (std::size_t a = 0; a < 3; ++a) out[a] = h->pixdim[a + 1];
    }
    std::free(raw);
    return out;
}

}  // namespace

namespace detail {

LazySliceStack openNifti(const fs::path& path, const ReadOptions& options) {
    const std::string name = path.string();
    (void)fileSize(path);  // a clear IoError for a missing or unreadable file

    // nifticlib chooses how to read a file by its name: a NIfTI file under another name is
    // refused saying what it is, rather than with nifticlib's failure.
    const std::string content = describeContent(path);
    if (!hasNiftiName(path)) {
        throw FormatError(name +
                          ": expected a NIfTI file named *.nii, *.nii.gz or *.hdr/*.img, found " +
                          (content.empty() ? std::string("a file") : content) + " named '" +
                          path.filename().string() +
                          "' (nifticlib reads NIfTI by its name; rename it to .nii, or .nii.gz if "
                          "it is gzip-compressed)");
    }

    std::unique_lock<std::mutex> lock(niftiMutex());
    nifti_set_debug_level(0);
    NiftiPtr nim(nifti_image_read(name.c_str(), 0));
    if (!nim) {
        throw FormatError(name + ": expected a NIfTI-1 or NIfTI-2 header, found " +
                          (content.empty() ? std::string("a file without the NIfTI magic "
                                                         "('n+1', 'ni1', 'n+2' or 'ni2')")
                                           : content) +
                          " that nifticlib cannot read");
    }

    const auto type = niftiType(nim->datatype);
    if (!type) {
        throw FormatError(
            name +
            ": expected a scalar NIfTI datatype (int8..uint64, float32, float64), found datatype " +
            std::to_string(nim->datatype) + " (" + nifti_datatype_string(nim->datatype) + ")");
    }
    if (static_cast<std::size_t>(nim->nbyper) != elementSize(*type)) {
        throw FormatError(name + ": expected " + std::to_string(elementSize(*type)) +
                          " bytes per voxel for " + elementTypeName(*type) + ", found " +
                          std::to_string(nim->nbyper));
    }
    const std::int64_t ndim = nim->dim[0];
    if (ndim < 1 || ndim > 7) {
        throw FormatError(name + ": expected dim[0] between 1 and 7, found " +
                          std::to_string(ndim));
    }
    std::vector<std::int64_t> dims;
    for (std::int64_t d = 1; d <= 7; ++d) dims.push_back(d <= ndim ? nim->dim[d] : 1);
    for (std::size_t d = 0; d < dims.size(); ++d) {
        if (dims[d] <= 0) {
            throw FormatError(name + ": expected positive dimensions, found dim[" +
                              std::to_string(d + 1) + "] = " + std::to_string(dims[d]));
        }
    }
    for (std::size_t a = 0; a < 3; ++a) {
        if (dims[a] > std::numeric_limits<std::int32_t>::max()) {
            throw ValueError(name +
                             ": expected at most 2147483647 samples per spatial axis, found " +
                             std::to_string(dims[a]));
        }
    }
    const std::uint64_t esize = elementSize(*type);
    const std::uint64_t total = checkedDataBytes(dims, esize, options.maxSourceBytes, name);
    if (static_cast<std::uint64_t>(nim->nvox) * esize != total) {
        throw FormatError(name + ": expected " + std::to_string(total / esize) +
                          " voxels from the dimensions, found nvox " + std::to_string(nim->nvox));
    }
    // dims[3..6] are time and other non-spatial axes, stored as consecutive 3D volumes.
    std::int64_t volumeCount = 1;
    for (std::size_t d = 3; d < 7; ++d) volumeCount *= dims[d];
    const int t = detail::chooseTimePoint(volumeCount, options, name);

    // An uncompressed image file must hold the data before nifticlib allocates for it.
    const std::string iname = nim->iname ? nim->iname : name;
    if (!isGzipName(iname)) {
        const std::uint64_t isize = fileSize(iname);
        const auto off = static_cast<std::uint64_t>(std::max<std::int64_t>(nim->iname_offset, 0));
        const std::uint64_t avail = isize > off ? isize - off : 0;
        if (avail < total) {
            throw FormatError(iname + ": expected " + std::to_string(total) +
                              " bytes of voxel data after the header, found " +
                              std::to_string(avail));
        }
    }

    // Index-to-world (RAS, file units): sform, else qform, else pixdim scaling. nifticlib
    // replaces a zero or non-finite pixdim by 1 (and the qform a non-positive one): the raw
    // header's values are checked so that a spacing the file gives is used or refused.
    const bool useSform = nim->sform_code > 0;
    const bool useQform = !useSform && nim->qform_code > 0;
    int headerVersion = 0;
    std::array<double, 3> pixdim = rawPixdim(name, *nim, headerVersion);
    for (std::size_t a = 0; a < 3; ++a) {
        // An axis beyond dim[0] has one sample and no width in the file: 1, as nifticlib.
        const double d = pixdim[a];
        if (static_cast<std::int64_t>(a) >= ndim && !(std::isfinite(d) && d > 0)) pixdim[a] = 1;
    }
    if (!useSform) {
        for (std::size_t a = 0; a < 3; ++a) {
            const double d = pixdim[a];
            const bool ok = std::isfinite(d) && (useQform ? d > 0 : d != 0);
            if (!ok) {
                throw FormatError(name + ": pixdim[" + std::to_string(a + 1) + "]" +
                                  (useQform ? " (qform)" : "") + ": expected a finite " +
                                  (useQform ? "positive" : "non-zero") + " voxel width, found " +
                                  formatValue(d));
            }
        }
    }
    Eigen::Matrix4d ras = Eigen::Matrix4d::Identity();
    if (useSform || useQform) {
        const nifti_dmat44& m = nim->sform_code > 0 ? nim->sto_xyz : nim->qto_xyz;
        for (int r = 0; r < 4; ++r) {
            for (int c = 0; c < 4; ++c) ras(r, c) = m.m[r][c];
        }
    } else {
        for (int a = 0; a < 3; ++a) {
            ras(a, a) = std::abs(pixdim[static_cast<std::size_t>(a)]);
        }
    }
    double unit = 1e-3;  // millimetres unless the header says otherwise
    switch (nim->xyz_units) {
        case NIFTI_UNITS_METER:
            unit = 1;
            break;
        case NIFTI_UNITS_MICRON:
            unit = 1e-6;
            break;
        default:
            break;
    }
    Eigen::Matrix3d axes = ras.topLeftCorner<3, 3>() * unit;
    Eigen::Vector3d origin = ras.topRightCorner<3, 1>() * unit;
    axes.row(0) *= -1;
    axes.row(1) *= -1;
    origin[0] *= -1;
    origin[1] *= -1;
    if (!axes.allFinite() || !origin.allFinite()) {
        throw FormatError(
            name + ": expected a finite orientation (sform/qform/pixdim), found non-finite values");
    }
    if (useSform) {
        detail::checkAffine(name, "srow_x/srow_y/srow_z (sform)", "srow_x/srow_y/srow_z (sform)",
                            "srow_x/srow_y/srow_z[3] (sform offset)", axes, origin);
    } else if (useQform) {
        detail::checkAffine(name, "pixdim[1..3] (qform)", "quatern_b/c/d (qform)",
                            "qoffset_x/y/z (qform)", axes, origin);
    } else {
        detail::checkAffine(name, "pixdim[1..3]", "pixdim[1..3]", "origin", axes, origin);
    }

    // NIfTI: scl_slope 0 means the data are not scaled; nifticlib reads a non-finite slope or
    // intercept as 0, so a NaN slope (as some writers store for "none") also leaves the data as
    // stored, and a NaN intercept with a finite slope is 0 (nibabel reads them the same way).
    const double slope = nim->scl_slope;
    const double inter = std::isfinite(nim->scl_inter) ? nim->scl_inter : 0.0;
    const bool rescale = slope != 0 && std::isfinite(slope);

    const char* descrip = nim->descrip;
    const std::string description(descrip, strnlen(descrip, sizeof(nim->descrip)));
    const int niftiKind = nim->nifti_type;

    // The chosen volume, decoded a slice at a time (nifticlib would read every volume of the
    // file into memory, to be converted to float beside it).
    const std::uint64_t volumeBytes = total / static_cast<std::uint64_t>(volumeCount);
    const std::uint64_t start = t > 0 ? static_cast<std::uint64_t>(t) * volumeBytes : 0;
    const auto voxOffset = static_cast<std::uint64_t>(std::max<std::int64_t>(nim->iname_offset, 0));
    RawVolume raw;
    raw.file = iname;
    raw.item = name;
    raw.compressed = isGzipName(iname);
    if (raw.compressed) {
        // A gzip stream of the header (.nii.gz) or of the image alone (.img.gz): the data start
        // vox_offset bytes into the decompressed stream; what follows the data is not read (as
        // nifticlib reads it).
        raw.streamBytes = voxOffset + total;
        raw.volumeAt = voxOffset + start;
        raw.trailingAllowed = true;
    } else {
        raw.offset = voxOffset + start;
    }
    raw.type = *type;
    // nifticlib's MSB_FIRST (2; its LSB_FIRST is 1), defined only inside nifticlib.
    raw.order = nim->byteorder == 2 ? ByteOrder::Big : ByteOrder::Little;
    raw.dims = {dims[0], dims[1], dims[2]};
    raw.rescale = rescale;
    raw.slope = slope;
    raw.intercept = inter;
    nim.reset();
    lock.unlock();

    LazySliceStack lazy = openRawVolume(raw, axes, origin);
    SliceStack& stack = lazy.stack;
    stack.info.sourceFormat = headerVersion == 2 || niftiKind >= NIFTI_FTYPE_NIFTI2_1 ? "NIfTI-2"
                              : niftiKind == NIFTI_FTYPE_ANALYZE ? "Analyze 7.5"
                                                                 : "NIfTI-1";
    stack.info.sourceDescription = detail::trim(description).empty()
                                       ? path.filename().string()
                                       : std::string(detail::trim(description));
    stack.info.timePoint = t;
    stack.info.timePointCount =
        static_cast<int>(std::min<std::int64_t>(volumeCount, std::numeric_limits<int>::max()));
    if (rescale) {
        stack.info.rescaleSlope = slope;
        stack.info.rescaleIntercept = inter;
    }
    return lazy;
}

}  // namespace detail

SliceStack readNifti(const fs::path& path, const ReadOptions& options) {
    return detail::decodeAll(detail::openNifti(path, options));
}

}  // namespace palp::volume
