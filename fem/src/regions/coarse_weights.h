#pragma once
/// @file
/// The secondary's interpolation weights of a fine node on a coarse cell's corners, shared by
/// the layouts (layout_builder.cpp) and the global secondary (async_capacitance.cpp) so that a
/// layout's secondary rows are the global rows.

#include <array>
#include <cmath>

#include "palp/fem/hex_mesh.h"

namespace palp::fem {

/// Trilinear weights of the fine node at lattice coordinates @p ijk on the 8 corners of coarse
/// cell (@p I, @p J, @p K) of level @p lod (corner c at (I + (c & 1), J + (c >> 1 & 1),
/// K + (c >> 2)) coarse), into @p w. A corner whose fine node is void (no active cell touches
/// it) gets no weight and the others are scaled to sum to one, so every coarse unknown is the
/// displacement of an active fine node (its own row is a unit row: the interpolation has full
/// column rank and the Galerkin system is positive definite on any body the supports hold, thin
/// shells and the corners of a scalp included) and a rigid translation is still interpolated
/// exactly. Weights depend only on the corners with a trilinear weight, which are the same for
/// every coarse cell holding the node. Returns false (w all zero) when every such corner is
/// void: the node has no coarse support and the secondary holds it at rest.
inline bool coarseWeights(const HexMesh& mesh, int lod, const std::array<int, 3>& ijk, int I, int J,
                          int K, std::array<double, 8>& w) noexcept {
    const auto& active = mesh.nodeActive();
    const double inv = 1.0 / static_cast<double>(lod);
    double sum = 0.0;
    for (int corner = 0; corner < 8; ++corner) {
        const int X = I + (corner & 1), Y = J + ((corner >> 1) & 1), Z = K + (corner >> 2);
        double wc = (1.0 - std::abs(ijk[0] - X * lod) * inv) *
                    (1.0 - std::abs(ijk[1] - Y * lod) * inv) *
                    (1.0 - std::abs(ijk[2] - Z * lod) * inv);
        if (wc != 0.0 && !active[static_cast<std::size_t>(mesh.node(X * lod, Y * lod, Z * lod))])
            wc = 0.0;
        w[static_cast<std::size_t>(corner)] = wc;
        sum += wc;
    }
    if (sum <= 0.0) return false;
    // Exactly one (a box: no corner void) leaves the weights bit for bit as they were.
    if (sum != 1.0)
        for (double& wc : w) wc /= sum;
    return true;
}

}  // namespace palp::fem
