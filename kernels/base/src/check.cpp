#include "palp/base/check.h"

#include <cstdio>
#include <cstdlib>

namespace palp::detail {

void checkFailed(const char* condition, const char* file, int line) noexcept {
    std::fprintf(stderr, "palp: internal check failed: %s (%s:%d)\n", condition, file, line);
    std::fflush(stderr);
    std::abort();
}

}  // namespace palp::detail
