// WatchdogDevice's judgement of each sample and its ramp. A NaN, a sample 20 km or 1e300 m away,
// one outside the workspace grown by its margin, a velocity or a jump no hand makes, a repeated
// one: each is flagged on the read it arrives, counts as missing (the force whole for the 2 ms
// grace, (10 - n) / 8 after n missing reads, zero from the 10th: one trip), and good samples
// bring the force back at 1/50 per read. Bad samples come back as they came (for the caller to
// refuse), repeated ones as the last good one held still. A spec without a workspace is checked
// against palp's 10 m world bound; bad parameters are refused by name; nothing allocates.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/watchdog_device.h"

namespace palp::haptics {
namespace {

constexpr double kT = 1e-3;

/// A device that returns whatever the test put in next, and keeps the force written.
struct Scripted final : Device {
    DeviceSpec s = *findDeviceSpec("3D Systems Touch X");  // x +-80, y +-60, z +-60 mm
    DeviceState next;
    Eigen::Vector3d written{Eigen::Vector3d::Zero()};
    DeviceState read() noexcept override { return next; }
    void write(const Eigen::Vector3d& f) noexcept override { written = f; }
    const DeviceSpec& spec() const noexcept override { return s; }
};

/// Good sample i: a hand moving along y at 10 mm/s from the origin, one sample per period.
DeviceState good(std::uint64_t i) {
    DeviceState d;
    d.position = Eigen::Vector3d(0.0, 1e-5 * static_cast<double>(i), 0.0);
    d.velocity = Eigen::Vector3d(0.0, 0.01, 0.0);
    d.sequence = i;
    d.timestampSeconds = static_cast<double>(i) * kT;
    return d;
}

/// The scale the ramp allows after @p n consecutive missing reads (grace 2, timeout 10).
double allowed(int n) { return n <= 2 ? 1.0 : std::max(0.0, (10.0 - n) / 8.0); }

struct Case {
    const char* name;
    std::function<DeviceState(std::uint64_t)> bad;  // the sample of read i during the fault
    std::uint32_t bit;                              // what health().faults must have
    bool asItCame;                                  // read() returns it (else the held one)
};

std::vector<Case> cases() {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    return {
        {"NaN x",
         [nan](std::uint64_t i) {
             DeviceState d = good(i);
             d.position.x() = nan;
             return d;
         },
         kFaultNonFinite, true},
        {"x 20 km",
         [](std::uint64_t i) {
             DeviceState d = good(i);
             d.position.x() = 2e4;
             return d;
         },
         kFaultOutOfRange, true},
        {"y 1e300 m",
         [](std::uint64_t i) {
             DeviceState d = good(i);
             d.position.y() = 1e300;
             return d;
         },
         kFaultOutOfRange, true},
        {"z 0.25 m (workspace 0.06 + margin 0.1)",
         [](std::uint64_t i) {
             DeviceState d = good(i);
             d.position.z() = 0.25;
             return d;
         },
         kFaultOutOfRange, true},
        {"velocity 50 m/s",
         [](std::uint64_t i) {
             DeviceState d = good(i);
             d.velocity.x() = 50;
             return d;
         },
         kFaultTooFast, true},
        {"jump 0.15 m in x",
         [](std::uint64_t i) {
             DeviceState d = good(i);
             d.position.x() = 0.15;
             return d;
         },
         kFaultTooFast, true},
        {"repeated sample", [](std::uint64_t) { return good(20); }, kFaultStale, false},
    };
}

TEST(WatchdogDevice, EachBadSampleIsFlaggedAtOnceAndRampsToZeroLikeAMissingOne) {
    for (const Case& c : cases()) {
        SCOPED_TRACE(c.name);
        Scripted inner;
        WatchdogDevice w(inner, WatchdogParams{}, kT);  // grace 2 ms, timeout 10 ms, resume 50
        std::uint64_t i = 1;
        for (; i <= 20; ++i) {
            inner.next = good(i);
            w.read();
            ASSERT_EQ(w.health().faults, 0u);
        }
        for (int n = 1; n <= 12; ++n, ++i) {
            inner.next = c.bad(i);
            const DeviceState d = w.read();
            const DeviceHealth h = w.health();
            EXPECT_TRUE(h.faults & c.bit) << "missing read " << n;  // on the very read
            EXPECT_TRUE(h.stale);
            EXPECT_EQ(h.staleTicks, static_cast<std::uint64_t>(n));
            EXPECT_NEAR(h.forceScale, allowed(n), 1e-12) << n;
            if (c.asItCame) {
                EXPECT_TRUE(d.position == inner.next.position ||
                            !inner.next.position.allFinite());  // NaN != NaN
            } else {
                EXPECT_EQ(d.position, good(20).position);
                EXPECT_EQ(d.velocity, Eigen::Vector3d::Zero());
            }
            w.write(Eigen::Vector3d(0, 0, 4));  // N: limited to scale x 7.9 N
            EXPECT_NEAR(inner.written.z(), std::min(4.0, allowed(n) * 7.9), 1e-12);
        }
        EXPECT_EQ(w.health().trips, 1u);
        EXPECT_EQ(inner.written.norm(), 0.0);
        // Good samples again (the hand's path went on meanwhile): back at 1/50 per read.
        for (int k = 1; k <= 60; ++k, ++i) {
            inner.next = good(i);
            w.read();
            ASSERT_EQ(w.health().faults, 0u) << k;
            EXPECT_NEAR(w.health().forceScale, std::min(1.0, 0.02 * k), 1e-12) << k;
        }
        EXPECT_EQ(w.health().trips, 1u);
    }
}

// A device that really did move 0.15 m during a glitch is taken as good again once 10 m/s could
// have carried the hand there since the last good sample: (n + 1) x 10 mm >= 150 mm at n = 14.
TEST(WatchdogDevice, ATooFastJumpIsMeasuredFromTheLastGoodSample) {
    Scripted inner;
    WatchdogDevice w(inner, WatchdogParams{}, kT);
    for (std::uint64_t i = 1; i <= 20; ++i) {
        inner.next = good(i);
        w.read();
    }
    int acceptedAt = -1;
    for (int n = 1; n <= 20 && acceptedAt < 0; ++n) {
        inner.next = good(20 + static_cast<std::uint64_t>(n));
        inner.next.position.x() = 0.15;
        w.read();
        if (w.health().faults == 0) acceptedAt = n;
    }
    EXPECT_EQ(acceptedAt, 15);  // reach (n + 1) x 10 mm: 150 mm reached by the 14th, 160 > 150.2
}

TEST(WatchdogDevice, ASpecWithoutWorkspaceIsCheckedAgainstPalpsWorldBound) {
    Scripted inner;
    inner.s.workspace = WorkspaceBox{};  // no volume: none given
    WatchdogDevice w(inner, WatchdogParams{}, kT);
    inner.next = good(1);
    inner.next.position.x() = 5.0;  // m: far outside any desktop device, inside palp's world
    w.read();
    EXPECT_EQ(w.health().faults, 0u);
    inner.next = good(2);
    inner.next.position.x() = 11.0;
    w.read();
    EXPECT_TRUE(w.health().faults & kFaultOutOfRange);
}

TEST(WatchdogDevice, BadParamsAreRefusedNamingTheField) {
    Scripted inner;
    const auto refused = [&](WatchdogParams p, const std::string& field) {
        try {
            WatchdogDevice w(inner, p, kT);
            ADD_FAILURE() << field;
        } catch (const ValueError& e) {
            EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
        }
    };
    WatchdogParams p;
    p.workspaceMarginMeters = -1;
    refused(p, "workspaceMarginMeters");
    p = {};
    p.maxSpeedMps = 0;
    refused(p, "maxSpeedMps");
    p.maxSpeedMps = std::numeric_limits<double>::quiet_NaN();
    refused(p, "maxSpeedMps");
}

TEST(WatchdogDevice, BadSamplesAllocateNothing) {
    Scripted inner;
    WatchdogDevice w(inner, WatchdogParams{}, kT);
    const std::vector<Case> all = cases();
    std::vector<DeviceState> samples;
    for (std::uint64_t i = 1; i < 400; ++i)
        samples.push_back(i % 40 < 20 ? good(i) : all[i % all.size()].bad(i));
    const std::uint64_t before = test::threadAllocationCount();
    for (const DeviceState& s : samples) {
        inner.next = s;
        w.read();
        w.write(Eigen::Vector3d(0, 1, 0));
    }
    EXPECT_EQ(test::threadAllocationCount() - before, 0u);
    EXPECT_GT(w.health().trips, 0u);
}

}  // namespace
}  // namespace palp::haptics
