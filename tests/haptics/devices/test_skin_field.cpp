// The skin under a path (skin_field.h) and the patch of a box face whose skin faces the press
// (skin_patch.h), against analytic surfaces: a flat plane, a sloped plane, a sphere, a cube.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/skin_field.h"
#include "palp/haptics/devices/skin_patch.h"
#include "palp/haptics/devices/trajectory.h"
#include "palp/kernels/embree_scene.h"
#include "palp/studies/offline_run.h"

namespace palp::haptics {
namespace {

using Vec = Eigen::Vector3d;

/// The surface y = f(x, z) over [-half, half]^2 as a grid of @p n x @p n quads (two triangles
/// each); quads with a corner where f is NaN are left out.
TriangleMesh heightMesh(const std::function<double(double, double)>& f, double half, int n) {
    TriangleMesh m;
    std::vector<double> y;
    for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i) {
            const double x = -half + 2 * half * i / n, z = -half + 2 * half * j / n;
            y.push_back(f(x, z));
            m.positions.insert(m.positions.end(),
                               {static_cast<float>(x),
                                static_cast<float>(std::isfinite(y.back()) ? y.back() : 0.0),
                                static_cast<float>(z)});
        }
    }
    const auto id = [n](int i, int j) { return static_cast<std::uint32_t>(j * (n + 1) + i); };
    for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
            if (!std::isfinite(y[id(i, j)]) || !std::isfinite(y[id(i + 1, j)]) ||
                !std::isfinite(y[id(i, j + 1)]) || !std::isfinite(y[id(i + 1, j + 1)]))
                continue;
            m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            m.indices.insert(m.indices.end(), {id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
    }
    return m;
}

/// The closed surface of the box [lo, hi] (12 triangles).
TriangleMesh cubeMesh(const Vec& lo, const Vec& hi) {
    TriangleMesh m;
    for (int k = 0; k < 8; ++k) {
        m.positions.insert(m.positions.end(), {static_cast<float>(k & 1 ? hi.x() : lo.x()),
                                               static_cast<float>(k & 2 ? hi.y() : lo.y()),
                                               static_cast<float>(k & 4 ? hi.z() : lo.z())});
    }
    m.indices = {0, 1, 3, 0, 3, 2, 4, 6, 7, 4, 7, 5, 0, 4, 5, 0, 5, 1,
                 2, 3, 7, 2, 7, 6, 0, 2, 6, 0, 6, 4, 1, 5, 7, 1, 7, 3};
    return m;
}

/// A committed scene of @p mesh as the proxy's surface.
std::unique_ptr<kernels::EmbreeScene> surfaceScene(const TriangleMesh& mesh) {
    auto s = std::make_unique<kernels::EmbreeScene>(true);
    s->addRigidMesh(mesh, kernels::kMaskSurface);
    s->commit();
    return s;
}

/// A field over the plane y = 0, 40 x 40 mm, pressing +y, without smoothing or slope limit
/// (so that it holds the surface as measured).
SkinFieldSpec rawSpec() {
    SkinFieldSpec s;
    s.extentU = s.extentV = 0.04;
    s.cellM = 1e-3;
    s.smoothM = 0;
    s.maxSlope = std::numeric_limits<double>::infinity();
    return s;
}

RasterTrajectory raster() {
    RasterTrajectory r;
    r.extentU = r.extentV = 0.03;
    r.lineSpacingM = 4e-3;
    return r;
}

TEST(SkinField, DefaultFieldLeavesEveryPathUnchanged) {
    const auto flat = std::make_shared<const SkinField>();
    RasterTrajectory r = raster();
    RasterTrajectory rs = r;
    rs.skin = flat;
    CircleTrajectory c;
    CircleTrajectory cs = c;
    cs.skin = flat;
    for (double t = 0; t < 2; t += 0.0137) {
        Vec x0, v0, x1, v1;
        r.sample(t, x0, v0);
        rs.sample(t, x1, v1);
        EXPECT_EQ(x0, x1);
        EXPECT_EQ(v0, v1);
        c.sample(t, x0, v0);
        cs.sample(t, x1, v1);
        EXPECT_EQ(x0, x1);
        EXPECT_EQ(v0, v1);
    }
}

TEST(SkinField, FlatSkinOnThePlaneLeavesARasterUnchanged) {
    // The skin is the plane the path lies on: every height is 0 and the raster is as it was, to
    // Embree's float rounding of the ray (origin and t of 1-5 cm carry float steps of 1-4 nm; on
    // an AMD EPYC, Embree's AVX2 path gives -1.15e-9 m where 1e-9 was asked): far below a
    // micrometre.
    constexpr double kFloatRay = 1e-8;  // m
    const auto scene = surfaceScene(heightMesh([](double, double) { return 0.0; }, 0.05, 4));
    const auto field = std::make_shared<const SkinField>(SkinField::measure(*scene, rawSpec()));
    EXPECT_EQ(field->hitFraction(), 1.0);
    for (int j = 0; j < field->nodesV(); ++j)
        for (int i = 0; i < field->nodesU(); ++i) EXPECT_NEAR(field->height(i, j), 0, kFloatRay);
    RasterTrajectory r = raster();
    RasterTrajectory rs = r;
    rs.skin = field;
    for (double t = 0; t < trajectoryDuration(r); t += 0.0137) {
        Vec x0, v0, x1, v1;
        r.sample(t, x0, v0);
        rs.sample(t, x1, v1);
        EXPECT_LT((x1 - x0).norm(), kFloatRay) << "t = " << t;
        EXPECT_LT((v1 - v0).norm(), kFloatRay) << "t = " << t;
    }
}

TEST(SkinField, SlopedPlaneGivesItsHeightsAndSlope) {
    // y = 3 mm + 0.3 x - 0.2 z: h(a, b) = 3 mm + 0.3 a - 0.2 b (u = x, v = z); bilinear
    // interpolation of a plane is exact, so every lateral point has the plane's height.
    const auto plane = [](double x, double z) { return 3e-3 + 0.3 * x - 0.2 * z; };
    const auto scene = surfaceScene(heightMesh(plane, 0.05, 4));
    const SkinField field = SkinField::measure(*scene, rawSpec());
    for (double a = -0.019; a < 0.02; a += 0.0031) {
        for (double b = -0.019; b < 0.02; b += 0.0029) {
            double h = 0, ga = 0, gb = 0;
            field.sample(a, b, h, ga, gb);
            EXPECT_NEAR(h, plane(a, b), 1e-7) << a << ", " << b;
            EXPECT_NEAR(ga, 0.3, 1e-4);
            EXPECT_NEAR(gb, -0.2, 1e-4);
        }
    }
    // apply(): the point moves onto the skin along press, the velocity gains the rate of h.
    Vec x(0.01, 0.0, -0.005), v(0.1, 0.0, 0.05);
    field.apply(x, v);
    EXPECT_NEAR(x.y(), plane(0.01, -0.005), 1e-7);
    EXPECT_NEAR(v.y(), 0.3 * 0.1 - 0.2 * 0.05, 1e-5);
    EXPECT_EQ(x.x(), 0.01);
    EXPECT_EQ(v.x(), 0.1);
}

TEST(SkinField, SlopeLimitRaisesThePathBeforeASteepRise) {
    // A plane rising toward the hand at slope 2 (h = -2 a): limited to 1, the heights are the
    // lower envelope h(p) = min_q h(q) + |p - q|, i.e. the plane's value at the field's
    // a = +20 mm edge continued at slope 1: -40 mm + (20 mm - a).
    const auto scene = surfaceScene(heightMesh([](double x, double) { return -2 * x; }, 0.1, 4));
    SkinFieldSpec s = rawSpec();
    s.maxSlope = 1;
    s.startOffsetM = 0.05;
    const SkinField field = SkinField::measure(*scene, s);
    for (int i = 0; i < field.nodesU(); ++i) {
        const double a = field.nodeA(i);
        EXPECT_NEAR(field.rawHeight(i, 7), -2 * a, 1e-7);
        EXPECT_NEAR(field.height(i, 7), -0.04 + (0.02 - a), 1e-7) << "a = " << a;
        EXPECT_LE(field.height(i, 7), field.rawHeight(i, 7) + 1e-9);  // never below the skin
    }
}

/// A sphere of radius R whose nearest point to the plane y = 0 is @p gap below it.
struct Sphere {
    double r = 0.05, gap = 0.004;
    double operator()(double x, double z) const {
        const double q = r * r - x * x - z * z;
        return q > 0 ? gap + r - std::sqrt(q) : std::numeric_limits<double>::quiet_NaN();
    }
};

TEST(SkinField, SphereGivesItsHeights) {
    // Against the analytic cap: the mesh's chords (0.25 mm) and the field's bilinear cells
    // (1 mm) are each within curvature x cell^2 / 8 per direction of it (the curvature is up
    // to 30 /m at the corners): 0.5 um and 7.5 um.
    const Sphere sphere;
    const auto scene = surfaceScene(heightMesh(sphere, 0.045, 360));
    const SkinField field = SkinField::measure(*scene, rawSpec());
    EXPECT_EQ(field.hitFraction(), 1.0);
    double worst = 0;
    for (double a = -0.0195; a < 0.02; a += 0.0013) {
        for (double b = -0.0195; b < 0.02; b += 0.0017) {
            double h = 0, ga = 0, gb = 0;
            field.sample(a, b, h, ga, gb);
            worst = std::max(worst, std::abs(h - sphere(a, b)));
            // The gradient is that of the cap within the change of slope over a cell.
            const double q = std::sqrt(sphere.r * sphere.r - a * a - b * b);
            EXPECT_NEAR(ga, a / q, 1.5e-3 / q) << a << ", " << b;
            EXPECT_NEAR(gb, b / q, 1.5e-3 / q) << a << ", " << b;
        }
    }
    EXPECT_LT(worst, 1e-5);
}

/// Velocity = d position / dt on a path laid on @p field, by central differences at @p h,
/// skipping the instants where the lateral point crosses a cell line of the field within
/// [t - h, t + h] (the bilinear field's slope jumps there).
void expectVelocityIsDerivative(const Trajectory& path, const SkinField& field, double t1) {
    constexpr double h = 1e-6;
    const auto cell = [&](const Vec& x) {
        const Vec r = x - field.spec().centre;
        const double du = field.spec().extentU / (field.nodesU() - 1);
        const double dv = field.spec().extentV / (field.nodesV() - 1);
        return std::pair{std::floor((r.dot(field.spec().u) + 0.5 * field.spec().extentU) / du),
                         std::floor((r.dot(field.spec().v) + 0.5 * field.spec().extentV) / dv)};
    };
    int checked = 0, failures = 0;
    for (double t = 0.0011; t < t1; t += 0.0037) {
        Vec xm, vm, x, v, xp, vp;
        sampleTrajectory(path, t - h, xm, vm);
        sampleTrajectory(path, t, x, v);
        sampleTrajectory(path, t + h, xp, vp);
        if (cell(xm) != cell(xp)) continue;
        ++checked;
        const Vec fd = (xp - xm) / (2 * h);
        // Path accelerations ~ 10 m/s^2 (turns, curvature of the skin at 0.1 m/s): h a / 2
        // plus rounding 2 eps |x| / 2h.
        const double tol = 1e-5 + 1e-12 / h;
        if ((fd - v).norm() > tol && failures++ < 5)
            ADD_FAILURE() << "t = " << t << ": v " << v.transpose() << ", dx/dt " << fd.transpose();
    }
    EXPECT_EQ(failures, 0);
    EXPECT_GT(checked, 100);
}

TEST(SkinField, VelocityIsTheDerivativeOnASphere) {
    const auto scene = surfaceScene(heightMesh(Sphere{}, 0.045, 180));
    SkinFieldSpec s = rawSpec();
    s.extentU = s.extentV = 0.05;  // the paths keep 4 sigma from its edge
    s.smoothM = 2e-3;              // the tool's settings
    s.maxSlope = 1;
    const auto field = std::make_shared<const SkinField>(SkinField::measure(*scene, s));
    RasterTrajectory r = raster();
    r.skin = field;
    expectVelocityIsDerivative(r, *field, trajectoryDuration(r));
    CircleTrajectory c;
    c.radiusM = 0.012;
    c.skin = field;
    expectVelocityIsDerivative(c, *field, 2.0);
    SweepTrajectory w;
    w.lengthM = 0.03;
    w.skin = field;
    expectVelocityIsDerivative(w, *field, 2.0);
    // After the approach the raster's target is its depth below the skin under it.
    for (double t = r.approachSeconds + 0.1; t < trajectoryDuration(r); t += 0.05) {
        Vec x, v;
        r.sample(t, x, v);
        double h = 0, ga = 0, gb = 0;
        field->sample(x.x(), x.z(), h, ga, gb);
        EXPECT_NEAR(x.y(), h + r.depthM, 1e-12);
        EXPECT_NEAR(h, Sphere{}(x.x(), x.z()), 3e-4);  // smoothed over 2 mm: within 0.3 mm
    }
}

TEST(SkinField, NoSkinUnderThePlaneIsAnError) {
    // The only surface lies beside the plane's rectangle: no ray along press meets it.
    const auto scene = surfaceScene(cubeMesh(Vec(0.1, 0.0, 0.1), Vec(0.12, 0.02, 0.12)));
    try {
        (void)SkinField::measure(*scene, rawSpec());
        ADD_FAILURE() << "expected palp::ValueError";
    } catch (const ValueError& e) {
        const std::string m = e.what();
        EXPECT_NE(m.find("press axis"), std::string::npos) << m;
        EXPECT_NE(m.find("found no surface"), std::string::npos) << m;
    }
    kernels::EmbreeScene empty;
    EXPECT_THROW((void)SkinField::measure(empty, rawSpec()), ValueError);
    SkinFieldSpec bad = rawSpec();
    bad.v = Vec(1, 0, 0);  // not perpendicular to u
    EXPECT_THROW((void)SkinField::measure(*scene, bad), ValueError);
    bad = rawSpec();
    bad.cellM = 0;
    EXPECT_THROW(validateSkinFieldSpec(bad), ValueError);
}

TEST(SkinField, HolesAreFilledFromTheirNeighbours) {
    // A sphere cap smaller than the field: nodes beyond its rim have no hit, and take heights
    // from the nearest measured ones (no jump to the ray's length).
    const Sphere small{0.015, 0.004};
    const auto scene = surfaceScene(heightMesh(small, 0.02, 160));
    const SkinField field = SkinField::measure(*scene, rawSpec());
    EXPECT_GT(field.hitFraction(), 0.3);
    EXPECT_LT(field.hitFraction(), 0.6);
    EXPECT_TRUE(std::isnan(field.rawHeight(0, 0)));
    EXPECT_TRUE(std::isnan(field.skinPoint(0, 0).x()));
    for (int j = 0; j < field.nodesV(); ++j)
        for (int i = 0; i < field.nodesU(); ++i) {
            EXPECT_GE(field.height(i, j), small.gap - 1e-6);  // float rays
            EXPECT_LE(field.height(i, j), small.gap + small.r + 1e-6);
        }
}

TEST(SkinField, SampleAndApplyAndPathsDoNotAllocate) {
    const auto scene = surfaceScene(heightMesh(Sphere{}, 0.045, 60));
    const auto field = std::make_shared<const SkinField>(SkinField::measure(*scene, rawSpec()));
    RasterTrajectory r = raster();
    r.skin = field;
    const Trajectory path = r;
    double sum = 0;
    const std::uint64_t before = test::allocationCount();
    for (int n = 0; n < 2000; ++n) {
        double h = 0, ga = 0, gb = 0;
        field->sample(1e-5 * n - 0.01, 0.003, h, ga, gb);
        Vec x(1e-5 * n, 0, 0), v(0.1, 0, 0);
        field->apply(x, v);
        Vec px, pv;
        sampleTrajectory(path, 1e-3 * n, px, pv);
        sum += h + x.y() + px.y();
    }
    EXPECT_EQ(test::allocationCount(), before);
    EXPECT_TRUE(std::isfinite(sum));
}

// --- SkinPatch -----------------------------------------------------------------------------

TEST(SkinPatch, CubeFaceGivesItsRectangleLessTheMargin) {
    // A 60 mm cube in a 100 mm box: from -y the rays meet the cube's face where |x|, |z| < 30
    // mm; the rectangle is that square less a grid node each side (each node needs its 8
    // neighbours on the skin) and the 5 mm margin.
    const auto scene = surfaceScene(cubeMesh(Vec(-0.03, -0.03, -0.03), Vec(0.03, 0.03, 0.03)));
    const Eigen::AlignedBox3d box(Vec(-0.05, -0.05, -0.05), Vec(0.05, 0.05, 0.05));
    const SkinPatch p = findSkinPatch(*scene, box, Vec::UnitY());
    EXPECT_EQ(p.press, Vec::UnitY());
    EXPECT_EQ(p.u, Vec::UnitX());
    EXPECT_EQ(p.v, Vec::UnitZ());
    EXPECT_NEAR(p.centre.y(), -0.05, 1e-12);  // on the box face
    EXPECT_NEAR(p.centre.x(), 0, 2.1e-3);
    EXPECT_NEAR(p.centre.z(), 0, 2.1e-3);
    for (double e : {p.extentU, p.extentV}) {
        EXPECT_GE(e, 0.06 - 2 * 2e-3 - 2 * 2e-3 - 0.01 - 1e-9);
        EXPECT_LE(e, 0.06 - 0.01 + 1e-9);
    }
    // Nodes within the cube's face less one each side: 27^2 to 29^2 of 51^2.
    EXPECT_GT(p.facingFraction, 0.27);
    EXPECT_LT(p.facingFraction, 0.33);
}

TEST(SkinPatch, SphereKeepsToWhereItsSkinFacesThePress) {
    // A sphere of radius 40 mm: its skin faces +y within 35 degrees (slope 0.7) inside a disc
    // of radius R sin(35 deg) = 22.9 mm, whose largest square has a side of 32.4 mm; less the
    // margin, a node each side for the slope stencil and one for the grid: 18-23 mm.
    const double r = 0.04;
    const auto cap = [r](double x, double z) {
        const double q = r * r - x * x - z * z;
        return q > 0 ? -std::sqrt(q) : std::numeric_limits<double>::quiet_NaN();
    };
    const auto scene = surfaceScene(heightMesh(cap, 0.04, 200));
    const Eigen::AlignedBox3d box(Vec(-0.05, -0.05, -0.05), Vec(0.05, 0.05, 0.05));
    SkinPatchOptions o;
    o.smoothM = 0;
    const SkinPatch p = findSkinPatch(*scene, box, Vec::UnitY(), o);
    for (double e : {p.extentU, p.extentV}) {
        EXPECT_GT(e, 0.014);
        EXPECT_LT(e, 0.028);
    }
    EXPECT_NEAR(p.extentU * p.extentV, 0.022 * 0.022, 0.3 * 0.022 * 0.022);
    EXPECT_NEAR(p.centre.x(), 0, 2.1e-3);
    EXPECT_NEAR(p.centre.z(), 0, 2.1e-3);
    EXPECT_THROW((void)findSkinPatch(*scene, box, Vec(1, 1, 0).normalized(), o), ValueError);
}

TEST(SkinPatch, BestSideIsTheBroadest) {
    // A slab 10 mm thick in x, 70 mm in y and z: the x faces have a 70 x 70 mm face of skin,
    // the others 10 x 70 mm, too narrow once the margins are taken. Ties go to +x over -x.
    const auto scene =
        surfaceScene(cubeMesh(Vec(-0.005, -0.035, -0.035), Vec(0.005, 0.035, 0.035)));
    const Eigen::AlignedBox3d box(Vec(-0.05, -0.05, -0.05), Vec(0.05, 0.05, 0.05));
    const SkinPatch p = findBestSkinPatch(*scene, box);
    EXPECT_EQ(p.press, Vec::UnitX());
    EXPECT_EQ(p.u, Vec::UnitY());
    EXPECT_EQ(p.v, Vec::UnitZ());
    EXPECT_GT(p.extentU, 0.05);
    EXPECT_GT(p.extentV, 0.05);
    // A plate 30 mm thick in z (as a scan's flat cut ends): its z faces (80 x 70 mm) are the
    // broadest; among the four sides across z (kSidePressAxes) the y faces (80 x 30 mm) beat
    // the x faces (70 x 30 mm), and +y comes before -y.
    const auto plate = surfaceScene(cubeMesh(Vec(-0.04, -0.035, -0.015), Vec(0.04, 0.035, 0.015)));
    EXPECT_EQ(findBestSkinPatch(*plate, box).press, Vec::UnitZ());
    const SkinPatch side = findBestSkinPatch(*plate, box, {}, kSidePressAxes);
    EXPECT_EQ(side.press, Vec::UnitY());
    EXPECT_GT(side.extentU, side.extentV);
    EXPECT_EQ(axisVector(SignedAxis::MinusZ), -Vec::UnitZ());
    // No skin anywhere: a patch of zero size.
    const auto far = surfaceScene(cubeMesh(Vec(1, 1, 1), Vec(1.01, 1.01, 1.01)));
    const SkinPatch none = findBestSkinPatch(*far, box);
    EXPECT_EQ(none.extentU * none.extentV, 0);
}

}  // namespace
}  // namespace palp::haptics
