#pragma once
/// @file
/// Internal to palp_volume: a float grid whose leaf buffers are compressed in parallel when an
/// OpenVDB archive writes it, in the same bytes OpenVDB's serial writer produces.

#include <openvdb/openvdb.h>

#include <cstddef>
#include <cstdint>

#include "vdb/vdb_packed.h"

namespace palp::volume::detail {

/// A grid sharing @p source's tree and transform, with a copy of its metadata, whose
/// writeBuffers() compresses the leaves in parallel (batches of ~2,000 leaves: chunks of 64
/// compressed on every thread into memory, then written in order). The file is the one
/// openvdb::io::File would write for @p source (same layout, compression and values); memory
/// held besides the grid: a few compressed chunks.
/// @par Threading  Writing it uses TBB inside; the tree must not change meanwhile.
openvdb::FloatGrid::Ptr parallelWritingGrid(const openvdb::FloatGrid& source);

}  // namespace palp::volume::detail
