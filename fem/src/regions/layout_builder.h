#pragma once
/// @file
/// LayoutBuilder: builds, assembles and factorises a layout of the asynchronous regions (the
/// regions around a contact, the primary operator's cell lists, the secondary's Galerkin system
/// and, per options, its factorisation and its responses to the primary border).

#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "regions/async_capacitance.h"
#include "regions/async_layout.h"
#include "regions/async_setup.h"

namespace palp::fem {

/// The @p count active nodes nearest @p contactNodes in graph distance over lattice edges
/// (ties by Euclidean distance), nearest first, with their distances in @p distance when given
/// (LayoutBuilder::seedOrder on @p mesh).
std::vector<int> primarySeedOrder(const HexMesh& mesh, const std::vector<int>& contactNodes,
                                  int count, std::vector<int>* distance = nullptr);
/// The cells touching the first @p seedCount nodes of @p order, widened to whole coarse cells
/// of @p lod fine cells a side: a mask over the mesh's cells.
std::vector<std::uint8_t> primaryCellsOf(const HexMesh& mesh, const std::vector<int>& order,
                                         int seedCount, int lod);

/// Prepares layouts off the servo path: in the constructor, on the builder thread (threaded
/// contact changes) or at a synchronous period boundary. Seconds for large meshes.
/// @par Threading  After construction every member is const and reads only immutable data (the
/// setup, the model, the assembled stiffness); the generation counter is atomic. So build() and
/// prepare() may run on any thread, also concurrently with the servo and the secondary.
class LayoutBuilder {
  public:
    /// Assembles the fine stiffness once and, for the quasi-static CHOLMOD secondary with
    /// globalSecondary, factorises the whole body's secondary (GlobalSecondary) with the zone
    /// of the contacts around @p contactNodes' slide nodes. @p setup must outlive the builder.
    LayoutBuilder(const AsyncSetup& setup, const std::vector<int>& contactNodes);
    /// Whether @p node is one the contact may slide to without a factorisation.
    bool isSlideNode(int node) const {
        return node >= 0 && static_cast<std::size_t>(node) < mSlide.size() &&
               mSlide[static_cast<std::size_t>(node)] != 0;
    }
    /// The zone of coarse nodes (coarseCounts order) a primary of @p setup around any slide
    /// node of @p contactNodes can reach (see AsyncRegionsOptions::slideNodes; empty: no slide
    /// nodes), with the slide nodes marked per fine node in @p slideMark when given. O(nodes).
    static std::vector<int> zoneCoarseNodes(const AsyncSetup& setup,
                                            const std::vector<int>& contactNodes,
                                            std::vector<std::uint8_t>* slideMark = nullptr);
    /// The @p count active nodes nearest @p contactNodes in graph distance (ties by Euclidean
    /// distance), nearest first (fewer when fewer are reachable), with the distances in
    /// @p distance when given. O(nodes reached): the search stops at the graph distance of the
    /// count-th node.
    static std::vector<int> seedOrder(const AsyncSetup& setup, const std::vector<int>& contactNodes,
                                      int count, std::vector<int>* distance = nullptr);
    /// The whole body's secondary, or null when every layout is factorised.
    const GlobalSecondary* global() const { return mGlobal.get(); }

    /// The regions around @p contactNodes with @p seeds seed nodes and the secondary system
    /// (assembled, not factorised), with a new generation number. With @p capacitanceOnly, null
    /// instead of a layout that the capacitance secondary cannot give (one that would need its
    /// own assembly and factorisation: seconds, not worth it for a prefetch).
    /// @throw palp::ValueError for a non-zero prescribed displacement on a secondary node.
    std::unique_ptr<Layout> build(const std::vector<int>& contactNodes, int seeds,
                                  bool capacitanceOnly = false) const;
    /// Factorises the secondary system of @p layout (CHOLMOD or the PCG matrices) and takes the
    /// condensed and direct responses to the border.
    /// @throw palp::ValueError for a failed factorisation (rigid-body motion left free).
    void prepare(Layout& layout) const;
    /// build() then prepare() for the single contact node @p node (null: see build()).
    std::unique_ptr<Layout> buildPrepared(int node, int seeds, bool capacitanceOnly = false) const;

  private:
    // Steps of build(), in order.
    std::vector<std::uint8_t> drivenDofs(const std::vector<int>& contact, Layout& L) const;
    bool buildGlobal(const std::vector<std::uint8_t>& primaryCell, Layout& L) const;
    std::vector<std::uint8_t> primaryCells(const std::vector<int>& order, int seedCount) const;
    std::vector<std::uint8_t> classifyNodes(const std::vector<std::uint8_t>& primaryCell,
                                            const std::vector<std::uint8_t>& driven,
                                            const std::vector<int>& contact, Layout& L) const;
    void collectPrimaryDofs(const std::vector<std::uint8_t>& primaryCell,
                            const std::vector<std::uint8_t>& touchesPrimary,
                            const std::vector<std::uint8_t>& driven, Layout& L) const;
    SparseMatrix interpolation(const std::vector<std::uint8_t>& primaryCell,
                               const std::vector<std::uint8_t>& driven, Layout& L) const;
    void restrictInterpolation(Layout& L) const;
    void assembleSecondary(const SparseMatrix& interp, Layout& L) const;
    void sizeWorkVectors(Layout& L) const;
    void checkPrescribed(const Layout& L) const;
    // Steps of prepare().
    void factorise(const SparseMatrix& a, Layout& L) const;
    void takeResponses(const SparseMatrix& a, Layout& L) const;

    const AsyncSetup& mSetup;
    SparseMatrix mStiffness;  // fine K
    std::unique_ptr<GlobalSecondary> mGlobal;
    std::vector<std::uint8_t> mSlide;  // per fine node: a slide node (with mGlobal)
    mutable std::atomic<std::uint64_t> mNextGeneration{1};
};

}  // namespace palp::fem
