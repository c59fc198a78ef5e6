// The analytic phantoms (phantom.h): scene and shape names, the transition profile, the
// tumour's icosphere, and the Phantom model (its parameters checked, its bounds, description
// and value at any world point). Rendering a phantom into CT-like slices and volumes is in
// phantom_slices.cpp.
#include "palp/volume/phantom.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"
#include "phantoms/phantom_detail.h"

namespace palp::volume {

namespace {

namespace pg = phantom_geometry;
using detail::kPi;
using detail::mm;

bool inRange(double v, double lo, double hi) { return lo <= v && v < hi; }

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

}  // namespace palp::volume
