#include "palp/haptics/tissue/deformable.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <span>
#include <string>
#include <string_view>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::haptics {
namespace {

// Slack of the surface BVH's boxes, in element edges (see the constructor).
constexpr double kRefitSlackEdges = 0.05;

// Rest positions of the surface vertices as a kernels::TriangleMesh.
kernels::TriangleMesh toTriangleMesh(const fem::SurfaceMesh& s) {
    kernels::TriangleMesh m;
    m.positions.reserve(3 * s.vertices.size());
    for (const Eigen::Vector3f& v : s.vertices) {
        m.positions.push_back(v.x());
        m.positions.push_back(v.y());
        m.positions.push_back(v.z());
    }
    m.indices.reserve(3 * s.triangles.size());
    for (const auto& t : s.triangles) m.indices.insert(m.indices.end(), t.begin(), t.end());
    return m;
}

}  // namespace

void validateDeformableOptions(const DeformableOptions& o) {
    requireWithin("deformable filterWidth", o.filterWidth, bounds::kSpan);
    requireAtLeast("deformable filterCutoff", o.filterCutoff, 1.0);
    requireWithin("deformable tickSeconds", o.tickSeconds, bounds::kPeriod);
    if (!(o.contactDampingRatio >= 0 && o.contactDampingRatio <= 10)) {
        throwExpected("deformable contactDampingRatio", "a value in [0, 10]",
                      formatValue(o.contactDampingRatio));
    }
    const auto substeps = [](std::string_view what, double safety, int maxSubsteps) {
        if (!(safety > 0 && safety <= 1)) {
            throwExpected(std::string(what) + ".safetyFactor", "a value in (0, 1]",
                          formatValue(safety));
        }
        if (maxSubsteps < 1 || maxSubsteps > fem::kMaxExplicitSubsteps) {
            throwExpected(std::string(what) + ".maxSubsteps",
                          "a count in [1, " + std::to_string(fem::kMaxExplicitSubsteps) + "]",
                          std::to_string(maxSubsteps));
        }
    };
    substeps("deformable solver", o.solver.safetyFactor, o.solver.maxSubsteps);
    if (o.surfaceSweepAbove < 1) {
        throwExpected("deformable surfaceSweepAbove", ">= 1", std::to_string(o.surfaceSweepAbove));
    }
    if (!(o.recentreHysteresis >= 0 && o.recentreHysteresis < 1)) {
        throwExpected("deformable recentreHysteresis", "a value in [0, 1)",
                      formatValue(o.recentreHysteresis));
    }
    if (!o.regionsCentre.array().isNaN().all()) {
        for (int a = 0; a < 3; ++a) {
            requireWithin("deformable regionsCentre (NaN for none)", o.regionsCentre[a],
                          bounds::kPosition);
        }
    }
    if (o.solverKind == DeformableSolver::asyncRegions) {
        requireWithin("deformable regions.tickSeconds", o.regions.tickSeconds, bounds::kPeriod);
        substeps("deformable regions", o.regions.safetyFactor, o.regions.maxSubsteps);
    }
}

DeformableModel::DeformableModel(fem::FemModel model, std::vector<int> fixedNodes,
                                 const DeformableOptions& options)
    : mModel(std::move(model)),
      mFixed(std::move(fixedNodes)),
      mConstraints(mModel.dofCount()),
      mOptions(options) {
    validateDeformableOptions(options);
    // Set-up refusal of a body too stiff for its tick (never a capped, unstable substep nor a
    // tick of thousands of substeps that advances less time than asked).
    if (options.solverKind == DeformableSolver::asyncRegions) {
        fem::requireExplicitSubsteps(mModel, options.regions.safetyFactor,
                                     options.regions.maxSubsteps, options.regions.tickSeconds,
                                     "deformable regions.maxSubsteps");
    } else {
        fem::requireExplicitSubsteps(mModel, options.solver.safetyFactor,
                                     options.solver.maxSubsteps, options.tickSeconds,
                                     "deformable solver.maxSubsteps");
    }
    std::sort(mFixed.begin(), mFixed.end());
    mFixed.erase(std::unique(mFixed.begin(), mFixed.end()), mFixed.end());
    if (mFixed.empty()) {
        throw ValueError(
            "deformable: expected fixed nodes (a support face or an inhomogeneity), found none");
    }
    mConstraints.fixNodes(mFixed);  // throws for nodes outside the model
    fem::requireAnchored(mModel.mesh(), mFixed);
    mSurface = mModel.mesh().boundarySurface();
    std::vector<std::uint8_t> seen(static_cast<std::size_t>(mModel.mesh().nodeCount()), 0);
    for (const std::int32_t n : mSurface.vertexNode) {
        const auto i = static_cast<std::size_t>(n);
        if (seen[i]) continue;
        seen[i] = 1;
        if (!mConstraints.isFixed(3 * n)) mLoadNodes.push_back(n);
    }
    std::sort(mLoadNodes.begin(), mLoadNodes.end());
    mVertexOfNode.assign(seen.size(), -1);
    for (std::size_t v = 0; v < mSurface.vertexNode.size(); ++v)
        mVertexOfNode[static_cast<std::size_t>(mSurface.vertexNode[v])] = static_cast<int>(v);
    mTriStart.assign(mSurface.vertices.size() + 1, 0);
    for (const auto& t : mSurface.triangles)
        for (const std::uint32_t v : t) ++mTriStart[v + 1];
    for (std::size_t v = 0; v + 1 < mTriStart.size(); ++v) mTriStart[v + 1] += mTriStart[v];
    mVertexTris.resize(static_cast<std::size_t>(mTriStart.back()));
    std::vector<int> fill(mTriStart.begin(), mTriStart.end() - 1);
    for (std::size_t i = 0; i < mSurface.triangles.size(); ++i)
        for (const std::uint32_t v : mSurface.triangles[i])
            mVertexTris[static_cast<std::size_t>(fill[v]++)] = static_cast<int>(i);
    if (mLoadNodes.empty()) {
        throw ValueError("deformable: expected free nodes on the boundary surface, found all " +
                         std::to_string(mSurface.vertices.size()) + " surface nodes fixed");
    }
    mWatchNodes = mLoadNodes;
}

void DeformableModel::embedMesh(const kernels::TriangleMesh& rest, unsigned mask) {
    if (mask == 0 || (mask & kernels::kMaskSurface) != 0) {
        throw ValueError(
            "deformable embedded mesh mask: expected a non-zero mask without "
            "kMaskSurface (the proxy's), found " +
            std::to_string(mask));
    }
    mEmbedded.push_back(Embedded{fem::EmbeddedMesh(mModel, rest), mask});
    // Watch its nodes too (regions): the load nodes first, then the new ones, sorted.
    std::vector<int> extra;
    for (const int n : mEmbedded.back().mesh.nodes()) {
        if (!std::binary_search(mLoadNodes.begin(), mLoadNodes.end(), n)) extra.push_back(n);
    }
    std::vector<int> old(mWatchNodes.begin() + static_cast<std::ptrdiff_t>(mLoadNodes.size()),
                         mWatchNodes.end());
    std::vector<int> merged;
    std::set_union(old.begin(), old.end(), extra.begin(), extra.end(), std::back_inserter(merged));
    mWatchNodes.resize(mLoadNodes.size());
    mWatchNodes.insert(mWatchNodes.end(), merged.begin(), merged.end());
}

int DeformableModel::regionsCentreNode() const noexcept {
    int centre = mLoadNodes.front();
    if (!mOptions.regionsCentre.allFinite()) return centre;
    double best = std::numeric_limits<double>::infinity();
    for (const int n : mLoadNodes) {  // on the rest mesh
        const double d2 = (mModel.mesh().nodePosition(n) - mOptions.regionsCentre).squaredNorm();
        if (d2 < best) {
            best = d2;
            centre = n;
        }
    }
    return centre;
}

std::shared_ptr<DeformableModel> DeformableModel::box(const Eigen::Vector3d& size,
                                                      const std::array<int, 3>& nodeCounts,
                                                      const fem::ElasticMaterial& material,
                                                      fem::BoxFace supportFace,
                                                      const DeformableOptions& options,
                                                      const Eigen::Vector3d& origin) {
    fem::FemModel model(fem::HexMesh::box(size, nodeCounts, material.youngsModulus, origin),
                        material);
    std::vector<int> fixed = model.mesh().faceNodes(supportFace);
    return std::make_shared<DeformableModel>(std::move(model), std::move(fixed), options);
}

std::shared_ptr<DeformableModel> DeformableModel::fromVolume(
    const volume::Volume& volume, fem::VoxelizeOptions voxelize,
    const fem::ElasticMaterial& material, std::optional<fem::BoxFace> supportFace,
    const DeformableOptions& options,
    const std::function<bool(const Eigen::Vector3d&)>& fixedMask) {
    validateDeformableOptions(options);
    fem::validate(material);
    if (!voxelize.youngsFromValue) {
        const double e = material.youngsModulus;
        voxelize.youngsFromValue = [e](double) { return e; };
    }
    // Every piece the supports hold stays (fem::anchorBody), not only the largest.
    voxelize.keepLargestComponent = false;
    fem::VoxelizedMesh vm = fem::voxelizeVolume(volume, voxelize);
    std::vector<int> fixed = vm.boneNodes;
    if (supportFace) {
        const std::vector<int> face = vm.mesh.faceNodes(*supportFace);
        fixed.insert(fixed.end(), face.begin(), face.end());
    }
    if (fixedMask) {
        const std::vector<int> masked = vm.mesh.nodesWhere(fixedMask);
        fixed.insert(fixed.end(), masked.begin(), masked.end());
    }
    fem::AnchoredBody body = fem::anchorBody(vm.mesh, fixed);
    fem::FemModel model(std::move(body.mesh), material);
    auto out =
        std::make_shared<DeformableModel>(std::move(model), std::move(body.fixedNodes), options);
    out->mKept = std::move(body.kept);
    out->mDropped = std::move(body.dropped);
    return out;
}

std::shared_ptr<DeformableModel> DeformableModel::withOptions(
    const DeformableOptions& options) const {
    auto out = std::make_shared<DeformableModel>(mModel, mFixed, options);
    out->mKept = mKept;
    out->mDropped = mDropped;
    return out;
}

DeformableBody::DeformableBody(std::shared_ptr<const DeformableModel> model)
    : mModel(model ? std::move(model)
                   : throw ValueError("deformable body: expected a model, found a null pointer")),
      mScene(std::make_unique<kernels::EmbreeScene>(/*robust=*/true)) {
    const DeformableOptions& options = mModel->options();
    if (options.solverKind == DeformableSolver::asyncRegions) {
        const std::vector<int>& nodes = mModel->loadNodes();
        fem::AsyncRegionsOptions o = options.regions;
        o.drive = fem::ContactDrive::force;
        o.watchNodes = mModel->watchNodes();
        o.maxLoads = static_cast<int>(nodes.size());
        mU = Eigen::VectorXd::Zero(mModel->model().dofCount());
        mForce = mU;
        mCentre = mModel->regionsCentreNode();
        mRegions = std::make_unique<fem::AsyncRegions>(mModel->model(), mModel->constraints(),
                                                       std::vector<int>{mCentre}, o);
        mLoads.resize(nodes.size());
        mWatched.resize(mModel->watchNodes().size());
        mChanged.resize(mWatched.size());
    } else {
        mSolver = std::make_unique<fem::ExplicitSolver>(mModel->model(), mModel->constraints(),
                                                        options.solver);
        mSolver->externalForce().setZero();
    }
    const kernels::TriangleMesh mesh = toTriangleMesh(mModel->surface());
    mRest = mesh.positions;
    mPositions = mesh.positions;
    mSurface = std::make_unique<kernels::RefitMesh>(mesh);
    // Embree's box of the surface: the rest box grown by its largest extent on every side. A
    // body deformed by more than its own size has left any regime this model describes; step()
    // flags kSurfaceOutsideBounds if it happens.
    const kernels::Box3f rest = mSurface->bounds();
    float extent = 0;
    for (std::size_t k = 0; k < 3; ++k) extent = std::max(extent, rest.hi[k] - rest.lo[k]);
    // Boxes grown by 5 % of an element edge: the far field, which drifts by far less every
    // tick, then costs a sweep over the vertices, and only the boxes around the contact are
    // refitted (kernels::RefitMesh::setRefitSlack; hits stay exact).
    const auto slack = static_cast<float>(kRefitSlackEdges * mModel->model().mesh().edge());
    mSurface->setRefitSlack(slack);
    mGeom = mScene->addRefitMesh(*mSurface, kernels::kMaskSurface, extent);
    for (const DeformableModel::Embedded& e : mModel->embedded()) {
        mInclusions.push_back(std::make_unique<kernels::RefitMesh>(e.mesh.restMesh()));
        mInclusions.back()->setRefitSlack(slack);
        mInclusionPositions.push_back(e.mesh.restMesh().positions);
        mScene->addRefitMesh(*mInclusions.back(), e.mask, extent);
    }
    mScene->commit();  // once: later steps refit palp's BVH only
    mLoaded.resize(mModel->loadNodes().size());
    mWeights.resize(mModel->loadNodes().size());
    mLoadRest.reserve(3 * mModel->loadNodes().size());
    const auto nodeCount = static_cast<std::size_t>(mModel->model().mesh().nodeCount());
    mLoadIndex.assign(nodeCount, -1);
    for (const int n : mModel->loadNodes()) {
        const Eigen::Vector3d x = mModel->model().mesh().nodePosition(n);
        mLoadIndex[static_cast<std::size_t>(n)] = static_cast<int>(mLoadRest.size() / 3);
        mLoadRest.insert(mLoadRest.end(), {x.x(), x.y(), x.z()});
    }
    if (mRegions &&
        mModel->loadNodes().size() > static_cast<std::size_t>(options.surfaceSweepAbove)) {
        // A slice a tick covers the surface once per secondary period.
        const std::vector<int>& watch = mModel->watchNodes();
        mWatchIndex.assign(nodeCount, -1);
        for (std::size_t i = 0; i < watch.size(); ++i)
            mWatchIndex[static_cast<std::size_t>(watch[i])] = static_cast<int>(i);
        mWatchShown.assign(3 * watch.size(), 0.0);
        const double period = 1.0 / (options.regions.secondaryRate * options.regions.tickSeconds);
        const auto ticks =
            static_cast<std::size_t>(std::max(1.0, std::floor(kSweepPeriods * period)));
        mSweepSlice = (watch.size() + ticks - 1) / ticks;
        // The vertices a tick moves: the slice and the nodes near the contact (bounded by
        // twice the surface; more falls back to a refit that sweeps every vertex).
        mMoved.reserve(2 * mRest.size() / 3);
    }
}

DeformableBody::~DeformableBody() = default;

Eigen::Vector3d DeformableBody::nodePosition(int n) const noexcept {
    const Eigen::VectorXd& u = displacement();
    return mModel->model().mesh().nodePosition(n) + u.segment<3>(3 * n);
}

int DeformableBody::nearestLoadNode(const Eigen::Vector3d& point) const noexcept {
    double best = std::numeric_limits<double>::infinity();
    int nearest = -1;
    for (const int n : mModel->loadNodes()) {
        const double d2 = (nodePosition(n) - point).squaredNorm();
        if (d2 < best) {
            best = d2;
            nearest = n;
        }
    }
    return nearest;
}

bool DeformableBody::requestRegionsCentre(const Eigen::Vector3d& point) noexcept {
    if (!mRegions || !point.allFinite()) return false;
    const int n = nearestLoadNode(point);
    if (n < 0) return false;
    if (n != mCentre && mRegions->requestContactNode(n)) {
        mCentre = n;
        ++mRecentres;
    }
    return true;
}

Eigen::Vector3d DeformableBody::loadSum() const noexcept {
    // loadVector() is non-const (ExplicitSolver::externalForce()); reading it changes nothing.
    const Eigen::VectorXd& f = const_cast<DeformableBody*>(this)->loadVector();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < mLoadedCount; ++i) sum += f.segment<3>(3 * mLoaded[i]);
    return sum;
}

void DeformableBody::clearForce() noexcept {
    Eigen::VectorXd& f = loadVector();
    if (!mSpring.active()) {
        for (std::size_t i = 0; i < mLoadedCount; ++i) f.segment<3>(3 * mLoaded[i]).setZero();
    }
    mSpring = fem::CouplingSpring{};
    mLoadedCount = 0;
    mContactNode = -1;
    mAnchorTri = -1;
}

int DeformableBody::filterWeights(const Eigen::Vector3d& point, double& nearestD2) noexcept {
    mLoadedCount = 0;
    const std::vector<int>& nodes = mModel->loadNodes();
    const double sigma = mModel->options().filterWidth;
    FilterScan scan;
    scan.point = point;
    scan.gaussian = sigma > 0;
    scan.cutoff2 = scan.gaussian ? std::pow(mModel->options().filterCutoff * sigma, 2) : 0;
    scan.inv2s2 = scan.gaussian ? 1.0 / (2 * sigma * sigma) : 0;
    scan.nearestSlot = nodes.size();
    if (!localFilter(scan)) {
        for (std::size_t i = 0; i < nodes.size(); ++i) scanFilterNode(scan, nodes[i], i);
    }
    nearestD2 = scan.best;
    return finishFilter(scan.nearest, scan.nearestSlot, scan.total);
}

void DeformableBody::scanFilterNode(FilterScan& scan, int n, std::size_t li) noexcept {
    // nodePosition(n), from contiguous rest positions (this runs every tick).
    const Eigen::Vector3d x =
        Eigen::Vector3d::Map(&mLoadRest[3 * li]) + displacement().segment<3>(3 * n);
    const double d2 = (x - scan.point).squaredNorm();
    const bool listed = scan.gaussian && d2 <= scan.cutoff2;
    if (listed) {
        const double w = std::exp(-d2 * scan.inv2s2);
        mLoaded[mLoadedCount] = n;
        mWeights[mLoadedCount] = w;
        scan.total += w;
    }
    if (d2 < scan.best) {
        scan.best = d2;
        scan.nearest = n;
        scan.nearestSlot = listed ? mLoadedCount : mModel->loadNodes().size();
    }
    if (listed) ++mLoadedCount;
}

int DeformableBody::finishFilter(int nearest, std::size_t nearestSlot, double total) noexcept {
    if (nearest < 0) return -1;
    mFilterHint = nearest;
    if (nearestSlot >= mLoadedCount || !(total > 0)) {
        // Sigma 0, or every node farther than the cutoff (then none was listed): the nearest
        // node carries all of it.
        mLoaded[0] = nearest;
        mWeights[0] = 1.0;
        mLoadedCount = 1;
        return nearest;
    }
    // Normalised; the nearest node takes the remainder, so the weights sum to 1 to rounding.
    double rest = 1.0;
    for (std::size_t i = 0; i < mLoadedCount; ++i) {
        if (i == nearestSlot) continue;
        mWeights[i] /= total;
        rest -= mWeights[i];
    }
    mWeights[nearestSlot] = rest;
    return nearest;
}

int DeformableBody::applyContactForce(const Eigen::Vector3d& point,
                                      const Eigen::Vector3d& force) noexcept {
    clearForce();
    if (!point.allFinite() || !force.allFinite()) return -1;
    double best = 0;
    const int nearest = filterWeights(point, best);
    if (nearest < 0) return -1;
    Eigen::VectorXd& f = loadVector();
    // The nearest node takes the remainder, so the shares sum to the force to rounding.
    Eigen::Vector3d rest = force;
    std::size_t nearestSlot = 0;
    for (std::size_t i = 0; i < mLoadedCount; ++i) {
        if (mLoaded[i] == nearest) {
            nearestSlot = i;
            continue;
        }
        const Eigen::Vector3d share = mWeights[i] * force;
        f.segment<3>(3 * mLoaded[i]) = share;
        rest -= share;
    }
    f.segment<3>(3 * mLoaded[nearestSlot]) = rest;
    mContactNode = nearest;
    recentreRegions(point, best);
    return nearest;
}

int DeformableBody::coupleContact(const Eigen::Vector3d& point, const Eigen::Vector3d& force,
                                  double stiffness, double maxForce,
                                  const Eigen::Vector3d& probeVelocity) noexcept {
    if (!(stiffness > 0) || !std::isfinite(stiffness) || !(maxForce > 0))
        return applyContactForce(point, force);
    clearForce();
    if (!point.allFinite() || !force.allFinite()) return -1;
    double best = 0;
    const int nearest = filterWeights(point, best);
    if (nearest < 0) return -1;
    mContactNode = nearest;
    mSpring.nodes = std::span<const int>(mLoaded.data(), mLoadedCount);
    mSpring.weights = std::span<const double>(mWeights.data(), mLoadedCount);
    mSpring.stiffness = stiffness;
    mSpring.maxForce = maxForce;
    // The target: the spring pulls with @p force at the current filtered point.
    Eigen::Vector3d a = Eigen::Vector3d::Zero();
    const Eigen::VectorXd& u = displacement();
    for (std::size_t i = 0; i < mLoadedCount; ++i)
        a += mWeights[i] * u.segment<3>(3 * static_cast<Eigen::Index>(mLoaded[i]));
    mSpring.target = a + force / stiffness;
    mSpring.targetVelocity = probeVelocity.allFinite() ? probeVelocity : Eigen::Vector3d::Zero();
    mSpring.damping =
        fem::criticalDamping(mModel->model(), mSpring, mModel->options().contactDampingRatio);
    recentreRegions(point, best);
    return nearest;
}

void DeformableBody::recentreRegions(const Eigen::Vector3d& point, double nearestD2) noexcept {
    // Regions: move the centre once the contact is clearly nearer another node than the
    // centre the regions use now (hysteresis), unless that node was the last one asked for
    // (its layout is being built, or was rejected).
    if (!mRegions || mContactNode < 0) return;
    const int adopted = mRegions->contactNodes().front();
    const int nearest = mContactNode;
    if (nearest != adopted && nearest != mCentre &&
        (point - nodePosition(adopted)).norm() - std::sqrt(nearestD2) >
            mModel->options().recentreHysteresis * mModel->model().mesh().edge() &&
        mRegions->requestContactNode(nearest)) {
        mCentre = nearest;
        ++mRecentres;
    }
}

bool DeformableBody::anchorOn(int tri, const Eigen::Vector3d& point,
                              const Eigen::Vector3d& normal) noexcept {
    const auto& t = mModel->surface().triangles[static_cast<std::size_t>(tri)];
    Eigen::Vector3d v[3];
    for (int k = 0; k < 3; ++k) {
        const std::size_t i = 3 * static_cast<std::size_t>(t[static_cast<std::size_t>(k)]);
        v[k] = Eigen::Vector3d(mPositions[i], mPositions[i + 1], mPositions[i + 2]);
    }
    const Eigen::Vector3d ng = (v[1] - v[0]).cross(v[2] - v[0]);
    const double ngn = ng.norm();
    if (!(ngn > 0)) return false;
    // Barycentric coordinates of the point's projection, in double (Embree's u, v are float).
    const Eigen::Vector3d e1 = v[1] - v[0], e2 = v[2] - v[0], w = point - v[0];
    const double a11 = e1.dot(e1), a12 = e1.dot(e2), a22 = e2.dot(e2);
    const double det = a11 * a22 - a12 * a12;
    if (!(det > 0)) return false;
    const double b1 = (a22 * w.dot(e1) - a12 * w.dot(e2)) / det;
    const double b2 = (a11 * w.dot(e2) - a12 * w.dot(e1)) / det;
    mAnchorBary = {1 - b1 - b2, b1, b2};
    mAnchorSign = ng.dot(normal) >= 0 ? 1.0 : -1.0;
    mAnchorOffset = mAnchorSign * ng.dot(w) / ngn;
    mAnchorTri = tri;
    return true;
}

bool DeformableBody::anchor(const Eigen::Vector3d& point, const Eigen::Vector3d& normal) noexcept {
    mAnchorTri = -1;
    const double nn = normal.norm();
    if (!point.allFinite() || !(nn > 0) || !std::isfinite(nn)) return false;
    const Eigen::Vector3d d = -normal / nn;
    kernels::MeshHit hit;
    kernels::intersectOne(*mScene, point, d, 0.0f, 1e-3f, kernels::kMaskSurface, hit);
    if (hit.geomId == mGeom && anchorOn(static_cast<int>(hit.primId), point, normal)) return true;
    // The surface's ray test is watertight, but the point may lie more than 1 mm off the
    // surface or the ray may graze it. Then take the triangle around the nearest surface node
    // whose (clamped) barycentric point is closest, among those facing the normal.
    const int node = mContactNode;
    if (node < 0) return false;
    const int vertex = mModel->vertexOfNode(node);
    if (vertex < 0) return false;
    const std::vector<int>& start = mModel->triangleStart();
    const std::vector<int>& tris = mModel->vertexTriangles();
    int best = -1;
    double bestD = std::numeric_limits<double>::infinity();
    for (int i = start[static_cast<std::size_t>(vertex)];
         i < start[static_cast<std::size_t>(vertex) + 1]; ++i) {
        const int tri = tris[static_cast<std::size_t>(i)];
        if (!anchorOn(tri, point, normal)) continue;
        const auto& t = mModel->surface().triangles[static_cast<std::size_t>(tri)];
        Eigen::Vector3d v[3];
        for (int k = 0; k < 3; ++k) {
            const std::size_t j = 3 * static_cast<std::size_t>(t[static_cast<std::size_t>(k)]);
            v[k] = Eigen::Vector3d(mPositions[j], mPositions[j + 1], mPositions[j + 2]);
        }
        const Eigen::Vector3d ng = (v[1] - v[0]).cross(v[2] - v[0]);
        if (ng.dot(normal) * mAnchorSign <= 0 || std::abs(ng.normalized().dot(d)) < 0.5) continue;
        std::array<double, 3> b = mAnchorBary;
        for (double& x : b) x = std::max(x, 0.0);
        const double sum = b[0] + b[1] + b[2];
        const Eigen::Vector3d q = (b[0] * v[0] + b[1] * v[1] + b[2] * v[2]) / sum;
        const double dist = (point - q).squaredNorm();
        if (dist < bestD) {
            bestD = dist;
            best = tri;
        }
    }
    mAnchorTri = -1;
    return best >= 0 && anchorOn(best, point, normal);
}

Eigen::Vector3d DeformableBody::anchoredPosition() const noexcept {
    if (mAnchorTri < 0) return Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
    const auto& tri = mModel->surface().triangles[static_cast<std::size_t>(mAnchorTri)];
    Eigen::Vector3d v[3];
    for (int k = 0; k < 3; ++k) {
        const std::size_t i = 3 * static_cast<std::size_t>(tri[static_cast<std::size_t>(k)]);
        v[k] = Eigen::Vector3d(mPositions[i], mPositions[i + 1], mPositions[i + 2]);
    }
    const Eigen::Vector3d ng = (v[1] - v[0]).cross(v[2] - v[0]);
    const double ngn = ng.norm();
    const Eigen::Vector3d onTri =
        mAnchorBary[0] * v[0] + mAnchorBary[1] * v[1] + mAnchorBary[2] * v[2];
    if (!(ngn > 0)) return onTri;
    return onTri + (mAnchorSign * mAnchorOffset / ngn) * ng;
}

unsigned DeformableBody::step(double dtSeconds) noexcept {
    unsigned flags = 0;
    if (mRegions) {
        const double tick = mModel->options().regions.tickSeconds;
        if (!(std::abs(dtSeconds - tick) <= 1e-9 * tick)) return fem::kStepBadTimeStep;
        const Eigen::VectorXd& f = mForce;
        fem::AsyncTickResult r;
        if (mSpring.active()) {
            // The regions integrate the spring in the primary's substeps (its share on nodes
            // outside the primary reaches the secondary as loads).
            r = mRegions->tick(std::span<const fem::NodalLoad>(), mSpring);
            mLastContactForce = r.spring.meanForce;
            mLastClamped = r.spring.clamped;
        } else {
            for (std::size_t i = 0; i < mLoadedCount; ++i)
                mLoads[i] = fem::NodalLoad{mLoaded[i], f.segment<3>(3 * mLoaded[i])};
            r = mRegions->tick(std::span<const fem::NodalLoad>(mLoads.data(), mLoadedCount));
            mLastContactForce = loadSum();
            mLastClamped = false;
        }
        mLastSubsteps = r.substeps;
        flags = r.flags;
        if (mSweepSlice > 0) return flags | sweepSurface();
        mRegions->watchedDisplacements(mWatched);
        const std::vector<int>& nodes = mModel->watchNodes();
        for (std::size_t i = 0; i < nodes.size(); ++i) mU.segment<3>(3 * nodes[i]) = mWatched[i];
    } else if (mSpring.active()) {
        fem::SpringResult sr;
        const fem::StepResult r = mSolver->step(dtSeconds, mSpring, &sr);
        mLastSubsteps = r.substeps;
        flags = r.flags;
        mLastContactForce = sr.meanForce;
        mLastClamped = sr.clamped;
    } else {
        const fem::StepResult r = mSolver->step(dtSeconds);
        mLastSubsteps = r.substeps;
        flags = r.flags;
        mLastContactForce = loadSum();
        mLastClamped = false;
    }
    const Eigen::VectorXd& u = displacement();
    const std::vector<std::int32_t>& vn = mModel->surface().vertexNode;
    double maxD2 = 0;
    for (std::size_t i = 0; i < vn.size(); ++i) {
        const auto n = static_cast<Eigen::Index>(vn[i]);
        const double ux = u[3 * n], uy = u[3 * n + 1], uz = u[3 * n + 2];
        maxD2 = std::max(maxD2, ux * ux + uy * uy + uz * uz);
        mPositions[3 * i] = static_cast<float>(mRest[3 * i] + ux);
        mPositions[3 * i + 1] = static_cast<float>(mRest[3 * i + 1] + uy);
        mPositions[3 * i + 2] = static_cast<float>(mRest[3 * i + 2] + uz);
    }
    mMaxSurfaceDisplacement = std::sqrt(maxD2);
    flags |= refitSurfaces();
    return flags;
}

}  // namespace palp::haptics
