#include <gtest/gtest.h>

#include "palp/kernels/trilinear.h"

namespace {

// A linear field is reproduced exactly by trilinear interpolation, anywhere between voxels.
TEST(Trilinear, ReproducesLinearFieldExactly) {
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(0.0f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(0.5e-3));
    auto f = [](double x, double y, double z) { return 3.0 * x - 2.0 * y + 0.5 * z + 7.0; };
    auto acc = grid->getAccessor();
    for (int i = -2; i < 12; ++i)
        for (int j = -2; j < 12; ++j)
            for (int k = -2; k < 12; ++k) acc.setValue({i, j, k}, static_cast<float>(f(i, j, k)));
    const auto cacc = grid->getConstAccessor();
    for (double x : {0.0, 0.25, 3.7, 8.99})
        for (double y : {0.1, 5.5})
            for (double z : {2.0, 7.3}) {
                EXPECT_NEAR(palp::kernels::sampleIndex(cacc, {x, y, z}), f(x, y, z), 1e-4);
                const openvdb::Vec3d w = grid->transform().indexToWorld(openvdb::Vec3d(x, y, z));
                EXPECT_NEAR(palp::kernels::sampleWorld(cacc, grid->transform(), w), f(x, y, z),
                            1e-4);
            }
}

TEST(Trilinear, BackgroundOutsideActiveVoxels) {
    openvdb::initialize();
    auto grid = openvdb::FloatGrid::create(-1000.0f);
    grid->tree().setValue({0, 0, 0}, 1000.0f);
    const auto cacc = grid->getConstAccessor();
    EXPECT_FLOAT_EQ(palp::kernels::sampleIndex(cacc, {0.5, 0, 0}), 0.0f);
    EXPECT_FLOAT_EQ(palp::kernels::sampleIndex(cacc, {5, 5, 5}), -1000.0f);
}

}  // namespace
