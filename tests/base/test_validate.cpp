#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp {
namespace {

std::string messageOf(void (*f)()) {
    try {
        f();
    } catch (const ValueError& e) {
        return e.what();
    }
    return "(no error)";
}

TEST(Validate, MessagesNameTheThingTheRequirementAndTheValue) {
    EXPECT_EQ(messageOf([] { requirePositive("--depth", -1.5, "mm"); }),
              "--depth: expected a finite value > 0 mm, found -1.5");
    EXPECT_EQ(messageOf([] { requireFinite("centre.x", std::nan("")); }),
              "centre.x: expected a finite value, found nan");
    EXPECT_EQ(messageOf([] { requireNonNegative("damping", -2); }),
              "damping: expected a finite value >= 0, found -2");
    EXPECT_EQ(messageOf([] { requireAtLeast("maxMultiplier", 0.5, 1); }),
              "maxMultiplier: expected a finite value >= 1, found 0.5");
    EXPECT_EQ(messageOf([] { requireInRange("nu", 0.7, 0, 0.5); }),
              "nu: expected a value in [0, 0.5], found 0.7");
    EXPECT_EQ(messageOf([] { throwExpected("scan.nrrd", "3 sizes", "'64 0'"); }),
              "scan.nrrd: expected 3 sizes, found '64 0'");
}

TEST(Validate, RefusesEveryNonFiniteValueAndAcceptsTheBoundaries) {
    const double inf = std::numeric_limits<double>::infinity();
    for (double bad : {std::nan(""), inf, -inf}) {
        EXPECT_THROW(requireFinite("v", bad), ValueError);
        EXPECT_THROW(requirePositive("v", bad), ValueError);
        EXPECT_THROW(requireNonNegative("v", bad), ValueError);
        EXPECT_THROW(requireAtLeast("v", bad, -1e300), ValueError);
        EXPECT_THROW(requireInRange("v", bad, -1e300, 1e300), ValueError);
    }
    EXPECT_THROW(requirePositive("v", 0), ValueError);
    EXPECT_NO_THROW(requirePositive("v", 1e-300));
    EXPECT_NO_THROW(requireNonNegative("v", 0));
    EXPECT_NO_THROW(requireAtLeast("v", 1, 1));
    EXPECT_NO_THROW(requireInRange("v", 0.5, 0, 0.5));
    EXPECT_EQ(formatValue(1e300), "1e+300");
    EXPECT_EQ(formatValue(-std::numeric_limits<double>::infinity()), "-inf");
}

TEST(Bounds, RefuseNonFiniteAndAbsurdValuesShowingTheCallersUnit) {
    const double inf = std::numeric_limits<double>::infinity();
    for (double bad : {std::nan(""), inf, -inf, 1e300, -1e300}) {
        EXPECT_THROW(requireWithin("v", bad, bounds::kPosition), ValueError);
        EXPECT_FALSE(bounds::kStiffness.contains(bad));
    }
    EXPECT_EQ(messageOf([] {
                  requireWithin("--depth", 1e297, bounds::kSpan, {1e3, "mm"});
              }),
              "--depth: expected a value in [0, 10000] mm, found 1e+300");
    EXPECT_EQ(messageOf([] { requireWithin("speed", 0, bounds::kPositiveSpeed); }),
              "speed: expected a value in (0, 10] m/s, found 0");
    EXPECT_EQ(messageOf([] { requireWithin("poisson", 0.5, bounds::kPoissonRatio); }),
              "poisson: expected a value in (-1, 0.5), found 0.5");
    // Closed ends are accepted, open ones refused.
    EXPECT_NO_THROW(requireWithin("v", 0, bounds::kSpan));
    EXPECT_NO_THROW(requireWithin("v", 10, bounds::kLength));
    EXPECT_THROW(requireWithin("v", 0, bounds::kLength), ValueError);
    EXPECT_THROW(requireWithin("v", -1, bounds::kPoissonRatio), ValueError);
}

}  // namespace
}  // namespace palp
