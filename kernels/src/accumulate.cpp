#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <new>
#include <string>
#include <type_traits>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "palp/kernels/volume_ray.h"
#include "ray_sample.h"

namespace palp::kernels {

void validateAccumulateParams(const AccumulateParams& p) {
    requireWithin("accumulate step", p.step, bounds::kSpacing);
    requireWithin("accumulate tauStop", p.tauStop, bounds::kTauStop);
    if (p.reportFirstHit && std::isnan(p.firstHitThreshold))
        throw ValueError("accumulate firstHitThreshold: expected a number, found NaN");
}

AccumulateHit accumulate(const VolumeView& view, const Eigen::Vector3d& origin,
                         const Eigen::Vector3d& direction, double length,
                         const AccumulateParams& params) noexcept {
    AccumulateHit out;
    out.t = std::isfinite(length) && length > 0 ? static_cast<float>(length) : 0.0f;
    const TransferFunction& tf = params.sigma;
    const float thr = params.firstHitThreshold;
    const bool wantHit = params.reportFirstHit;
    const float bg = view.background();
    const bool clip = !(tf.sigma(bg) > 0) && !(wantHit && bg >= thr);
    IndexRay r;
    if (!(params.tauStop > 0) || !setupRay(view, origin, direction, length, params.step, clip, r))
        return out;
    out.t = static_cast<float>(r.length);
    const Table& tb = detail::viewTable(view);
    const float zeroBelow = tf.zeroBelow();
    const bool skip = params.skipEmpty;
    double tau = 0;
    float prev = 0;
    double prevT = 0;
    bool prevValid = false;
    bool found = false;
    double hitT = 0;
    Cell c;
    CornerCache cache;
    for (std::int64_t k = r.kBegin; k <= r.kEnd;) {
        const double t = r.t(k);
        locate(tb, r.o[0] + t * r.d[0], r.o[1] + t * r.d[1], r.o[2] + t * r.d[2], c);
        if (skip && c.block >= 0) {
            const float mx = tb.maxDilated[static_cast<std::size_t>(c.block)];
            if (mx < zeroBelow && (!wantHit || found || mx < thr)) {
                const bool hitDone = !wantHit || found;
                k = skipBlocks(tb, r, c, k, [zeroBelow, hitDone, thr](float bmx, float) {
                    return bmx < zeroBelow && (hitDone || bmx < thr);
                });
                prevValid = false;
                continue;
            }
        }
        const float v = sampleCached(tb, bg, c, cache);
        if (k == 0) {
            if (wantHit && v >= thr) {
                found = true;
                hitT = 0;
            }
            prev = v;
            prevT = 0;
            prevValid = true;
            ++k;
            continue;
        }
        if (!prevValid) {
            prevT = r.t(k - 1);
            prev = sampleAt(view, r, prevT, cache);
        }
        if (wantHit && !found && v >= thr) {
            found = true;
            hitT = prev >= thr
                       ? prevT
                       : refineCrossing(view, r, thr, prevT, static_cast<double>(prev) - thr, t,
                                        static_cast<double>(v) - thr, 4, cache);
        }
        const double dt = t - prevT;
        const double v0 = prev, dv = static_cast<double>(v) - v0;
        const bool flat = std::fabs(dv) <= 1e-6 * std::max(1.0, std::fabs(v0));
        const double s0 = flat ? 0.0 : tf.integral(v0);
        const double seg = flat ? dt * tf.sigma(static_cast<float>(v0 + 0.5 * dv))
                                : dt * (tf.integral(static_cast<double>(v)) - s0) / dv;
        if (tau + seg >= params.tauStop && seg > 0) {
            double u;
            if (flat) {
                u = (params.tauStop - tau) / seg;
            } else {
                double lo = 0, hi = 1;
                for (int it = 0; it < 48; ++it) {
                    const double mid = 0.5 * (lo + hi);
                    const double g = tau + dt * (tf.integral(v0 + mid * dv) - s0) / dv;
                    if (g >= params.tauStop)
                        hi = mid;
                    else
                        lo = mid;
                }
                u = hi;
            }
            const double ts = prevT + std::clamp(u, 0.0, 1.0) * dt;
            out.t = static_cast<float>(ts);
            out.integral = static_cast<float>(params.tauStop);
            out.stopped = true;
            out.firstHit = found && hitT <= ts;
            out.firstHitT = out.firstHit ? static_cast<float>(hitT) : 0.0f;
            return out;
        }
        tau += seg;
        prev = v;
        prevT = t;
        prevValid = true;
        ++k;
    }
    out.integral = static_cast<float>(tau);
    out.firstHit = found;
    out.firstHitT = found ? static_cast<float>(hitT) : 0.0f;
    return out;
}

void traceAccumulate(const VolumeView& view, const RayBundle& bundle,
                     const AccumulateParams& params, BundleAccumulation& out) noexcept {
    out.count = bundle.valid ? std::clamp(bundle.count, 0, kMaxBundleRays) : 0;
    for (int i = 0; i < out.count; ++i) {
        const auto r = static_cast<std::size_t>(i);
        const AccumulateHit h = accumulate(
            view, Eigen::Vector3d(bundle.ox[r], bundle.oy[r], bundle.oz[r]),
            Eigen::Vector3d(bundle.dx[r], bundle.dy[r], bundle.dz[r]), bundle.length[r], params);
        out.t[r] = h.t;
        out.integral[r] = h.integral;
        out.firstHitT[r] = h.firstHitT;
        out.stopped[r] = h.stopped ? 1 : 0;
        out.firstHit[r] = h.firstHit ? 1 : 0;
    }
}

}  // namespace palp::kernels
