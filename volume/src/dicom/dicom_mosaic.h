#pragma once
// Siemens MOSAIC images (internal): one 2D image holding a whole volume's slices as tiles
// (fMRI, DWI). Layout and geometry as dcm2niix and nibabel document them
// (https://nipy.org/nibabel/dicom/dicom_mosaic.html):
//  * Image Type (0008,0008) holds MOSAIC; the slice count is Number Of Images In Mosaic
//    (0019,100A) (private block "SIEMENS MR HEADER"), else the CSA Image Header's
//    NumberOfImagesInMosaic;
//  * the tiles form a square grid of ceil(sqrt(n)) x ceil(sqrt(n)), filled row by row, each
//    Columns/grid x Rows/grid pixels;
//  * Image Position (Patient) is the corner of the whole mosaic taken as one image with the
//    file's orientation and spacing, centred on the tiles' field of view; the first slice's
//    corner is therefore (Columns - tileColumns)/2 column steps and (Rows - tileRows)/2 row steps
//    further on;
//  * slice k lies k x Spacing Between Slices (0018,0088) (else Slice Thickness) along the CSA
//    Image Header's SliceNormalVector (else row cosine x column cosine).
#include <gdcmDataSet.h>

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "dicom/dicom_header.h"
#include "palp/volume/slice_stack.h"

namespace palp::volume::dicom {

/// Whether @p h is a mosaic: Image Type (0008,0008) holds the value MOSAIC.
bool isMosaic(const Header& h);

/// How one mosaic file packs its slices.
struct MosaicLayout {
    int slices = 0;  ///< tiles that hold slices
    int grid = 0;    ///< tiles per mosaic row and per mosaic column
    int tileColumns = 0, tileRows = 0;
    Eigen::Vector3d normal{0, 0, 1};  ///< unit, the direction slice k + 1 lies from slice k
    bool normalFromCsa = false;       ///< else row cosine x column cosine
    double spacingMm = 0;             ///< between slice centres along the normal
};

/// Reads the layout of the mosaic @p h from its data set @p ds (private tags and CSA header).
/// @throw FormatError naming the file when the slice count is missing or does not tile the
///        image, the CSA normal is not normal to the image plane, or no slice spacing is given.
MosaicLayout mosaicLayout(const Header& h, const gdcm::DataSet& ds);

/// The number of slices in the mosaic @p h, reading its header from the file (for listing a
/// series); 0 when it cannot be told.
int mosaicSliceCount(const Header& h);

/// Cuts the rescaled @p mosaic (Columns x Rows of @p h, row by row) into the slices of layout
/// @p m, each with its own position (from @p h's geometry), in tile order.
/// @throw FormatError naming the file when the layout does not fit the image, or the geometry is
///        missing or bad.
std::vector<Slice> mosaicSlices(const Header& h, const MosaicLayout& m,
                                const std::vector<float>& mosaic);

/// Decodes the mosaic @p h into its slices (values rescaled, each slice with its own position),
/// in tile order; @p originalDims receives tile columns, tile rows and the slice count.
/// @throw FormatError naming the file (see mosaicLayout and decodeFile).
std::vector<Slice> readMosaic(const Header& h, std::array<std::int64_t, 3>& originalDims);

/// The value items of the element @p name in a Siemens CSA header (SV10 or the older CSA1
/// layout) held in @p bytes; empty when absent. Bounds-checked: a damaged header gives empty.
std::vector<std::string> csaItems(const std::string& bytes, const std::string& name);

}  // namespace palp::volume::dicom
