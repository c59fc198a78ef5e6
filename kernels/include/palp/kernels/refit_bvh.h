#pragma once
/// @file
/// A triangle mesh of fixed topology with palp's own bounding volume hierarchy: built once off
/// the servo thread, refitted in place from new vertex positions without allocating, and traced
/// with a watertight ray/triangle test (Woop, Benthin and Wald 2013), so a ray through a shared
/// edge or vertex of a closed mesh cannot slip between its triangles. Hits follow Embree's
/// triangle conventions (t, primID, u, v, unnormalised Ng = (v1 - v0) x (v2 - v0)), so it can
/// stand in for an Embree deforming mesh (EmbreeScene::addRefitMesh) without an Embree commit
/// per update.

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "palp/kernels/triangle_mesh.h"

namespace palp::kernels {

/// An axis-aligned box, metres. Empty when lo > hi on an axis.
struct Box3f {
    std::array<float, 3> lo{};
    std::array<float, 3> hi{};
    /// True when @p b lies inside this box (faces included).
    bool contains(const Box3f& b) const noexcept;
};

/// A closest hit: t in units of |direction|, the triangle (index in the input mesh), Embree's
/// barycentrics (point = (1 - u - v) v0 + u v1 + v v2) and geometric normal
/// ng = (v1 - v0) x (v2 - v0), unnormalised.
struct TriangleHit {
    float t = 0;
    std::uint32_t primId = 0;
    float u = 0, v = 0;
    std::array<float, 3> ng{};
};

/// What refit() did.
enum class RefitStatus {
    Ok,            ///< positions taken, hierarchy refitted, inside the limit box
    OutsideLimit,  ///< taken and refitted, but the mesh left the limit box (setLimit)
    Rejected,      ///< wrong size or a non-finite coordinate: nothing changed
};

/// A triangle mesh with a binary BVH over fixed topology, built by binned SAH on the rest
/// positions (median splits below depth 32 or when centroids coincide; leaves of at most
/// leafSize triangles). Nodes are stored in depth-first order (children after their parent), so
/// a refit is one reverse sweep over the node array: O(#T), no allocation (or, with a slack,
/// only the nodes above vertices that moved beyond it). Queries test both
/// children at their parent and descend into the nearer first.
///
/// @par Threading  Construction, refit() and setLimit() are for one thread at a time and must
///      not overlap with queries; any number of threads may query at once between refits.
/// @par Real-time  refit(), intersect() and occluded() are noexcept, allocate nothing, take no
///      lock and are bounded: a refit touches every node once, a query uses a fixed stack of
///      kMaxDepth entries (the build guarantees the depth) and visits each node at most once.
class RefitMesh {
  public:
    /// Largest tree depth (root = 1); the build stays below 32 + log2(#T) + 1.
    static constexpr int kMaxDepth = 64;

    /// Builds the hierarchy over @p mesh (rest positions). Degenerate triangles are allowed
    /// (they are never hit).
    /// @throw palp::ValueError for an empty mesh, indices out of range, non-finite positions or
    ///        @p leafSize outside [1, 16].
    explicit RefitMesh(const TriangleMesh& mesh, int leafSize = 4);
    // Not copyable or movable: EmbreeScene::addRefitMesh keeps its address and shares its
    // arrays with Embree.
    RefitMesh(const RefitMesh&) = delete;
    RefitMesh& operator=(const RefitMesh&) = delete;

    /// Copies @p positions (#V by 3, metres) in and refits the hierarchy. A wrong size or a
    /// non-finite coordinate is rejected (the previous positions stay). @par Real-time
    /// With a slack (setRefitSlack) only the leaves of vertices that moved more than the slack
    /// since their boxes were made, and their ancestors, are refitted: O(#V + changed nodes x
    /// depth) instead of O(#T).
    RefitStatus refit(std::span<const float> positions) noexcept;
    /// refit() when only the vertices listed in @p moved changed since the last refit (the
    /// others are promised unchanged): O(#moved + changed nodes x depth) with a slack, no sweep
    /// over every vertex; a vertex may be listed more than once. Without a slack it refits every
    /// node. Rejected (nothing changed) for a wrong size, an index out of range or a non-finite
    /// coordinate of a listed vertex.
    RefitStatus refit(std::span<const float> positions,
                      std::span<const std::uint32_t> moved) noexcept;

    /// Boxes grown by @p slack metres (>= 0, finite; 0: exact boxes, the default): a vertex
    /// that stays within the slack (per axis) of the position its boxes were made from needs no
    /// refit, so a surface that deforms mostly far below the slack (a tissue's far field) costs
    /// a sweep over the vertices, not over the tree. Queries stay exact (triangles are tested at
    /// their current positions); only their boxes are looser. Refits every node (set-up, not
    /// real-time). @throw palp::ValueError for a negative or non-finite slack.
    void setRefitSlack(float slack);
    float refitSlack() const noexcept { return mSlack; }
    /// Nodes the last refit() recomputed (all of them without slack).
    std::size_t lastRefitNodes() const noexcept { return mLastRefitNodes; }

    /// Closest hit of the ray org + t dir with tnear < t <= tfar. NaN or infinite input, a zero
    /// direction or tnear > tfar give no hit. @return whether @p hit was filled. @par Real-time
    bool intersect(const std::array<float, 3>& org, const std::array<float, 3>& dir, float tnear,
                   float tfar, TriangleHit& hit) const noexcept;
    /// Whether any triangle is hit with tnear < t <= tfar. @par Real-time
    bool occluded(const std::array<float, 3>& org, const std::array<float, 3>& dir, float tnear,
                  float tfar) const noexcept;

    /// Box the mesh is promised to stay in (EmbreeScene registers it with Embree); refit()
    /// reports OutsideLimit when it leaves it. Default: unlimited.
    void setLimit(const Box3f& limit) noexcept { mLimit = limit; }
    const Box3f& limit() const noexcept { return mLimit; }
    /// Current bounds of the mesh (the root box).
    Box3f bounds() const noexcept;

    std::size_t vertexCount() const noexcept { return mVertexCount; }
    std::size_t triangleCount() const noexcept { return mIndices.size() / 3; }
    std::size_t nodeCount() const noexcept { return mNodes.size(); }
    /// Depth of the tree (a single leaf: 1).
    int depth() const noexcept { return mDepth; }
    /// Current positions, #V by 3 (the array has one float of padding after them, so Embree
    /// may share it as a vertex buffer).
    std::span<const float> positions() const noexcept {
        return {mPositions.data(), 3 * mVertexCount};
    }
    /// Triangle vertex indices, #T by 3, in input order.
    std::span<const std::uint32_t> indices() const noexcept { return mIndices; }

  private:
    struct Node {
        std::array<float, 3> lo, hi;
        std::uint32_t first;  // leaf: first slot in mSlotPrim; inner: right child
        std::uint32_t count;  // leaf: triangle count (> 0); inner: kInner | split axis
    };
    static constexpr std::uint32_t kInner = 0x80000000u;

    template <bool kAny>
    bool traverse(const std::array<float, 3>& org, const std::array<float, 3>& dir, float tnear,
                  float tfar, TriangleHit* hit) const noexcept;
    void refitNodes() noexcept;
    /// With a slack: marks vertex @p v's leaves when it drifted beyond the slack from its base
    /// (and moves the base); refitMarked() then refits the marked leaves and their ancestors.
    void markIfDrifted(std::size_t v) noexcept;
    RefitStatus refitMarked() noexcept;
    // Leaf box of node @p n from mBase (slack refits) grown by the slack.
    void refitLeafFromBase(Node& n) noexcept;
    void refitInner(std::size_t i) noexcept;

    std::size_t mVertexCount = 0;
    std::vector<float> mPositions;          // 3 #V + 1 (padding)
    std::vector<std::uint32_t> mIndices;    // #T by 3, input order
    std::vector<std::uint32_t> mSlotPrim;   // leaf slot -> triangle
    std::vector<std::uint32_t> mSlotIndex;  // leaf slot -> its 3 vertex indices
    std::vector<Node> mNodes;               // depth-first
    int mDepth = 0;
    Box3f mLimit;
    // Slack refits (setRefitSlack): positions the boxes were made from, parents, the leaves of
    // each vertex (CSR), and scratch for the changed nodes.
    float mSlack = 0;
    std::size_t mLastRefitNodes = 0;
    std::vector<float> mBase;                     // 3 #V
    std::vector<std::uint32_t> mParent;           // per node; the root's is itself
    std::vector<std::uint32_t> mVertexLeafStart;  // #V + 1
    std::vector<std::uint32_t> mVertexLeaves;     // leaf node indices
    std::vector<std::uint32_t> mChanged;          // scratch, capacity #nodes
    std::vector<std::uint8_t> mChangedMark;       // per node
};

}  // namespace palp::kernels
