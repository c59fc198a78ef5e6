// A deformable body's surface on a patient-sized skin (deformable.h): the filter's local
// search and the swept refresh of the surface with asynchronous regions, and the refit.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>

#include "palp/haptics/tissue/deformable.h"

namespace palp::haptics {

bool DeformableBody::localFilter(FilterScan& scan) noexcept {
    const fem::HexMesh& mesh = mModel->model().mesh();
    const double h = mesh.edge();
    const double cutoff = std::sqrt(scan.cutoff2);
    // The box: the filter's reach and two cells for the strain between the contact node and
    // its neighbours, around where the contact is at rest.
    const int reach = static_cast<int>(std::ceil(cutoff / h)) + 2;
    const double boxNodes = std::pow(2.0 * reach + 1, 3);
    if (mFilterHint < 0 || !(boxNodes < static_cast<double>(mModel->loadNodes().size())))
        return false;
    const Eigen::Vector3d rest = scan.point - displacement().segment<3>(3 * mFilterHint);
    const auto& counts = mesh.nodeCounts();
    std::array<int, 3> lo{}, hi{};
    for (int a = 0; a < 3; ++a) {
        const double t = (rest[a] - mesh.origin()[a]) / h;
        if (!std::isfinite(t)) return false;
        const auto c = static_cast<int>(
            std::lround(std::clamp(t, -1.0, counts[static_cast<std::size_t>(a)] + 1.0)));
        lo[static_cast<std::size_t>(a)] = std::max(0, c - reach);
        hi[static_cast<std::size_t>(a)] =
            std::min(counts[static_cast<std::size_t>(a)] - 1, c + reach);
    }
    // Ascending node order, as the full scan: the same list, weights and sums.
    for (int k = lo[2]; k <= hi[2]; ++k) {
        for (int j = lo[1]; j <= hi[1]; ++j) {
            for (int i = lo[0]; i <= hi[0]; ++i) {
                const int n = mesh.node(i, j, k);
                const int li = mLoadIndex[static_cast<std::size_t>(n)];
                if (li >= 0) scanFilterNode(scan, n, static_cast<std::size_t>(li));
            }
        }
    }
    // A contact farther than a cell from every node in the box has left it (a jump, a fold):
    // the caller scans them all.
    if (scan.nearest >= 0 && scan.best <= h * h) return true;
    mLoadedCount = 0;
    scan.best = std::numeric_limits<double>::infinity();
    scan.nearest = -1;
    scan.nearestSlot = mModel->loadNodes().size();
    scan.total = 0;
    return false;
}

void DeformableBody::refreshNode(int n, int w, const Eigen::Vector3d& d, bool skipStill) noexcept {
    mSweepMax2 = std::max(mSweepMax2, d.squaredNorm());
    if (w >= 0) {
        double* shown = &mWatchShown[3 * static_cast<std::size_t>(w)];
        if (skipStill && std::abs(d[0] - shown[0]) < kStillMetres &&
            std::abs(d[1] - shown[1]) < kStillMetres && std::abs(d[2] - shown[2]) < kStillMetres)
            return;
        shown[0] = d[0];
        shown[1] = d[1];
        shown[2] = d[2];
    }
    mU.segment<3>(3 * n) = d;
    const int v = mModel->vertexOfNode(n);
    if (v < 0) return;
    if (mMoved.size() < mMoved.capacity()) {
        mMoved.push_back(static_cast<std::uint32_t>(v));
    } else {
        mMovedOverflow = true;  // the refit sweeps every vertex instead
    }
    const auto i = 3 * static_cast<std::size_t>(v);
    for (std::size_t k = 0; k < 3; ++k)
        mPositions[i + k] = static_cast<float>(mRest[i + k] + d[static_cast<Eigen::Index>(k)]);
}

unsigned DeformableBody::refitSurfaces(bool onlyMoved) noexcept {
    unsigned flags = 0;
    const bool partial = onlyMoved && !mMovedOverflow;
    const auto status = [&](kernels::RefitMesh& mesh, const std::vector<float>& x, bool surface) {
        return partial && surface
                   ? mesh.refit(std::span<const float>(x),
                                std::span<const std::uint32_t>(mMoved.data(), mMoved.size()))
                   : mesh.refit(std::span<const float>(x));
    };
    const auto refit = [&](kernels::RefitMesh& mesh, const std::vector<float>& x,
                           bool surface = false) {
        switch (status(mesh, x, surface)) {
            case kernels::RefitStatus::Ok:
                break;
            case kernels::RefitStatus::OutsideLimit:
                flags |= kSurfaceOutsideBounds;
                break;
            case kernels::RefitStatus::Rejected:
                flags |= kRefitFailed;
                break;
        }
    };
    refit(*mSurface, mPositions, true);
    mMoved.clear();
    mMovedOverflow = false;
    // Embedded meshes follow the trilinear interpolation of their cells' displacements.
    const Eigen::VectorXd& u = displacement();
    for (std::size_t e = 0; e < mInclusions.size(); ++e) {
        std::vector<float>& x = mInclusionPositions[e];
        mModel->embedded()[e].mesh.update(u, std::span<float>(x));
        refit(*mInclusions[e], x);
    }
    return flags;
}

unsigned DeformableBody::sweepSurface() noexcept {
    // Near the contact every tick: the primary region, Gamma (those that moved) and the loaded
    // nodes.
    const auto near = [this](const std::vector<int>& nodes) {
        for (const int n : nodes) {
            const int w = mWatchIndex[static_cast<std::size_t>(n)];
            if (w >= 0) refreshNode(n, w, mRegions->nodeDisplacement(n), true);
        }
    };
    near(mRegions->primaryNodes());
    near(mRegions->secondaryBorderNodes());
    for (std::size_t i = 0; i < mLoadedCount; ++i) refreshNode(mLoaded[i]);
    // Elsewhere a slice of the round robin in one pass: the regions pass over the nodes that
    // cannot have moved from what is shown (kStillMetres, as refreshNode skips them), and
    // interpolate the others (mWatched and mChanged are one per watched node: any slice fits).
    const std::vector<int>& watch = mModel->watchNodes();
    for (std::size_t left = mSweepSlice; left > 0;) {
        const std::size_t first = mSweepNext;
        const fem::WatchedChanges c = mRegions->watchedChanges(
            first, left, std::span<const double>(mWatchShown), kStillMetres,
            std::span<std::uint32_t>(mChanged), std::span<Eigen::Vector3d>(mWatched));
        // A node passed over counts with its shown value (within kStillMetres of its own).
        mSweepMax2 = std::max(mSweepMax2, c.skippedMax2);
        for (std::size_t i = 0; i < c.changed; ++i)
            refreshNode(watch[mChanged[i]], static_cast<int>(mChanged[i]), mWatched[i], true);
        const std::size_t count = c.examined;
        left -= std::min(left, std::max<std::size_t>(count, 1));
        mSweepNext += count;
        if (mSweepNext >= watch.size()) {
            mSweepNext = 0;
            mSweepMaxPrev2 = mSweepMax2;
            mSweepMax2 = 0;
        }
    }
    mMaxSurfaceDisplacement = std::sqrt(std::max(mSweepMax2, mSweepMaxPrev2));
    return refitSurfaces(/*onlyMoved=*/true);
}

}  // namespace palp::haptics
