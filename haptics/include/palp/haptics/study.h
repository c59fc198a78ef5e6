#pragma once
/// @file
/// Palpation studies: run a session offline over a scripted trajectory and keep its snapshots,
/// bin a run into a 2D map over the palpated plane (stiffness, force or energy-term force),
/// threshold a map and compare it with a mask (IoU), write maps as PNG and runs as CSV traces,
/// and the coupling defaults of the thesis scenes (ALGORITHMS.md sections 2, 3 and 9).
///
/// Used by `palp palpate` and by the virtual AVC/AVCEC experiments (test_experiments).

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "palp/haptics/coupling.h"
#include "palp/haptics/session.h"
#include "palp/haptics/trajectory.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {

// ---------------------------------------------------------------------------------------------
// Scene defaults

/// Coupling defaults for a thesis scene (mode AVC or AVCEC, ray source, lengths, stiffness).
///
/// * Avc: the rigid plate (y 10-12 mm) hides the box (y 20-28 mm) from a first-hit ray, so the
///   source is VolumeAccumulate with sigma = 1/mm above 500 HU (a step between soft 40 HU and
///   rigid 1000 HU) and tau_stop = 3: the 2 mm plate alone (tau = 2) does not stop the ray, the
///   plate plus 1 mm of box does, so L ~ 21 mm over the box and L_max = 40 mm elsewhere (the
///   block is 50 mm deep, nothing rigid below the box). L_ref = L_max = 40 mm, so m(L_max) = 1
///   (soft tissue feels like k_s) and m(21 mm) ~ 1.9: the box nearly doubles k (a change of
///   about 90 %, six times the 15.8 % lateral-sweep stiffness JND of section 8).
/// * Avcec: the plate (y 8-10 mm) is not obscured: VolumeFirstHit at 500 HU, L_max = 40 mm,
///   L_ref = 20 mm, so k = k_s over soft tissue and 2.5 k_s over the plate (L ~ 8 mm).
/// * Bone: VolumeFirstHit at 500 HU, L_max = 40 mm, L_ref = 40 mm (slab top 25 mm +- 7 mm).
/// * Stiffness: VolumeFirstHit at 200 HU (between soft 40 and hard 300), L_max = 40 mm,
///   L_ref = 40 mm.
/// Common: k_s = 300 N/m, m_max = 8, k_max = 2400 N/m (clamp to the device with
/// clampToDevice()), step 0.5 mm (1 mm voxels and finer), no ring (ringCount 0), Sobel angle
/// 0.1 rad and surface offset 1 mm (the stencils must straddle structures a few mm wide).
CouplingParams sceneCouplingDefaults(volume::PhantomScene scene);

/// Coupling defaults for a scan (CT assumed): AVC, VolumeFirstHit at 300 HU (bone), L_max =
/// L_ref = 40 mm (k_s when nothing hard lies within 40 mm, 4 k_s for bone 10 mm deep),
/// otherwise as sceneCouplingDefaults().
CouplingParams scanCouplingDefaults();

/// Lowers maxStiffness to the device's maxStiffnessNpm and to the sampled-wall passivity bound
/// k < 2 b / T (b: the device's maxDampingNspm, T: @p periodSeconds), and baseStiffness to
/// maxStiffness when it is above. Returns the adjusted copy.
CouplingParams clampToDevice(CouplingParams params, const DeviceSpec& device, double periodSeconds);

// ---------------------------------------------------------------------------------------------
// Offline runs

/// Steps @p session (not running) @p ticks times with Session::step() on the calling thread
/// and returns every @p every-th snapshot (the last tick's always included).
/// @throw palp::ValueError for every == 0.
std::vector<Snapshot> runOffline(Session& session, std::uint64_t ticks, std::uint64_t every = 1);

/// Duration (s) after which @p trajectory has done what it scripts: the approach plus
/// @p passes passes for a sweep (length / speed + turn per pass), durationSeconds() for a
/// raster, the approach plus @p passes revolutions for a circle, 2 press + hold for a press,
/// @p passes periods (plus growSeconds) for a sinusoid.
double trajectoryDuration(const Trajectory& trajectory, int passes = 1) noexcept;

/// Figures of one run.
struct RunSummary {
    std::uint64_t ticks = 0;
    double seconds = 0;              ///< simulated (snapshot) time covered, s
    double maxForceN = 0;            ///< largest |force| sent, N
    double finalObserverEnergy = 0;  ///< passivity W at the end, J
    double minObserverEnergy = 0;    ///< smallest W seen, J (negative: the observer saw energy
                                     ///< generated)
    double meanRays = 0;             ///< rays per tick, mean over ticks with a ray bundle
    int maxRays = 0;
    double contactFraction = 0;                 ///< share of ticks with the proxy on a surface
    double minStiffness = 0, maxStiffness = 0;  ///< over contact ticks, N/m
    std::uint64_t faultedTicks = 0, clampedTicks = 0;
};
RunSummary summarize(std::span<const Snapshot> snapshots) noexcept;

// ---------------------------------------------------------------------------------------------
// Maps over the palpated plane

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

/// A binary image over a MapPlane (row-major from the bottom row), 1 = inside.
using Mask = std::vector<std::uint8_t>;

/// Otsu's threshold of the finite pixel values (256 bins between min and max); NaN when the
/// map has fewer than two distinct values.
double otsuThreshold(const ScalarMap& map);
/// Pixels whose value is >= @p threshold (NaN pixels are outside).
Mask thresholdMap(const ScalarMap& map, double threshold);
/// Pixels whose centre satisfies @p inside.
Mask rasterizeMask(const MapPlane& plane,
                   const std::function<bool(const Eigen::Vector3d&)>& inside);
/// |A and B| / |A or B| (1 when both are empty). @throw palp::ValueError for different sizes.
double intersectionOverUnion(const Mask& a, const Mask& b);

/// Index of the largest of @p scores; scores within @p relativeTolerance of the largest
/// (score >= max - tol |max|) are tied and one of them is chosen with a random generator seeded
/// by @p seed, never by position. NaN scores never win. -1 when every score is NaN.
int pickLargest(std::span<const double> scores, double relativeTolerance, std::uint64_t seed);

// ---------------------------------------------------------------------------------------------
// Files

enum class ColorMap { Grey, Heat };
struct PngOptions {
    ColorMap colorMap = ColorMap::Heat;
    double lo = std::numeric_limits<double>::quiet_NaN();  ///< value shown darkest; NaN: min
    double hi = std::numeric_limits<double>::quiet_NaN();  ///< value shown brightest; NaN: max
    int scale = 1;  ///< each map pixel becomes scale x scale image pixels (1-16)
};

/// Writes @p map as an 8-bit PNG (grey, or RGB for Heat: black-red-yellow-white), row 0 at
/// the top = largest v; empty pixels are black (grey) or dark blue (Heat). Written to a
/// temporary file next to @p path and renamed into place.
/// @throw palp::IoError naming the file; palp::ValueError for bad options.
void writeMapPng(const std::filesystem::path& path, const ScalarMap& map,
                 const PngOptions& options = {});

/// Writes a CSV trace, one row per snapshot, SI units:
/// `t,tick,probe_x,probe_y,probe_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,stiffness,
/// ray_length,distance,energy_force_x,energy_force_y,energy_force_z,proxy_force_x,
/// proxy_force_y,proxy_force_z,coupling_energy,observer_energy,added_damping,contacts,rays,
/// sticking,gate_open,faulted,clamped`. Temporary file renamed into place.
/// @throw palp::IoError naming the file.
void writeTraceCsv(const std::filesystem::path& path, std::span<const Snapshot> snapshots);

}  // namespace palp::haptics
