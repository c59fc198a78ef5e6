#include "palp/haptics/devices/skin_patch.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/haptics/devices/skin_field.h"

namespace palp::haptics {

namespace {

/// Largest rectangle of true cells in the nu x nv mask (row-major in v): node ranges
/// [i0, i1] x [j0, j1] maximising (i1 - i0) du * (j1 - j0) dv, by the histogram method.
void largestRectangle(const std::vector<char>& mask, int nu, int nv, double du, double dv, int& i0,
                      int& i1, int& j0, int& j1) {
    std::vector<int> height(static_cast<std::size_t>(nu), 0);
    std::vector<int> stack;
    double best = -1;
    i0 = i1 = j0 = j1 = -1;
    for (int j = 0; j < nv; ++j) {
        for (int i = 0; i < nu; ++i) {
            const bool on = mask[static_cast<std::size_t>(j) * static_cast<std::size_t>(nu) +
                                 static_cast<std::size_t>(i)] != 0;
            height[static_cast<std::size_t>(i)] = on ? height[static_cast<std::size_t>(i)] + 1 : 0;
        }
        stack.clear();
        for (int i = 0; i <= nu; ++i) {
            const int h = i < nu ? height[static_cast<std::size_t>(i)] : 0;
            while (!stack.empty() && height[static_cast<std::size_t>(stack.back())] >= h) {
                const int top = stack.back();
                stack.pop_back();
                const int ht = height[static_cast<std::size_t>(top)];
                const int left = stack.empty() ? 0 : stack.back() + 1;
                const int right = i - 1;
                // Nodes left..right by ht rows: a rectangle (right - left) du x (ht - 1) dv.
                const double area = (right - left) * du * (ht - 1) * dv;
                if (ht > 0 && area > best) {
                    best = area;
                    i0 = left;
                    i1 = right;
                    j0 = j - ht + 1;
                    j1 = j;
                }
            }
            stack.push_back(i);
        }
    }
}

}  // namespace

SkinPatch findSkinPatch(const kernels::EmbreeScene& surfaces, const Eigen::AlignedBox3d& box,
                        const Eigen::Vector3d& press, const SkinPatchOptions& options) {
    if (box.isEmpty() || !box.min().allFinite() || !box.max().allFinite())
        throw ValueError("skin patch: expected a non-empty finite box, found an empty one");
    int pa = 0;
    press.cwiseAbs().maxCoeff(&pa);
    if (!(std::abs(std::abs(press[pa]) - 1) < 1e-9 && std::abs(press.norm() - 1) < 1e-9))
        throw ValueError("skin patch: expected a press axis +-x, +-y or +-z, found (" +
                         std::to_string(press.x()) + ", " + std::to_string(press.y()) + ", " +
                         std::to_string(press.z()) + ")");
    if (!(options.cellM > 0) || !(options.maxSlope > 0) || !(options.marginM >= 0) ||
        !(options.smoothM >= 0))
        throw ValueError(
            "skin patch: expected positive cellM and maxSlope, non-negative "
            "marginM and smoothM, found cellM " +
            std::to_string(options.cellM) + ", maxSlope " + std::to_string(options.maxSlope));
    const int ua = std::min((pa + 1) % 3, (pa + 2) % 3), va = 3 - pa - ua;
    SkinPatch patch;
    patch.press = Eigen::Vector3d::Unit(pa) * (press[pa] > 0 ? 1.0 : -1.0);
    patch.u = Eigen::Vector3d::Unit(ua);
    patch.v = Eigen::Vector3d::Unit(va);
    Eigen::Vector3d centre = box.center();
    centre[pa] = press[pa] > 0 ? box.min()[pa] : box.max()[pa];
    patch.centre = centre;

    SkinFieldSpec spec;
    spec.centre = centre;
    spec.u = patch.u;
    spec.v = patch.v;
    spec.press = patch.press;
    spec.extentU = box.sizes()[ua];
    spec.extentV = box.sizes()[va];
    spec.cellM = std::max(options.cellM, std::max(spec.extentU, spec.extentV) / 4000);
    spec.startOffsetM = 5e-3;
    spec.rayLengthM = box.sizes()[pa] + 10e-3;
    spec.smoothM = options.smoothM;
    spec.maxSlope = std::numeric_limits<double>::infinity();
    SkinField field;
    try {
        field = SkinField::measure(surfaces, spec);
    } catch (const ValueError&) {
        return patch;  // no skin on this side
    }
    const int nu = field.nodesU(), nv = field.nodesV();
    const double du = spec.extentU / (nu - 1), dv = spec.extentV / (nv - 1);
    std::vector<char> mask(static_cast<std::size_t>(nu) * static_cast<std::size_t>(nv), 0);
    std::size_t facing = 0;
    for (int j = 1; j + 1 < nv; ++j) {
        for (int i = 1; i + 1 < nu; ++i) {
            bool all = true;
            for (int dj = -1; dj <= 1 && all; ++dj)
                for (int di = -1; di <= 1 && all; ++di)
                    all = std::isfinite(field.rawHeight(i + di, j + dj));
            if (!all) continue;
            const double ga = (field.height(i + 1, j) - field.height(i - 1, j)) / (2 * du);
            const double gb = (field.height(i, j + 1) - field.height(i, j - 1)) / (2 * dv);
            if (std::hypot(ga, gb) > options.maxSlope) continue;
            mask[static_cast<std::size_t>(j) * static_cast<std::size_t>(nu) +
                 static_cast<std::size_t>(i)] = 1;
            ++facing;
        }
    }
    patch.facingFraction = static_cast<double>(facing) / static_cast<double>(mask.size());
    int i0 = 0, i1 = 0, j0 = 0, j1 = 0;
    largestRectangle(mask, nu, nv, du, dv, i0, i1, j0, j1);
    if (i0 < 0) return patch;
    const double eu = (i1 - i0) * du - 2 * options.marginM;
    const double ev = (j1 - j0) * dv - 2 * options.marginM;
    if (!(eu > 0 && ev > 0)) return patch;
    patch.extentU = eu;
    patch.extentV = ev;
    patch.centre = centre + 0.5 * (field.nodeA(i0) + field.nodeA(i1)) * patch.u +
                   0.5 * (field.nodeB(j0) + field.nodeB(j1)) * patch.v;
    return patch;
}

Eigen::Vector3d axisVector(SignedAxis axis) noexcept {
    const int i = static_cast<int>(axis) / 2;
    return Eigen::Vector3d::Unit(i) * (static_cast<int>(axis) % 2 == 0 ? 1.0 : -1.0);
}

SkinPatch findBestSkinPatch(const kernels::EmbreeScene& surfaces, const Eigen::AlignedBox3d& box,
                            const SkinPatchOptions& options, std::span<const SignedAxis> axes) {
    SkinPatch best;
    double bestArea = -1;
    for (const SignedAxis a : axes) {
        const SkinPatch p = findSkinPatch(surfaces, box, axisVector(a), options);
        const double area = p.extentU * p.extentV;
        if (area > bestArea) {
            bestArea = area;
            best = p;
        }
    }
    return best;
}

}  // namespace palp::haptics
