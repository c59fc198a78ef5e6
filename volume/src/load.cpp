#include "palp/volume/load.h"

#include <openvdb/io/File.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <fstream>
#include <new>
#include <stdexcept>

#include "formats/formats.h"
#include "formats/reader_util.h"
#include "lazy_stack.h"
#include "palp/base/atomic_file.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"
#include "palp/volume/dicom.h"
#include "vdb/vdb_errors.h"
#include "vdb/vdb_packed.h"
#include "vdb/vdb_read.h"
#include "vdb/vdb_write.h"

namespace palp::volume {

namespace fs = std::filesystem;

namespace {

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

/// A stored grid palp can use: a linear transform with cubic voxels, or (native spacing) an
/// axis-aligned scale with a different edge per axis, each edge a voxel spacing
/// (bounds::kSpacing), and finite values inside bounds::kVolumeValue (the background and every
/// active value), so that nothing the file holds reaches the mesher or the kernels unchecked.
/// @throw FormatError naming @p name.
void checkStoredGrid(const std::string& name, const openvdb::FloatGrid& grid) try {
    const openvdb::math::Transform& xform = grid.transform();
    const openvdb::Vec3d voxel = xform.voxelSize();
    const bool cubic = voxel[0] == voxel[1] && voxel[1] == voxel[2];
    bool axisAligned = xform.isLinear();
    if (axisAligned) {
        const openvdb::Mat4d m = xform.baseMap()->getAffineMap()->getMat4();
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) axisAligned &= r == c || m(r, c) == 0.0;
    }
    if (!xform.isLinear() || (!cubic && !axisAligned)) {
        throwExpected(name + ": grid transform",
                      "a linear transform with cubic voxels, or an axis-aligned scale",
                      "voxel (" + formatValue(voxel[0] * 1e3) + " " + formatValue(voxel[1] * 1e3) +
                          " " + formatValue(voxel[2] * 1e3) + ") mm" +
                          (xform.isLinear() ? " (rotated)" : " (not linear)"));
    }
    for (int a = 0; a < 3; ++a)
        requireWithin(name + ": grid voxel size", voxel[a], bounds::kSpacing, {1e3, "mm"});
    requireWithin(name + ": grid background", static_cast<double>(grid.background()),
                  bounds::kVolumeValue);
    const auto refuse = [&](const openvdb::Coord& c, float v) {
        requireWithin(name + ": grid value at (" + std::to_string(c.x()) + ", " +
                          std::to_string(c.y()) + ", " + std::to_string(c.z()) + ")",
                      static_cast<double>(v), bounds::kVolumeValue);
    };
    // Active tiles above the leaves (few), then the leaves in parallel: a branch-free pass over
    // each leaf's active values (NaN fails both comparisons), and the first leaf in tree order
    // with a value out of bounds names its first such voxel.
    auto tiles = grid.cbeginValueOn();
    tiles.setMaxDepth(openvdb::FloatTree::ValueOnCIter::LEAF_DEPTH - 1);
    for (; tiles; ++tiles)
        if (!bounds::kVolumeValue.contains(static_cast<double>(*tiles)))
            refuse(tiles.getCoord(), *tiles);
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    leaves.reserve(grid.tree().leafCount());
    for (auto it = grid.tree().cbeginLeaf(); it; ++it) leaves.push_back(it.getLeaf());
    constexpr auto lo = static_cast<float>(bounds::kVolumeValue.min);
    constexpr auto hi = static_cast<float>(bounds::kVolumeValue.max);
    static_assert(static_cast<double>(lo) == bounds::kVolumeValue.min &&
                  static_cast<double>(hi) == bounds::kVolumeValue.max);
    std::vector<char> bad(leaves.size(), 0);
    palp::parallelForEach(
        std::size_t{0}, leaves.size(),
        [&](std::size_t i) {
            const auto& leaf = *leaves[i];
            const float* v = leaf.buffer().data();
            if (v == nullptr) return;  // no buffer: every value is the (checked) background
            const auto& mask = leaf.getValueMask();
            bool within = true;
            for (openvdb::Index k = 0; k < leaf.SIZE; ++k)
                within &= (!mask.isOn(k)) | ((v[k] >= lo) & (v[k] <= hi));
            bad[i] = within ? 0 : 1;
        },
        std::size_t{64});
    for (std::size_t i = 0; i < leaves.size(); ++i) {
        if (!bad[i]) continue;
        for (auto it = leaves[i]->cbeginValueOn(); it; ++it)
            if (!bounds::kVolumeValue.contains(static_cast<double>(*it)))
                refuse(it.getCoord(), *it);
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

namespace {

/// A file's format as its content tells it, with the words for messages.
struct Sniffed {
    Format format = Format::Unknown;
    std::string what;  // "a NIfTI-1 file", ...; empty when nothing matched
};

/// The first @p n bytes of the gzip stream @p path, inflated (fewer when the stream is
/// shorter or damaged).
std::string gunzipPrefix(const fs::path& path, std::size_t n) {
    gzFile gz = gzopen(path.c_str(), "rb");
    if (!gz) return {};
    std::string buf(n, '\0');
    const int got = gzread(gz, buf.data(), static_cast<unsigned>(n));
    gzclose(gz);
    buf.resize(got > 0 ? static_cast<std::size_t>(got) : 0);
    return buf;
}

/// Whether @p head starts (after blank lines and comments) with a MetaImage key and '='.
bool looksLikeMetaImage(const std::string& head) {
    static const char* const kKeys[] = {
        "ObjectType",     "NDims",          "DimSize", "ElementType", "ElementDataFile",
        "ElementSpacing", "ObjectSubType",  "Comment", "BinaryData",  "ElementByteOrderMSB",
        "CompressedData", "TransformMatrix"};
    std::size_t at = head.find_first_not_of(" \t\r\n");
    if (at == std::string::npos) return false;
    for (const char* key : kKeys) {
        const std::size_t len = std::char_traits<char>::length(key);
        if (head.compare(at, len, key) != 0) continue;
        const std::size_t eq = head.find_first_not_of(" \t", at + len);
        return eq != std::string::npos && head[eq] == '=';
    }
    return false;
}

Sniffed sniff(const fs::path& path) {
    std::string head = readPrefix(path, 540);
    const auto byte = [&](std::size_t i) { return static_cast<unsigned char>(head[i]); };
    const bool gzip = head.size() >= 2 && byte(0) == 0x1f && byte(1) == 0x8b;
    if (gzip) head = gunzipPrefix(path, 540);
    const std::string packed = gzip ? "a gzip-compressed " : "a ";
    if (head.size() >= 132 && head.compare(128, 4, "DICM") == 0)
        return {Format::Dicom, packed + "DICOM file"};
    if (head.rfind("NRRD000", 0) == 0) return {Format::Nrrd, packed + "NRRD file"};
    if (head.size() >= 4 && byte(0) == 0x20 && byte(1) == 0xBD && byte(2) == 0xB3 &&
        byte(3) == 0x56) {
        return {Format::Vdb, gzip ? "a gzip-compressed OpenVDB file" : "an OpenVDB file"};
    }
    if (head.size() >= 348 && (head.compare(344, 4, std::string("n+1\0", 4)) == 0 ||
                               head.compare(344, 4, std::string("ni1\0", 4)) == 0)) {
        return {Format::Nifti, packed + (head[345] == '+' ? "NIfTI-1 file" : "NIfTI-1 header")};
    }
    if (head.size() >= 8 && (head.compare(4, 4, std::string("n+2\0", 4)) == 0 ||
                             head.compare(4, 4, std::string("ni2\0", 4)) == 0)) {
        return {Format::Nifti, packed + (head[5] == '+' ? "NIfTI-2 file" : "NIfTI-2 header")};
    }
    if (!gzip && looksLikeMetaImage(head)) return {Format::MetaImage, "a MetaImage header"};
    if (gzip) return {Format::Unknown, "a gzip stream"};
    return {};
}

}  // namespace

std::string describeContent(const fs::path& path) { return sniff(path).what; }

bool hasNiftiName(const fs::path& path) {
    const std::string name = detail::lower(path.filename().string());
    for (const char* ext : {".nii", ".nii.gz", ".hdr", ".img", ".hdr.gz", ".img.gz"}) {
        if (endsWith(name, ext)) return true;
    }
    return false;
}

Format detectFormat(const fs::path& path) {
    std::error_code ec;
    if (fs::is_directory(path, ec)) return Format::Dicom;
    // The content decides; the name only where the content says nothing (Analyze .hdr, a
    // DICOM file without its preamble, a damaged file a reader should name).
    const Sniffed s = sniff(path);
    if (s.format != Format::Unknown) return s.format;
    const std::string name = detail::lower(path.filename().string());
    if (endsWith(name, ".nii") || endsWith(name, ".nii.gz") || endsWith(name, ".hdr"))
        return Format::Nifti;
    if (endsWith(name, ".nrrd") || endsWith(name, ".nhdr")) return Format::Nrrd;
    if (endsWith(name, ".mha") || endsWith(name, ".mhd")) return Format::MetaImage;
    if (endsWith(name, ".vdb")) return Format::Vdb;
    if (endsWith(name, ".dcm") || endsWith(name, ".ima")) return Format::Dicom;
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

namespace {

/// load(); with @p packed, a source that is resampled has its leaves packed there and its grid
/// has none (*@p packedUsed then set true).
Volume loadPacking(const std::vector<fs::path>& inputs, const LoadOptions& options,
                   detail::PackedLeaves* packed, bool* packedUsed) {
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
        if (packedUsed) *packedUsed = packed != nullptr;
        if (!inputs.empty() && detectFormat(inputs.front()) == Format::Dicom) {
            // Decoded as the resampler reaches each slice and released behind it: the whole
            // series is never held (readStack() would hold it beside the grid).
            for (const fs::path& p : inputs) requireExists(p);
            detail::LazySliceStack lazy = detail::openDicom(inputs, options);
            return detail::resampleLazy(lazy, options.resample, packed);
        }
        if (inputs.size() == 1) {
            // Likewise a NIfTI, NRRD or MetaImage volume: read (or converted from the stored
            // bytes) a slice at a time, never held as float beside the grid.
            const fs::path& in = inputs.front();
            detail::LazySliceStack lazy;
            switch (detectFormat(in)) {
                case Format::Nifti:
                    lazy = detail::openNifti(in, options);
                    break;
                case Format::Nrrd:
                    lazy = detail::openNrrd(in, options);
                    break;
                case Format::MetaImage:
                    lazy = detail::openMetaImage(in, options);
                    break;
                default:
                    // An unknown format: readStack() says what the file is.
                    return resample(readStack(inputs, options), options.resample);
            }
            return detail::resampleLazy(lazy, options.resample, packed);
        }
        // Several non-DICOM inputs: readStack() refuses them.
        return resample(readStack(inputs, options), options.resample);
    });
}

}  // namespace

Volume load(const std::vector<fs::path>& inputs, const LoadOptions& options) {
    return loadPacking(inputs, options, nullptr, nullptr);
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
    const std::string what = describeContent(inputs.front());
    throw FormatError(inputs.front().string() +
                      ": expected a DICOM file or directory, NIfTI (.nii, .nii.gz), NRRD (.nrrd, "
                      ".nhdr), MetaImage (.mha, .mhd) or OpenVDB (.vdb), found " +
                      (what.empty() ? std::string("an unknown format (its first bytes match none "
                                                  "of them and its name says nothing)")
                                    : what + " palp cannot read"));
}

}  // namespace

Volume loadVdb(const fs::path& path) {
    initialize();
    openvdb::GridPtrVecPtr grids;
    try {
        grids = detail::readGridsMapped(path);
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
    // carries the file's name and metadata, so the caller's grid is left as it was; its leaves
    // are compressed in parallel (the bytes OpenVDB's serial writer would write).
    const openvdb::FloatGrid::Ptr grid = detail::parallelWritingGrid(*volume.grid);
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

ConvertSummary convert(const std::vector<fs::path>& inputs, const fs::path& output,
                       const LoadOptions& options, const SaveOptions& saveOptions) {
    const auto summarise = [](const Volume& v) {
        return ConvertSummary{v.info, v.grid->activeVoxelCount(), v.worldBounds(), v.voxelSizes(),
                              v.grid->background()};
    };
    if (saveOptions.compression != Compression::ActiveMask) {
        const Volume v = load(inputs, options);
        save(v, output, saveOptions);
        return summarise(v);
    }
    detail::PackedLeaves packed;
    bool packedUsed = false;
    const Volume v = loadPacking(inputs, options, &packed, &packedUsed);
    if (!packedUsed) {
        save(v, output, saveOptions);
        return summarise(v);
    }
    v.grid->setName(kScanGridName);
    const detail::PackedStats stats = detail::writePackedVdb(*v.grid, packed, output);
    ConvertSummary out{v.info, stats.activeVoxels, openvdb::BBoxd(), v.voxelSizes(),
                       v.grid->background()};
    if (!stats.box.empty()) out.worldBounds = v.grid->transform().indexToWorld(stats.box);
    return out;
}

}  // namespace palp::volume
