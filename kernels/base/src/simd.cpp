#include "palp/base/simd.h"

#include <cstdlib>
#include <cstring>

namespace palp {

namespace {
bool turnedOff() noexcept {
    const char* env = std::getenv("PALP_SIMD");
    return env && (std::strcmp(env, "off") == 0 || std::strcmp(env, "0") == 0);
}

#if (defined(__x86_64__) || defined(__i386__)) && (defined(__GNUC__) || defined(__clang__))
bool cpuHas(bool fma) noexcept {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && (!fma || __builtin_cpu_supports("fma"));
}
#else
bool cpuHas(bool) noexcept { return false; }
#endif
}  // namespace

bool avx2Enabled() noexcept {
    static const bool enabled = !turnedOff() && cpuHas(false);
    return enabled;
}

bool avx2FmaEnabled() noexcept {
    static const bool enabled = !turnedOff() && cpuHas(true);
    return enabled;
}

}  // namespace palp
