#pragma once
/// @file
/// Internal to palp_volume: reading a .vdb file's grids from a read-only memory map.

#include <openvdb/openvdb.h>

#include <filesystem>

namespace palp::volume::detail {

/// Every grid of the OpenVDB file @p path, read whole (no delayed loading) through a stream over
/// a read-only memory map of the file. openvdb::io::File's default (delayed loading) first
/// copies a file below 500 MB to a temporary one and then loads each leaf on its first access;
/// File without delayed loading reads through a std::filebuf whose tellg() (called for every
/// leaf) is a seek system call that drops its buffer.
/// @throw IoError naming @p path when it cannot be opened or mapped; FormatError naming it when
///        the grids need more bytes than the file holds; what openvdb::io::Stream throws for a
///        damaged file (openvdb::Exception, std::bad_alloc, std::length_error).
openvdb::GridPtrVecPtr readGridsMapped(const std::filesystem::path& path);

}  // namespace palp::volume::detail
