// SurfaceFrame (surface_frame.h): a deformable body's surface, copied for a viewer.

#include "palp/haptics/surface_frame.h"

#include <algorithm>

#include "palp/haptics/deformable.h"

namespace palp::haptics {

void SurfaceFrame::fill(const DeformableBody& body, std::uint64_t tickIn,
                        double timeSecondsIn) noexcept {
    tick = tickIn;
    timeSeconds = timeSecondsIn;
    const std::vector<std::int32_t>& nodes = body.model().surface().vertexNode;
    const std::size_t count = std::min(nodes.size(), positions.size() / 3);
    for (std::size_t v = 0; v < count; ++v) {
        const Eigen::Vector3d p = body.nodePosition(nodes[v]);
        positions[3 * v] = static_cast<float>(p.x());
        positions[3 * v + 1] = static_cast<float>(p.y());
        positions[3 * v + 2] = static_cast<float>(p.z());
    }
}

}  // namespace palp::haptics
