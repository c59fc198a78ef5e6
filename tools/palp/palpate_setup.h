#pragma once
/// @file
/// The set-up of `palp palpate` before it runs: the volume or phantom, the coupling its options
/// ask for, the deformable body, and the path: the press axis and the rectangle it covers (the
/// volume's face, or on a scan the patch of skin that faces the press), the skin it follows and
/// the trajectory.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "palp/haptics/devices/skin_field.h"
#include "palp/haptics/devices/skin_patch.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/haptics/rendering/coupling.h"
#include "palp/haptics/scene.h"
#include "palp/haptics/tissue/deformable.h"
#include "palp/haptics/tissue/deformable_setup.h"
#include "palp/haptics/tissue/material_table.h"
#include "palp/volume/phantom.h"
#include "palp/volume/volume.h"
#include "palpate_options.h"

namespace palp::tool {

/// "+x", "-y", ... for a unit axis.
std::string axisName(const Eigen::Vector3d& a);

/// The volume to palpate, its default coupling and a label for it.
struct Input {
    volume::Volume vol;
    haptics::CouplingParams cp;
    std::string label;
    std::optional<volume::PhantomParams> phantom;  ///< the phantom's, for --phantom
};

/// The phantom --phantom names, or the FILE. @throw palp::Error from the readers.
Input loadInput(const PalpateArgs& a);

/// @p cp with the coupling options applied over it (mode, source, stiffness, rays, damping).
/// @throw palp::ValueError naming the option.
haptics::CouplingParams couplingFromOptions(const PalpateArgs& a, haptics::CouplingParams cp);

/// The table --material-table names ("ct": the one palp ships), or null without one.
/// @throw palp::ValueError naming --material-table, the file and the row it refuses.
std::shared_ptr<const haptics::MaterialTable> materialTableFromOptions(const PalpateArgs& a);

/// Peak resident memory of the process so far, MiB.
double peakRssMiB();
/// Cells of the pieces in @p pieces.
long pieceCells(const std::vector<fem::BodyPiece>& pieces);
/// Active nodes of @p mesh (those its elements use).
int activeNodes(const fem::HexMesh& mesh);

/// What --json says of --material-table: "none", or the table, its rows and the body's nu and
/// density. @throw as materialTableFromOptions().
nlohmann::json materialTableJson(const PalpateArgs& a);

/// The deformable body of --deformable, supported on the face opposite the pressed one, of the
/// law --material names and the moduli of --material-table (or --young-kpa); the solver
/// --fem-solver names (auto: haptics::chooseSolver) and why into @p choice.
std::shared_ptr<const haptics::DeformableModel> makeBody(
    const PalpateArgs& a, const Input& in, const Eigen::Vector3d& press,
    const Eigen::Vector3d& pathCentre, double period, haptics::SolverChoice* choice,
    const haptics::SlidePatch* slide = nullptr);

/// The CT defaults (HU) a scan without Hounsfield units replaces: a scan that is not CT (its
/// modality is not "CT" and no active value lies below -100, e.g. an MR, whose values start at
/// 0) has no air at -1000 nor bone at +500. Its skin (--surface-iso) and tissue (--tissue-hu)
/// are then Otsu's threshold of its active values (256 bins between their least and greatest),
/// it has no bone (--bone-hu: none; a deformable body is fixed on the face opposite the press
/// only) and no hard structure for the rays (--threshold above its greatest value).
struct ScanDefaults {
    bool applies = false;  ///< the scan has no HU
    double threshold = 0;  ///< Otsu's threshold of its values
    double greatest = 0;   ///< its greatest active value
};
ScanDefaults scanDefaults(const volume::Volume& vol);

/// The box of the volume (m): its active voxels' centres grown by half a voxel.
/// @throw palp::ValueError naming @p label when the volume has no active voxel.
Eigen::AlignedBox3d volumeBox(const volume::Volume& vol, const std::string& label);

/// Where the path lies: its centre on the plane of the volume's face against the press (m), the
/// lateral axes u (sweep direction, image right) and v (image up), and the raster extents along
/// them (m).
struct PathFrame {
    Eigen::Vector3d centre, u, v;
    double extentU = 0, extentV = 0;
};

/// The press axis, the skin the path follows, and where that choice came from.
struct SkinPlan {
    Eigen::Vector3d press{Eigen::Vector3d::UnitY()};
    bool follow = false;  ///< the path is laid on the skin
    /// The rectangle of the face whose skin faces the press (when the path follows the skin and
    /// --centre or --extent left it to palp).
    std::optional<haptics::SkinPatch> patch;
    bool pressChosen = false;  ///< the press axis came from findBestSkinPatch() (no --press-axis)
    std::shared_ptr<const haptics::SkinField> field;  ///< set by measureSkin()
};

/// Whether the path follows the skin (--follow-skin; auto: on a scan, rigid or deformable, not
/// on a phantom, whose flat skin keeps its results as they were), the press axis (--press-axis;
/// on a scan followed on its skin without one, the side of the volume with the largest patch of
/// skin facing it) and that patch, found on @p surfaces (the scan's iso-surface).
/// @throw palp::ValueError naming --follow-skin or --press-axis when no skin faces the press.
SkinPlan planSkin(const PalpateArgs& a, bool pressAxisGiven, const Input& in,
                  const kernels::EmbreeScene& surfaces, const Eigen::AlignedBox3d& box);
/// Whether the path follows the skin (planSkin()'s rule, without the surfaces).
bool followsSkin(const PalpateArgs& a, const Input& in);

/// The frame of the path: on @p box's face against @p press, over the lateral box less 5 mm
/// each side or over @p patch, unless --centre, --sweep-axis or --extent say otherwise.
PathFrame pathFrame(const PalpateArgs& a, const Eigen::AlignedBox3d& box,
                    const Eigen::Vector3d& press, const haptics::SkinPatch* patch = nullptr);

/// Measures the skin under the path (frame @p f widened by what the path leaves it: the
/// raster's turns, the circle's radius) along @p plan.press on @p surfaces (a rigid scan's
/// iso-surface; a deformable body's surface at rest), once, off the servo thread; on return
/// @p plan.field is set when @p plan.follow. With skin-following the frame's centre lies on the
/// plane of the volume's face (its component along the press comes from there).
/// @throw palp::ValueError naming --follow-skin when no skin lies under the path.
void measureSkin(const PalpateArgs& a, const kernels::EmbreeScene& surfaces,
                 const Eigen::AlignedBox3d& box, PathFrame& f, SkinPlan& plan);

/// The trajectory --trajectory names over @p f and the time it needs (s).
struct PathPlan {
    haptics::Trajectory traj;
    double duration = 0;
    double approach = 0;  ///< when the path proper starts (the energy budget's origin), s
    /// When the target first rests pressed on the path (after the approach; 0 for a press), s.
    double pressedFrom = 0;
};

/// The path of --trajectory over @p f, pressed along @p press, laid on @p skin when set.
/// @throw palp::ValueError naming the option (speed, radius, frequency).
PathPlan trajectoryFromOptions(const PalpateArgs& a, const PathFrame& f,
                               const Eigen::Vector3d& press,
                               const std::shared_ptr<const haptics::SkinField>& skin);

}  // namespace palp::tool
