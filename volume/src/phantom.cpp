#include "palp/volume/phantom.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <numbers>
#include <utility>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"

namespace palp::volume {

namespace {

namespace pg = phantom_geometry;

constexpr double kPi = std::numbers::pi;

bool inRange(double v, double lo, double hi) { return lo <= v && v < hi; }

std::string mm(double metres) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%gmm", metres * 1e3);
    return buf;
}

// Counter-based noise: a standard normal variate that depends only on (seed, counter), so the
// result is independent of thread scheduling.
std::uint64_t splitMix64(std::uint64_t x) {
    x += 0x9E3779B97F4A7C15ULL;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
}

double gaussianNoise(std::uint64_t seed, std::uint64_t counter) {
    const std::uint64_t h1 = splitMix64(splitMix64(seed) ^ splitMix64(counter * 2 + 1));
    const std::uint64_t h2 = splitMix64(h1 ^ 0xD1B54A32D192ED03ULL);
    constexpr double kScale = 1.0 / 9007199254740992.0;  // 2^-53
    const double u1 = (static_cast<double>(h1 >> 11) + 0.5) * kScale;
    const double u2 = static_cast<double>(h2 >> 11) * kScale;
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

std::vector<double> gaussianKernel(double sigmaSteps) {
    const int radius = std::max(1, static_cast<int>(std::ceil(3.0 * sigmaSteps)));
    std::vector<double> k(static_cast<std::size_t>(2 * radius + 1));
    double sum = 0;
    for (int i = -radius; i <= radius; ++i) {
        const double w = std::exp(-0.5 * (i * i) / (sigmaSteps * sigmaSteps));
        k[static_cast<std::size_t>(i + radius)] = w;
        sum += w;
    }
    for (double& w : k) w /= sum;
    return k;
}

// One pass of a separable convolution with edge clamping: n lines of length len, element
// (line, i) at data[line * lineStride + i * step].
void convolveLines(std::vector<double>& data, std::vector<double>& scratch,
                   const std::vector<double>& kernel, int lines, int len, std::size_t lineStride,
                   std::size_t step) {
    const int radius = static_cast<int>(kernel.size() / 2);
    scratch.resize(static_cast<std::size_t>(len));
    for (int l = 0; l < lines; ++l) {
        const std::size_t base = static_cast<std::size_t>(l) * lineStride;
        for (int i = 0; i < len; ++i) {
            double acc = 0;
            for (int j = -radius; j <= radius; ++j) {
                const int s = std::clamp(i + j, 0, len - 1);
                acc += kernel[static_cast<std::size_t>(j + radius)] *
                       data[base + static_cast<std::size_t>(s) * step];
            }
            scratch[static_cast<std::size_t>(i)] = acc;
        }
        for (int i = 0; i < len; ++i) {
            data[base + static_cast<std::size_t>(i) * step] = scratch[static_cast<std::size_t>(i)];
        }
    }
}

std::string mmPoint(const Eigen::Vector3d& p) {
    std::string s("(");
    s += formatValue(p.x() * 1e3);
    s += ", ";
    s += formatValue(p.y() * 1e3);
    s += ", ";
    s += formatValue(p.z() * 1e3);
    s += ") mm";
    return s;
}

/// The tumour's inclusion: a finite sphere of [0.5, 20] mm radius inside the block, below the
/// fat layer (checked for every scene, so parameters stay valid when the scene changes).
void checkInclusion(const PhantomParams& params) {
    const Eigen::Vector3d& c = params.inclusionCentre;
    const char* const axes[] = {"x", "y", "z"};
    for (int a = 0; a < 3; ++a) {
        palp::requireWithin(std::string("phantom inclusion centre ") + axes[a], c[a],
                            bounds::kPosition, DisplayUnit{1e3, "mm"});
    }
    const double r = params.inclusionRadius;
    if (!(r >= pg::kTumourMinRadius && r <= pg::kTumourMaxRadius)) {
        throwExpected(
            "phantom inclusion radius",
            "a value in [" + mm(pg::kTumourMinRadius) + ", " + mm(pg::kTumourMaxRadius) + "]",
            mm(r));
    }
    const double hw = pg::kBlockHalfWidth;
    if (!(std::abs(c.x()) + r <= hw && std::abs(c.z()) + r <= hw &&
          c.y() - r >= params.fatThickness && c.y() + r <= pg::kBlockDepth)) {
        throwExpected("phantom inclusion",
                      "a sphere inside the block below the fat layer (x, z in +-" + mm(hw) +
                          ", y in [" + mm(params.fatThickness) + ", " + mm(pg::kBlockDepth) + "])",
                      "centre " + mmPoint(c) + " radius " + mm(r));
    }
}

}  // namespace

TriangleMesh icosphere(const PhantomSphere& sphere, int subdivisions) {
    for (int a = 0; a < 3; ++a) {
        palp::requireFinite("icosphere centre", sphere.centre[a], "m");
    }
    palp::requireWithin("icosphere radius", sphere.radius, bounds::kLength);
    if (subdivisions < 0 || subdivisions > 6) {
        throwExpected("icosphere subdivisions", "0 to 6", std::to_string(subdivisions));
    }
    // The icosahedron: vertices (0, +-1, +-g) cycled, g the golden ratio; faces counter-
    // clockwise seen from outside.
    const double g = std::numbers::phi;
    std::vector<Eigen::Vector3d> v = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0},
                                      {0, -1, g}, {0, 1, g}, {0, -1, -g}, {0, 1, -g},
                                      {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
    for (Eigen::Vector3d& p : v) p.normalize();
    std::vector<std::array<std::uint32_t, 3>> tris = {
        {0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
        {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
        {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
    for (int s = 0; s < subdivisions; ++s) {
        std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> midpoints;
        const auto midpoint = [&](std::uint32_t a, std::uint32_t b) {
            const auto key = std::minmax(a, b);
            const auto [it, added] =
                midpoints.try_emplace(key, static_cast<std::uint32_t>(v.size()));
            if (added) v.push_back((v[a] + v[b]).normalized());
            return it->second;
        };
        std::vector<std::array<std::uint32_t, 3>> next;
        next.reserve(4 * tris.size());
        for (const auto& [a, b, c] : tris) {
            const std::uint32_t ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
            next.push_back({a, ab, ca});
            next.push_back({b, bc, ab});
            next.push_back({c, ca, bc});
            next.push_back({ab, bc, ca});
        }
        tris = std::move(next);
    }
    TriangleMesh mesh;
    mesh.positions.reserve(3 * v.size());
    for (const Eigen::Vector3d& p : v) {
        const Eigen::Vector3d x = sphere.centre + sphere.radius * p;
        for (int a = 0; a < 3; ++a) mesh.positions.push_back(static_cast<float>(x[a]));
    }
    mesh.indices.reserve(3 * tris.size());
    for (const auto& t : tris) mesh.indices.insert(mesh.indices.end(), t.begin(), t.end());
    return mesh;
}

double transitionProfile(TransitionProfile profile, double x, double width, double tanhSharpness) {
    if (x <= 0) return 0;
    if (x >= width) return 1;
    const double t = x / width;
    switch (profile) {
        case TransitionProfile::Linear:
            return t;
        case TransitionProfile::Cosine:
            return 0.5 * (1.0 - std::cos(kPi * t));
        case TransitionProfile::Tanh:
            return 0.5 *
                   (std::tanh(tanhSharpness * (2.0 * t - 1.0)) / std::tanh(tanhSharpness) + 1.0);
    }
    return t;
}

const char* sceneName(PhantomScene scene) {
    switch (scene) {
        case PhantomScene::Avc:
            return "avc";
        case PhantomScene::Avcec:
            return "avcec";
        case PhantomScene::Bone:
            return "bone";
        case PhantomScene::Stiffness:
            return "stiffness";
        case PhantomScene::Tumour:
            return "tumour";
    }
    return "unknown";
}

const char* shapeName(PlateShape shape) {
    switch (shape) {
        case PlateShape::Circle:
            return "circle";
        case PlateShape::Triangle:
            return "triangle";
        case PlateShape::Rectangle:
            return "rectangle";
        case PlateShape::Hexagon:
            return "hexagon";
        case PlateShape::Pentagon:
            return "pentagon";
    }
    return "unknown";
}

const char* profileName(TransitionProfile profile) {
    switch (profile) {
        case TransitionProfile::Linear:
            return "linear";
        case TransitionProfile::Cosine:
            return "cosine";
        case TransitionProfile::Tanh:
            return "tanh";
    }
    return "unknown";
}

PhantomScene parseScene(std::string_view name) {
    for (PhantomScene s : {PhantomScene::Avc, PhantomScene::Avcec, PhantomScene::Bone,
                           PhantomScene::Stiffness, PhantomScene::Tumour}) {
        if (name == sceneName(s)) return s;
    }
    throw ValueError("phantom scene: expected avc, avcec, bone, stiffness or tumour, found '" +
                     std::string(name) + "'");
}

PlateShape parseShape(std::string_view name) {
    for (PlateShape s : {PlateShape::Circle, PlateShape::Triangle, PlateShape::Rectangle,
                         PlateShape::Hexagon, PlateShape::Pentagon}) {
        if (name == shapeName(s)) return s;
    }
    throw ValueError(
        "phantom shape: expected circle, triangle, rectangle, hexagon or pentagon, found '" +
        std::string(name) + "'");
}

TransitionProfile parseProfile(std::string_view name) {
    for (TransitionProfile p :
         {TransitionProfile::Linear, TransitionProfile::Cosine, TransitionProfile::Tanh}) {
        if (name == profileName(p)) return p;
    }
    throw ValueError("phantom profile: expected linear, cosine or tanh, found '" +
                     std::string(name) + "'");
}

Phantom::Phantom(const PhantomParams& params) : mParams(params) {
    if (params.quadrant < 0 || params.quadrant > 3) {
        throw ValueError("phantom quadrant: expected 0, 1, 2 or 3, found " +
                         std::to_string(params.quadrant));
    }
    if (params.displacement < -1 || params.displacement > 1) {
        throw ValueError("phantom displacement: expected -1, 0 or 1, found " +
                         std::to_string(params.displacement));
    }
    if (!(std::abs(params.boneTiltDeg) < 30)) {
        throw ValueError("phantom bone tilt: expected less than 30 degrees, found " +
                         formatValue(params.boneTiltDeg));
    }
    palp::requirePositive("phantom transition width", params.transitionWidth, "m");
    palp::requirePositive("phantom tanh sharpness", params.tanhSharpness);
    palp::requireNonNegative("phantom hard depth", params.hardDepth, "m");
    palp::requireNonNegative("phantom fat thickness", params.fatThickness, "m");
    if (params.fatThickness > 0.005) {
        throw ValueError("phantom fat thickness: expected at most 5 mm, found " +
                         mm(params.fatThickness));
    }
    if (params.transitionWidth > pg::kStiffBoxWidth) {
        throw ValueError("phantom transition width: expected at most 40 mm, found " +
                         mm(params.transitionWidth));
    }
    const PhantomMaterials& m = params.materials;
    const std::pair<const char*, double> materials[] = {
        {"air", m.airHu},   {"fat", m.fatHu},     {"soft", m.softHu},
        {"hard", m.hardHu}, {"rigid", m.rigidHu}, {"inclusion", m.inclusionHu}};
    for (const auto& [material, hu] : materials) {
        palp::requireWithin(std::string("phantom materials: ") + material + " HU", hu,
                            bounds::kVolumeValue);
    }
    checkInclusion(params);

    int sides = 0;
    switch (params.shape) {
        case PlateShape::Triangle:
            sides = 3;
            break;
        case PlateShape::Pentagon:
            sides = 5;
            break;
        case PlateShape::Hexagon:
            sides = 6;
            break;
        default:
            break;
    }
    if (sides > 0) {
        // Regular polygon with a vertex towards +z; edge normals halfway between vertices.
        mApothem = pg::kAvcecPlateRadius * std::cos(kPi / sides);
        for (int k = 0; k < sides; ++k) {
            const double a = 0.5 * kPi + 2.0 * kPi * k / sides + kPi / sides;
            mEdgeNormals.emplace_back(std::cos(a), std::sin(a));
        }
    }
    mBoneSlope = -params.displacement * std::tan(params.boneTiltDeg * kPi / 180.0);
}

WorldBox Phantom::avcPlate() {
    WorldBox b;
    b.min = Eigen::Vector3d(-pg::kAvcPlateHalfWidth, pg::kAvcPlateTop, -pg::kAvcPlateHalfWidth);
    b.max = Eigen::Vector3d(pg::kAvcPlateHalfWidth, pg::kAvcPlateBottom, pg::kAvcPlateHalfWidth);
    return b;
}

WorldBox Phantom::avcHiddenBox(int quadrant) {
    const double cx = (quadrant & 1) ? pg::kAvcBoxOffset : -pg::kAvcBoxOffset;
    const double cz = (quadrant & 2) ? pg::kAvcBoxOffset : -pg::kAvcBoxOffset;
    WorldBox b;
    b.min = Eigen::Vector3d(cx - pg::kAvcBoxHalfWidth, pg::kAvcBoxTop, cz - pg::kAvcBoxHalfWidth);
    b.max =
        Eigen::Vector3d(cx + pg::kAvcBoxHalfWidth, pg::kAvcBoxBottom, cz + pg::kAvcBoxHalfWidth);
    return b;
}

double Phantom::stiffnessBoxCentreX(int index) { return (index - 1) * pg::kStiffBoxPitch; }

PhantomSphere Phantom::inclusion() const {
    if (mParams.scene != PhantomScene::Tumour) {
        throw ValueError(std::string("phantom inclusion: expected the tumour scene, found ") +
                         sceneName(mParams.scene) + " (it has no inclusion)");
    }
    return {mParams.inclusionCentre, mParams.inclusionRadius};
}

TriangleMesh Phantom::inclusionMesh(int subdivisions) const {
    return icosphere(inclusion(), subdivisions);
}

double Phantom::boneTopDepth(double x) const { return pg::kBoneCentreDepth + mBoneSlope * x; }

WorldBox Phantom::bounds() const {
    WorldBox b;
    if (mParams.scene == PhantomScene::Stiffness) {
        const double hw = 0.5 * pg::kStiffBoxWidth;
        b.min = Eigen::Vector3d(stiffnessBoxCentreX(0) - hw, 0, -hw);
        b.max = Eigen::Vector3d(stiffnessBoxCentreX(2) + hw, pg::kStiffBoxWidth, hw);
    } else {
        b.min = Eigen::Vector3d(-pg::kBlockHalfWidth, 0, -pg::kBlockHalfWidth);
        b.max = Eigen::Vector3d(pg::kBlockHalfWidth, pg::kBlockDepth, pg::kBlockHalfWidth);
    }
    return b;
}

std::string Phantom::description() const {
    std::string d = sceneName(mParams.scene);
    switch (mParams.scene) {
        case PhantomScene::Avc:
            d += " quadrant=" + std::to_string(mParams.quadrant);
            break;
        case PhantomScene::Avcec:
            d += std::string(" shape=") + shapeName(mParams.shape);
            break;
        case PhantomScene::Bone:
            d += " displacement=" + std::to_string(mParams.displacement) +
                 " tilt=" + formatValue(mParams.boneTiltDeg) + "deg";
            break;
        case PhantomScene::Stiffness:
            d += std::string(" profile=") + profileName(mParams.profile) +
                 " width=" + mm(mParams.transitionWidth) + " hard-depth=" + mm(mParams.hardDepth);
            if (mParams.profile == TransitionProfile::Tanh)
                d += " tanh-a=" + formatValue(mParams.tanhSharpness);
            break;
        case PhantomScene::Tumour: {
            const Eigen::Vector3d& c = mParams.inclusionCentre;
            d += " centre=(" + formatValue(c.x() * 1e3) + "," + formatValue(c.y() * 1e3) + "," +
                 formatValue(c.z() * 1e3) + ")mm radius=" + mm(mParams.inclusionRadius);
            break;
        }
    }
    d += " fat=" + mm(mParams.fatThickness);
    return d;
}

bool Phantom::insidePlateOutline(double x, double z) const {
    switch (mParams.shape) {
        case PlateShape::Circle:
            return x * x + z * z < pg::kAvcecPlateRadius * pg::kAvcecPlateRadius;
        case PlateShape::Rectangle:
            return std::abs(x) < pg::kAvcecRectHalfX && std::abs(z) < pg::kAvcecRectHalfZ;
        default:
            break;
    }
    for (const Eigen::Vector2d& n : mEdgeNormals) {
        if (n.x() * x + n.y() * z >= mApothem) return false;
    }
    return true;
}

double Phantom::tissueValue(double depth) const {
    return depth < mParams.fatThickness ? mParams.materials.fatHu : mParams.materials.softHu;
}

double Phantom::valueAt(const Eigen::Vector3d& p) const {
    const PhantomMaterials& m = mParams.materials;
    const double x = p.x(), y = p.y(), z = p.z();
    if (mParams.scene == PhantomScene::Stiffness) {
        const double hw = 0.5 * pg::kStiffBoxWidth;
        if (!inRange(y, 0, pg::kStiffBoxWidth) || !inRange(z, -hw, hw)) return m.airHu;
        for (int box = 0; box < 3; ++box) {
            const double cx = stiffnessBoxCentreX(box);
            if (!inRange(x, cx - hw, cx + hw)) continue;
            if (y < mParams.fatThickness) return m.fatHu;
            double f = 0;
            if (box == 0) {
                f = 1;
            } else if (box == 1) {
                f = y >= mParams.hardDepth ? 1 : 0;
            } else {
                f = transitionProfile(mParams.profile, x - (cx - 0.5 * mParams.transitionWidth),
                                      mParams.transitionWidth, mParams.tanhSharpness);
            }
            return m.softHu + (m.hardHu - m.softHu) * f;
        }
        return m.airHu;
    }
    if (!inRange(x, -pg::kBlockHalfWidth, pg::kBlockHalfWidth) ||
        !inRange(z, -pg::kBlockHalfWidth, pg::kBlockHalfWidth) || !inRange(y, 0, pg::kBlockDepth)) {
        return m.airHu;
    }
    switch (mParams.scene) {
        case PhantomScene::Avc: {
            const WorldBox plate = avcPlate();
            const WorldBox box = avcHiddenBox(mParams.quadrant);
            for (const WorldBox* b : {&plate, &box}) {
                if (inRange(x, b->min.x(), b->max.x()) && inRange(y, b->min.y(), b->max.y()) &&
                    inRange(z, b->min.z(), b->max.z())) {
                    return m.rigidHu;
                }
            }
            break;
        }
        case PhantomScene::Avcec:
            if (inRange(y, pg::kAvcecPlateTop, pg::kAvcecPlateBottom) && insidePlateOutline(x, z))
                return m.rigidHu;
            break;
        case PhantomScene::Bone: {
            const double top = boneTopDepth(x);
            if (inRange(x, -pg::kBoneHalfWidth, pg::kBoneHalfWidth) &&
                inRange(z, -pg::kBoneHalfWidth, pg::kBoneHalfWidth) &&
                inRange(y, top, top + pg::kBoneThickness)) {
                return m.rigidHu;
            }
            break;
        }
        case PhantomScene::Tumour: {
            const double r = mParams.inclusionRadius;
            if ((p - mParams.inclusionCentre).squaredNorm() < r * r) return m.inclusionHu;
            break;
        }
        case PhantomScene::Stiffness:
            break;
    }
    return tissueValue(y);
}

namespace {

/// Index range [lo, hi] of cells of size @p step whose centres (k + 1/2) step cover [a, b].
std::pair<std::int64_t, std::int64_t> cellRange(double a, double b, double step) {
    const auto lo = static_cast<std::int64_t>(std::floor(a / step));
    const auto hi = std::max(lo, static_cast<std::int64_t>(std::ceil(b / step)) - 1);
    return {lo, hi};
}

/// Checks what makePhantomSlices needs beyond the phantom's own parameters.
/// @throw ValueError naming the offending field.
void checkSliceSpec(const PhantomSpec& spec, const SliceGeometry& geometry) {
    // Noise and materials within palp's volume-value bounds keep every sample a finite float
    // (a 1e300 HU noise would overflow); spacings within bounds::kSpacing.
    palp::requireWithin("phantom noise sigma", spec.noiseSigmaHu, bounds::kVolumeSpread);
    palp::requireWithin("phantom blur sigma", spec.blurSigma, bounds::kSpan, {1e3, "mm"});
    palp::requireWithin("phantom margin", spec.margin, bounds::kSpan, {1e3, "mm"});
    if (spec.supersample < 1 || spec.supersample > 8) {
        throw ValueError("phantom supersample: expected 1 to 8, found " +
                         std::to_string(spec.supersample));
    }
    palp::requireWithin("phantom pixel spacing", geometry.pixelSpacing, bounds::kSpacing,
                        {1e3, "mm"});
    palp::requireWithin("phantom slice spacing", geometry.sliceSpacing, bounds::kSpacing,
                        {1e3, "mm"});
    for (double g : geometry.sliceGaps) {
        palp::requireWithin("phantom slice gap", g, bounds::kSpacing, {1e3, "mm"});
    }
    palp::requireWithin("phantom slice thickness", geometry.sliceThickness, bounds::kSpan,
                        {1e3, "mm"});
    // The in-plane blur kernel spans 6 sigma in pixels: bounded so the work per pixel is.
    if (spec.blurSigma > 100 * geometry.pixelSpacing) {
        throwExpected("phantom blur sigma",
                      "at most 100 pixel spacings (" + mm(100 * geometry.pixelSpacing) + ")",
                      mm(spec.blurSigma));
    }
    if (!(std::abs(geometry.tiltDeg) < 60)) {
        throw ValueError("phantom gantry tilt: expected less than 60 degrees, found " +
                         formatValue(geometry.tiltDeg));
    }
    // Guards the integer conversions below against absurd spacings.
    const double smallest =
        std::min({geometry.pixelSpacing, geometry.sliceSpacing,
                  geometry.sliceGaps.empty()
                      ? geometry.sliceSpacing
                      : *std::min_element(geometry.sliceGaps.begin(), geometry.sliceGaps.end())});
    if (smallest < 1e-6 || geometry.pixelSpacing > 0.1 || spec.margin > 0.1) {
        throw ValueError(
            "phantom: expected spacings from 0.001 mm to 100 mm and a margin up to 100 mm, found "
            "pixel " +
            mm(geometry.pixelSpacing) + ", smallest gap " + mm(smallest) + ", margin " +
            mm(spec.margin));
    }
}

/// Centres along z of slices @p gaps apart (cycled; divided by cos tilt @p ct) covering
/// [@p zLo, @p zHi).
std::vector<double> sliceCentres(double zLo, double zHi, const std::vector<double>& gaps,
                                 double ct) {
    std::vector<double> zs;
    const double dz0 = gaps[0] / ct;
    double z = (std::floor(zLo / dz0) + 0.5) * dz0;
    zs.push_back(z);
    for (std::size_t k = 0;; ++k) {
        const double dz = gaps[k % gaps.size()] / ct;
        if (z + 0.5 * dz >= zHi) break;
        z += dz;
        zs.push_back(z);
    }
    return zs;
}

}  // namespace

SliceStack makePhantomSlices(const PhantomSpec& spec, const SliceGeometry& geometry) {
    const Phantom phantom(spec.params);
    checkSliceSpec(spec, geometry);
    const std::vector<double> gaps = geometry.sliceGaps.empty()
                                         ? std::vector<double>{geometry.sliceSpacing}
                                         : geometry.sliceGaps;
    const double minGap = *std::min_element(gaps.begin(), gaps.end());

    const double t = geometry.tiltDeg * kPi / 180.0;
    const double ct = std::cos(t), st = std::sin(t);
    const double p = geometry.pixelSpacing;
    const Eigen::Vector3d colDir(1, 0, 0);
    const Eigen::Vector3d rowDir(0, ct, -st);
    const Eigen::Vector3d normal = colDir.cross(rowDir);  // (0, sin t, cos t)

    WorldBox dom = phantom.bounds();
    dom.min.array() -= spec.margin;
    dom.max.array() += spec.margin;
    const auto [cx0, cx1] = cellRange(dom.min.x(), dom.max.x(), p);
    const auto [ry0, ry1] = cellRange(dom.min.y(), dom.max.y(), p * ct);
    const std::int64_t cols = cx1 - cx0 + 1;
    const std::int64_t rows = ry1 - ry0 + 1;
    const double x0 = (static_cast<double>(cx0) + 0.5) * p;
    const double y0 = (static_cast<double>(ry0) + 0.5) * p * ct;

    // Slice k's pixel (0, 0) is at (x0, y0, z_k); a world point (y, z) lies on the slice with
    // z_k = z + (y - y0) tan t, so the z_k must cover this range.
    const double yExtent = static_cast<double>(rows - 1) * p * ct;
    const double shift = yExtent * std::tan(t);
    const double zLo = dom.min.z() + std::min(0.0, shift);
    const double zHi = dom.max.z() + std::max(0.0, shift);
    const std::uint64_t maxSlices =
        static_cast<std::uint64_t>(std::ceil((zHi - zLo) / (minGap / ct))) + 2;
    constexpr std::uint64_t kMaxPixels = std::uint64_t{1} << 28;
    if (static_cast<std::uint64_t>(cols * rows) * maxSlices > kMaxPixels) {
        throw ValueError("phantom: expected at most 2^28 pixels, found " + std::to_string(cols) +
                         "x" + std::to_string(rows) + "x" + std::to_string(maxSlices) +
                         "; choose a larger pixel or slice spacing");
    }
    const std::vector<double> zs = sliceCentres(zLo, zHi, gaps, ct);

    SliceStack stack;
    stack.slices.resize(zs.size());
    const int n = spec.supersample;
    const double thickness = geometry.sliceThickness > 0 ? geometry.sliceThickness : minGap;
    // Partial volume: sub-sample offsets (in-plane in pixels, along the normal in metres), then
    // Gaussian blur along the normal by planes every sigma/2 and in-plane on the pixel lattice.
    std::vector<double> subOffsets(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) subOffsets[static_cast<std::size_t>(i)] = (i + 0.5) / n - 0.5;
    std::vector<std::pair<double, double>> planes;  // (offset along normal in m, weight)
    if (spec.blurSigma > 0) {
        const std::vector<double> k = gaussianKernel(2.0);  // step sigma/2, radius 3 sigma
        const int radius = static_cast<int>(k.size() / 2);
        for (int j = -radius; j <= radius; ++j) {
            planes.emplace_back(j * 0.5 * spec.blurSigma, k[static_cast<std::size_t>(j + radius)]);
        }
    } else {
        planes.emplace_back(0.0, 1.0);
    }
    const std::vector<double> inPlaneKernel =
        spec.blurSigma > 0 ? gaussianKernel(spec.blurSigma / p) : std::vector<double>{};
    const auto ncols = static_cast<int>(cols);
    const auto nrows = static_cast<int>(rows);
    const Eigen::Vector3d colStep = p * colDir;
    const Eigen::Vector3d rowStep = p * rowDir;
    const double subWeight = 1.0 / (n * n * n);

    palp::parallelFor(
        tbb::blocked_range<std::size_t>(0, zs.size()),
        [&](const tbb::blocked_range<std::size_t>& range) {
            std::vector<double> img;
            std::vector<double> scratch;
            for (std::size_t k = range.begin(); k != range.end(); ++k) {
                Slice& s = stack.slices[k];
                s.position = Eigen::Vector3d(x0, y0, zs[k]);
                s.colStep = colStep;
                s.rowStep = rowStep;
                s.cols = ncols;
                s.rows = nrows;
                s.source = "phantom slice " + std::to_string(k);
                img.assign(static_cast<std::size_t>(ncols) * static_cast<std::size_t>(nrows), 0.0);
                for (int r = 0; r < nrows; ++r) {
                    for (int c = 0; c < ncols; ++c) {
                        const Eigen::Vector3d centre = s.position + c * colStep + r * rowStep;
                        double acc = 0;
                        for (const auto& [offset, weight] : planes) {
                            double box = 0;
                            for (double a : subOffsets) {
                                for (double b : subOffsets) {
                                    for (double d : subOffsets) {
                                        box += phantom.valueAt(centre +
                                                               (offset + d * thickness) * normal +
                                                               a * colStep + b * rowStep);
                                    }
                                }
                            }
                            acc += weight * box * subWeight;
                        }
                        img[static_cast<std::size_t>(r) * static_cast<std::size_t>(ncols) +
                            static_cast<std::size_t>(c)] = acc;
                    }
                }
                if (!inPlaneKernel.empty()) {
                    convolveLines(img, scratch, inPlaneKernel, nrows, ncols,
                                  static_cast<std::size_t>(ncols), 1);
                    convolveLines(img, scratch, inPlaneKernel, ncols, nrows, 1,
                                  static_cast<std::size_t>(ncols));
                }
                s.values.resize(img.size());
                const std::uint64_t base = static_cast<std::uint64_t>(k) * img.size();
                for (std::size_t i = 0; i < img.size(); ++i) {
                    double v = img[i];
                    if (spec.noiseSigmaHu > 0)
                        v += spec.noiseSigmaHu * gaussianNoise(spec.seed, base + i);
                    s.values[i] = static_cast<float>(v);
                }
            }
        });

    VolumeInfo& info = stack.info;
    info.modality = "CT";
    info.valueUnits = "HU";
    info.sourceFormat = "phantom";
    info.sourceDescription = "phantom " + phantom.description() +
                             " noise=" + formatValue(spec.noiseSigmaHu) +
                             "HU blur=" + mm(spec.blurSigma) + " supersample=" + std::to_string(n) +
                             " seed=" + std::to_string(spec.seed);
    info.originalDims = {cols, rows, static_cast<std::int64_t>(zs.size())};
    std::vector<double> sortedGaps;
    for (std::size_t k = 1; k < zs.size(); ++k) sortedGaps.push_back((zs[k] - zs[k - 1]) * ct);
    std::sort(sortedGaps.begin(), sortedGaps.end());
    const double medianGap = sortedGaps.empty() ? thickness : sortedGaps[sortedGaps.size() / 2];
    info.originalSpacing = {p, p, medianGap};
    info.minSliceGap = sortedGaps.empty() ? 0 : sortedGaps.front();
    info.maxSliceGap = sortedGaps.empty() ? 0 : sortedGaps.back();
    info.gantryTiltDeg = std::abs(geometry.tiltDeg);
    info.backgroundThreshold = -900;
    return stack;
}

Volume makePhantomVolume(const PhantomSpec& spec) {
    palp::requireWithin("phantom voxel size", spec.voxelSize, bounds::kSpacing, {1e3, "mm"});
    SliceGeometry geometry;
    geometry.pixelSpacing = spec.voxelSize;
    geometry.sliceSpacing = spec.voxelSize;
    geometry.sliceThickness = spec.voxelSize;
    const SliceStack stack = makePhantomSlices(spec, geometry);
    ResampleOptions options;
    options.voxelSize = spec.voxelSize;
    options.backgroundThreshold = -900.0f;
    Volume vol = resample(stack, options);
    vol.info.modality = "CT";
    vol.info.valueUnits = "HU";
    vol.info.sourceFormat = "phantom";
    vol.info.sourceDescription = stack.info.sourceDescription + " voxel=" + mm(spec.voxelSize);
    writeInfo(vol.info, *vol.grid);
    return vol;
}

}  // namespace palp::volume
