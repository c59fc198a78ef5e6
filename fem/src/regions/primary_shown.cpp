// PrimaryRegion: what the servo shows of a node (docs/algorithms.md section 6): the primary's
// own values on P and Gamma, the constraint values on fixed dofs, and elsewhere the secondary's
// watched values interpolated over the period; one node at a time, or a run of watched nodes in
// one pass (a deformable body's swept surface, section 10).
#include <algorithm>
#include <cmath>
#include <limits>

#include "index_cast.h"
#include "regions/primary_region.h"

namespace palp::fem {

Eigen::Vector3d PrimaryRegion::shown(const Layout& L, int node, double frac) const noexcept {
    const std::size_t n = sz(node);
    const double g = watchedFraction(frac);
    if (L.isPrimary[n] || L.isGamma[n]) return mU.segment<3>(3 * node);
    const int w = mSetup.watchIndex[n];
    Eigen::Vector3d out = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
    const bool active = mSetup.model.mesh().nodeActive()[n];
    for (int k = 0; k < 3; ++k) {
        const int d = 3 * node + k;
        if (mSetup.fixed[sz(d)] || !active) {
            out[k] = mU[d];
        } else if (w >= 0) {
            const std::size_t i = 3 * sz(w) + sz(k);
            out[k] = mWPrev[i] + g * (mWCur[i] - mWPrev[i]);
        }
    }
    return out;
}

std::size_t PrimaryRegion::shownWatched(const Layout& L, double frac, std::size_t first,
                                        std::span<Eigen::Vector3d> out) const noexcept {
    const std::vector<int>& watch = mSetup.options.watchNodes;
    const std::size_t end = std::min(first + out.size(), watch.size());
    const std::vector<std::uint8_t>& active = mSetup.model.mesh().nodeActive();
    const double g = watchedFraction(frac);
    for (std::size_t i = first; i < end; ++i) {
        const int n = watch[i];
        const std::size_t ni = sz(n);
        Eigen::Vector3d& o = out[i - first];
        if (L.isPrimary[ni] || L.isGamma[ni] || !active[ni]) {  // as shown()
            o = mU.segment<3>(3 * n);
            continue;
        }
        for (std::size_t k = 0; k < 3; ++k) {
            const std::size_t j = 3 * i + k;
            const int d = 3 * n + static_cast<int>(k);
            o[static_cast<Eigen::Index>(k)] =
                mSetup.fixed[sz(d)] ? mU[d] : mWPrev[j] + g * (mWCur[j] - mWPrev[j]);
        }
    }
    return end > first ? end - first : 0;
}

WatchedChanges PrimaryRegion::changedWatched(const Layout& L, double frac, std::size_t first,
                                             std::size_t count, std::span<const double> shown,
                                             double still, std::span<std::uint32_t> index,
                                             std::span<Eigen::Vector3d> out) const noexcept {
    const std::vector<int>& watch = mSetup.options.watchNodes;
    const std::size_t end =
        std::min({first + std::min(count, watch.size()), watch.size(), shown.size() / 3});
    const std::size_t room = std::min(index.size(), out.size());
    const std::vector<std::uint8_t>& active = mSetup.model.mesh().nodeActive();
    const double g = watchedFraction(frac);
    WatchedChanges r;
    std::size_t i = first;
    for (; i < end; ++i) {
        const int n = watch[i];
        const std::size_t ni = sz(n);
        const std::size_t j = 3 * i;
        const bool own = L.isPrimary[ni] || L.isGamma[ni];
        // A node shown from the secondary alone, both ends of its interpolation within @p still
        // of what the caller shows: every value on the way between is too (g in [0, 1]).
        if (!own && mSetup.watchPlain[i]) {
            bool near = true;
            double s2 = 0;
            for (std::size_t k = 0; k < 3; ++k) {
                const double s = shown[j + k];
                near = near && std::abs(mWPrev[j + k] - s) < still &&
                       std::abs(mWCur[j + k] - s) < still;
                s2 += s * s;
            }
            if (near) {
                r.skippedMax2 = std::max(r.skippedMax2, s2);
                continue;
            }
        }
        if (r.changed == room) break;  // examined up to here; the caller resumes at i
        Eigen::Vector3d& o = out[r.changed];
        if (own || !active[ni]) {  // as shown()
            o = mU.segment<3>(3 * n);
        } else {
            for (std::size_t k = 0; k < 3; ++k) {
                const int d = 3 * n + static_cast<int>(k);
                o[static_cast<Eigen::Index>(k)] =
                    mSetup.fixed[sz(d)] ? mU[d]
                                        : mWPrev[j + k] + g * (mWCur[j + k] - mWPrev[j + k]);
            }
        }
        index[r.changed] = static_cast<std::uint32_t>(i);
        ++r.changed;
    }
    r.examined = i > first ? i - first : 0;
    return r;
}

void PrimaryRegion::shownWatched(const Layout& L, double frac,
                                 std::span<Eigen::Vector3d> out) const noexcept {
    const std::size_t count = std::min(out.size(), mWPrev.size() / 3);
    const double g = watchedFraction(frac);
    for (std::size_t i = 0; i < count; ++i) {
        for (std::size_t k = 0; k < 3; ++k) {
            const std::size_t j = 3 * i + k;
            out[i][static_cast<Eigen::Index>(k)] = mWPrev[j] + g * (mWCur[j] - mWPrev[j]);
        }
    }
    for (const int j : mSetup.watchFixedDofs) {
        const std::size_t i = sz(j / 3);
        if (i < count) {
            const int node = mSetup.options.watchNodes[i];
            out[i][j % 3] = mU[3 * node + j % 3];
        }
    }
    // P and Gamma show the primary's own state (all three components, as shown()).
    const auto own = [&](const std::vector<int>& nodes) {
        for (const int n : nodes) {
            const int w = mSetup.watchIndex[sz(n)];
            if (w >= 0 && sz(w) < count) out[sz(w)] = mU.segment<3>(3 * n);
        }
    };
    own(L.primaryNodes);
    own(L.gammaNodes);
}

}  // namespace palp::fem
