#pragma once
/// @file
/// LayoutBuilder: builds, assembles and factorises a layout of the asynchronous regions (the
/// regions around a contact, the primary operator's cell lists, the secondary's Galerkin system
/// and, per options, its factorisation and its responses to the primary border).

#include <atomic>
#include <cstdint>
#include <memory>
#include <vector>

#include "async_layout.h"
#include "async_setup.h"

namespace palp::fem {

/// Prepares layouts off the servo path: in the constructor, on the builder thread (threaded
/// contact changes) or at a synchronous period boundary. Seconds for large meshes.
/// @par Threading  After construction every member is const and reads only immutable data (the
/// setup, the model, the assembled stiffness); the generation counter is atomic. So build() and
/// prepare() may run on any thread, also concurrently with the servo and the secondary.
class LayoutBuilder {
  public:
    /// Assembles the fine stiffness once. @p setup must outlive the builder.
    explicit LayoutBuilder(const AsyncSetup& setup);

    /// The regions around @p contactNodes with @p seeds seed nodes and the secondary system
    /// (assembled, not factorised), with a new generation number.
    /// @throw palp::ValueError for a non-zero prescribed displacement on a secondary node.
    std::unique_ptr<Layout> build(const std::vector<int>& contactNodes, int seeds) const;
    /// Factorises the secondary system of @p layout (CHOLMOD or the PCG matrices) and takes the
    /// condensed and direct responses to the border.
    /// @throw palp::ValueError for a failed factorisation (rigid-body motion left free).
    void prepare(Layout& layout) const;
    /// build() then prepare() for the single contact node @p node.
    std::unique_ptr<Layout> buildPrepared(int node, int seeds) const;

  private:
    // Steps of build(), in order.
    std::vector<std::uint8_t> drivenDofs(const std::vector<int>& contact, Layout& L) const;
    std::vector<int> seedOrder(const std::vector<int>& contact) const;
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
    mutable std::atomic<std::uint64_t> mNextGeneration{1};
};

}  // namespace palp::fem
