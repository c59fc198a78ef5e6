#pragma once
/// @file
/// SurfaceFrame: one tick's deformed surface of a deformable body, for drawing. A Session
/// publishes one per tick through a triple buffer of frames preallocated at set-up
/// (NothrowSlot: frames of one body have one size, so a copy reuses the capacity;
/// Session::latestSurface()); the triangles never change and are the model's
/// (DeformableModel::surface().triangles).

#include <cstddef>
#include <cstdint>
#include <vector>

namespace palp::haptics {

class DeformableBody;

/// Vertex positions of a deformable body's boundary surface at one tick, in the order of
/// DeformableModel::surface().vertices.
struct SurfaceFrame {
    std::uint64_t tick = 0;        ///< the Snapshot::tick this surface belongs to
    double timeSeconds = 0;        ///< its Snapshot::timeSeconds, s
    std::vector<float> positions;  ///< #V by 3 (x, y, z per vertex), world metres

    SurfaceFrame() = default;
    /// A frame of @p vertexCount vertices at the origin (allocates: set-up only).
    explicit SurfaceFrame(std::size_t vertexCount) : positions(3 * vertexCount, 0.0f) {}

    /// Writes @p body's current surface (its nodes' deformed positions) with @p tick and
    /// @p timeSeconds. The frame must have been sized for the body's model.
    /// @par Real-time  O(#V), allocation-free.
    void fill(const DeformableBody& body, std::uint64_t tick, double timeSeconds) noexcept;
};

}  // namespace palp::haptics
