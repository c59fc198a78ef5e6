#pragma once
/// @file
/// Volumes from a host's memory (a viewer's image buffer, a numpy array): a strided grid of
/// scalars with an index-to-world affine, checked like the file readers' and made into a
/// Volume the same way (SliceStack, then resample()).

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>

#include "palp/volume/read_options.h"
#include "palp/volume/resample.h"
#include "palp/volume/slice_stack.h"
#include "palp/volume/volume.h"

namespace palp::volume {

/// Scalar type of the host's voxels (native byte order).
enum class ValueType : std::uint8_t { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

/// The frame and unit of a host's index-to-world affine. palp's world is LPS in metres; RAS
/// (the frame of NIfTI, 3D Slicer and ITK-SNAP's display) negates x and y; millimetres are
/// scaled by 1e-3.
enum class WorldFrame : std::uint8_t { LpsMetres, RasMetres, LpsMillimetres, RasMillimetres };

/// A grid in memory: voxel (i, j, k) (0 <= i < dims[0], ...) holds the value of @p type at
/// byte offset i strides[0] + j strides[1] + k strides[2] from @p data (unaligned is fine), and
/// lies at world = indexToWorld * (i, j, k, 1) in @p frame.
struct MemoryGrid {
    const void* data = nullptr;
    ValueType type = ValueType::Float32;
    std::array<std::int64_t, 3> dims{0, 0, 0};
    /// Byte strides, each > 0 for an axis longer than 1, the axes not overlapping (sorted by
    /// stride, each at least the previous stride times its size, the smallest at least the
    /// element size); all 0: packed with i fastest.
    std::array<std::int64_t, 3> strides{0, 0, 0};
    /// Index to world; the last row must be (0, 0, 0, 1); the columns are the axis steps and
    /// the origin, checked like a file's (spacing within bounds::kSpacing, independent axes,
    /// origin within bounds::kPosition).
    Eigen::Matrix4d indexToWorld{Eigen::Matrix4d::Identity()};
    WorldFrame frame = WorldFrame::LpsMetres;
    /// What the messages call the grid and its fields ("<name>: strides[1]: expected ...").
    std::string name = "memory grid";
};

/// Bytes of one element of @p type.
std::size_t valueTypeSize(ValueType type);
/// "uint8", "int16", ... for messages; nullptr for a value outside the enumerators.
const char* valueTypeName(ValueType type) noexcept;

/// The grid as slices (values converted to float, the affine to LPS metres), with the readers'
/// checks: positive dims whose product of float bytes stays within @p maxBytes (checkedDataBytes'
/// text), at most 2^31 - 1 per axis, strides as above, a finite affine with (0, 0, 0, 1) below,
/// its axes and origin through the readers' affine check, and every value finite inside
/// bounds::kVolumeValue (checkStackValues). info.sourceFormat is "memory".
/// @throw palp::ValueError `<name>: <field>: expected ..., found ...` naming the value.
SliceStack stackFromMemory(const MemoryGrid& grid,
                           std::uint64_t maxBytes = ReadOptions{}.maxSourceBytes);

/// stackFromMemory() resampled into a Volume like load() does (options checked first).
/// @throw palp::ValueError as stackFromMemory() and checkResampleOptions().
Volume fromMemory(const MemoryGrid& grid, const ResampleOptions& options = {});

}  // namespace palp::volume
