#pragma once
/// @file
/// SliceStack: a 3D scan as the reader found it, before resampling. Every slice carries its own
/// world geometry, so gantry tilt and uneven spacing are represented exactly.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "palp/volume/volume_info.h"

namespace palp::volume {

/// One 2D slice: world(c, r) = position + c * colStep + r * rowStep (metres, LPS), where c is
/// the column index (0..cols-1, fastest in `values`) and r the row index.
/// In DICOM terms colStep = ImageOrientation row cosine * PixelSpacing[1] and
/// rowStep = column cosine * PixelSpacing[0].
struct Slice {
    Eigen::Vector3d position = Eigen::Vector3d::Zero();  ///< centre of pixel (0, 0), metres
    Eigen::Vector3d colStep = Eigen::Vector3d::UnitX();  ///< from column c to c+1, metres
    Eigen::Vector3d rowStep = Eigen::Vector3d::UnitY();  ///< from row r to r+1, metres
    std::int32_t cols = 0;
    std::int32_t rows = 0;
    std::vector<float> values;  ///< rows * cols rescaled values, row-major (index r * cols + c)
    std::string source;         ///< file the slice came from (for messages)
};

/// The slices of one 3D volume plus what is known about the acquisition.
struct SliceStack {
    std::vector<Slice> slices;
    VolumeInfo info;
};

/// Builds a stack from a regular grid given by an index-to-world affine (metres, LPS): voxel
/// (i, j, k) is at origin + i*axes.col(0) + j*axes.col(1) + k*axes.col(2). @p values holds
/// dims[0]*dims[1]*dims[2] values with i fastest. Moves the values slice by slice.
SliceStack stackFromAffine(const std::vector<float>& values,
                           const std::array<std::int64_t, 3>& dims, const Eigen::Matrix3d& axes,
                           const Eigen::Vector3d& origin, const std::string& source);

/// Checks that every value of @p stack is finite and inside bounds::kVolumeValue (NaN or
/// infinite voxels would reach the iso-surface mesher and the ray kernels; palp refuses them
/// rather than mapping them to a value the scan does not hold).
/// @throw ValueError `<slice source>: voxel (column c, row r, slice k): expected ..., found nan`.
void checkStackValues(const SliceStack& stack);

}  // namespace palp::volume
