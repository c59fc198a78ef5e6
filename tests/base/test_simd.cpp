// The AVX2 switch (palp/base/simd.h): what the CPU says, unless PALP_SIMD turns it off. The
// suite runs this test again with PALP_SIMD=off (tests/base/CMakeLists.txt), together with the
// agreement tests of the FEM's AVX2 paths, so their portable paths run on AVX2 machines too.
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>

#include "palp/base/simd.h"

namespace {

bool cpuHas(const char* feature) {
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
    __builtin_cpu_init();
    if (std::strcmp(feature, "avx2") == 0) return __builtin_cpu_supports("avx2");
    if (std::strcmp(feature, "fma") == 0) return __builtin_cpu_supports("fma");
#endif
    (void)feature;
    return false;
}

TEST(Simd, FollowsTheCpuUnlessTurnedOff) {
    const char* env = std::getenv("PALP_SIMD");
    const bool off = env && (std::strcmp(env, "off") == 0 || std::strcmp(env, "0") == 0);
    EXPECT_EQ(palp::avx2Enabled(), !off && cpuHas("avx2"));
    EXPECT_EQ(palp::avx2FmaEnabled(), !off && cpuHas("avx2") && cpuHas("fma"));
    // Read once: the same answer every time.
    EXPECT_EQ(palp::avx2Enabled(), palp::avx2Enabled());
    std::printf("PALP_SIMD=%s: avx2 %d, avx2+fma %d\n", env ? env : "(unset)",
                palp::avx2Enabled() ? 1 : 0, palp::avx2FmaEnabled() ? 1 : 0);
}

}  // namespace
