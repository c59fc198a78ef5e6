#pragma once
/// @file
/// Internal to palp_volume: the chosen 3D volume of a NIfTI, NRRD or MetaImage file decoded a
/// slice at a time as the resampler reaches it (LazySliceStack), so that load() never holds the
/// volume as float beside the grid, nor (from 32 MiB) a compressed volume's stored bytes.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <string>

#include "formats/raw_data.h"
#include "lazy_stack.h"

namespace palp::volume::detail {

/// Where and how one 3D volume is stored: dims[0] x dims[1] x dims[2] elements, i fastest, k
/// slowest, contiguous.
struct RawVolume {
    std::filesystem::path file;  ///< the data file
    std::string item;            ///< names the source in messages and in Slice::source
    /// Uncompressed: the volume's first element is at byte @ref offset of @ref file.
    /// Compressed (zlib or gzip stream at byte @ref offset): the stream holds @ref streamBytes
    /// decompressed bytes (or more, with @ref trailingAllowed), the volume's first element at
    /// decompressed byte @ref volumeAt.
    bool compressed = false;
    std::uint64_t offset = 0;
    std::uint64_t compressedLimit = UINT64_MAX;  ///< compressed bytes at most (a header's size)
    std::uint64_t streamBytes = 0;
    std::uint64_t volumeAt = 0;
    bool trailingAllowed = false;
    ElementType type = ElementType::Float32;
    ByteOrder order = ByteOrder::Little;
    std::array<std::int64_t, 3> dims{};
    /// Compressed volumes of at least this many stored bytes are not kept: the stream is checked
    /// and indexed once, and each slice decompressed again from the access point before it.
    std::uint64_t indexFromBytes = std::uint64_t{32} << 20;
    bool rescale = false;  ///< values are slope * stored + intercept
    double slope = 1, intercept = 0;
};

/// A lazy stack over @p raw with stackFromAffine()'s slices (voxel (i, j, k) at origin +
/// i axes.col(0) + j axes.col(1) + k axes.col(2)), the same values once decoded. An uncompressed
/// volume is read a slice at a time (pread); a compressed one is decompressed here, the whole
/// stream checked, and either only the volume's stored bytes kept or (from
/// RawVolume::indexFromBytes, one gzip member) an index of access points, from which each slice
/// is decompressed again; then converted a slice at a time.
/// @throw IoError, FormatError as readFileRange() and inflateFileWindow() (a file too short for
///        the volume is refused here, before any slice is decoded).
LazySliceStack openRawVolume(const RawVolume& raw, const Eigen::Matrix3d& axes,
                             const Eigen::Vector3d& origin);

/// Every slice of @p lazy decoded (in parallel), as a resident stack.
/// @throw what its decode throws (the lowest slice's error first).
SliceStack decodeAll(LazySliceStack&& lazy);

}  // namespace palp::volume::detail
