#include "palp/kernels/transfer_function.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <string>
#include <type_traits>

#include "palp/base/error.h"

namespace palp::kernels {

// ---------------------------------------------------------------------------------------------
// TransferFunction

TransferFunction::TransferFunction(std::span<const std::array<float, 2>> nodes) {
    if (nodes.empty() || nodes.size() > static_cast<std::size_t>(kMaxNodes))
        throw ValueError("transfer function nodes: expected 1.." + std::to_string(kMaxNodes) +
                         " nodes, found " + std::to_string(nodes.size()));
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        const float v = nodes[i][0], s = nodes[i][1];
        if (!std::isfinite(v) || !std::isfinite(s) || s < 0)
            throw ValueError("transfer function node " + std::to_string(i) +
                             ": expected a finite value and a finite sigma >= 0, found (" +
                             std::to_string(v) + ", " + std::to_string(s) + ")");
        if (i > 0 && v < nodes[i - 1][0])
            throw ValueError("transfer function node " + std::to_string(i) +
                             ": expected values in non-decreasing order, found " +
                             std::to_string(v) + " after " + std::to_string(nodes[i - 1][0]));
        mV[i] = v;
        mS[i] = s;
    }
    mCount = static_cast<int>(nodes.size());
    mCum[0] = 0;
    for (std::size_t i = 1; i < nodes.size(); ++i)
        mCum[i] = mCum[i - 1] + 0.5 * (static_cast<double>(mS[i - 1]) + mS[i]) *
                                    (static_cast<double>(mV[i]) - mV[i - 1]);
    mZeroBelow = std::numeric_limits<float>::infinity();
    if (mS[0] > 0) {
        mZeroBelow = -std::numeric_limits<float>::infinity();
    } else {
        for (std::size_t i = 1; i < nodes.size(); ++i)
            if (mS[i] > 0) {
                mZeroBelow = mV[i - 1];
                break;
            }
    }
}

TransferFunction TransferFunction::step(float threshold, float height) {
    const std::array<std::array<float, 2>, 2> n{{{threshold, 0.0f}, {threshold, height}}};
    return TransferFunction(n);
}

float TransferFunction::sigma(float v) const noexcept {
    if (mCount == 0) return 0;
    if (v < mV[0]) return mS[0];
    const auto last = static_cast<std::size_t>(mCount - 1);
    if (v >= mV[last]) return mS[last];
    for (std::size_t i = 0; i < last; ++i)
        if (v < mV[i + 1]) {
            const float w = mV[i + 1] - mV[i];
            return w > 0 ? mS[i] + (mS[i + 1] - mS[i]) * ((v - mV[i]) / w) : mS[i + 1];
        }
    return mS[last];
}

double TransferFunction::integral(double v) const noexcept {
    if (mCount == 0) return 0;
    if (v <= mV[0]) return mS[0] * (v - mV[0]);
    const auto last = static_cast<std::size_t>(mCount - 1);
    if (v >= mV[last]) return mCum[last] + mS[last] * (v - mV[last]);
    for (std::size_t i = 0; i < last; ++i)
        if (v < mV[i + 1]) {
            const double w = static_cast<double>(mV[i + 1]) - mV[i];
            if (!(w > 0)) continue;
            const double s = mS[i] + (static_cast<double>(mS[i + 1]) - mS[i]) * ((v - mV[i]) / w);
            return mCum[i] + 0.5 * (mS[i] + s) * (v - mV[i]);
        }
    return mCum[last];
}

}  // namespace palp::kernels
