#pragma once
/// @file
/// Deformable tissue for palpation (docs/algorithms.md sections 5 and 10): a hexahedral FEM body
/// with fixed nodes (a support face, nodes inside static inhomogeneities such as bone) and
/// optionally embedded meshes that deform with it (a tumour), stepped every servo tick with the
/// coupling spring solved inside its substeps (coupleContact; or under a held load, by the
/// whole-mesh explicit solver, or by asynchronous regions: an explicit primary region around the
/// contact every tick and an implicit secondary at a lower rate, fem/async_regions.h), spread over
/// the surface nodes near the contact by a Gaussian low-pass filter; its boundary surface is a
/// kernels::RefitMesh (palp's own BVH, refitted in place every tick without allocating) registered
/// in an Embree scene as user geometry (mask kMaskSurface) that is committed once, so the proxy
/// moves on the deformed surface.
///
/// Split in two: DeformableModel (built off the servo thread, immutable, shared by sessions:
/// mesh, material, constraints, surface topology) and DeformableBody (one per session: the
/// solver state, the nodal forces, the refit surface and its Embree scene).
///
/// Choices where the spec is silent:
/// * Filter: weights w_i = exp(-|x_i - c|^2 / (2 sigma^2)) over the free surface nodes within
///   filterCutoff * sigma of the contact point c, on their deformed positions; the nearest
///   free surface node always carries a weight (so a contact farther than the cutoff from every
///   node still loads one node) and takes the rounding remainder, so the nodal forces sum to the
///   total force to rounding (1 ulp per component). sigma = 0: the nearest node only.
/// * Fixed nodes take no load (their share would vanish into the support); only free nodes
///   of the boundary surface are candidates.
/// * Solver: the whole-mesh explicit solver (default; per-tick cost grows with the element
///   count) or asynchronous regions in force drive (DeformableSolver::asyncRegions: the
///   per-tick cost is the primary region's, so larger meshes stay real-time). With the regions
///   the filtered nodal loads are the regions' loads, the region centre follows the load's
///   nearest node with a hysteresis (recentreEdges), and the surface is fed from the regions'
///   watched nodes (the free surface nodes) every tick.

#include <Eigen/Core>
#include <array>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "palp/fem/async_regions.h"
#include "palp/fem/components.h"
#include "palp/fem/constraints.h"
#include "palp/fem/coupling_spring.h"
#include "palp/fem/embedded_mesh.h"
#include "palp/fem/explicit_solver.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/hex_mesh.h"
#include "palp/fem/voxelize.h"
#include "palp/kernels/embree_scene.h"
#include "palp/kernels/refit_bvh.h"
#include "palp/volume/volume.h"

namespace palp::haptics {

/// FEM solver of a deformable body.
enum class DeformableSolver {
    wholeMeshExplicit,  ///< fem::ExplicitSolver over the whole mesh every tick
    asyncRegions,       ///< fem::AsyncRegions, force drive (primary region around the contact)
};

/// Settings of a deformable body.
struct DeformableOptions {
    /// sigma of the Gaussian that spreads the contact force over surface nodes, m (>= 0).
    /// 0: the nearest surface node carries all of it (force steps when it changes).
    double filterWidth = 3e-3;
    /// Nodes farther than filterCutoff * filterWidth from the contact get no load (>= 1).
    double filterCutoff = 3.0;
    /// The whole-mesh explicit solver (substeps of safetyFactor times the critical step). Its
    /// maxSubsteps is 64 here (as the regions' primary), not the solver's 4096: every tick
    /// steps the whole mesh that many times, and at 4096 an in-range but stiff body (1 GPa, or
    /// dampingBeta 0.5 s on 5 kPa) took seconds per tick on the bone phantom; such a body is
    /// now refused at set-up (see tickSeconds).
    fem::ExplicitOptions solver = [] {
        fem::ExplicitOptions o;
        o.maxSubsteps = 64;
        return o;
    }();
    /// Whole-mesh explicit: the period step() will be called with, s (bounds::kPeriod; the
    /// session's servo period). The model is refused at set-up when it needs more than
    /// solver.maxSubsteps substeps per tick (fem::requireExplicitSubsteps names the Young's
    /// modulus, cell size or dampingBeta that makes it too stiff, and what fits); a step() of
    /// another length still runs, bounded by solver.maxSubsteps. asyncRegions use
    /// regions.tickSeconds instead.
    double tickSeconds = 1e-3;
    /// Damping of a coupled contact (coupleContact) as a ratio of critical on the contact's
    /// effective mass (fem::criticalDamping), in [0, 10]. The coupling spring on the light
    /// surface under the probe is a fast mode the tissue's own damping barely touches: without
    /// this the surface overshoots the probe and the contact chatters. It acts only while the
    /// surface under the probe moves (no effect on a held press), dissipates, and is implicit
    /// (no step limit).
    double contactDampingRatio = 1.0;
    /// Whole-mesh explicit (default) or asynchronous regions.
    DeformableSolver solverKind = DeformableSolver::wholeMeshExplicit;
    /// asyncRegions: the regions' options. The body sets drive = force, watchNodes = the free
    /// surface nodes and maxLoads = their count; tickSeconds must be the period step() is
    /// called with. threaded (true here, as a live session needs: the secondary and contact
    /// changes run on their own threads) or false: synchronous and deterministic (tests,
    /// offline runs; the secondary is solved inline every period). condensedOncePerTick is on
    /// here: the condensed correction of Gamma was a third of a live tick on a 35,301-node body
    /// when applied at every substep, for the same force error (bench/README.md).
    fem::AsyncRegionsOptions regions = [] {
        fem::AsyncRegionsOptions o;
        o.threaded = true;
        o.condensedOncePerTick = true;
        return o;
    }();
    /// asyncRegions: the region centre moves to the load's nearest free surface node once the
    /// contact point is nearer to it than to the current centre node by more than
    /// recentreHysteresis element edges (in [0, 1); the hysteresis keeps a contact on the
    /// boundary between two nodes from asking for a new layout every tick). Each move costs a
    /// new layout (regions, primary operator, secondary factorisation and responses: built off
    /// the servo thread, ~0.1-1 s on a 13^3 cube); until it is adopted the old centre stays,
    /// and loads outside its primary reach the tissue through the secondary, one to two
    /// secondary periods late.
    double recentreHysteresis = 0.25;
    /// asyncRegions: a body with more free surface nodes than this (a patient's skin: 17,000 on
    /// the head CT at 5 mm) refreshes its surface near the contact (the primary region, Gamma
    /// and the loaded nodes) every tick and everywhere else in round-robin slices that cover it
    /// once every kSweepPeriods secondary periods (40 ms at 100 Hz), and refits only the
    /// vertices it moved: the far field, which only the secondary moves, then costs a slice a
    /// tick instead of the whole skin (the surface away from the contact lags the secondary by
    /// at most that long). Smaller bodies refresh all of it every tick (>= 1).
    int surfaceSweepAbove = 4096;
    /// asyncRegions: the free surface node nearest this point (m, world) is the initial region
    /// centre; NaN: the first free surface node (the first contact then asks for a move).
    Eigen::Vector3d regionsCentre =
        Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
};

/// Throws palp::ValueError naming the field as `deformable <field>` (`deformable filterWidth:
/// expected a value in [0, 10] m, found -0.001`): filterWidth in bounds::kSpan, filterCutoff
/// finite >= 1, tickSeconds in bounds::kPeriod, solver.safetyFactor in (0, 1],
/// solver.maxSubsteps in [1, fem::kMaxExplicitSubsteps], recentreHysteresis in [0, 1),
/// regionsCentre all NaN or in bounds::kPosition; with asyncRegions also regions.tickSeconds
/// in bounds::kPeriod, regions.safetyFactor in (0, 1] and regions.maxSubsteps in [1,
/// fem::kMaxExplicitSubsteps]. The material and the voxelisation are checked by fem::validate().
/// @throw palp::ValueError
void validateDeformableOptions(const DeformableOptions& options);

/// What can deform: the FEM model, its fixed nodes and boundary surface.
/// @par Threading  Built on one thread, then immutable; shared (const) by sessions.
class DeformableModel {
  public:
    /// @p fixedNodes (all three components fixed) must hold every piece of the mesh
    /// (fem::bodyPieces: three fixed nodes of each face-connected piece not on one line; a
    /// support face does). @throw palp::ValueError for a piece the supports do not hold (named
    /// with its cells and box: it would move as a rigid body), bad options, a model that
    /// needs more explicit substeps per tick than the solver's maxSubsteps (whole mesh:
    /// solver.maxSubsteps at tickSeconds; regions: regions.maxSubsteps at regions.tickSeconds;
    /// fem::requireExplicitSubsteps), nodes outside the model, no fixed node, or no free surface
    /// node.
    DeformableModel(fem::FemModel model, std::vector<int> fixedNodes,
                    const DeformableOptions& options = {});

    /// A box of @p size metres with @p nodeCounts nodes per axis (cubic cells), uniform
    /// @p material, fixed on @p supportFace. @throw palp::ValueError as HexMesh::box.
    static std::shared_ptr<DeformableModel> box(const Eigen::Vector3d& size,
                                                const std::array<int, 3>& nodeCounts,
                                                const fem::ElasticMaterial& material,
                                                fem::BoxFace supportFace,
                                                const DeformableOptions& options = {},
                                                const Eigen::Vector3d& origin = {0, 0, 0});

    /// Voxelises @p volume (fem::voxelizeVolume with @p voxelize) into tissue of uniform
    /// @p material (voxelize.youngsFromValue, when set, gives per-element moduli instead), fixes
    /// the nodes of bone cells (value above voxelize.boneThreshold), the nodes of
    /// @p supportFace when given and the nodes where @p fixedMask (world point -> bool) is true.
    /// Bone cells stay elements (their nodes are fixed, so their modulus only enters the stable
    /// time step: give them the tissue's). The pieces the fixed nodes do not hold (islands, parts
    /// hanging on an edge or a corner) are dropped and the lattice cropped (fem::anchorBody;
    /// voxelize.keepLargestComponent is not used: every held piece stays); keptPieces() and
    /// droppedPieces() say what happened. @throw palp::ValueError (voxelisation, no piece held).
    static std::shared_ptr<DeformableModel> fromVolume(
        const volume::Volume& volume, fem::VoxelizeOptions voxelize,
        const fem::ElasticMaterial& material, std::optional<fem::BoxFace> supportFace,
        const DeformableOptions& options = {},
        const std::function<bool(const Eigen::Vector3d&)>& fixedMask = {});

    /// The same body (mesh, material, supports, pieces) with other @p options; set-up only,
    /// before embedMesh() (embedded meshes are not carried over).
    /// @throw palp::ValueError as the constructor.
    std::shared_ptr<DeformableModel> withOptions(const DeformableOptions& options) const;

    /// Embeds @p rest (world metres; a tumour, cartilage: a dynamic inhomogeneity, docs/
    /// algorithms.md section 10) in the hex elements with trilinear weights (fem::EmbeddedMesh):
    /// every body made from this model deforms it with the tissue each step and refits it in
    /// its Embree scene under @p mask (kMaskBone by default: what AVC/AVCEC's Mesh source casts
    /// against; never kMaskSurface, which the proxy would collide with). Set-up only: call it
    /// before the model is shared with a Scene. @throw palp::ValueError from fem::EmbeddedMesh
    /// (empty mesh, vertices outside the tissue), or for mask 0 or one with kMaskSurface.
    void embedMesh(const kernels::TriangleMesh& rest, unsigned mask = kernels::kMaskBone);
    /// One embedded mesh and its mask.
    struct Embedded {
        fem::EmbeddedMesh mesh;
        unsigned mask;
    };
    const std::vector<Embedded>& embedded() const noexcept { return mEmbedded; }
    /// The nodes a body needs the displacement of every tick: the load nodes, then the nodes
    /// of embedded meshes that are not load nodes (the regions watch these).
    const std::vector<int>& watchNodes() const noexcept { return mWatchNodes; }

    const fem::FemModel& model() const noexcept { return mModel; }
    const fem::Constraints& constraints() const noexcept { return mConstraints; }
    /// Sorted fixed nodes (support and inhomogeneities).
    const std::vector<int>& fixedNodes() const noexcept { return mFixed; }
    /// Boundary surface (rest positions, outward triangles, vertex -> node).
    const fem::SurfaceMesh& surface() const noexcept { return mSurface; }
    /// Free nodes of the boundary surface: the nodes a contact force may load.
    const std::vector<int>& loadNodes() const noexcept { return mLoadNodes; }
    const DeformableOptions& options() const noexcept { return mOptions; }
    /// The regions' initial centre: the free surface node nearest options().regionsCentre on
    /// the rest mesh (NaN: the first free surface node).
    int regionsCentreNode() const noexcept;
    /// Surface vertex of node @p n, -1 for a node not on the surface.
    int vertexOfNode(int n) const noexcept { return mVertexOfNode[static_cast<std::size_t>(n)]; }
    /// Triangles around surface vertex @p v: entries [triangleStart[v], triangleStart[v + 1]) of
    /// vertexTriangles().
    const std::vector<int>& triangleStart() const noexcept { return mTriStart; }
    const std::vector<int>& vertexTriangles() const noexcept { return mVertexTris; }
    /// fromVolume(): the pieces of the voxelised tissue its supports hold (kept, largest first)
    /// and those they do not (dropped); empty for a body made otherwise.
    const std::vector<fem::BodyPiece>& keptPieces() const noexcept { return mKept; }
    const std::vector<fem::BodyPiece>& droppedPieces() const noexcept { return mDropped; }

  private:
    fem::FemModel mModel;
    std::vector<int> mFixed;
    fem::Constraints mConstraints;
    fem::SurfaceMesh mSurface;
    std::vector<int> mLoadNodes;
    std::vector<int> mVertexOfNode, mTriStart, mVertexTris;
    std::vector<Embedded> mEmbedded;
    std::vector<int> mWatchNodes;
    DeformableOptions mOptions;
    std::vector<fem::BodyPiece> mKept, mDropped;
};

/// The per-session state of a deformable body: explicit solver, nodal forces and the deformed
/// surface (a kernels::RefitMesh) in its own EmbreeScene (user geometry, mask kMaskSurface).
///
/// One tick: applyContactForce() (or clearForce()), optionally anchor() a point on the surface,
/// step() (FEM step by T, copy of the deformed surface, refit of its BVH), then
/// anchoredPosition() is the anchored point carried with the surface.
///
/// Cost: the FEM step is O(#elements x substeps), the refit O(#triangles) (bench_refit: a few
/// microseconds for 2k triangles, against ~0.3 ms for Embree's refit commit it replaces); keep
/// real-time meshes to about a 13^3-node cube for the FEM step. Figures:
/// `palp palpate --deformable --fast` prints ticks/s, bench_refit the refit and trace costs.
///
/// Stability: with coupleContact (what a session uses) the coupling spring is integrated with
/// the tissue inside the explicit substeps (fem::CouplingSpring), the substep shrinks with the
/// spring's frequency, and the contact damper (contactDampingRatio) keeps the light surface
/// under a stiff spring from overshooting the probe: any k up to the device's limit holds a
/// press steady on 5-50 kPa tissue (test_deformable, bench/README.md). A load applied with
/// applyContactForce is held over the step (explicit): a loop that feeds the displacement back
/// into such loads needs k below about the local stiffness of the tissue at the contact.
///
/// Asynchronous regions (DeformableSolver::asyncRegions): step() is one AsyncRegions tick under
/// the filtered loads (the primary: explicit, substepped, O(primary cells); the secondary:
/// implicit at regions.secondaryRate), and the free surface nodes' displacements are read from
/// the regions' watched nodes. displacement() then holds the surface nodes only (interior nodes
/// stay 0: use regions()->displacement() off the servo path for the whole field).
/// With coupleContact the regions integrate the spring in the primary's substeps (its share on
/// nodes outside the primary reaches the secondary as loads, one to two periods late: keep the
/// primary centred under the contact, which the hysteresis and the regions' prefetched layouts
/// do). Held loads on the regions (applyContactForce) see about the body's static compliance
/// (the quasi-static secondary has no inertia), so a loop feeding them back needs k near or
/// below the contact's static stiffness unless the primary carries enough mass.
///
/// @par Threading  One thread (the servo thread) drives a body; surfaces() may be traced from
///      that thread between steps. With threaded regions the body owns their threads.
/// @par Real-time  applyContactForce, clearForce, anchor, step and the accessors are noexcept
///      and allocation-free (test_deformable counts zero allocations per tick); step() is
///      bounded by maxSubsteps and the refit is O(#triangles). Synchronous regions solve the
///      secondary inline every period inside step() (which may allocate in CHOLMOD when loads
///      fall on secondary nodes) and, after a recentre, build the new layout inline too
///      (allocating; milliseconds with the global secondary, seconds when a layout must be
///      factorised): threaded regions for live use.
class DeformableBody {
  public:
    /// Allocates everything, builds the surface BVH and commits the Embree scene (the only
    /// commit); with asyncRegions, builds the regions centred on the free surface node nearest
    /// options().regionsCentre (NaN: the first free surface node) and starts their threads.
    /// @throw palp::ValueError for a null model or bad regions options, palp::Error from Embree.
    explicit DeformableBody(std::shared_ptr<const DeformableModel> model);
    ~DeformableBody();
    DeformableBody(const DeformableBody&) = delete;
    DeformableBody& operator=(const DeformableBody&) = delete;

    const DeformableModel& model() const noexcept { return *mModel; }
    /// The deformed surface (committed once; its BVH follows every step()), for the proxy.
    const kernels::EmbreeScene& surfaces() const noexcept { return *mScene; }

    /// Replaces the external load by @p force (N, world) acting at @p point (m, on or near the
    /// surface), spread by the Gaussian filter. Returns the node with the largest share (the
    /// nearest), or -1 (and no load) for non-finite input.
    /// @par Real-time  O(#surface nodes).
    int applyContactForce(const Eigen::Vector3d& point, const Eigen::Vector3d& force) noexcept;
    /// Couples a probe to the surface at @p point for the next step()s, implicitly: a spring of
    /// @p stiffness (N/m) acts on the filtered surface point a(u) (the Gaussian filter's
    /// normalised weights over the nodes near @p point, as applyContactForce spreads a load) and
    /// is evaluated at every explicit substep (fem::CouplingSpring), so the tissue and the
    /// coupling are integrated together and any stiffness is stable. @p force (N, world) is the
    /// force on the tissue now (the reaction of what the hand feels); the spring's target is
    /// set so that it pulls with exactly @p force at the current displacement and changes by
    /// -stiffness times the motion of a(u) during the step; its magnitude is clamped to
    /// @p maxForce. Stiffness <= 0 or not finite: the same as applyContactForce (a load held
    /// over the step). @p probeVelocity (m/s): the spring's target moves with it over the step.
    /// The contact damper (DeformableOptions::contactDampingRatio) is the tissue's and is not
    /// in lastContactForce(). Returns the nearest node, or -1 (and no load) for non-finite
    /// input. lastContactForce() gives the force the tissue received over the step.
    /// @par Real-time  O(#surface nodes).
    int coupleContact(const Eigen::Vector3d& point, const Eigen::Vector3d& force, double stiffness,
                      double maxForce,
                      const Eigen::Vector3d& probeVelocity = Eigen::Vector3d::Zero()) noexcept;
    /// Removes the external load (and the coupling spring). @par Real-time
    void clearForce() noexcept;
    /// Mean force on the tissue over the last step() (N, world): the spring's impulse over the
    /// step for a coupled contact, the applied load otherwise (zero without one).
    const Eigen::Vector3d& lastContactForce() const noexcept { return mLastContactForce; }
    /// True when the last step() clamped the coupling spring's force to its maxForce.
    bool lastContactClamped() const noexcept { return mLastClamped; }

    /// Finds the surface triangle under @p point along -@p normal (within 1 mm; when the ray
    /// slips through an edge or vertex, the closest triangle around the contact node) and
    /// remembers the point in its barycentric frame with its offset along the triangle's normal;
    /// false when no triangle is found. @par Real-time
    bool anchor(const Eigen::Vector3d& point, const Eigen::Vector3d& normal) noexcept;
    /// The anchored point on the current (deformed) triangle, at the same offset along its
    /// current normal. @par Real-time
    Eigen::Vector3d anchoredPosition() const noexcept;

    /// FEM step by @p dtSeconds under the current load, then the deformed surface into the
    /// surface BVH and a refit. Returns the solver's flags (fem::StepFlag, and
    /// fem::kAsyncLoadsRefused) plus kRefitFailed or kSurfaceOutsideBounds. asyncRegions: a
    /// @p dtSeconds other than regions.tickSeconds does nothing and returns
    /// fem::kStepBadTimeStep. @par Real-time
    unsigned step(double dtSeconds) noexcept;
    /// Flag of step(): the deformed surface had a non-finite coordinate; the previous surface
    /// stays.
    static constexpr unsigned kRefitFailed = 1u << 8;
    /// Flag of step(): the surface left the box registered with Embree (the rest box grown by
    /// its largest extent); rays may miss the parts outside it.
    static constexpr unsigned kSurfaceOutsideBounds = 1u << 9;

    /// Nodal displacement, m (#dofs); asyncRegions: surface nodes only (see above).
    const Eigen::VectorXd& displacement() const noexcept {
        return mRegions ? mU : mSolver->displacement();
    }
    /// Current external nodal forces, N (#dofs).
    const Eigen::VectorXd& nodalForce() noexcept { return loadVector(); }
    /// The asynchronous regions (asyncRegions), else nullptr.
    fem::AsyncRegions* regions() noexcept { return mRegions.get(); }
    const fem::AsyncRegions* regions() const noexcept { return mRegions.get(); }
    /// asyncRegions: asks for the region centre to move to the free surface node nearest
    /// @p point (e.g. where the tool is about to touch, before the contact); false when none.
    /// @par Real-time
    bool requestRegionsCentre(const Eigen::Vector3d& point) noexcept;
    /// asyncRegions: the centre node last requested (or the initial one), -1 otherwise.
    int requestedCentre() const noexcept { return mCentre; }
    /// asyncRegions: number of centre moves requested so far.
    int recentreRequests() const noexcept { return mRecentres; }
    /// Nodes loaded by the last applyContactForce() (the first loadedCount() entries).
    const std::vector<int>& loadedNodes() const noexcept { return mLoaded; }
    std::size_t loadedCount() const noexcept { return mLoadedCount; }
    /// The filter's weights of the loaded nodes (first loadedCount() entries, summing to 1).
    const std::vector<double>& loadedWeights() const noexcept { return mWeights; }
    /// Sum of the current external nodal forces (over the loaded nodes), N. @par Real-time
    Eigen::Vector3d loadSum() const noexcept;
    /// Current deformed position of node @p n, m.
    Eigen::Vector3d nodePosition(int n) const noexcept;
    /// The node with the largest share of the last load, -1 without load.
    int contactNode() const noexcept { return mContactNode; }
    /// Embedded mesh @p e's deformed vertex positions after the last step (#V by 3, metres;
    /// the rest positions before the first step).
    std::span<const float> embeddedPositions(std::size_t e) const noexcept {
        return std::span<const float>(mInclusionPositions[e]);
    }
    /// Displacement (m, world) of the material point at rest position @p rest (m, world): the
    /// trilinear interpolation of the nodal displacements over the hex lattice, which inside an
    /// element is the FEM's own displacement field. Inactive (void) nodes count as undisplaced;
    /// a point outside the lattice takes the nearest lattice point's displacement; with
    /// asyncRegions, nodes the regions do not track on the servo thread (secondary nodes that
    /// are not watched: away from the primary region and the surface) count as undisplaced.
    /// @par Real-time  noexcept, allocation-free, O(1).
    Eigen::Vector3d displacementAtRest(const Eigen::Vector3d& rest) const noexcept;
    /// Where the material point at rest position @p rest is now: rest + displacementAtRest().
    /// @par Real-time
    Eigen::Vector3d currentFromRest(const Eigen::Vector3d& rest) const noexcept;
    /// The rest position of the material point now at @p current (the inverse of
    /// currentFromRest): the fixed point of X = x - u(X) from X = x - u(x), at most 12
    /// iterations to 1e-9 m. Exact where |grad u| < 1 (compression or shear below 100 %;
    /// always true of a body that is not turned inside out). Volume rays on a deformable scene
    /// sample the scan here (docs/algorithms.md section 10). @par Real-time  bounded.
    Eigen::Vector3d restFromCurrent(const Eigen::Vector3d& current) const noexcept;
    /// The material rotation at the anchored point (anchor()), from rest to now: each vertex of
    /// the anchored triangle has the rotation that best takes its one-ring's rest edges and
    /// normal to the current ones (least squares: the polar factor of their correlation, as an
    /// as-rigid-as-possible local step), and these are blended with the anchor's barycentric
    /// weights (clamped to the triangle) and taken to the nearest rotation. So R is continuous
    /// as the anchor crosses an edge or a vertex (a per-triangle frame jumped there by twice the
    /// facets' tilt, and at the bottom of a pressed dimple, where the proxy changes facet every
    /// tick, AVCEC's spherical term flipped with it: a buzz, docs/algorithms.md section 3), and
    /// it is the identity for a rigid translation and the rotation itself for a rigid rotation.
    /// Identity while the proxy is not anchored (free space, or clearForce() since) or a ring is
    /// degenerate. AVC/AVCEC rays on deformable tissue are cast in this material frame
    /// (Coupling::setMaterialFrame): a dimple's slope does not turn them (docs/algorithms.md
    /// section 10). @par Real-time  noexcept, allocation-free, O(the three vertices' rings).
    Eigen::Matrix3d anchorRotation() const noexcept;
    /// Largest displacement magnitude over the surface vertices after the last step, m.
    double maxSurfaceDisplacement() const noexcept { return mMaxSurfaceDisplacement; }
    /// The deformed surface as the last step() left it (#V by 3 floats, world metres, in
    /// model().surface() vertex order; the rest surface before the first step).
    const std::vector<float>& surfacePositions() const noexcept { return mPositions; }
    /// Substeps of the last step().
    int lastSubsteps() const noexcept { return mLastSubsteps; }

  private:
    bool anchorOn(int tri, const Eigen::Vector3d& point, const Eigen::Vector3d& normal) noexcept;
    Eigen::VectorXd& loadVector() noexcept { return mRegions ? mForce : mSolver->externalForce(); }
    int nearestLoadNode(const Eigen::Vector3d& point) const noexcept;
    /// Node @p n's displacement for the rest/current map (deformable_map.cpp).
    Eigen::Vector3d nodeDisplacement(int n) const noexcept;
    /// Fills mLoaded/mWeights (weights normalised to sum 1) with the filter around @p point;
    /// returns the nearest free surface node (-1 for none) and its squared distance.
    int filterWeights(const Eigen::Vector3d& point, double& nearestD2) noexcept;
    /// One filterWeights() pass: the contact point, the filter's constants and what it found.
    struct FilterScan {
        Eigen::Vector3d point;
        double cutoff2 = 0, inv2s2 = 0;
        bool gaussian = false;  ///< sigma > 0: nodes within the cutoff are listed
        double best = std::numeric_limits<double>::infinity();
        int nearest = -1;
        std::size_t nearestSlot = 0;
        double total = 0;
    };
    /// Adds load node @p n (index @p li in loadNodes()) to @p scan: listed with its Gaussian
    /// weight when within the cutoff, and the nearest so far. @par Real-time
    void scanFilterNode(FilterScan& scan, int n, std::size_t li) noexcept;
    /// filterWeights() over the load nodes of the lattice box around the contact's rest point
    /// (from the last filter's nearest node's displacement); false when the box cannot be trusted
    /// (no contact before, the nearest node found too far): then the caller scans every node.
    bool localFilter(FilterScan& scan) noexcept;
    /// Regions: the surface node @p n's displacement into mU and its vertex's position.
    void refreshNode(int n) noexcept {
        refreshNode(n, mWatchIndex[static_cast<std::size_t>(n)], mRegions->nodeDisplacement(n),
                    false);
    }
    /// refreshNode() of the node @p n with watch index @p w (-1: not watched) and the
    /// displacement @p d already read; @p skipStill: a node that moved less than kStillMetres
    /// (per axis) since its last refresh keeps its value and is not listed for the refit (the
    /// swept far field, most of which barely moves). The test reads mWatchShown, in watch
    /// order, not the lattice-sized mU.
    void refreshNode(int n, int w, const Eigen::Vector3d& d, bool skipStill) noexcept;
    /// A swept node that moved less than this per axis since its last refresh is left as it is.
    static constexpr double kStillMetres = 1e-6;
    /// The rest of filterWeights(): normalisation, the nearest node's remainder.
    int finishFilter(int nearest, std::size_t nearestSlot, double total) noexcept;
    /// Regions on a big surface: the surface near the contact and a slice of the rest, then
    /// refitSurfaces(); returns its flags.
    unsigned sweepSurface() noexcept;
    /// Refits the surface (@p onlyMoved: only the vertices refreshNode() listed since the last
    /// refit) and the embedded meshes (from displacement()); returns the flags.
    unsigned refitSurfaces(bool onlyMoved = false) noexcept;
    /// Secondary periods one round of the swept surface takes.
    static constexpr double kSweepPeriods = 4;
    /// Regions: asks for the centre to follow the contact node (with the hysteresis).
    void recentreRegions(const Eigen::Vector3d& point, double nearestD2) noexcept;

    std::shared_ptr<const DeformableModel> mModel;
    std::unique_ptr<fem::ExplicitSolver> mSolver;  // wholeMeshExplicit
    std::unique_ptr<fem::AsyncRegions> mRegions;   // asyncRegions
    Eigen::VectorXd mU, mForce;                    // asyncRegions: surface displacement, loads
    std::vector<fem::NodalLoad> mLoads;            // asyncRegions: one per load node
    std::vector<Eigen::Vector3d> mWatched;         // asyncRegions: one per load node
    std::vector<std::uint32_t> mChanged;           // swept surface: watch indices of mWatched
    int mCentre = -1;
    int mRecentres = 0;
    std::unique_ptr<kernels::RefitMesh> mSurface;  // declared before mScene: outlives it
    std::vector<std::unique_ptr<kernels::RefitMesh>> mInclusions;  // one per embedded mesh
    std::vector<std::vector<float>> mInclusionPositions;           // #V by 3 each
    std::unique_ptr<kernels::EmbreeScene> mScene;
    unsigned mGeom = 0;               // the geometry id hits on the surface report
    std::vector<float> mRest;         // #V by 3, rest surface positions
    std::vector<float> mPositions;    // #V by 3, deformed, as handed to the refit
    std::vector<int> mLoaded;         // nodes loaded by the last applyContactForce
    std::vector<double> mWeights;     // scratch, one per load node
    std::vector<double> mLoadRest;    // 3 per load node: its rest position (filterWeights)
    std::vector<int> mLoadIndex;      // per lattice node: its index in loadNodes(), or -1
    std::vector<int> mWatchIndex;     // per lattice node: its index in watchNodes(), or -1
    std::vector<double> mWatchShown;  // swept surface: 3 per watched node, its value in mU
    int mFilterHint = -1;             // the last filter's nearest node: where the next one looks
    std::size_t mSweepNext = 0;       // swept surface: the next watched node of the round robin
    std::size_t mSweepSlice = 0;      // swept surface: watched nodes a tick (0: no sweep)
    double mSweepMax2 = 0, mSweepMaxPrev2 = 0;  // swept surface: largest |u|^2 this and last sweep
    std::vector<std::uint32_t> mMoved;          // swept surface: vertices moved since the refit
    bool mMovedOverflow = false;                // mMoved ran out of room: refit them all
    std::size_t mLoadedCount = 0;
    int mContactNode = -1;
    fem::CouplingSpring mSpring;  // active while a coupled contact holds (spans into mLoaded)
    Eigen::Vector3d mLastContactForce = Eigen::Vector3d::Zero();
    bool mLastClamped = false;
    double mMaxSurfaceDisplacement = 0;
    int mLastSubsteps = 0;
    // Anchor: triangle, barycentric weights, offset along the oriented normal.
    int mAnchorTri = -1;
    std::array<double, 3> mAnchorBary{};
    double mAnchorOffset = 0;
    double mAnchorSign = 1;
};

}  // namespace palp::haptics
