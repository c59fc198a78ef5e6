// Volumes from memory (palp::volume::fromMemory, palp_volume_from_memory): a buffer with the
// geometry of a NRRD file gives the reader's grid voxel for voxel (same transform, same
// values) for an oblique LPS and a RAS affine, in metres or millimetres, packed or strided,
// from every value type; bad dims, strides, affines, types and values are refused naming them.

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/palp.h"
#include "palp/volume/from_memory.h"
#include "palp/volume/load.h"

namespace fs = std::filesystem;
namespace pv = palp::volume;

namespace {

constexpr std::int64_t kNx = 7, kNy = 6, kNz = 5;

std::int16_t value(std::int64_t i, std::int64_t j, std::int64_t k) {
    return static_cast<std::int16_t>(10 * i - 20 * j + 37 * k - 100 + (i * j) % 7);
}

std::vector<std::int16_t> packed() {
    std::vector<std::int16_t> v;
    for (std::int64_t k = 0; k < kNz; ++k)
        for (std::int64_t j = 0; j < kNy; ++j)
            for (std::int64_t i = 0; i < kNx; ++i) v.push_back(value(i, j, k));
    return v;
}

/// Index to LPS millimetres: spacing 0.8, 1.1, 1.5 mm, turned 20 degrees about z and 10 about x.
Eigen::Matrix4d lpsMm() {
    const Eigen::Matrix3d r = (Eigen::AngleAxisd(20 * M_PI / 180, Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(10 * M_PI / 180, Eigen::Vector3d::UnitX()))
                                  .toRotationMatrix();
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = r * Eigen::Vector3d(0.8, 1.1, 1.5).asDiagonal();
    m.topRightCorner<3, 1>() = Eigen::Vector3d(10, -20, 30);
    return m;
}

Eigen::Matrix4d toRas(Eigen::Matrix4d m) {
    m.row(0) *= -1;
    m.row(1) *= -1;
    return m;
}

/// A NRRD with @p m (index to @p space, mm) and the packed int16 values.
fs::path writeNrrd(const std::string& file, const char* space, const Eigen::Matrix4d& m) {
    const fs::path p = fs::temp_directory_path() / ("palp_from_memory_" + file);
    std::ofstream o(p, std::ios::binary);
    o.precision(17);
    o << "NRRD0004\ntype: short\ndimension: 3\nspace: " << space << "\nsizes: " << kNx << " " << kNy
      << " " << kNz << "\nspace directions:";
    for (int c = 0; c < 3; ++c) o << " (" << m(0, c) << "," << m(1, c) << "," << m(2, c) << ")";
    o << "\nspace origin: (" << m(0, 3) << "," << m(1, 3) << "," << m(2, 3)
      << ")\nendian: little\nencoding: raw\n\n";
    const std::vector<std::int16_t> v = packed();
    o.write(reinterpret_cast<const char*>(v.data()),
            static_cast<std::streamsize>(v.size() * sizeof(std::int16_t)));
    return p;
}

pv::ResampleOptions options() {
    pv::ResampleOptions o;
    o.voxelSize = 0.7e-3;
    return o;
}

pv::Volume loadFile(const fs::path& p) {
    pv::LoadOptions o;
    o.resample = options();
    pv::Volume v = pv::load({p}, o);
    fs::remove(p);
    return v;
}

pv::MemoryGrid grid(const void* data, pv::ValueType type, const Eigen::Matrix4d& m,
                    pv::WorldFrame frame) {
    pv::MemoryGrid g;
    g.data = data;
    g.type = type;
    g.dims = {kNx, kNy, kNz};
    g.indexToWorld = m;
    g.frame = frame;
    return g;
}

/// Same transform and the same active voxels with the same values (exactly: one pipeline).
void expectSameGrid(const pv::Volume& a, const pv::Volume& b) {
    ASSERT_TRUE(a.grid && b.grid);
    EXPECT_EQ(a.grid->transform(), b.grid->transform());
    EXPECT_EQ(a.grid->activeVoxelCount(), b.grid->activeVoxelCount());
    EXPECT_GT(a.grid->activeVoxelCount(), 200u);  // 284 in the oblique 7 x 6 x 5 grid
    EXPECT_EQ(a.grid->background(), b.grid->background());
    auto acc = b.grid->getConstAccessor();
    std::size_t differ = 0;
    for (auto it = a.grid->cbeginValueOn(); it; ++it) {
        if (!acc.isValueOn(it.getCoord()) || acc.getValue(it.getCoord()) != *it) ++differ;
    }
    EXPECT_EQ(differ, 0u);
}

std::string refusal(const pv::MemoryGrid& g) {
    try {
        pv::fromMemory(g, options());
    } catch (const palp::ValueError& e) {
        return e.what();
    }
    return "(accepted)";
}

}  // namespace

TEST(FromMemory, EqualsTheNrrdReaderInLpsAndRas) {
    const std::vector<std::int16_t> v = packed();
    const pv::Volume lpsFile = loadFile(writeNrrd("lps.nrrd", "left-posterior-superior", lpsMm()));
    const pv::Volume rasFile =
        loadFile(writeNrrd("ras.nrrd", "right-anterior-superior", toRas(lpsMm())));
    const pv::Volume lps = pv::fromMemory(
        grid(v.data(), pv::ValueType::Int16, lpsMm(), pv::WorldFrame::LpsMillimetres), options());
    const pv::Volume ras = pv::fromMemory(
        grid(v.data(), pv::ValueType::Int16, toRas(lpsMm()), pv::WorldFrame::RasMillimetres),
        options());
    expectSameGrid(lpsFile, lps);
    expectSameGrid(rasFile, ras);
    expectSameGrid(lps, ras);  // one physical grid, two frames
    // The same grid given in metres.
    Eigen::Matrix4d metres = lpsMm();
    metres.topRows<3>() *= 1e-3;
    const pv::Volume m = pv::fromMemory(
        grid(v.data(), pv::ValueType::Int16, metres, pv::WorldFrame::LpsMetres), options());
    expectSameGrid(lps, m);
    // World position (LPS m): the active voxels' box is centred on the grid's centre, the
    // affine at index (3, 2.5, 2), within two 0.7 mm voxels (measured: 1.1 mm along z, where
    // the lattice cuts the oblique slab unevenly; a frame mix-up moves it by cm).
    const Eigen::Vector3d centre = (metres * Eigen::Vector4d(3, 2.5, 2, 1)).head<3>();
    const openvdb::BBoxd b = ras.worldBounds();
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(0.5 * (b.min()[i] + b.max()[i]), centre[i], 1.4e-3);
    EXPECT_EQ(lps.info.sourceFormat, "memory");
}

TEST(FromMemory, StridesAndTypesGiveTheSameGrid) {
    const std::vector<std::int16_t> v = packed();
    const pv::Volume ref = pv::fromMemory(
        grid(v.data(), pv::ValueType::Int16, lpsMm(), pv::WorldFrame::LpsMillimetres), options());
    // k fastest, rows padded by 4 bytes: offset = i s0 + j s1 + k s2.
    const std::int64_t s2 = 2, s1 = 2 * kNz + 4, s0 = s1 * kNy;
    std::vector<unsigned char> buf(static_cast<std::size_t>(s0 * kNx));
    for (std::int64_t k = 0; k < kNz; ++k)
        for (std::int64_t j = 0; j < kNy; ++j)
            for (std::int64_t i = 0; i < kNx; ++i) {
                const std::int16_t x = value(i, j, k);
                std::memcpy(buf.data() + i * s0 + j * s1 + k * s2, &x, 2);
            }
    pv::MemoryGrid g =
        grid(buf.data(), pv::ValueType::Int16, lpsMm(), pv::WorldFrame::LpsMillimetres);
    g.strides = {s0, s1, s2};
    expectSameGrid(ref, pv::fromMemory(g, options()));

    std::vector<double> f64(v.begin(), v.end());
    std::vector<float> f32(v.begin(), v.end());
    std::vector<std::int32_t> i32(v.begin(), v.end());
    expectSameGrid(ref, pv::fromMemory(grid(f64.data(), pv::ValueType::Float64, lpsMm(),
                                            pv::WorldFrame::LpsMillimetres),
                                       options()));
    expectSameGrid(ref, pv::fromMemory(grid(f32.data(), pv::ValueType::Float32, lpsMm(),
                                            pv::WorldFrame::LpsMillimetres),
                                       options()));
    expectSameGrid(ref, pv::fromMemory(grid(i32.data(), pv::ValueType::Int32, lpsMm(),
                                            pv::WorldFrame::LpsMillimetres),
                                       options()));
    // Unsigned types: the values shifted by +300 stay positive; u16 and u8 agree where u8 fits.
    std::vector<std::uint16_t> u16;
    std::vector<std::uint8_t> u8;
    for (const std::int16_t x : v) {
        u16.push_back(static_cast<std::uint16_t>(x + 300));
        u8.push_back(static_cast<std::uint8_t>((x + 300) / 4));
    }
    std::vector<std::uint16_t> u8as16(u8.begin(), u8.end());
    expectSameGrid(pv::fromMemory(grid(u8as16.data(), pv::ValueType::UInt16, lpsMm(),
                                       pv::WorldFrame::LpsMillimetres),
                                  options()),
                   pv::fromMemory(grid(u8.data(), pv::ValueType::UInt8, lpsMm(),
                                       pv::WorldFrame::LpsMillimetres),
                                  options()));
}

TEST(FromMemory, RefusesNamingTheValue) {
    const std::vector<std::int16_t> v = packed();
    const auto base = [&] {
        pv::MemoryGrid g =
            grid(v.data(), pv::ValueType::Int16, lpsMm(), pv::WorldFrame::LpsMillimetres);
        g.name = "host";
        return g;
    };
    pv::MemoryGrid g = base();
    g.indexToWorld(0, 1) = std::nan("");
    EXPECT_NE(refusal(g).find("host: index_to_world[0][1]: expected a finite"), std::string::npos)
        << refusal(g);
    g = base();
    g.indexToWorld.col(1) = g.indexToWorld.col(0);  // parallel axes: singular
    g.indexToWorld(3, 1) = 0;
    EXPECT_NE(refusal(g).find("three independent axis directions"), std::string::npos)
        << refusal(g);
    g = base();
    g.indexToWorld(3, 0) = 0.5;
    EXPECT_NE(refusal(g).find("index_to_world[3][0]: expected 0"), std::string::npos);
    g = base();
    g.dims[1] = 0;
    EXPECT_NE(refusal(g).find("host: dims[1]: expected a size in 1..2147483647, found 0"),
              std::string::npos);
    g.dims[1] = -3;
    EXPECT_NE(refusal(g).find("found -3"), std::string::npos);
    g = base();
    g.dims = {2000000000, 2000000000, 2000000000};
    EXPECT_NE(refusal(g).find("host: expected at most"), std::string::npos) << refusal(g);
    g = base();
    g.strides = {2, 2, 2 * kNx * kNy};
    EXPECT_NE(refusal(g).find("host: strides[1]: expected at least 14 bytes"), std::string::npos)
        << refusal(g);
    g.strides = {1, 14, 84};
    EXPECT_NE(refusal(g).find("strides[0]: expected at least 2 bytes"), std::string::npos)
        << refusal(g);
    g.strides = {-2, 14, 84};
    EXPECT_NE(refusal(g).find("strides[0]: expected a positive byte stride"), std::string::npos);
    g.strides = {2, 14, 40};  // the slices overlap
    EXPECT_NE(refusal(g).find("strides[2]: expected at least 84 bytes"), std::string::npos)
        << refusal(g);
    g = base();
    g.type = static_cast<pv::ValueType>(42);
    EXPECT_NE(refusal(g).find("host: type: expected int8, uint8"), std::string::npos);
    EXPECT_NE(refusal(g).find("found 42"), std::string::npos);
    g = base();
    g.indexToWorld.topLeftCorner<3, 3>() *= 1e3;  // 0.8 m voxels
    EXPECT_NE(refusal(g).find("host: index_to_world (axis columns) (axis 0 step)"),
              std::string::npos)
        << refusal(g);
    std::vector<float> nan(v.begin(), v.end());
    nan[3 + kNx * 2] = std::nanf("");
    g = base();
    g.data = nan.data();
    g.type = pv::ValueType::Float32;
    EXPECT_NE(refusal(g).find("host: voxel (column 3, row 2, slice 0)"), std::string::npos)
        << refusal(g);
}

TEST(FromMemory, CApi) {
    const std::vector<std::int16_t> v = packed();
    const std::int64_t dims[3] = {kNx, kNy, kNz};
    double m[16];
    const Eigen::Matrix4d ras = toRas(lpsMm());
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) m[4 * r + c] = ras(r, c);
    palp_volume* volume = nullptr;
    ASSERT_EQ(palp_volume_from_memory(v.data(), PALP_VALUE_I16, dims, nullptr, m, PALP_FRAME_RAS_MM,
                                      0.7e-3, &volume),
              PALP_OK)
        << palp_last_error();
    const pv::Volume file = loadFile(writeNrrd("capi.nrrd", "left-posterior-superior", lpsMm()));
    double size = 0, lo[3], hi[3];
    ASSERT_EQ(palp_volume_geometry(volume, &size, lo, hi), PALP_OK);
    EXPECT_DOUBLE_EQ(size, file.voxelSize());
    const openvdb::BBoxd b = file.worldBounds();
    for (int i = 0; i < 3; ++i) {
        EXPECT_DOUBLE_EQ(lo[i], b.min()[i]);
        EXPECT_DOUBLE_EQ(hi[i], b.max()[i]);
    }
    palp_volume_release(volume);
    volume = nullptr;
    std::int64_t strides[3] = {2, 2, 84};
    EXPECT_EQ(palp_volume_from_memory(v.data(), PALP_VALUE_I16, dims, strides, m, PALP_FRAME_RAS_MM,
                                      0, &volume),
              PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("palp_volume_from_memory: strides[1]"),
              std::string::npos)
        << palp_last_error();
    palp_value_type bad;
    const int fortyTwo = 42;
    std::memcpy(&bad, &fortyTwo, sizeof bad);
    EXPECT_EQ(
        palp_volume_from_memory(v.data(), bad, dims, nullptr, m, PALP_FRAME_RAS_MM, 0, &volume),
        PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("type: expected PALP_VALUE_I8"),
              std::string::npos);
    EXPECT_EQ(palp_volume_from_memory(v.data(), PALP_VALUE_I16, dims, nullptr, m, PALP_FRAME_RAS_MM,
                                      -1, &volume),
              PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_EQ(volume, nullptr);
}
