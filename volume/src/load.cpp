#include "palp/volume/load.h"

#include <openvdb/io/File.h>

#include <algorithm>
#include <cctype>
#include <fstream>
#include <new>
#include <stdexcept>

#include "formats.h"
#include "grid_copy.h"
#include "palp/base/atomic_file.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/volume/dicom.h"
#include "vdb_errors.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

std::string lower(std::string s) {
    std::transform(s.begin(), s.end(), s.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return s;
}

bool endsWith(const std::string& s, const std::string& suffix) {
    return s.size() >= suffix.size() &&
           s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string readPrefix(const fs::path& path, std::size_t n) {
    std::ifstream in(path, std::ios::binary);
    std::string buf(n, '\0');
    in.read(buf.data(), static_cast<std::streamsize>(n));
    buf.resize(static_cast<std::size_t>(std::max<std::streamsize>(in.gcount(), 0)));
    return buf;
}

/// A stored grid palp can use: a uniform linear transform whose voxel is a voxel spacing
/// (bounds::kSpacing), and finite values inside bounds::kVolumeValue (the background and every
/// active value), so that nothing the file holds reaches the mesher or the kernels unchecked.
/// @throw FormatError naming @p name.
void checkStoredGrid(const std::string& name, const openvdb::FloatGrid& grid) try {
    const openvdb::math::Transform& xform = grid.transform();
    const openvdb::Vec3d voxel = xform.voxelSize();
    if (!xform.isLinear() || !(voxel[0] == voxel[1] && voxel[1] == voxel[2])) {
        throwExpected(name + ": grid transform", "a linear transform with cubic voxels",
                      "voxel (" + formatValue(voxel[0] * 1e3) + " " + formatValue(voxel[1] * 1e3) +
                          " " + formatValue(voxel[2] * 1e3) + ") mm" +
                          (xform.isLinear() ? "" : " (not linear)"));
    }
    requireWithin(name + ": grid voxel size", voxel[0], bounds::kSpacing, {1e3, "mm"});
    requireWithin(name + ": grid background", static_cast<double>(grid.background()),
                  bounds::kVolumeValue);
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        if (bounds::kVolumeValue.contains(static_cast<double>(*it))) continue;
        const openvdb::Coord c = it.getCoord();
        requireWithin(name + ": grid value at (" + std::to_string(c.x()) + ", " +
                          std::to_string(c.y()) + ", " + std::to_string(c.z()) + ")",
                      static_cast<double>(*it), bounds::kVolumeValue);
    }
} catch (const ValueError& e) {
    throw FormatError(e.what());
}

void requireExists(const fs::path& p) {
    std::error_code ec;
    if (!fs::exists(p, ec))
        throw IoError(p.string() + ": expected an existing file or directory, found nothing");
}

/// readStack() without the value check: the format's reader.
SliceStack readStackUnchecked(const std::vector<fs::path>& inputs, const ReadOptions& options);

}  // namespace

const char* formatName(Format f) {
    switch (f) {
        case Format::Dicom:
            return "DICOM";
        case Format::Nifti:
            return "NIfTI";
        case Format::Nrrd:
            return "NRRD";
        case Format::MetaImage:
            return "MetaImage";
        case Format::Vdb:
            return "OpenVDB";
        case Format::Unknown:
            break;
    }
    return "unknown";
}

Format detectFormat(const fs::path& path) {
    std::error_code ec;
    if (fs::is_directory(path, ec)) return Format::Dicom;
    const std::string head = readPrefix(path, 352);
    if (head.size() >= 132 && head.compare(128, 4, "DICM") == 0) return Format::Dicom;
    if (head.rfind("NRRD000", 0) == 0) return Format::Nrrd;
    if (head.size() >= 4 && static_cast<unsigned char>(head[0]) == 0x20 &&
        static_cast<unsigned char>(head[1]) == 0xBD &&
        static_cast<unsigned char>(head[2]) == 0xB3 &&
        static_cast<unsigned char>(head[3]) == 0x56) {
        return Format::Vdb;
    }
    if (head.size() >= 348 &&
        (head.compare(344, 3, "n+1") == 0 || head.compare(344, 3, "ni1") == 0)) {
        return Format::Nifti;
    }
    if (head.size() >= 8 && (head.compare(4, 3, "n+2") == 0 || head.compare(4, 3, "ni2") == 0)) {
        return Format::Nifti;
    }
    const std::string name = lower(path.filename().string());
    if (endsWith(name, ".nii") || endsWith(name, ".nii.gz") || endsWith(name, ".hdr"))
        return Format::Nifti;
    if (endsWith(name, ".nrrd") || endsWith(name, ".nhdr")) return Format::Nrrd;
    if (endsWith(name, ".mha") || endsWith(name, ".mhd")) return Format::MetaImage;
    if (endsWith(name, ".vdb")) return Format::Vdb;
    if (endsWith(name, ".dcm") || endsWith(name, ".ima")) return Format::Dicom;
    // MetaImage headers are text starting with a known key.
    if (head.rfind("ObjectType", 0) == 0 || head.rfind("NDims", 0) == 0) return Format::MetaImage;
    return Format::Unknown;
}

SliceStack readStack(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    SliceStack stack = readStackUnchecked(inputs, options);
    // NaN or infinite voxels are refused at load, with the file named (they would reach the
    // mesher and the ray kernels); the file is at fault, so FormatError.
    try {
        checkStackValues(stack);
    } catch (const ValueError& e) {
        throw FormatError(e.what());
    }
    return stack;
}

Volume load(const std::vector<fs::path>& inputs, const LoadOptions& options) {
    initialize();
    checkResampleOptions(options.resample);
    const std::string what = inputs.empty() ? std::string("load") : inputs.front().string();
    return detail::withVdbErrors<FormatError>(what, "a scan OpenVDB can grid", [&] {
        if (inputs.size() == 1) {
            requireExists(inputs.front());
            // A stored grid has no slices: it is re-gridded as a volume, with the same options.
            if (detectFormat(inputs.front()) == Format::Vdb)
                return resample(loadVdb(inputs.front()), options.resample);
        }
        return resample(readStack(inputs, options), options.resample);
    });
}

namespace {

SliceStack readStackUnchecked(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    if (inputs.empty()) throwExpected("load", "at least one input", "none");
    for (const fs::path& p : inputs) requireExists(p);
    const Format f = detectFormat(inputs.front());
    if (f != Format::Dicom && inputs.size() > 1) {
        throwExpected(inputs[1].string(), std::string("one ") + formatName(f) + " file",
                      std::to_string(inputs.size()) + " inputs");
    }
    switch (f) {
        case Format::Dicom:
            return readDicom(inputs, options);
        case Format::Nifti:
            return readNifti(inputs.front(), options);
        case Format::Nrrd:
            return readNrrd(inputs.front(), options);
        case Format::MetaImage:
            return readMetaImage(inputs.front(), options);
        case Format::Vdb:
            throw ValueError(inputs.front().string() +
                             ": a .vdb holds a grid, not slices; use load()");
        case Format::Unknown:
            break;
    }
    throw FormatError(inputs.front().string() +
                      ": expected a DICOM file or directory, NIfTI (.nii, .nii.gz), NRRD (.nrrd, "
                      ".nhdr), MetaImage (.mha, .mhd) or OpenVDB (.vdb), found an unknown format");
}

}  // namespace

Volume loadVdb(const fs::path& path) {
    initialize();
    openvdb::GridPtrVecPtr grids;
    try {
        openvdb::io::File file(path.string());
        file.open();
        grids = file.getGrids();
        file.close();
    } catch (const openvdb::Exception& e) {
        throw IoError(path.string() +
                      ": expected a readable OpenVDB file, found an error: " + e.what());
    } catch (const std::bad_alloc&) {
        // A (damaged) file whose sizes drive an allocation larger than memory.
        throw FormatError(path.string() +
                          ": expected a readable OpenVDB file, found sizes that cannot be "
                          "allocated (out of memory)");
    } catch (const std::length_error& e) {
        throw FormatError(path.string() +
                          ": expected a readable OpenVDB file, found impossible sizes (" +
                          e.what() + ")");
    }
    openvdb::FloatGrid::Ptr chosen;
    for (const auto& g : *grids) {
        if (auto fg = openvdb::gridPtrCast<openvdb::FloatGrid>(g)) {
            if (fg->getName() == kScanGridName) {
                chosen = fg;
                break;
            }
            if (!chosen) chosen = fg;
        }
    }
    if (!chosen) {
        throw FormatError(path.string() + ": expected a float grid named 'scan', found " +
                          std::to_string(grids->size()) + " grids and none of type float");
    }
    checkStoredGrid(path.string(), *chosen);
    return Volume{chosen, readInfo(*chosen)};
}

void save(const Volume& volume, const fs::path& path, const SaveOptions& options) {
    initialize();
    if (!volume.grid) throwExpected(path.string(), "a volume with a grid", "none");
    AtomicFile out(path, "volume");
    // A grid sharing the caller's tree and transform, with metadata and name of its own,
    // carries the file's name and metadata, so the caller's grid is left as it was.
    const openvdb::FloatGrid::Ptr grid = detail::gridWithTree(*volume.grid, volume.grid->treePtr());
    writeInfo(volume.info, *grid);
    grid->setName(kScanGridName);
    try {
        openvdb::io::File file(out.tempPath().string());
        std::uint32_t flags = openvdb::io::COMPRESS_ACTIVE_MASK;
        if (options.compression == Compression::Blosc &&
            openvdb::io::Archive::hasBloscCompression()) {
            flags |= openvdb::io::COMPRESS_BLOSC;
        } else if (options.compression != Compression::ActiveMask) {
            flags |= openvdb::io::COMPRESS_ZIP;
        }
        file.setCompression(flags);
        openvdb::MetaMap fileMeta;
        fileMeta.insertMeta("creator", openvdb::StringMetadata("palp"));
        file.write({grid}, fileMeta);
        file.close();
    } catch (const std::exception& e) {
        throw IoError(path.string() +
                      ": expected a writable location, found an error: " + e.what());
    }
    out.commit();
}

}  // namespace palp::volume
