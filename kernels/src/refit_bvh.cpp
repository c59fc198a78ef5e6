#include "palp/kernels/refit_bvh.h"

// The watertight test relies on the edge functions of a shared edge being exact negatives of
// each other in the two triangles; a fused multiply-add would round them differently, so this
// file is compiled with -ffp-contract=off (kernels/CMakeLists.txt).

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <string>

#include "palp/base/error.h"

namespace palp::kernels {

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

/// 2 gamma(3) (pbrt's bound on the relative rounding of the slab distances): widening each
/// slab interval by it keeps the box test conservative (Ize 2013), so a triangle lying in the
/// face of a flat box is still reached.
constexpr float kBoxSlack = 2.0f * (3.0f * std::numeric_limits<float>::epsilon() * 0.5f) /
                            (1.0f - 3.0f * std::numeric_limits<float>::epsilon() * 0.5f);
constexpr std::size_t kNoParent = std::numeric_limits<std::size_t>::max();
constexpr int kSahDepth = 32;
constexpr std::size_t kBins = 16;

/// A box for the build's surface-area heuristic.
struct AreaBox {
    std::array<float, 3> lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf};
    void grow(const float* p) noexcept {
        for (std::size_t k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], p[k]);
            hi[k] = std::max(hi[k], p[k]);
        }
    }
    void grow(const AreaBox& b) noexcept {
        for (std::size_t k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], b.lo[k]);
            hi[k] = std::max(hi[k], b.hi[k]);
        }
    }
    double area() const noexcept {
        if (!(hi[0] >= lo[0])) return 0;
        const double x = static_cast<double>(hi[0]) - lo[0], y = static_cast<double>(hi[1]) - lo[1],
                     z = static_cast<double>(hi[2]) - lo[2];
        return x * y + y * z + z * x;
    }
};

struct Bin {
    AreaBox box;
    std::size_t count = 0;
};

std::size_t binOf(float c, float lo, double scale) noexcept {
    const double b = (static_cast<double>(c) - lo) * scale;
    return std::min(kBins - 1, static_cast<std::size_t>(std::max(0.0, b)));
}

bool finite3(const std::array<float, 3>& a) noexcept {
    return std::isfinite(a[0]) && std::isfinite(a[1]) && std::isfinite(a[2]);
}

/// Per-ray set-up of the watertight test: the axis of the largest direction component becomes
/// z, the other two are sheared onto the plane orthogonal to the ray.
struct WatertightRay {
    std::array<float, 3> org;
    int kx, ky, kz;
    float sx, sy, sz;
    std::array<float, 3> invDir;

    bool init(const std::array<float, 3>& o, const std::array<float, 3>& d) noexcept {
        org = o;
        const std::array<float, 3> a = {std::abs(d[0]), std::abs(d[1]), std::abs(d[2])};
        kz = a[0] >= a[1] ? (a[0] >= a[2] ? 0 : 2) : (a[1] >= a[2] ? 1 : 2);
        if (!(a[static_cast<std::size_t>(kz)] > 0)) return false;
        kx = (kz + 1) % 3;
        ky = (kx + 1) % 3;
        // Keep the winding (the sign of the edge functions) independent of the direction.
        if (d[static_cast<std::size_t>(kz)] < 0) std::swap(kx, ky);
        const float dz = d[static_cast<std::size_t>(kz)];
        sx = d[static_cast<std::size_t>(kx)] / dz;
        sy = d[static_cast<std::size_t>(ky)] / dz;
        sz = 1.0f / dz;
        for (std::size_t i = 0; i < 3; ++i) invDir[i] = 1.0f / d[i];  // +-inf for a zero one
        return true;
    }

    /// Slab test of the box against (tnear, tfar]. NaN slab distances (a ray in the plane of
    /// a flat box) are ignored, which keeps the test conservative.
    bool hitsBox(const std::array<float, 3>& lo, const std::array<float, 3>& hi, float tnear,
                 float tfar, float& tEntry) const noexcept {
        float t0 = tnear, t1 = tfar;
        for (std::size_t i = 0; i < 3; ++i) {
            float tn = (lo[i] - org[i]) * invDir[i];
            float tf = (hi[i] - org[i]) * invDir[i];
            if (tn > tf) std::swap(tn, tf);
            // A zero direction component with the origin outside the slab: both distances are
            // +inf (or -inf) and the ray never enters it. The slack below would turn them NaN
            // (inf - inf) and let every such box pass: an axis-aligned ray then walked most of
            // the tree (1.5 ms a query on the head CT's 35,440 triangles).
            if (tn == std::numeric_limits<float>::infinity() ||
                tf == -std::numeric_limits<float>::infinity())
                return false;
            // Slack on finite distances only; a NaN one (the origin on a flat box's plane) is
            // ignored below, which keeps the test conservative.
            if (std::abs(tn) < std::numeric_limits<float>::infinity())
                tn -= std::abs(tn) * kBoxSlack;
            if (std::abs(tf) < std::numeric_limits<float>::infinity())
                tf += std::abs(tf) * kBoxSlack;
            t0 = tn > t0 ? tn : t0;
            t1 = tf < t1 ? tf : t1;
            if (t0 > t1) return false;
        }
        tEntry = t0;
        return true;
    }

    /// Woop, Benthin and Wald 2013. Fills t, u, v when the triangle is hit with
    /// tnear < t <= tfar.
    bool hitsTriangle(const float* p0, const float* p1, const float* p2, float tnear, float tfar,
                      float& t, float& u, float& v) const noexcept {
        const auto ux = static_cast<std::size_t>(kx), uy = static_cast<std::size_t>(ky),
                   uz = static_cast<std::size_t>(kz);
        const float ax = p0[ux] - org[ux], ay = p0[uy] - org[uy], az = p0[uz] - org[uz];
        const float bx = p1[ux] - org[ux], by = p1[uy] - org[uy], bz = p1[uz] - org[uz];
        const float cx = p2[ux] - org[ux], cy = p2[uy] - org[uy], cz = p2[uz] - org[uz];
        const float axs = ax - sx * az, ays = ay - sy * az;
        const float bxs = bx - sx * bz, bys = by - sy * bz;
        const float cxs = cx - sx * cz, cys = cy - sy * cz;
        float e0 = cxs * bys - cys * bxs;
        float e1 = axs * cys - ays * cxs;
        float e2 = bxs * ays - bys * axs;
        if (e0 == 0.0f || e1 == 0.0f || e2 == 0.0f) {
            // On an edge to float precision: decide in double, where the products are exact.
            e0 =
                static_cast<float>(static_cast<double>(cxs) * bys - static_cast<double>(cys) * bxs);
            e1 =
                static_cast<float>(static_cast<double>(axs) * cys - static_cast<double>(ays) * cxs);
            e2 =
                static_cast<float>(static_cast<double>(bxs) * ays - static_cast<double>(bys) * axs);
        }
        if ((e0 < 0 || e1 < 0 || e2 < 0) && (e0 > 0 || e1 > 0 || e2 > 0)) return false;
        const float det = e0 + e1 + e2;
        if (det == 0.0f || !std::isfinite(det)) return false;  // degenerate or edge-on
        const float tScaled = e0 * (sz * az) + e1 * (sz * bz) + e2 * (sz * cz);
        const float tt = tScaled / det;
        if (!(tt > tnear && tt <= tfar)) return false;
        const float inv = 1.0f / det;
        t = tt;
        u = e1 * inv;
        v = e2 * inv;
        return true;
    }
};

}  // namespace

bool Box3f::contains(const Box3f& b) const noexcept {
    for (std::size_t i = 0; i < 3; ++i)
        if (!(b.lo[i] >= lo[i] && b.hi[i] <= hi[i])) return false;
    return true;
}

RefitMesh::RefitMesh(const TriangleMesh& mesh, int leafSize) {
    if (leafSize < 1 || leafSize > 16)
        throw ValueError("refit mesh: expected a leaf size in [1, 16], found " +
                         std::to_string(leafSize));
    if (mesh.triangleCount() == 0 || mesh.positions.size() % 3 != 0 || mesh.indices.size() % 3 != 0)
        throw ValueError(
            "refit mesh: expected at least one triangle and 3 floats per vertex, "
            "found " +
            std::to_string(mesh.positions.size()) + " position floats and " +
            std::to_string(mesh.indices.size()) + " indices");
    if (mesh.triangleCount() >= kInner)
        throw ValueError("refit mesh: expected fewer than 2^31 triangles, found " +
                         std::to_string(mesh.triangleCount()));
    mVertexCount = mesh.vertexCount();
    for (std::size_t i = 0; i < mesh.indices.size(); ++i)
        if (mesh.indices[i] >= mVertexCount)
            throw ValueError("refit mesh index " + std::to_string(i) + ": expected < " +
                             std::to_string(mVertexCount) + ", found " +
                             std::to_string(mesh.indices[i]));
    for (std::size_t i = 0; i < mesh.positions.size(); ++i)
        if (!std::isfinite(mesh.positions[i]))
            throw ValueError("refit mesh position " + std::to_string(i / 3) +
                             ": expected finite coordinates, found " +
                             std::to_string(mesh.positions[i]));
    mPositions.assign(mesh.positions.size() + 1, 0.0f);
    std::copy(mesh.positions.begin(), mesh.positions.end(), mPositions.begin());
    mIndices = mesh.indices;
    mLimit.lo = {-kInf, -kInf, -kInf};
    mLimit.hi = {kInf, kInf, kInf};

    // Binned SAH on triangle centroids (rest positions) down to depth kSahDepth, median splits
    // below it, so the depth stays under kSahDepth + log2(#T) + 1 <= kMaxDepth.
    const std::size_t nt = triangleCount();
    std::vector<std::array<float, 3>> centroid(nt);
    std::vector<AreaBox> triBox(nt);
    for (std::size_t t = 0; t < nt; ++t)
        for (std::size_t c = 0; c < 3; ++c)
            triBox[t].grow(&mPositions[3 * static_cast<std::size_t>(mIndices[3 * t + c])]);
    for (std::size_t t = 0; t < nt; ++t)
        for (std::size_t k = 0; k < 3; ++k)
            centroid[t][k] =
                (mPositions[3 * mIndices[3 * t] + k] + mPositions[3 * mIndices[3 * t + 1] + k] +
                 mPositions[3 * mIndices[3 * t + 2] + k]) /
                3.0f;
    mSlotPrim.resize(nt);
    std::iota(mSlotPrim.begin(), mSlotPrim.end(), 0u);
    mNodes.reserve(2 * nt / static_cast<std::size_t>(leafSize) + 2);
    const auto leaf = static_cast<std::size_t>(leafSize);
    struct Task {
        std::size_t begin, end;
        int depth;
        std::size_t parent;  // node whose right child this is, or kNoParent
    };
    std::vector<Task> tasks{{0, nt, 1, kNoParent}};
    while (!tasks.empty()) {
        const Task task = tasks.back();
        tasks.pop_back();
        const std::size_t id = mNodes.size();
        mNodes.push_back(Node{});
        if (task.parent != kNoParent) mNodes[task.parent].first = static_cast<std::uint32_t>(id);
        mDepth = std::max(mDepth, task.depth);
        const std::size_t n = task.end - task.begin;
        if (n <= leaf) {
            mNodes[id].first = static_cast<std::uint32_t>(task.begin);
            mNodes[id].count = static_cast<std::uint32_t>(n);
            continue;
        }
        std::array<float, 3> lo = {kInf, kInf, kInf}, hi = {-kInf, -kInf, -kInf};
        for (std::size_t s = task.begin; s < task.end; ++s)
            for (std::size_t k = 0; k < 3; ++k) {
                lo[k] = std::min(lo[k], centroid[mSlotPrim[s]][k]);
                hi[k] = std::max(hi[k], centroid[mSlotPrim[s]][k]);
            }
        std::size_t axis = 0;
        for (std::size_t k = 1; k < 3; ++k)
            if (hi[k] - lo[k] > hi[axis] - lo[axis]) axis = k;
        std::size_t mid = task.begin + n / 2;
        const auto first = mSlotPrim.begin() + static_cast<std::ptrdiff_t>(task.begin);
        const auto last = mSlotPrim.begin() + static_cast<std::ptrdiff_t>(task.end);
        bool split = false;
        if (task.depth < kSahDepth && hi[axis] > lo[axis]) {
            // Binned SAH over the centroid extent of every axis (nodes split down to leafSize
            // regardless of cost: leaves stay small for the refit's sake).
            double bestCost = std::numeric_limits<double>::infinity();
            std::size_t bestAxis = 0, bestBin = 0;
            for (std::size_t k = 0; k < 3; ++k) {
                if (!(hi[k] > lo[k])) continue;
                std::array<Bin, kBins> bins{};
                const double scale = kBins / (static_cast<double>(hi[k]) - lo[k]);
                for (std::size_t s2 = task.begin; s2 < task.end; ++s2) {
                    const std::uint32_t t = mSlotPrim[s2];
                    Bin& b = bins[binOf(centroid[t][k], lo[k], scale)];
                    ++b.count;
                    b.box.grow(triBox[t]);
                }
                // Sweep from the right, then from the left.
                std::array<double, kBins> rightCost{};
                AreaBox acc;
                std::size_t cnt = 0;
                for (std::size_t b = kBins - 1; b > 0; --b) {
                    acc.grow(bins[b].box);
                    cnt += bins[b].count;
                    rightCost[b] = acc.area() * static_cast<double>(cnt);
                }
                acc = AreaBox{};
                cnt = 0;
                for (std::size_t b = 0; b + 1 < kBins; ++b) {
                    acc.grow(bins[b].box);
                    cnt += bins[b].count;
                    if (cnt == 0 || cnt == n) continue;
                    const double cost = acc.area() * static_cast<double>(cnt) + rightCost[b + 1];
                    if (cost < bestCost) {
                        bestCost = cost;
                        bestAxis = k;
                        bestBin = b;
                    }
                }
            }
            if (std::isfinite(bestCost)) {
                axis = bestAxis;
                const double scale = kBins / (static_cast<double>(hi[axis]) - lo[axis]);
                const auto cut = std::partition(first, last, [&](std::uint32_t t) {
                    return binOf(centroid[t][axis], lo[axis], scale) <= bestBin;
                });
                mid = static_cast<std::size_t>(cut - mSlotPrim.begin());
                split = true;
            }
        }
        if (!split) {
            // Median split (beyond kSahDepth, or when SAH found nothing): balanced.
            std::nth_element(first, mSlotPrim.begin() + static_cast<std::ptrdiff_t>(mid), last,
                             [&](std::uint32_t a, std::uint32_t b) {
                                 return centroid[a][axis] < centroid[b][axis] ||
                                        (centroid[a][axis] == centroid[b][axis] && a < b);
                             });
        }
        mNodes[id].count = kInner | static_cast<std::uint32_t>(axis);
        // Depth-first: the left child is processed next (it becomes node id + 1), the right
        // child after the whole left subtree.
        tasks.push_back({mid, task.end, task.depth + 1, id});
        tasks.push_back({task.begin, mid, task.depth + 1, kNoParent});
    }
    if (mDepth > kMaxDepth)
        throw ValueError("refit mesh: expected a tree depth <= " + std::to_string(kMaxDepth) +
                         ", found " + std::to_string(mDepth));
    mSlotIndex.resize(3 * nt);
    for (std::size_t s = 0; s < nt; ++s)
        for (std::size_t k = 0; k < 3; ++k) mSlotIndex[3 * s + k] = mIndices[3 * mSlotPrim[s] + k];
    refitNodes();
}

void RefitMesh::refitNodes() noexcept {
    // Children follow their parent in the array: a reverse sweep sees them first.
    for (std::size_t i = mNodes.size(); i-- > 0;) {
        Node& n = mNodes[i];
        if (n.count & kInner) {
            const Node& l = mNodes[i + 1];
            const Node& r = mNodes[n.first];
            for (std::size_t k = 0; k < 3; ++k) {
                n.lo[k] = std::min(l.lo[k], r.lo[k]);
                n.hi[k] = std::max(l.hi[k], r.hi[k]);
            }
            continue;
        }
        if (mSlack > 0) {
            refitLeafFromBase(n);
            continue;
        }
        n.lo = {kInf, kInf, kInf};
        n.hi = {-kInf, -kInf, -kInf};
        for (std::size_t s = 3 * n.first; s < 3 * (n.first + n.count); ++s) {
            const float* p = &mPositions[3 * static_cast<std::size_t>(mSlotIndex[s])];
            for (std::size_t k = 0; k < 3; ++k) {
                n.lo[k] = std::min(n.lo[k], p[k]);
                n.hi[k] = std::max(n.hi[k], p[k]);
            }
        }
    }
}

void RefitMesh::refitLeafFromBase(Node& n) noexcept {
    // Grown a little beyond the slack, so the float rounding of base +- slack and of the
    // drift test in refit() cannot leave a vertex within the slack outside its box.
    const float grow = mSlack * 1.001f;
    n.lo = {kInf, kInf, kInf};
    n.hi = {-kInf, -kInf, -kInf};
    for (std::size_t s = 3 * n.first; s < 3 * (n.first + n.count); ++s) {
        const float* p = &mBase[3 * static_cast<std::size_t>(mSlotIndex[s])];
        for (std::size_t k = 0; k < 3; ++k) {
            n.lo[k] = std::min(n.lo[k], p[k] - grow);
            n.hi[k] = std::max(n.hi[k], p[k] + grow);
        }
    }
}

void RefitMesh::refitInner(std::size_t i) noexcept {
    Node& n = mNodes[i];
    const Node& l = mNodes[i + 1];
    const Node& r = mNodes[n.first];
    for (std::size_t k = 0; k < 3; ++k) {
        n.lo[k] = std::min(l.lo[k], r.lo[k]);
        n.hi[k] = std::max(l.hi[k], r.hi[k]);
    }
}

void RefitMesh::setRefitSlack(float slack) {
    if (!(slack >= 0) || !std::isfinite(slack))
        throw ValueError("refit mesh slack: expected a finite value >= 0 m, found " +
                         std::to_string(slack));
    mSlack = slack;
    if (slack == 0) {
        refitNodes();
        return;
    }
    const std::size_t nn = mNodes.size();
    if (mParent.empty()) {
        mParent.assign(nn, 0);
        std::vector<std::vector<std::uint32_t>> leaves(mVertexCount);
        for (std::size_t i = 0; i < nn; ++i) {
            const Node& n = mNodes[i];
            if (n.count & kInner) {
                mParent[i + 1] = static_cast<std::uint32_t>(i);
                mParent[n.first] = static_cast<std::uint32_t>(i);
                continue;
            }
            for (std::size_t s = 3 * n.first; s < 3 * (n.first + n.count); ++s) {
                std::vector<std::uint32_t>& l = leaves[mSlotIndex[s]];
                if (l.empty() || l.back() != i) l.push_back(static_cast<std::uint32_t>(i));
            }
        }
        mVertexLeafStart.assign(mVertexCount + 1, 0);
        for (std::size_t v = 0; v < mVertexCount; ++v)
            mVertexLeafStart[v + 1] =
                mVertexLeafStart[v] + static_cast<std::uint32_t>(leaves[v].size());
        mVertexLeaves.clear();
        mVertexLeaves.reserve(mVertexLeafStart.back());
        for (const auto& l : leaves) mVertexLeaves.insert(mVertexLeaves.end(), l.begin(), l.end());
        mChanged.reserve(nn);
        mChangedMark.assign(nn, 0);
    }
    mBase.assign(mPositions.begin(),
                 mPositions.begin() + static_cast<std::ptrdiff_t>(3 * mVertexCount));
    refitNodes();
}

RefitStatus RefitMesh::refit(std::span<const float> positions) noexcept {
    if (positions.size() != 3 * mVertexCount) return RefitStatus::Rejected;
    for (const float x : positions)
        if (!std::isfinite(x)) return RefitStatus::Rejected;
    std::copy(positions.begin(), positions.end(), mPositions.begin());
    if (mSlack == 0) {
        refitNodes();
        mLastRefitNodes = mNodes.size();
        return mLimit.contains(bounds()) ? RefitStatus::Ok : RefitStatus::OutsideLimit;
    }
    mChanged.clear();
    for (std::size_t v = 0; v < mVertexCount; ++v) markIfDrifted(v);
    return refitMarked();
}

RefitStatus RefitMesh::refit(std::span<const float> positions,
                             std::span<const std::uint32_t> moved) noexcept {
    if (positions.size() != 3 * mVertexCount) return RefitStatus::Rejected;
    for (const std::uint32_t v : moved) {
        if (v >= mVertexCount) return RefitStatus::Rejected;
        for (std::size_t k = 0; k < 3; ++k)
            if (!std::isfinite(positions[3 * v + k])) return RefitStatus::Rejected;
    }
    if (mSlack == 0) return refit(positions);
    mChanged.clear();
    for (const std::uint32_t v : moved) {
        for (std::size_t k = 0; k < 3; ++k) mPositions[3 * v + k] = positions[3 * v + k];
        markIfDrifted(v);
    }
    return refitMarked();
}

void RefitMesh::markIfDrifted(std::size_t v) noexcept {
    // A vertex that drifted beyond the slack takes its current position as its new base, and
    // marks its leaves.
    float* b = &mBase[3 * v];
    const float* p = &mPositions[3 * v];
    if (std::abs(p[0] - b[0]) <= mSlack && std::abs(p[1] - b[1]) <= mSlack &&
        std::abs(p[2] - b[2]) <= mSlack)
        return;
    b[0] = p[0];
    b[1] = p[1];
    b[2] = p[2];
    for (std::uint32_t j = mVertexLeafStart[v]; j < mVertexLeafStart[v + 1]; ++j) {
        const std::uint32_t leaf = mVertexLeaves[j];
        if (mChangedMark[leaf]) continue;
        mChangedMark[leaf] = 1;
        mChanged.push_back(leaf);
    }
}

RefitStatus RefitMesh::refitMarked() noexcept {
    // The leaves, then every ancestor once, children before parents (descending index: a
    // child follows its parent in the array).
    const std::size_t leaves = mChanged.size();
    for (std::size_t i = 0; i < leaves; ++i) {
        refitLeafFromBase(mNodes[mChanged[i]]);
        for (std::uint32_t n = mParent[mChanged[i]]; !mChangedMark[n]; n = mParent[n]) {
            mChangedMark[n] = 1;
            mChanged.push_back(n);
        }
    }
    std::sort(mChanged.begin() + static_cast<std::ptrdiff_t>(leaves), mChanged.end(),
              std::greater<>());
    for (std::size_t i = leaves; i < mChanged.size(); ++i) refitInner(mChanged[i]);
    for (const std::uint32_t n : mChanged) mChangedMark[n] = 0;
    mLastRefitNodes = mChanged.size();
    return mLimit.contains(bounds()) ? RefitStatus::Ok : RefitStatus::OutsideLimit;
}

Box3f RefitMesh::bounds() const noexcept {
    Box3f b;
    b.lo = mNodes[0].lo;
    b.hi = mNodes[0].hi;
    return b;
}

template <bool kAny>
bool RefitMesh::traverse(const std::array<float, 3>& org, const std::array<float, 3>& dir,
                         float tnear, float tfar, TriangleHit* hit) const noexcept {
    if (!finite3(org) || !finite3(dir) || std::isnan(tnear) || std::isnan(tfar) || !(tnear <= tfar))
        return false;
    WatertightRay ray;
    if (!ray.init(org, dir)) return false;
    std::array<std::uint32_t, kMaxDepth> stack;
    int top = 0;
    std::uint32_t node = 0;
    float best = tfar;
    std::uint32_t bestSlot = 0;
    float bestU = 0, bestV = 0;
    bool found = false;
    // Children are tested at their parent and visited nearest first; the far one waits on the
    // stack with its entry distance and is dropped when a closer hit has been found since.
    std::array<float, kMaxDepth> stackT;
    float entry;
    if (!ray.hitsBox(mNodes[0].lo, mNodes[0].hi, tnear, best, entry)) return false;
    for (;;) {
        const Node& n = mNodes[node];
        if (n.count & kInner) {
            const std::uint32_t left = node + 1, right = n.first;
            float tl = 0.0f, tr = 0.0f;
            const bool hl = ray.hitsBox(mNodes[left].lo, mNodes[left].hi, tnear, best, tl);
            const bool hr = ray.hitsBox(mNodes[right].lo, mNodes[right].hi, tnear, best, tr);
            if (hl && hr) {
                const bool leftFirst = tl <= tr;
                stack[static_cast<std::size_t>(top)] = leftFirst ? right : left;
                stackT[static_cast<std::size_t>(top)] = leftFirst ? tr : tl;
                ++top;
                node = leftFirst ? left : right;
                continue;
            }
            if (hl || hr) {
                node = hl ? left : right;
                continue;
            }
        } else {
            for (std::uint32_t s = n.first; s < n.first + n.count; ++s) {
                const std::size_t i = 3 * static_cast<std::size_t>(s);
                float t, u, v;
                if (ray.hitsTriangle(&mPositions[3 * static_cast<std::size_t>(mSlotIndex[i])],
                                     &mPositions[3 * static_cast<std::size_t>(mSlotIndex[i + 1])],
                                     &mPositions[3 * static_cast<std::size_t>(mSlotIndex[i + 2])],
                                     tnear, best, t, u, v)) {
                    if constexpr (kAny) return true;
                    found = true;
                    best = t;
                    bestSlot = s;
                    bestU = u;
                    bestV = v;
                }
            }
        }
        // Pop the next subtree whose box starts no later than the best hit so far (its entry
        // distance is conservative: computed with the slack of hitsBox).
        bool next = false;
        while (top > 0) {
            --top;
            if (stackT[static_cast<std::size_t>(top)] <= best) {
                node = stack[static_cast<std::size_t>(top)];
                next = true;
                break;
            }
        }
        if (!next) break;
    }
    if (!found || hit == nullptr) return found;
    const std::size_t i = 3 * static_cast<std::size_t>(bestSlot);
    const float* p0 = &mPositions[3 * static_cast<std::size_t>(mSlotIndex[i])];
    const float* p1 = &mPositions[3 * static_cast<std::size_t>(mSlotIndex[i + 1])];
    const float* p2 = &mPositions[3 * static_cast<std::size_t>(mSlotIndex[i + 2])];
    const float e1x = p1[0] - p0[0], e1y = p1[1] - p0[1], e1z = p1[2] - p0[2];
    const float e2x = p2[0] - p0[0], e2y = p2[1] - p0[1], e2z = p2[2] - p0[2];
    hit->t = best;
    hit->primId = mSlotPrim[bestSlot];
    hit->u = bestU;
    hit->v = bestV;
    hit->ng = {e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x};
    return true;
}

bool RefitMesh::intersect(const std::array<float, 3>& org, const std::array<float, 3>& dir,
                          float tnear, float tfar, TriangleHit& hit) const noexcept {
    return traverse<false>(org, dir, tnear, tfar, &hit);
}

bool RefitMesh::occluded(const std::array<float, 3>& org, const std::array<float, 3>& dir,
                         float tnear, float tfar) const noexcept {
    return traverse<true>(org, dir, tnear, tfar, nullptr);
}

}  // namespace palp::kernels
