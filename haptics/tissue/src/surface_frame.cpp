// SurfaceFrame (surface_frame.h): a deformable body's surface, copied for a viewer.

#include "palp/haptics/tissue/surface_frame.h"

#include <algorithm>

#include "palp/haptics/tissue/deformable.h"

namespace palp::haptics {

void SurfaceFrame::fill(const DeformableBody& body, std::uint64_t tickIn,
                        double timeSecondsIn) noexcept {
    tick = tickIn;
    timeSeconds = timeSecondsIn;
    // The body's own float surface (as refitted): one copy, no per-node lookups.
    const std::vector<float>& x = body.surfacePositions();
    std::copy_n(x.begin(), std::min(x.size(), positions.size()), positions.begin());
}

}  // namespace palp::haptics
