#include "palp/haptics/devices/skin_field.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

#include "palp/base/error.h"
#include "palp/kernels/embree_scene.h"

namespace palp::haptics {

namespace {

/// A field sample that holds nothing.
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Nodes along a side of @p extent at about @p cell spacing (at least 2).
int nodeCount(double extent, double cell) {
    return std::max(2, static_cast<int>(std::ceil(extent / cell - 1e-9)) + 1);
}

std::string vec(const Eigen::Vector3d& p) {
    std::ostringstream s;
    s << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
    return s.str();
}

/// Fills the NaN entries of @p h (nu x nv) with the mean of their filled 8-neighbours, pass
/// after pass, until none is left (@p h has at least one finite entry).
void fillMissing(std::vector<double>& h, int nu, int nv) {
    std::vector<double> next = h;
    for (bool missing = true; missing;) {
        missing = false;
        for (int j = 0; j < nv; ++j) {
            for (int i = 0; i < nu; ++i) {
                const auto k = static_cast<std::size_t>(j) * static_cast<std::size_t>(nu) +
                               static_cast<std::size_t>(i);
                if (std::isfinite(h[k])) continue;
                double sum = 0;
                int n = 0;
                for (int dj = -1; dj <= 1; ++dj) {
                    for (int di = -1; di <= 1; ++di) {
                        const int ii = i + di, jj = j + dj;
                        if (ii < 0 || jj < 0 || ii >= nu || jj >= nv) continue;
                        const double x =
                            h[static_cast<std::size_t>(jj) * static_cast<std::size_t>(nu) +
                              static_cast<std::size_t>(ii)];
                        if (std::isfinite(x)) {
                            sum += x;
                            ++n;
                        }
                    }
                }
                if (n > 0) {
                    next[k] = sum / n;
                } else {
                    missing = true;
                }
            }
        }
        h = next;
    }
}

/// Separable Gaussian of @p sigmaNodes (in nodes) over @p h, weights renormalised at the edges.
void smooth(std::vector<double>& h, int nu, int nv, double sigmaNodes) {
    if (!(sigmaNodes > 0.05)) return;
    const int r = std::max(1, static_cast<int>(std::ceil(3 * sigmaNodes)));
    std::vector<double> w(static_cast<std::size_t>(2 * r + 1));
    for (int k = -r; k <= r; ++k)
        w[static_cast<std::size_t>(k + r)] = std::exp(-0.5 * k * k / (sigmaNodes * sigmaNodes));
    std::vector<double> tmp(h.size());
    const auto at = [nu](int i, int j) {
        return static_cast<std::size_t>(j) * static_cast<std::size_t>(nu) +
               static_cast<std::size_t>(i);
    };
    for (int pass = 0; pass < 2; ++pass) {
        const std::vector<double>& src = pass == 0 ? h : tmp;
        std::vector<double>& dst = pass == 0 ? tmp : h;
        for (int j = 0; j < nv; ++j) {
            for (int i = 0; i < nu; ++i) {
                double sum = 0, wsum = 0;
                for (int k = -r; k <= r; ++k) {
                    const int ii = pass == 0 ? i + k : i, jj = pass == 0 ? j : j + k;
                    if (ii < 0 || jj < 0 || ii >= nu || jj >= nv) continue;
                    const double wk = w[static_cast<std::size_t>(k + r)];
                    sum += wk * src[at(ii, jj)];
                    wsum += wk;
                }
                dst[at(i, j)] = sum / wsum;
            }
        }
    }
}

/// Lower envelope of @p h with slope @p s: h(p) <- min_q h(q) + s |p - q| (chamfer distances
/// over the 8-neighbours, forward and backward sweeps until nothing changes).
void limitSlope(std::vector<double>& h, int nu, int nv, double du, double dv, double s) {
    if (!(s > 0) || !std::isfinite(s)) return;
    const double cu = s * du, cv = s * dv, cd = s * std::hypot(du, dv);
    const auto at = [nu](int i, int j) {
        return static_cast<std::size_t>(j) * static_cast<std::size_t>(nu) +
               static_cast<std::size_t>(i);
    };
    const auto relax = [&](int i, int j, int di, int dj, double c, bool& changed) {
        const int ii = i + di, jj = j + dj;
        if (ii < 0 || jj < 0 || ii >= nu || jj >= nv) return;
        const double cand = h[at(ii, jj)] + c;
        if (cand < h[at(i, j)] - 1e-15) {
            h[at(i, j)] = cand;
            changed = true;
        }
    };
    for (bool changed = true; changed;) {
        changed = false;
        for (int j = 0; j < nv; ++j) {
            for (int i = 0; i < nu; ++i) {
                relax(i, j, -1, 0, cu, changed);
                relax(i, j, 0, -1, cv, changed);
                relax(i, j, -1, -1, cd, changed);
                relax(i, j, 1, -1, cd, changed);
            }
        }
        for (int j = nv - 1; j >= 0; --j) {
            for (int i = nu - 1; i >= 0; --i) {
                relax(i, j, 1, 0, cu, changed);
                relax(i, j, 0, 1, cv, changed);
                relax(i, j, 1, 1, cd, changed);
                relax(i, j, -1, 1, cd, changed);
            }
        }
    }
}

}  // namespace

void validateSkinFieldSpec(const SkinFieldSpec& s) {
    const auto bad = [](const std::string& field, const std::string& expected, double found) {
        std::ostringstream m;
        m << "skin field: expected " << field << " " << expected << ", found " << found;
        throw ValueError(m.str());
    };
    if (!s.centre.allFinite()) bad("a finite centre", "(m)", s.centre.norm());
    for (const auto& [name, a] : {std::pair<const char*, const Eigen::Vector3d*>{"|u|", &s.u},
                                  {"|v|", &s.v},
                                  {"|press|", &s.press}}) {
        if (!(std::abs(a->norm() - 1) < 1e-6)) bad(name, "1", a->norm());
    }
    if (!(std::abs(s.u.dot(s.v)) < 1e-6)) bad("u . v", "0", s.u.dot(s.v));
    const auto positive = [&](const char* field, double x) {
        if (!(x > 0 && std::isfinite(x))) bad(field, "> 0 (m)", x);
    };
    positive("extentU", s.extentU);
    positive("extentV", s.extentV);
    positive("cellM", s.cellM);
    positive("rayLengthM", s.rayLengthM);
    if (!(s.startOffsetM >= 0 && std::isfinite(s.startOffsetM)))
        bad("startOffsetM", ">= 0 (m)", s.startOffsetM);
    if (!(s.smoothM >= 0 && std::isfinite(s.smoothM))) bad("smoothM", ">= 0 (m)", s.smoothM);
    if (!(s.maxSlope > 0) || std::isnan(s.maxSlope)) bad("maxSlope", "> 0", s.maxSlope);
    if (std::max(s.extentU, s.extentV) / s.cellM > 4096)
        bad("at most 4096 cells a side: extent / cellM", "<= 4096",
            std::max(s.extentU, s.extentV) / s.cellM);
}

SkinField SkinField::measure(const kernels::EmbreeScene& surfaces, const SkinFieldSpec& spec) {
    validateSkinFieldSpec(spec);
    SkinField f;
    f.mSpec = spec;
    f.mNu = nodeCount(spec.extentU, spec.cellM);
    f.mNv = nodeCount(spec.extentV, spec.cellM);
    const auto n = static_cast<std::size_t>(f.mNu) * static_cast<std::size_t>(f.mNv);
    f.mRaw.assign(n, kNaN);
    std::size_t hits = 0;
    if (!surfaces.empty() && surfaces.committed()) {
        for (int j = 0; j < f.mNv; ++j) {
            for (int i = 0; i < f.mNu; ++i) {
                const Eigen::Vector3d origin = spec.centre + f.nodeA(i) * spec.u +
                                               f.nodeB(j) * spec.v - spec.startOffsetM * spec.press;
                kernels::MeshHit hit;
                if (kernels::intersectOne(surfaces, origin, spec.press, 0.0f,
                                          static_cast<float>(spec.rayLengthM),
                                          kernels::kMaskSurface, hit)) {
                    f.mRaw[static_cast<std::size_t>(j) * static_cast<std::size_t>(f.mNu) +
                           static_cast<std::size_t>(i)] = hit.t - spec.startOffsetM;
                    ++hits;
                }
            }
        }
    }
    if (hits == 0) {
        throw ValueError("skin field: expected the skin under the plane through " +
                         vec(spec.centre * 1e3) + " mm along the press axis " + vec(spec.press) +
                         " within " + std::to_string(spec.rayLengthM * 1e3) +
                         " mm, found no surface");
    }
    f.mHeight = f.mRaw;
    fillMissing(f.mHeight, f.mNu, f.mNv);
    const double du = spec.extentU / (f.mNu - 1), dv = spec.extentV / (f.mNv - 1);
    smooth(f.mHeight, f.mNu, f.mNv, spec.smoothM / std::min(du, dv));
    limitSlope(f.mHeight, f.mNu, f.mNv, du, dv, spec.maxSlope);
    return f;
}

double SkinField::nodeA(int i) const noexcept {
    return mNu > 1 ? -0.5 * mSpec.extentU + mSpec.extentU * i / (mNu - 1) : 0.0;
}

double SkinField::nodeB(int j) const noexcept {
    return mNv > 1 ? -0.5 * mSpec.extentV + mSpec.extentV * j / (mNv - 1) : 0.0;
}

double SkinField::height(int i, int j) const noexcept {
    if (i < 0 || j < 0 || i >= mNu || j >= mNv) return kNaN;
    return mHeight[static_cast<std::size_t>(j) * static_cast<std::size_t>(mNu) +
                   static_cast<std::size_t>(i)];
}

double SkinField::rawHeight(int i, int j) const noexcept {
    if (i < 0 || j < 0 || i >= mNu || j >= mNv) return kNaN;
    return mRaw[static_cast<std::size_t>(j) * static_cast<std::size_t>(mNu) +
                static_cast<std::size_t>(i)];
}

double SkinField::hitFraction() const noexcept {
    if (mRaw.empty()) return 0;
    const auto hits =
        std::count_if(mRaw.begin(), mRaw.end(), [](double x) { return std::isfinite(x); });
    return static_cast<double>(hits) / static_cast<double>(mRaw.size());
}

Eigen::Vector3d SkinField::skinPoint(int i, int j) const noexcept {
    const double h = rawHeight(i, j);
    if (!std::isfinite(h)) return Eigen::Vector3d::Constant(kNaN);
    return mSpec.centre + nodeA(i) * mSpec.u + nodeB(j) * mSpec.v + h * mSpec.press;
}

void SkinField::sample(double a, double b, double& h, double& dhda, double& dhdb) const noexcept {
    h = dhda = dhdb = 0;
    if (mNu < 2 || mNv < 2 || !std::isfinite(a) || !std::isfinite(b)) return;
    const double du = mSpec.extentU / (mNu - 1), dv = mSpec.extentV / (mNv - 1);
    // Outside the rectangle the height is the edge's (clamped), with no gradient across it.
    const double x = std::clamp((a + 0.5 * mSpec.extentU) / du, 0.0, static_cast<double>(mNu - 1));
    const double y = std::clamp((b + 0.5 * mSpec.extentV) / dv, 0.0, static_cast<double>(mNv - 1));
    const int i = std::min(static_cast<int>(x), mNu - 2);
    const int j = std::min(static_cast<int>(y), mNv - 2);
    const double fx = x - i, fy = y - j;
    const auto k =
        static_cast<std::size_t>(j) * static_cast<std::size_t>(mNu) + static_cast<std::size_t>(i);
    const auto nu = static_cast<std::size_t>(mNu);
    const double h00 = mHeight[k], h10 = mHeight[k + 1], h01 = mHeight[k + nu],
                 h11 = mHeight[k + nu + 1];
    h = (1 - fy) * ((1 - fx) * h00 + fx * h10) + fy * ((1 - fx) * h01 + fx * h11);
    const bool insideU = a > -0.5 * mSpec.extentU && a < 0.5 * mSpec.extentU;
    const bool insideV = b > -0.5 * mSpec.extentV && b < 0.5 * mSpec.extentV;
    if (insideU) dhda = ((1 - fy) * (h10 - h00) + fy * (h11 - h01)) / du;
    if (insideV) dhdb = ((1 - fx) * (h01 - h00) + fx * (h11 - h10)) / dv;
}

void SkinField::apply(Eigen::Vector3d& position, Eigen::Vector3d& velocity) const noexcept {
    if (mHeight.empty()) return;
    const Eigen::Vector3d r = position - mSpec.centre;
    double h = 0, ga = 0, gb = 0;
    sample(r.dot(mSpec.u), r.dot(mSpec.v), h, ga, gb);
    const double rate = ga * velocity.dot(mSpec.u) + gb * velocity.dot(mSpec.v);
    position += h * mSpec.press;
    velocity += rate * mSpec.press;
}

}  // namespace palp::haptics
