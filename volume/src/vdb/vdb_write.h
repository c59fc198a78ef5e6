#pragma once
/// @file
/// Internal to palp_volume: a float grid whose leaf buffers are compressed in parallel when an
/// OpenVDB archive writes it, in the same bytes OpenVDB's serial writer produces.

#include <openvdb/openvdb.h>

#include <cstddef>
#include <cstdint>

namespace palp::volume::detail {

/// Bytes of a leaf's buffers as LeafNode::writeBuffers writes them under COMPRESS_ACTIVE_MASK
/// alone (no half floats) when every inactive value is the background: the value mask, the
/// metadata byte and the @p active values.
constexpr std::size_t packedLeafBytes(std::size_t active) noexcept {
    return 64 + 1 + active * sizeof(float);
}

/// Writes those bytes for a leaf whose value mask is @p words (64-bit words in index order) and
/// whose 512 values are @p values, to @p dst; returns the end of what it wrote. Every inactive
/// value must equal the grid's background (the caller's promise: the mask alone restores them).
/// May store up to sizeof(float) bytes past the end it returns (@p dst needs that slack).
char* packLeafBuffers(const std::uint64_t (&words)[8], const float* values, char* dst) noexcept;

/// A grid sharing @p source's tree and transform, with a copy of its metadata, whose
/// writeBuffers() compresses the leaves in parallel (batches of ~2,000 leaves: chunks of 64
/// compressed on every thread into memory, then written in order). The file is the one
/// openvdb::io::File would write for @p source (same layout, compression and values); memory
/// held besides the grid: a few compressed chunks.
/// @par Threading  Writing it uses TBB inside; the tree must not change meanwhile.
openvdb::FloatGrid::Ptr parallelWritingGrid(const openvdb::FloatGrid& source);

}  // namespace palp::volume::detail
