// Phantoms (analytic truth, determinism, noise, blur), the DICOM series writer and `palp phantom`.
#include <gdcmAttribute.h>
#include <gdcmDataSet.h>
#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmStringFilter.h>
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <set>

#include "palp/base/error.h"
#include "palp/volume/dicom.h"
#include "palp/volume/load.h"
#include "palp/volume/phantom.h"
#include "test_support.h"

namespace {

using namespace palp::volume;
namespace pg = palp::volume::phantom_geometry;
namespace fs = std::filesystem;
using Eigen::Vector3d;

constexpr double kMm = 1e-3;
constexpr double kPi = std::numbers::pi;

Vector3d mm(double x, double y, double z) { return Vector3d(x, y, z) * kMm; }

PhantomParams paramsFor(PhantomScene scene) {
    PhantomParams p;
    p.scene = scene;
    return p;
}

Vector3d centre(const WorldBox& b) { return 0.5 * (b.min + b.max); }

// Index of the voxel whose centre is nearest to world point @p p.
openvdb::Coord nearestVoxel(const openvdb::math::Transform& xf, const Vector3d& p) {
    const openvdb::Vec3d i = xf.worldToIndex(openvdb::Vec3d(p.x(), p.y(), p.z()));
    return openvdb::Coord(static_cast<int>(std::lround(i.x())),
                          static_cast<int>(std::lround(i.y())),
                          static_cast<int>(std::lround(i.z())));
}

// ---------------------------------------------------------------- analytic truth

TEST(PhantomProfile, MatchesFormulasAtKnownPoints) {
    const double w = 0.01;
    for (TransitionProfile p :
         {TransitionProfile::Linear, TransitionProfile::Cosine, TransitionProfile::Tanh}) {
        EXPECT_DOUBLE_EQ(transitionProfile(p, 0, w, 3), 0) << profileName(p);
        EXPECT_NEAR(transitionProfile(p, w / 2, w, 3), 0.5, 1e-15) << profileName(p);
        EXPECT_DOUBLE_EQ(transitionProfile(p, w, w, 3), 1) << profileName(p);
        EXPECT_DOUBLE_EQ(transitionProfile(p, -w, w, 3), 0) << profileName(p);
        EXPECT_DOUBLE_EQ(transitionProfile(p, 2 * w, w, 3), 1) << profileName(p);
    }
    EXPECT_NEAR(transitionProfile(TransitionProfile::Linear, w / 4, w, 3), 0.25, 1e-15);
    EXPECT_NEAR(transitionProfile(TransitionProfile::Cosine, w / 4, w, 3),
                (1 - std::cos(kPi / 4)) / 2, 1e-15);
    EXPECT_NEAR(transitionProfile(TransitionProfile::Tanh, w / 4, w, 2),
                (std::tanh(2 * (0.5 - 1)) / std::tanh(2.0) + 1) / 2, 1e-15);
    // Tanh with a large sharpness approaches a step.
    EXPECT_LT(transitionProfile(TransitionProfile::Tanh, 0.4 * w, w, 20), 1e-3);
}

TEST(PhantomTruth, AvcHiddenBoxInItsQuadrantUnderThePlate) {
    const WorldBox plate = Phantom::avcPlate();
    for (int q = 0; q < 4; ++q) {
        PhantomParams params = paramsFor(PhantomScene::Avc);
        params.quadrant = q;
        const Phantom ph(params);
        const PhantomMaterials& m = params.materials;
        EXPECT_EQ(ph.valueAt(centre(plate)), m.rigidHu);
        for (int other = 0; other < 4; ++other) {
            const Vector3d c = centre(Phantom::avcHiddenBox(other));
            EXPECT_EQ(ph.valueAt(c), other == q ? m.rigidHu : m.softHu)
                << "box " << other << " quadrant " << q;
        }
        const WorldBox box = Phantom::avcHiddenBox(q);
        // The quadrant bits: bit 0 -> x > 0, bit 1 -> z > 0.
        EXPECT_EQ(centre(box).x() > 0, (q & 1) != 0);
        EXPECT_EQ(centre(box).z() > 0, (q & 2) != 0);
        // Below the plate and inside its shadow from above (the surface is at y = 0, depth +y).
        EXPECT_GT(box.min.y(), plate.max.y());
        EXPECT_GE(box.min.x(), plate.min.x());
        EXPECT_LE(box.max.x(), plate.max.x());
        EXPECT_GE(box.min.z(), plate.min.z());
        EXPECT_LE(box.max.z(), plate.max.z());
        // A vertical probe from the surface above the box meets fat, soft tissue, then the plate.
        const Vector3d c = centre(box);
        bool hitPlate = false;
        for (double y = 0.05e-3; y < c.y(); y += 0.1e-3) {
            const double v = ph.valueAt(Vector3d(c.x(), y, c.z()));
            if (v == m.rigidHu) {
                hitPlate = true;
                EXPECT_GE(y, plate.min.y());
                EXPECT_LE(y, plate.max.y());
                break;
            }
        }
        EXPECT_TRUE(hitPlate);
        // Box corners just inside and just outside.
        EXPECT_EQ(ph.valueAt(box.min + Vector3d::Constant(1e-5)), m.rigidHu);
        EXPECT_EQ(ph.valueAt(box.max - Vector3d::Constant(1e-5)), m.rigidHu);
        EXPECT_EQ(ph.valueAt(box.max + Vector3d::Constant(1e-5)), m.softHu);
    }
    const Phantom ph(paramsFor(PhantomScene::Avc));
    EXPECT_EQ(ph.valueAt(mm(0, 1, 0)), -100);     // fat layer (2 mm)
    EXPECT_EQ(ph.valueAt(mm(0, 5, 0)), 40);       // soft tissue
    EXPECT_EQ(ph.valueAt(mm(0, -1, 0)), -1000);   // air above the surface
    EXPECT_EQ(ph.valueAt(mm(0, 51, 0)), -1000);   // air below the block
    EXPECT_EQ(ph.valueAt(mm(49, 40, -49)), 40);   // a corner of the block
    EXPECT_EQ(ph.valueAt(mm(51, 40, 0)), -1000);  // beside the block
    EXPECT_THROW(
        {
            PhantomParams p = paramsFor(PhantomScene::Avc);
            p.quadrant = 4;
            Phantom bad(p);
        },
        palp::ValueError);
}

TEST(PhantomTruth, AvcecShapes) {
    const double y = 9;  // mid-plate depth, mm
    struct Probe {
        PlateShape shape;
        double x, z;  // mm
        bool inside;
    };
    const std::vector<Probe> probes = {
        {PlateShape::Circle, 0, 19.9, true},
        {PlateShape::Circle, 14, 14, true},
        {PlateShape::Circle, 14.5, 14.5, false},
        {PlateShape::Circle, 0, 20.1, false},
        // Triangle: vertex at +z (R = 20 mm), base at z = -R cos 60 = -10 mm.
        {PlateShape::Triangle, 0, 19.8, true},
        {PlateShape::Triangle, 0, -9.9, true},
        {PlateShape::Triangle, 0, -10.1, false},
        {PlateShape::Triangle, 15, -9, true},
        {PlateShape::Triangle, 10, 5, false},
        // Hexagon (vertex at +z): vertical edges at x = +-R cos 30 = 17.32 mm.
        {PlateShape::Hexagon, 17.2, 0, true},
        {PlateShape::Hexagon, -17.2, 0, true},
        {PlateShape::Hexagon, 17.45, 0, false},
        {PlateShape::Hexagon, 0, 19.9, true},
        // Pentagon (vertex at +z): bottom edge at z = -R cos 36 = -16.18 mm.
        {PlateShape::Pentagon, 0, -16.1, true},
        {PlateShape::Pentagon, 0, -16.3, false},
        {PlateShape::Pentagon, 0, 19.9, true},
        // Rectangle 40 x 24 mm.
        {PlateShape::Rectangle, 19.9, 11.9, true},
        {PlateShape::Rectangle, 19.9, 12.1, false},
        {PlateShape::Rectangle, 20.1, 0, false},
        {PlateShape::Rectangle, -19.9, -11.9, true},
    };
    for (const Probe& pr : probes) {
        PhantomParams params = paramsFor(PhantomScene::Avcec);
        params.shape = pr.shape;
        const Phantom ph(params);
        EXPECT_EQ(ph.valueAt(mm(pr.x, y, pr.z)), pr.inside ? 1000 : 40)
            << shapeName(pr.shape) << " at x " << pr.x << " z " << pr.z;
        // Never rigid just above or below the plate.
        EXPECT_EQ(ph.valueAt(mm(pr.x, 7.9, pr.z)), 40);
        EXPECT_EQ(ph.valueAt(mm(pr.x, 10.1, pr.z)), 40);
    }
}

TEST(PhantomTruth, BoneDisplacementSide) {
    for (int d = -1; d <= 1; ++d) {
        PhantomParams params = paramsFor(PhantomScene::Bone);
        params.displacement = d;
        const Phantom ph(params);
        const double slope = std::tan(10.0 * kPi / 180.0);
        for (double x : {-35.0, -10.0, 0.0, 20.0, 35.0}) {
            const double top = ph.boneTopDepth(x * kMm);
            EXPECT_NEAR(top, (25.0 - d * slope * x) * kMm, 1e-12);
            EXPECT_EQ(ph.valueAt(Vector3d(x * kMm, top + 3 * kMm, 0)), 1000);
            EXPECT_EQ(ph.valueAt(Vector3d(x * kMm, top - 0.1 * kMm, 0)), 40);
            EXPECT_EQ(ph.valueAt(Vector3d(x * kMm, top + 6.1 * kMm, 0)), 40);
        }
        const double left = ph.boneTopDepth(30 * kMm), right = ph.boneTopDepth(-30 * kMm);
        if (d == 1) {
            EXPECT_LT(left, right - 5 * kMm);  // the left side (+x) is closer
        } else if (d == -1) {
            EXPECT_GT(left, right + 5 * kMm);
        } else {
            EXPECT_EQ(left, right);
        }
        EXPECT_EQ(ph.valueAt(mm(45, 25, 0)), 40);  // beyond the slab's edge
    }
}

TEST(PhantomTruth, StiffnessBoxes) {
    for (TransitionProfile prof :
         {TransitionProfile::Linear, TransitionProfile::Cosine, TransitionProfile::Tanh}) {
        PhantomParams params = paramsFor(PhantomScene::Stiffness);
        params.profile = prof;
        params.transitionWidth = 10 * kMm;
        const Phantom ph(params);
        const double soft = 40, hard = 300;
        const double dp = Phantom::stiffnessBoxCentreX(0), cp = Phantom::stiffnessBoxCentreX(1),
                     cl = Phantom::stiffnessBoxCentreX(2);
        EXPECT_EQ(ph.valueAt(Vector3d(dp, 20 * kMm, 0)), hard);
        EXPECT_EQ(ph.valueAt(Vector3d(dp, 1 * kMm, 0)), -100);  // fat layer on top
        EXPECT_EQ(ph.valueAt(Vector3d(cp, 14.9 * kMm, 0)), soft);
        EXPECT_EQ(ph.valueAt(Vector3d(cp, 15.1 * kMm, 0)), hard);
        // CL: transition over [cl - w/2, cl + w/2] along +x.
        const double y = 20 * kMm;
        EXPECT_EQ(ph.valueAt(Vector3d(cl - 5.01 * kMm, y, 0)), soft);
        EXPECT_NEAR(ph.valueAt(Vector3d(cl, y, 0)), (soft + hard) / 2, 1e-9);
        EXPECT_EQ(ph.valueAt(Vector3d(cl + 5.01 * kMm, y, 0)), hard);
        const double quarter = transitionProfile(prof, 2.5 * kMm, 10 * kMm, 3);
        EXPECT_NEAR(ph.valueAt(Vector3d(cl - 2.5 * kMm, y, 0)), soft + (hard - soft) * quarter,
                    1e-9);
        // Air between the boxes.
        EXPECT_EQ(ph.valueAt(Vector3d(0.5 * (dp + cp), y, 0)), -1000);
    }
}

// ---------------------------------------------------------------- volumes

TEST(PhantomVolume, NoiseFreeGridEqualsTruthAtVoxelCentres) {
    PhantomSpec spec;
    spec.params.scene = PhantomScene::Avc;
    spec.params.quadrant = 3;
    spec.voxelSize = 1 * kMm;
    const Volume vol = makePhantomVolume(spec);
    const Phantom ph(spec.params);
    ASSERT_TRUE(vol.grid);
    EXPECT_EQ(vol.grid->getName(), kScanGridName);
    EXPECT_EQ(vol.grid->background(), -1000.0f);
    EXPECT_EQ(vol.info.modality, "CT");
    EXPECT_EQ(vol.info.valueUnits, "HU");
    EXPECT_EQ(vol.info.sourceFormat, "phantom");
    EXPECT_NE(vol.info.sourceDescription.find("avc quadrant=3"), std::string::npos);
    EXPECT_DOUBLE_EQ(vol.voxelSize(), 1e-3);

    // Every voxel centre in the block plus margin: grid value == truth; air is inactive.
    auto acc = vol.grid->getConstAccessor();
    const auto& xf = vol.grid->transform();
    std::size_t mismatches = 0, checked = 0, solid = 0;
    for (int i = -55; i < 55; ++i) {
        for (int j = -5; j < 55; ++j) {
            for (int k = -55; k < 55; ++k) {
                const Vector3d p((i + 0.5) * kMm, (j + 0.5) * kMm, (k + 0.5) * kMm);
                const openvdb::Coord ijk = nearestVoxel(xf, p);
                const openvdb::Vec3d back = xf.indexToWorld(ijk);
                ASSERT_NEAR(back.x(), p.x(), 1e-9);
                ASSERT_NEAR(back.y(), p.y(), 1e-9);
                ASSERT_NEAR(back.z(), p.z(), 1e-9);
                const double truth = ph.valueAt(p);
                const bool active = acc.isValueOn(ijk);
                if (truth < -900) {
                    if (active) ++mismatches;
                } else {
                    ++solid;
                    if (!active || acc.getValue(ijk) != static_cast<float>(truth)) ++mismatches;
                }
                ++checked;
            }
        }
    }
    EXPECT_EQ(mismatches, 0u) << "of " << checked;
    EXPECT_EQ(static_cast<std::size_t>(vol.grid->activeVoxelCount()), solid);
    EXPECT_EQ(solid, 100u * 50u * 100u);
}

TEST(PhantomVolume, SameSeedIdenticalOtherSeedDiffersNoiseSigma) {
    PhantomSpec spec;
    spec.params.scene = PhantomScene::Avc;
    spec.voxelSize = 1 * kMm;
    spec.noiseSigmaHu = 20;
    spec.seed = 7;
    const Volume a = makePhantomVolume(spec);
    Volume b;
    {
        // Bit-identical whatever the thread count.
        tbb::global_control oneThread(tbb::global_control::max_allowed_parallelism, 1);
        b = makePhantomVolume(spec);
    }
    spec.seed = 8;
    const Volume c = makePhantomVolume(spec);
    ASSERT_EQ(a.grid->activeVoxelCount(), b.grid->activeVoxelCount());
    auto accB = b.grid->getConstAccessor();
    auto accC = c.grid->getConstAccessor();
    std::size_t differB = 0, differC = 0;
    const Phantom ph(spec.params);
    double sum = 0, sumSq = 0;
    std::size_t n = 0;
    for (auto it = a.grid->cbeginValueOn(); it; ++it) {
        const openvdb::Coord ijk = it.getCoord();
        if (accB.getValue(ijk) != *it || !accB.isValueOn(ijk)) ++differB;
        if (accC.getValue(ijk) != *it) ++differC;
        const openvdb::Vec3d w = a.grid->indexToWorld(ijk);
        // Uniform soft tissue between the fat layer and the plate.
        if (w.y() > 3 * kMm && w.y() < 9 * kMm && std::abs(w.x()) < 45 * kMm &&
            std::abs(w.z()) < 45 * kMm) {
            const double r = static_cast<double>(*it) - ph.valueAt(Vector3d(w.x(), w.y(), w.z()));
            sum += r;
            sumSq += r * r;
            ++n;
        }
    }
    EXPECT_EQ(differB, 0u);
    EXPECT_GT(differC, static_cast<std::size_t>(a.grid->activeVoxelCount()) * 9 / 10);
    ASSERT_GT(n, 40000u);
    const double mean = sum / static_cast<double>(n);
    const double sd = std::sqrt(sumSq / static_cast<double>(n) - mean * mean);
    EXPECT_NEAR(mean, 0, 0.5);       // 5 standard errors
    EXPECT_NEAR(sd, 20, 0.03 * 20);  // within 3 %
    std::printf("noise: n=%zu mean=%.4f HU sd=%.4f HU (sigma 20)\n", n, mean, sd);
}

TEST(PhantomVolume, SupersampleAndBlurArePartialVolume) {
    PhantomSpec spec;
    spec.params.scene = PhantomScene::Stiffness;
    spec.params.fatThickness = 0;
    spec.voxelSize = 0.5 * kMm;
    spec.margin = 1 * kMm;
    spec.blurSigma = 1 * kMm;
    SliceGeometry geometry;  // a small stack around the CP box's step at 15 mm depth
    geometry.pixelSpacing = 0.5 * kMm;
    geometry.sliceSpacing = 0.5 * kMm;
    const SliceStack stack = makePhantomSlices(spec, geometry);
    // Sample the CP box's centre column (x = 0, z near 0) across the step.
    const Slice* mid = nullptr;
    for (const Slice& s : stack.slices) {
        if (std::abs(s.position.z() - 0.25 * kMm) < 1e-9) mid = &s;
    }
    ASSERT_NE(mid, nullptr);
    const int c =
        static_cast<int>(std::lround((0.25 * kMm - mid->position.x()) / mid->colStep.x()));
    double worst = 0;
    for (double y = 12.25; y < 18; y += 0.5) {
        const int r =
            static_cast<int>(std::lround((y * kMm - mid->position.y()) / mid->rowStep.y()));
        const double v = mid->values[static_cast<std::size_t>(r * mid->cols + c)];
        const double expected = 40 + 260 * 0.5 * std::erfc(-(y - 15) / std::sqrt(2.0));
        worst = std::max(worst, std::abs(v - expected));
    }
    std::printf("blur: largest deviation from the erf edge %.3f HU of 260\n", worst);
    EXPECT_LT(worst, 0.02 * 260);

    // Supersampling: a voxel straddling the CP step half and half averages the two values.
    PhantomSpec ss;
    ss.params.scene = PhantomScene::Stiffness;
    ss.params.hardDepth = 15.25 * kMm;  // through the voxel centres at (k + 1/2) 0.5 mm
    ss.supersample = 4;
    ss.margin = 1 * kMm;
    const SliceStack s4 = makePhantomSlices(ss, geometry);
    const Slice& m4 = s4.slices[s4.slices.size() / 2];
    const int c4 = static_cast<int>(std::lround((0.25 * kMm - m4.position.x()) / m4.colStep.x()));
    const int r4 = static_cast<int>(std::lround((15.25 * kMm - m4.position.y()) / m4.rowStep.y()));
    EXPECT_NEAR(m4.values[static_cast<std::size_t>(r4 * m4.cols + c4)], 170.0, 1e-4);
    EXPECT_EQ(m4.values[static_cast<std::size_t>((r4 - 1) * m4.cols + c4)], 40.0f);
    EXPECT_EQ(m4.values[static_cast<std::size_t>((r4 + 1) * m4.cols + c4)], 300.0f);
}

TEST(PhantomSlices, TiltedUnevenGeometry) {
    PhantomSpec spec;
    spec.params.scene = PhantomScene::Avc;
    SliceGeometry g;
    g.pixelSpacing = 1 * kMm;
    g.sliceGaps = {1.5 * kMm, 2.5 * kMm};
    g.tiltDeg = 15;
    const SliceStack stack = makePhantomSlices(spec, g);
    const double t = 15 * kPi / 180;
    const Phantom ph(spec.params);
    ASSERT_GT(stack.slices.size(), 40u);
    for (std::size_t k = 0; k < stack.slices.size(); ++k) {
        const Slice& s = stack.slices[k];
        EXPECT_TRUE(s.colStep.isApprox(Vector3d(1e-3, 0, 0), 1e-12));
        EXPECT_TRUE(s.rowStep.isApprox(1e-3 * Vector3d(0, std::cos(t), -std::sin(t)), 1e-12));
        if (k > 0) {
            const Vector3d d = s.position - stack.slices[k - 1].position;
            EXPECT_NEAR(d.x(), 0, 1e-15);
            EXPECT_NEAR(d.y(), 0, 1e-15);  // stacked along z
            const double gap = (k % 2 == 1 ? 1.5 : 2.5) * kMm;
            EXPECT_NEAR(d.z() * std::cos(t), gap, 1e-12);  // gap along the normal
        }
        // Noise-free, unblurred: pixel values are the truth at pixel centres.
        for (int r = 0; r < s.rows; r += 7) {
            for (int c = 0; c < s.cols; c += 5) {
                const Vector3d p = s.position + c * s.colStep + r * s.rowStep;
                ASSERT_EQ(s.values[static_cast<std::size_t>(r * s.cols + c)],
                          static_cast<float>(ph.valueAt(p)));
            }
        }
    }
    // Geometries that would need absurd memory or overflow are refused before allocating.
    SliceGeometry tiny = g;
    tiny.pixelSpacing = 1e-9;
    EXPECT_THROW(makePhantomSlices(spec, tiny), palp::ValueError);
    tiny.pixelSpacing = 0.01 * kMm;  // 11000 x 6000 pixels per slice
    EXPECT_THROW(makePhantomSlices(spec, tiny), palp::ValueError);
    SliceGeometry steep = g;
    steep.tiltDeg = 75;
    EXPECT_THROW(makePhantomSlices(spec, steep), palp::ValueError);
    EXPECT_NEAR(stack.info.gantryTiltDeg, 15, 1e-12);
    EXPECT_NEAR(stack.info.minSliceGap, 1.5e-3, 1e-12);
    EXPECT_NEAR(stack.info.maxSliceGap, 2.5e-3, 1e-12);
    // The slices cover the block: its deepest, most superior corner lies within the stack.
    const Vector3d corner = mm(0, 49.5, 49.5);
    const Vector3d n = stack.slices[0].colStep.cross(stack.slices[0].rowStep).normalized();
    EXPECT_GE(corner.dot(n), stack.slices.front().position.dot(n));
    EXPECT_LE(corner.dot(n), stack.slices.back().position.dot(n));
}

// ---------------------------------------------------------------- DICOM

std::string tagString(const gdcm::DataSet& ds, const gdcm::File& file, std::uint16_t g,
                      std::uint16_t e) {
    gdcm::StringFilter sf;
    sf.SetFile(file);
    std::string s = sf.ToString(gdcm::Tag(g, e));
    while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
    (void)ds;
    return s;
}

std::vector<fs::path> listFiles(const fs::path& dir) {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path());
    std::sort(files.begin(), files.end());
    return files;
}

void checkSeriesAgainstStack(const fs::path& dir, const SliceStack& stack, double tiltDeg,
                             double maxError) {
    const std::vector<fs::path> files = listFiles(dir);
    ASSERT_EQ(files.size(), stack.slices.size());
    std::set<std::string> sopUids;
    std::string seriesUid;
    double worst = 0;
    for (std::size_t k = 0; k < files.size(); ++k) {
        SCOPED_TRACE(files[k].string());
        EXPECT_EQ(files[k].extension(), ".dcm");
        gdcm::ImageReader reader;
        reader.SetFileName(files[k].c_str());
        ASSERT_TRUE(reader.Read());
        const gdcm::Image& img = reader.GetImage();
        const gdcm::File& file = reader.GetFile();
        const gdcm::DataSet& ds = file.GetDataSet();
        const Slice& s = stack.slices[k];
        ASSERT_EQ(img.GetDimension(0), static_cast<unsigned>(s.cols));
        ASSERT_EQ(img.GetDimension(1), static_cast<unsigned>(s.rows));
        EXPECT_EQ(img.GetPixelFormat().GetScalarType(), gdcm::PixelFormat::UINT16);
        EXPECT_NEAR(img.GetSpacing(0), s.colStep.norm() * 1e3, 1e-9);
        EXPECT_NEAR(img.GetSpacing(1), s.rowStep.norm() * 1e3, 1e-9);
        for (int a = 0; a < 3; ++a)
            EXPECT_NEAR(img.GetOrigin(static_cast<unsigned>(a)), s.position[a] * 1e3, 1e-9);
        const double* dc = img.GetDirectionCosines();
        const Vector3d rowCos = s.colStep.normalized(), colCos = s.rowStep.normalized();
        for (int a = 0; a < 3; ++a) {
            EXPECT_NEAR(dc[a], rowCos[a], 1e-9);
            EXPECT_NEAR(dc[3 + a], colCos[a], 1e-9);
        }
        EXPECT_DOUBLE_EQ(img.GetIntercept(), -1024);
        EXPECT_DOUBLE_EQ(img.GetSlope(), 1);
        EXPECT_EQ(tagString(ds, file, 0x0008, 0x0060), "CT");
        EXPECT_EQ(tagString(ds, file, 0x0008, 0x0016), "1.2.840.10008.5.1.4.1.1.2");
        EXPECT_EQ(tagString(ds, file, 0x0010, 0x0010), "PALP^PHANTOM");
        EXPECT_EQ(tagString(ds, file, 0x0010, 0x0020), "PHANTOM");
        EXPECT_EQ(std::stoi(tagString(ds, file, 0x0020, 0x0013)), static_cast<int>(k + 1));
        const std::string series = tagString(ds, file, 0x0020, 0x000e);
        if (k == 0) seriesUid = series;
        EXPECT_EQ(series, seriesUid);
        EXPECT_FALSE(series.empty());
        sopUids.insert(tagString(ds, file, 0x0008, 0x0018));
        if (tiltDeg != 0) {
            EXPECT_NEAR(std::stod(tagString(ds, file, 0x0018, 0x1120)), tiltDeg, 1e-9);
        } else {
            EXPECT_FALSE(ds.FindDataElement(gdcm::Tag(0x0018, 0x1120)));
        }
        EXPECT_GT(std::stod(tagString(ds, file, 0x0018, 0x0050)), 0);
        std::vector<std::uint16_t> buf(img.GetBufferLength() / 2);
        ASSERT_TRUE(img.GetBuffer(reinterpret_cast<char*>(buf.data())));
        ASSERT_EQ(buf.size(), s.values.size());
        for (std::size_t i = 0; i < buf.size(); ++i) {
            const double v = buf[i] * 1.0 - 1024.0;
            const double expected = std::clamp(static_cast<double>(s.values[i]), -1024.0, 64511.0);
            worst = std::max(worst, std::abs(v - expected));
        }
    }
    EXPECT_EQ(sopUids.size(), files.size());
    EXPECT_LE(worst, maxError);
    std::printf("DICOM: %zu files, largest |stored*slope+intercept - value| = %.4f HU\n",
                files.size(), worst);
}

TEST(DicomWrite, TagsGeometryAndValuesReadBackWithGdcm) {
    palp::test::TempDir tmp;
    PhantomSpec spec;
    spec.params.scene = PhantomScene::Avc;
    spec.params.quadrant = 1;
    spec.noiseSigmaHu = 15;
    SliceGeometry g;
    g.pixelSpacing = 2 * kMm;
    g.sliceSpacing = 2 * kMm;
    const SliceStack stack = makePhantomSlices(spec, g);
    // Noise on air goes below -1024 HU: refused by default, clipped on request.
    EXPECT_THROW(writeDicomSeries(stack, tmp / "axial"), palp::ValueError);
    DicomWriteOptions clip;
    clip.clampToStorage = true;
    writeDicomSeries(stack, tmp / "axial", clip);
    checkSeriesAgainstStack(tmp / "axial", stack, 0, 0.5 + 1e-4);

    SliceGeometry tilted = g;
    tilted.tiltDeg = 15;
    tilted.sliceGaps = {1.5 * kMm, 2.5 * kMm};
    const SliceStack tiltedStack = makePhantomSlices(spec, tilted);
    DicomWriteOptions opt;
    opt.gantryTiltDeg = 15;
    opt.clampToStorage = true;
    writeDicomSeries(tiltedStack, tmp / "tilted" / "nested", opt);
    checkSeriesAgainstStack(tmp / "tilted" / "nested", tiltedStack, 15, 0.5 + 1e-4);
}

TEST(DicomWrite, RefusesValuesThatDoNotFitAndLeavesNothing) {
    palp::test::TempDir tmp;
    PhantomSpec spec;
    SliceGeometry g;
    g.pixelSpacing = 4 * kMm;
    g.sliceSpacing = 4 * kMm;
    SliceStack stack = makePhantomSlices(spec, g);
    stack.slices.back().values[3] = 70000.0f;
    try {
        writeDicomSeries(stack, tmp / "out");
        FAIL() << "expected a ValueError";
    } catch (const palp::ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("70000"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(tmp / "out"));
    stack.slices.back().values[3] = -1025.0f;  // below the intercept
    EXPECT_THROW(writeDicomSeries(stack, tmp / "out"), palp::ValueError);
    EXPECT_FALSE(fs::exists(tmp / "out"));
    // An existing, non-empty directory is refused rather than mixed with another series.
    stack.slices.back().values[3] = 0.0f;
    writeDicomSeries(stack, tmp / "out");
    const std::size_t n = listFiles(tmp / "out").size();
    EXPECT_EQ(n, stack.slices.size());
    EXPECT_THROW(writeDicomSeries(stack, tmp / "out"), palp::IoError);
    EXPECT_EQ(listFiles(tmp / "out").size(), n);
    // A directory that cannot be created.
    EXPECT_THROW(writeDicomSeries(stack, "/proc/palp-no-such/dir"), palp::IoError);
}

// Round trip through palp's DICOM reader.
TEST(DicomRoundTrip, PhantomSeriesLoadsBackExactly) {
    struct Case {
        double tiltDeg;
        std::vector<double> gapsMm;
        double noiseHu;
    };
    for (const Case& cs : {Case{0, {}, 0}, Case{15, {1.5, 2.5}, 0}, Case{15, {1.5, 2.5}, 10}}) {
        SCOPED_TRACE("tilt " + std::to_string(cs.tiltDeg));
        palp::test::TempDir tmp;
        PhantomSpec spec;
        spec.params.scene = PhantomScene::Avc;
        spec.params.quadrant = 2;
        spec.noiseSigmaHu = cs.noiseHu;
        spec.seed = 11;
        SliceGeometry g;
        g.pixelSpacing = 1 * kMm;
        g.sliceSpacing = 1 * kMm;
        for (double v : cs.gapsMm) g.sliceGaps.push_back(v * kMm);
        g.tiltDeg = cs.tiltDeg;
        SliceStack stack = makePhantomSlices(spec, g);
        for (Slice& s : stack.slices) {
            for (float& v : s.values) v = std::max(v, -1024.0f);  // what the storage keeps
        }
        DicomWriteOptions opt;
        opt.gantryTiltDeg = cs.tiltDeg;
        opt.clampToStorage = true;
        writeDicomSeries(stack, tmp / "series", opt);
        LoadOptions lo;
        lo.resample.voxelSize = 1 * kMm;
        const Volume loaded = load({tmp / "series"}, lo);
        ResampleOptions ro;
        ro.voxelSize = 1 * kMm;
        ro.backgroundThreshold = -900.0f;
        const Volume direct = resample(stack, ro);
        EXPECT_EQ(loaded.info.modality, "CT");
        EXPECT_NEAR(loaded.info.gantryTiltDeg, cs.tiltDeg, 1e-3);
        // Same lattice: the transforms agree to the precision of the DICOM decimal strings.
        const openvdb::Vec3d o1 = loaded.grid->indexToWorld(openvdb::Coord(0, 0, 0));
        const openvdb::Vec3d o2 = direct.grid->indexToWorld(openvdb::Coord(0, 0, 0));
        EXPECT_NEAR((o1 - o2).length(), 0, 1e-9);
        EXPECT_NEAR(loaded.voxelSize(), direct.voxelSize(), 1e-15);
        // Values: the resampled in-memory stack and the loaded series differ only by the storage
        // quantisation (0.5 HU, carried through convex interpolation weights).
        auto accL = loaded.grid->getConstAccessor();
        double worst = 0;
        std::size_t n = 0;
        std::size_t flipped = 0;
        for (auto it = direct.grid->cbeginValueOn(); it; ++it) {
            if (!accL.isValueOn(it.getCoord())) {
                // Only a value within the quantisation of the -900 HU threshold may turn inactive.
                EXPECT_LT(*it, -900.0f + 0.5f + 1e-3f);
                ++flipped;
                continue;
            }
            worst =
                std::max(worst, std::abs(static_cast<double>(accL.getValue(it.getCoord()) - *it)));
            ++n;
        }
        EXPECT_LT(flipped, 100u);
        EXPECT_GT(n, 100000u);
        EXPECT_LE(worst, 0.5 + 1e-3);
        std::printf(
            "round trip tilt %.0f noise %.0f HU: %zu voxels, largest |loaded - in-memory| = %.4f "
            "HU\n",
            cs.tiltDeg, cs.noiseHu, n, worst);
        // Away from edges the loaded grid equals the analytic truth.
        if (cs.noiseHu > 0) continue;
        const Phantom ph(spec.params);
        auto accD = direct.grid->getConstAccessor();
        for (const Vector3d& p :
             {Vector3d(centre(Phantom::avcHiddenBox(2))), Vector3d(mm(0, 11, 0)),
              Vector3d(mm(20, 40, -20)), Vector3d(mm(0, 30, 30))}) {
            const openvdb::Coord ijk = nearestVoxel(loaded.grid->transform(), p);
            EXPECT_NEAR(accL.getValue(ijk), ph.valueAt(p), 0.5 + 1e-3);
            EXPECT_NEAR(accD.getValue(ijk), ph.valueAt(p), 1e-3);
        }
    }
}

// ---------------------------------------------------------------- the tool

TEST(PhantomTool, VdbAndDicomEndToEnd) {
    const fs::path palp = palp::test::palpTool();
    ASSERT_TRUE(fs::exists(palp)) << "palp tool not built at " << palp;
    palp::test::TempDir tmp;
    const std::string vdb = (tmp / "avc.vdb").string();
    auto r = palp::test::runCommand(
        palp.string() + " phantom avc --quadrant 2 --voxel-size 2 --noise 10 --seed 3 -o " + vdb);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("palp phantom: wrote"), std::string::npos) << r.output;
    const Volume v = loadVdb(vdb);
    EXPECT_EQ(v.info.modality, "CT");
    EXPECT_EQ(v.info.sourceFormat, "phantom");
    EXPECT_NEAR(v.voxelSize(), 2e-3, 1e-12);
    EXPECT_NE(v.info.sourceDescription.find("quadrant=2"), std::string::npos);

    r = palp::test::runCommand(palp.string() +
                               " --quiet phantom avcec --shape pentagon --voxel-size 2 -o " +
                               (tmp / "q.vdb").string());
    EXPECT_EQ(r.exitCode, 0) << r.output;
    EXPECT_TRUE(r.output.empty()) << r.output;

    r = palp::test::runCommand(palp.string() + " phantom avc --quadrant 7 -o " +
                               (tmp / "x.vdb").string());
    EXPECT_NE(r.exitCode, 0);
    r = palp::test::runCommand(palp.string() + " phantom avc --tilt 10 -o " +
                               (tmp / "x.vdb").string());
    EXPECT_NE(r.exitCode, 0);
    EXPECT_NE(r.output.find("palp: error:"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(tmp / "x.vdb"));

    const std::string dir = (tmp / "dcm").string();
    r = palp::test::runCommand(
        palp.string() +
        " phantom bone --displacement 1 --voxel-size 2 --slice-spacing 3 --tilt 15 --dicom-dir " +
        dir);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_GT(listFiles(dir).size(), 30u);

    const std::string conv = (tmp / "conv.vdb").string();
    r = palp::test::runCommand(palp.string() + " convert " + dir + " -o " + conv);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    r = palp::test::runCommand(palp.string() + " info " + conv);
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("CT"), std::string::npos) << r.output;
}

}  // namespace
