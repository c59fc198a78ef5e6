#pragma once
/// @file
/// Maps over the palpated plane: the plane and its pixels, the quantity a map shows, the mean
/// of that quantity per pixel (ScalarMap) and the binning of a run's snapshots into one.

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "palp/haptics/session.h"

namespace palp::haptics {

/// A rectangle of square pixels in a plane: columns along @p u (left to right in images), rows
/// along @p v (bottom to top in images: image row 0 is the largest v). For the phantoms
/// (surface at y = 0, depth +y) the default u = +x (patient left), v = +z (superior) shows the
/// surface as seen from the anterior side, like an examiner facing the patient.
struct MapPlane {
    Eigen::Vector3d centre{Eigen::Vector3d::Zero()};  ///< m
    Eigen::Vector3d u{Eigen::Vector3d::UnitX()};      ///< unit
    Eigen::Vector3d v{Eigen::Vector3d::UnitZ()};      ///< unit, perpendicular to u
    double extentU = 0.06, extentV = 0.06;            ///< m
    double pixelM = 1e-3;                             ///< pixel edge, m

    int cols() const noexcept;
    int rows() const noexcept;
    /// Pixel (column, row-from-bottom) holding the projection of @p world; false outside.
    bool pixelOf(const Eigen::Vector3d& world, int& col, int& row) const noexcept;
    /// World position (m) of the centre of pixel (@p col, @p row), in the plane.
    Eigen::Vector3d pixelCentre(int col, int row) const noexcept;
};

/// @throw palp::ValueError naming the field (non-finite, non-positive extents or pixel, u or v
///        not unit or not perpendicular, more than 4096 pixels along a side).
void validateMapPlane(const MapPlane& plane);

/// What a map shows, per snapshot.
enum class MapQuantity {
    Stiffness,  ///< k, N/m
    Force,      ///< |force sent|, N
    Energy,     ///< |AVCEC spherical term| + |AVCEC surface term|, N
};
/// "stiffness", "force", "energy". parseMapQuantity() @throw palp::ValueError naming the text.
const char* mapQuantityName(MapQuantity quantity) noexcept;
MapQuantity parseMapQuantity(const std::string& name);
double mapValue(const Snapshot& snapshot, MapQuantity quantity) noexcept;

/// Mean of a quantity per pixel of a MapPlane. Pixels with no sample are NaN.
class ScalarMap {
  public:
    /// @throw palp::ValueError through validateMapPlane().
    explicit ScalarMap(const MapPlane& plane);
    const MapPlane& plane() const noexcept { return mPlane; }
    int cols() const noexcept { return mCols; }
    int rows() const noexcept { return mRows; }
    /// Adds @p value at the pixel under @p world (ignored outside or non-finite).
    void add(const Eigen::Vector3d& world, double value) noexcept;
    /// Mean at (@p col, @p row-from-bottom), NaN when the pixel has no sample.
    double at(int col, int row) const noexcept;
    std::uint32_t count(int col, int row) const noexcept;
    /// Fills empty pixels with the mean of their filled 8-neighbours, repeated @p passes times
    /// (closes the gaps between raster lines coarser than the pixels).
    void fillGaps(int passes);
    /// Sets pixel (@p col, @p row) to @p value (one sample).
    void set(int col, int row, double value) noexcept;
    /// Smallest and largest finite mean (NaN, NaN when empty).
    void range(double& lo, double& hi) const noexcept;
    /// Finite means in pixel order (row-major from the bottom row).
    std::vector<double> finiteValues() const;

  private:
    MapPlane mPlane;
    int mCols = 0, mRows = 0;
    std::vector<double> mSum;
    std::vector<std::uint32_t> mCount;
};

/// Where a snapshot lands on a map.
enum class MapAnchor {
    Proxy,   ///< the proxy: what the hand feels where it is
    RayEnd,  ///< the end of the centre ray, proxy + L d (d = unit proxy -> probe): where the
             ///< structure that set k lies. Friction tilts d by up to atan(mu_s) toward the
             ///< motion, so a structure 20 mm deep shows ~9 mm ahead of the proxy in each sweep
             ///< direction; the ray end undoes that shift for the rays that hit it.
};
/// "proxy", "ray-end". parseMapAnchor() @throw palp::ValueError naming the text.
const char* mapAnchorName(MapAnchor anchor) noexcept;
MapAnchor parseMapAnchor(const std::string& name);

/// Bins @p snapshots at @p anchor; with @p contactOnly, only ticks pressing a surface (contact
/// planes, or D > 1 um) whose coupling had a ray (rays > 0 or mode VC) count.
ScalarMap binSnapshots(std::span<const Snapshot> snapshots, const MapPlane& plane,
                       MapQuantity quantity, bool contactOnly = true,
                       MapAnchor anchor = MapAnchor::Proxy);

}  // namespace palp::haptics
