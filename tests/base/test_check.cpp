#include <gtest/gtest.h>

#include "palp/base/check.h"

namespace palp {
namespace {

TEST(Check, PassingChecksDoNothing) {
    int evaluated = 0;
    PALP_CHECK(++evaluated == 1);
    EXPECT_EQ(evaluated, 1);  // PALP_CHECK evaluates its condition exactly once
    PALP_DCHECK(evaluated == 1);
}

TEST(CheckDeathTest, AFailedCheckAbortsNamingTheConditionAndPlace) {
    GTEST_FLAG_SET(death_test_style, "threadsafe");
    const int two = 2;
    EXPECT_DEATH(PALP_CHECK(two + two == 5),
                 "internal check failed: two \\+ two == 5 \\(.*test_check.cpp:[0-9]+\\)");
}

TEST(CheckDeathTest, DCheckFollowsNDebug) {
    GTEST_FLAG_SET(death_test_style, "threadsafe");
    int evaluated = 0;
#ifdef NDEBUG
    PALP_DCHECK(++evaluated == 5);  // compiled out: not even evaluated
    EXPECT_EQ(evaluated, 0);
#else
    EXPECT_DEATH(PALP_DCHECK(++evaluated == 5), "internal check failed");
#endif
}

}  // namespace
}  // namespace palp
