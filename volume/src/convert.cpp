// Formats, readStack() and convert(): palp_volume_core, without OpenVDB's library.
#include "palp/volume/convert.h"

#include <tbb/enumerable_thread_specific.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <optional>

#include "formats/formats.h"
#include "formats/reader_util.h"
#include "lazy_stack.h"
#include "palp/base/error.h"
#include "palp/base/shared_library.h"
#include "palp/volume/dicom.h"
#include "resample/leaf_sink.h"
#include "vdb/vdb_packed.h"

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

/// readStack() without the value check: the format's reader.
SliceStack readStackUnchecked(const std::vector<fs::path>& inputs, const ReadOptions& options);

}  // namespace

namespace detail {

void requireExists(const fs::path& p) {
    std::error_code ec;
    if (!fs::exists(p, ec))
        throw IoError(p.string() + ": expected an existing file or directory, found nothing");
}

}  // namespace detail

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

namespace detail {

std::optional<LazySliceStack> openLazy(const std::vector<fs::path>& inputs,
                                       const ReadOptions& options) {
    // The first input's format, sniffed once (its first bytes read).
    const Format format = inputs.empty() ? Format::Unknown : detectFormat(inputs.front());
    if (format == Format::Dicom) {
        // Decoded as the resampler reaches each slice and released behind it: the whole
        // series is never held (readStack() would hold it beside the grid).
        for (const fs::path& p : inputs) requireExists(p);
        return openDicom(inputs, options);
    }
    if (inputs.size() != 1) return std::nullopt;  // readStack() refuses them
    // Likewise a NIfTI, NRRD or MetaImage volume: read (or converted from the stored bytes) a
    // slice at a time, never held as float beside the grid.
    const fs::path& in = inputs.front();
    switch (format) {
        case Format::Nifti:
            return openNifti(in, options);
        case Format::Nrrd:
            return openNrrd(in, options);
        case Format::MetaImage:
            return openMetaImage(in, options);
        default:
            return std::nullopt;  // readStack() says what the file is
    }
}

}  // namespace detail

namespace {

/// The leaves go packed, as the file stores them (PackedLeaves), with the lattice they lie on.
class PackedSink final : public detail::LeafSink {
  public:
    void start(const Eigen::Vector3d& step, const Eigen::Vector3d& lo, float background) override {
        mGrid.step = step;
        mGrid.lo = lo;
        mGrid.background = background;
    }
    float* values() override {
        std::vector<float>& v = mValues.local();
        v.resize(512);
        return v.data();
    }
    void take(const openvdb::Coord& origin, const openvdb::util::NodeMask<3>& mask,
              float* values) override {
        mLeaves.add(origin, mask, values);
    }

    detail::PackedGrid mGrid;
    detail::PackedLeaves mLeaves;

  private:
    tbb::enumerable_thread_specific<std::vector<float>> mValues;
};

/// convert() of a source read slice by slice, written from its packed leaves.
ConvertSummary convertPacked(detail::LazySliceStack& lazy, const fs::path& output,
                             const ResampleOptions& options) {
    detail::checkLazyValues(lazy);
    PackedSink sink;
    sink.mGrid.info = detail::resampleInto(lazy.stack, options, sink, {}, &lazy);
    const detail::PackedStats stats = detail::writePackedVdb(sink.mGrid, sink.mLeaves, output);
    // The voxel and the world box as the grid's transform gives them (its map's scale and
    // translation: storedMap()); Transform::indexToWorld maps the box's corners, index times
    // scale plus translation.
    const detail::StoredMap map = detail::storedMap(sink.mGrid.step, sink.mGrid.lo);
    const Eigen::Vector3d& step = map.scale;
    const Eigen::Vector3d& lo = map.translation;
    ConvertSummary out{sink.mGrid.info, stats.activeVoxels, openvdb::BBoxd(),
                       openvdb::Vec3d(std::abs(step.x()), std::abs(step.y()), std::abs(step.z())),
                       sink.mGrid.background};
    if (!stats.box.empty()) {
        const auto world = [&](const openvdb::Coord& c) {
            return openvdb::Vec3d(static_cast<double>(c.x()) * step.x() + lo.x(),
                                  static_cast<double>(c.y()) * step.y() + lo.y(),
                                  static_cast<double>(c.z()) * step.z() + lo.z());
        };
        out.worldBounds = openvdb::BBoxd(world(stats.box.min()), world(stats.box.max()));
    }
    return out;
}

/// An object of this library, whose address dladdr() maps to the library's file.
const int kAnchor = 0;

/// palp_volume's load() then save(), from libpalp_volume beside this library (as loaded).
ConvertFn loadAndSave() {
    static const ConvertFn fn = [] {
        const fs::path dir = loadedFileDir(&kAnchor);
        const fs::path file =
            dir.empty() ? fs::path(PALP_VOLUME_LIBRARY_FILE) : dir / PALP_VOLUME_LIBRARY_FILE;
        using Entry = ConvertFn (*)();
        return reinterpret_cast<Entry>(
            openLibrarySymbol(file, kLoadAndSaveEntry, "palp's volume library (load and save)"))();
    }();
    return fn;
}

}  // namespace

ConvertSummary convert(const std::vector<fs::path>& inputs, const fs::path& output,
                       const LoadOptions& options, const SaveOptions& saveOptions) {
    if (saveOptions.compression == Compression::ActiveMask) {
        checkResampleOptions(options.resample);
        if (inputs.size() == 1) detail::requireExists(inputs.front());
        if (std::optional<detail::LazySliceStack> lazy = detail::openLazy(inputs, options))
            return convertPacked(*lazy, output, options.resample);
        // A stored grid has no slices: load() re-grids it as a volume. Anything else (an
        // unknown format, several files that are not DICOM): readStack() refuses it.
        if (inputs.size() != 1 || detectFormat(inputs.front()) != Format::Vdb)
            (void)readStack(inputs, options);
    }
    return loadAndSave()(inputs, output, options, saveOptions);
}

namespace {

SliceStack readStackUnchecked(const std::vector<fs::path>& inputs, const ReadOptions& options) {
    if (inputs.empty()) throwExpected("load", "at least one input", "none");
    for (const fs::path& p : inputs) detail::requireExists(p);
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

}  // namespace palp::volume
