#pragma once
/// @file
/// The thesis's experiments as CT-like phantoms (docs/algorithms.md section 9): each scene is an
/// analytic function world point (metres, LPS) -> HU with exact geometry, sampled into slices
/// or a sparse grid with optional partial-volume blur and deterministic Gaussian noise.
///
/// Frame of every scene: the palpated surface faces anterior (-y) and lies at y = 0; depth is
/// +y (posterior). The surface plane is x (patient left +) by z (superior +), centred on
/// x = z = 0. Axial slices therefore show a cross-section with the surface at the top.
///
/// Materials (HU, all configurable in PhantomMaterials): air -1000, fat -100 (a surface layer,
/// 2 mm by default), soft tissue +40, harder tissue +300 (stiffness scenes), the tumour's
/// inclusion +200, rigid (plates, hidden box, bone) +1000.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "palp/base/triangle_mesh.h"
#include "palp/volume/resample.h"
#include "palp/volume/slice_stack.h"
#include "palp/volume/volume.h"

namespace palp::volume {

/// Which thesis scene a phantom shows.
enum class PhantomScene {
    Avc,        ///< soft block, rigid plate, small rigid box hidden below it in one quadrant
    Avcec,      ///< soft block with a rigid flat plate of one of five shapes under the surface
    Bone,       ///< soft block over a bone slab tilted so that one side is closer to the surface
    Stiffness,  ///< three soft boxes side by side: DP (all harder), CP (harder below a depth),
                ///< CL (harder on one side with a transition profile)
    Tumour,     ///< soft block with a stiffer spherical inclusion (paper VI's dynamic
                ///< inhomogeneity: it deforms with the tissue, fem::EmbeddedMesh)
};

/// Outline of the AVCEC plate in the surface plane (x, z).
enum class PlateShape { Circle, Triangle, Rectangle, Hexagon, Pentagon };

/// Transition profile of the CL stiffness box.
enum class TransitionProfile { Linear, Cosine, Tanh };

/// Values of the materials, HU.
struct PhantomMaterials {
    double airHu = -1000;
    double fatHu = -100;
    double softHu = 40;
    double hardHu = 300;    ///< harder tissue of the stiffness boxes
    double rigidHu = 1000;  ///< plates, the hidden box, bone
    /// Tumour inclusion: harder than soft tissue, below a 500 HU bone threshold (so an FEM
    /// voxelisation keeps its nodes free and it deforms with the tissue).
    double inclusionHu = 200;
};

/// Fixed dimensions of the scenes (metres, in the frame described in the file comment).
namespace phantom_geometry {
inline constexpr double kBlockHalfWidth = 0.050;     ///< AVC/AVCEC/bone block: x, z in +-50 mm
inline constexpr double kBlockDepth = 0.050;         ///< block: y in [0, 50] mm
inline constexpr double kAvcPlateHalfWidth = 0.030;  ///< AVC plate: x, z in +-30 mm
inline constexpr double kAvcPlateTop = 0.010;        ///< AVC plate: y in [10, 12] mm
inline constexpr double kAvcPlateBottom = 0.012;
inline constexpr double kAvcBoxOffset = 0.015;     ///< hidden box centre at x, z = +-15 mm
inline constexpr double kAvcBoxHalfWidth = 0.005;  ///< hidden box 10 mm wide
inline constexpr double kAvcBoxTop = 0.020;        ///< hidden box: y in [20, 28] mm
inline constexpr double kAvcBoxBottom = 0.028;
inline constexpr double kAvcecPlateRadius = 0.020;  ///< circumradius of the AVCEC outlines
inline constexpr double kAvcecRectHalfX = 0.020;    ///< AVCEC rectangle: 40 mm (x) by 24 mm (z)
inline constexpr double kAvcecRectHalfZ = 0.012;
inline constexpr double kAvcecPlateTop = 0.008;  ///< AVCEC plate: y in [8, 10] mm
inline constexpr double kAvcecPlateBottom = 0.010;
inline constexpr double kBoneHalfWidth = 0.040;     ///< bone slab: x, z in +-40 mm
inline constexpr double kBoneCentreDepth = 0.025;   ///< depth of the slab's top at x = 0
inline constexpr double kBoneThickness = 0.006;     ///< measured along y
inline constexpr double kStiffBoxWidth = 0.040;     ///< stiffness boxes 40 x 40 x 40 mm
inline constexpr double kStiffBoxPitch = 0.050;     ///< box centres at x = -50, 0, +50 mm
inline constexpr double kTumourRadius = 0.008;      ///< default inclusion radius
inline constexpr double kTumourDepth = 0.016;       ///< default inclusion centre depth (y)
inline constexpr double kTumourMinRadius = 0.0005;  ///< inclusion radius bounds
inline constexpr double kTumourMaxRadius = 0.020;
}  // namespace phantom_geometry

/// Scene parameters. Lengths in metres.
struct PhantomParams {
    PhantomScene scene = PhantomScene::Avc;
    /// AVC: quadrant of the hidden box: bit 0 set -> x > 0 (patient left), bit 1 set -> z > 0
    /// (superior); 0 = right-inferior, 1 = left-inferior, 2 = right-superior, 3 = left-superior.
    int quadrant = 0;
    /// AVCEC: plate outline.
    PlateShape shape = PlateShape::Circle;
    /// Bone: -1 = patient right side (x < 0) closer to the surface, 0 = level, +1 = left side.
    int displacement = 0;
    /// Bone: tilt of the slab about the z axis for displacement +-1, degrees.
    double boneTiltDeg = 10;
    /// Stiffness CL: profile and width of the soft-to-hard transition along +x.
    TransitionProfile profile = TransitionProfile::Linear;
    double transitionWidth = 0.010;
    /// Stiffness CL: sharpness a of the scaled tanh profile.
    double tanhSharpness = 3;
    /// Stiffness CP: depth below which the box is harder.
    double hardDepth = 0.015;
    /// Tumour: centre of the spherical inclusion (x lateral, y depth, z), metres. It must lie
    /// with its whole sphere inside the block, below the fat layer.
    Eigen::Vector3d inclusionCentre{0, phantom_geometry::kTumourDepth, 0};
    /// Tumour: radius of the inclusion, metres ([0.5, 20] mm).
    double inclusionRadius = phantom_geometry::kTumourRadius;
    /// Thickness of the fat layer under the surface (0 for none).
    double fatThickness = 0.002;
    PhantomMaterials materials;
};

/// A sphere, world metres.
struct PhantomSphere {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double radius = 0;
};

/// A closed, outward-oriented (counter-clockwise seen from outside) triangle mesh of
/// @p sphere: the icosahedron subdivided @p subdivisions times (each triangle into 4), its
/// vertices on the sphere (to float rounding). 10 * 4^s + 2 vertices and 20 * 4^s triangles;
/// it is inscribed, so its volume falls short of the sphere's by about 0.9 % at s = 3.
/// @throw ValueError for a non-finite centre, a radius outside bounds::kLength, subdivisions
///        outside [0, 6].
TriangleMesh icosphere(const PhantomSphere& sphere, int subdivisions);

/// Smooth step from 0 (at @p x <= 0) to 1 (at @p x >= @p width): linear x/w, cosine
/// (1 - cos(pi x / w)) / 2, or scaled tanh (tanh(a (2x/w - 1)) / tanh(a) + 1) / 2.
double transitionProfile(TransitionProfile profile, double x, double width, double tanhSharpness);

/// A scene with exact geometry.
/// @par Threading  Immutable after construction; valueAt may be called from any thread.
class Phantom {
  public:
    /// @throw ValueError for parameters outside their ranges (quadrant 0-3, displacement -1..1,
    ///        positive widths, |boneTiltDeg| < 30, tanhSharpness > 0, materials inside
    ///        bounds::kVolumeValue, an inclusion radius outside [0.5, 20] mm or an inclusion
    ///        sphere not inside the block below the fat layer, ...).
    explicit Phantom(const PhantomParams& params);

    /// Noise-free, unblurred value (HU) at a world point in metres (LPS).
    double valueAt(const Eigen::Vector3d& worldMetres) const;

    /// World box (metres) of everything that is not air.
    WorldBox bounds() const;

    const PhantomParams& params() const { return mParams; }

    /// Scene name and parameters, e.g. "avc quadrant=2 fat=2mm".
    std::string description() const;

    /// AVC: the rigid plate and the hidden box of @p quadrant (metres).
    static WorldBox avcPlate();
    static WorldBox avcHiddenBox(int quadrant);

    /// Bone: depth (y, metres) of the slab's top surface at lateral position @p x.
    double boneTopDepth(double x) const;

    /// Stiffness: x of the centre of box @p index (0 = DP, 1 = CP, 2 = CL), metres.
    static double stiffnessBoxCentreX(int index);

    /// Tumour: the inclusion sphere (world metres), as in params().
    /// @throw ValueError for another scene (it has no inclusion).
    PhantomSphere inclusion() const;
    /// Tumour: the inclusion's surface, icosphere(inclusion(), @p subdivisions) (the default 3:
    /// 642 vertices, 1280 triangles), world metres, to embed in an FEM mesh
    /// (fem::EmbeddedMesh) or trace rays against.
    /// @throw ValueError for another scene or subdivisions outside [0, 6].
    TriangleMesh inclusionMesh(int subdivisions = 3) const;

  private:
    bool insidePlateOutline(double x, double z) const;
    double tissueValue(double depth) const;

    PhantomParams mParams;
    std::vector<Eigen::Vector2d> mEdgeNormals;  ///< AVCEC polygon edge normals (x, z)
    double mApothem = 0;                        ///< AVCEC polygon apothem, metres
    double mBoneSlope = 0;                      ///< d(depth)/dx of the bone slab's top
};

/// How a phantom is rendered into values. Lengths in metres.
struct PhantomSpec {
    PhantomParams params;
    double voxelSize = 0.0005;  ///< makePhantomVolume's isotropic voxel edge
    double noiseSigmaHu = 0;    ///< standard deviation of additive Gaussian noise, HU
    double blurSigma = 0;       ///< Gaussian blur (partial volume) standard deviation, metres
    int supersample = 1;        ///< n: each pixel averages n^3 sub-samples of its footprint (1-8)
    std::uint64_t seed = 0;     ///< noise seed: the same seed gives bit-identical output
    double margin = 0.005;      ///< air around the scene's bounds
};

/// An acquisition geometry: axial slices (tilted by the gantry) stacked along z, covering the
/// phantom's bounds plus the spec's margin. Lengths in metres.
struct SliceGeometry {
    double pixelSpacing = 0.0005;  ///< in-plane, both directions
    /// Gap between adjacent slices measured along the slice normal (the table moves by
    /// gap / cos(tilt) along z, as on a tilted scanner).
    double sliceSpacing = 0.001;
    /// Uneven gaps along the normal, used cyclically (gap k between slices k and k+1); when
    /// empty, sliceSpacing throughout.
    std::vector<double> sliceGaps;
    /// Gantry tilt, degrees: row direction (1, 0, 0), column direction (0, cos t, -sin t).
    double tiltDeg = 0;
    /// Footprint of a slice along its normal for supersampling; 0 -> the smallest gap.
    double sliceThickness = 0;
};

/// Samples the phantom on the slices of @p geometry: partial volume (supersampling over each
/// pixel's footprint and/or Gaussian blur), then noise. VolumeInfo is filled (CT, HU,
/// "phantom", the description). Each slice's `source` is "phantom slice K".
/// @throw ValueError for bad spec or geometry: spacings and gaps outside bounds::kSpacing, noise
///        outside bounds::kVolumeSpread (so no value overflows), blur or margin outside
///        bounds::kSpan, blur above 100 pixel spacings, |tilt| >= 60 degrees, more than 2^28
///        pixels in all, ...
/// @par Threading  Parallel inside (TBB); the result does not depend on the scheduling.
SliceStack makePhantomSlices(const PhantomSpec& spec, const SliceGeometry& geometry);

/// The phantom as a Volume: axial slices at spec.voxelSize in all three directions, with pixel
/// centres at (k + 1/2) voxelSize, resampled exactly into a grid named "scan" (background
/// -1000 HU, values below -900 inactive).
/// @throw ValueError for a voxel size outside bounds::kSpacing, and as makePhantomSlices and
///        resample().
Volume makePhantomVolume(const PhantomSpec& spec);

/// Names used by the palp tool and descriptions ("avc", "avcec", "bone", "stiffness",
/// "tumour").
const char* sceneName(PhantomScene scene);
const char* shapeName(PlateShape shape);
const char* profileName(TransitionProfile profile);
/// Parses the names above (lower case). @throw ValueError naming @p name and the choices.
PhantomScene parseScene(std::string_view name);
PlateShape parseShape(std::string_view name);
TransitionProfile parseProfile(std::string_view name);

}  // namespace palp::volume
