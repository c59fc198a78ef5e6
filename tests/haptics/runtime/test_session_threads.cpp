// Session on its real-time thread: snapshot time stays monotonic across runs and offline
// steps (also when the loop skips deadlines), and a run with a viewer thread and a producer
// thread publishes complete snapshots and traces every tick exactly once.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <thread>

#include "palp/haptics/session.h"
#include "session_fixtures.h"
#include "session_test_fixture.h"

namespace palp::haptics {
namespace {

using namespace sfix;  // SessionTest, kModes, expectSafe, at, kT, PathDevice, touchX

// A device that stalls the servo thread for 15 ms every 50th tick, so the real-time loop
// overruns and skips deadlines (its nominal clock then runs ahead of ticks x T).
class StallingDevice final : public Device {
  public:
    DeviceState read() noexcept override {
        if (mTick++ % 50 == 25) std::this_thread::sleep_for(std::chrono::milliseconds(15));
        DeviceState s;
        s.position = at(0.0, -0.01, 0.0);  // in free space
        return s;
    }
    void write(const Eigen::Vector3d&) noexcept override {}
    const DeviceSpec& spec() const noexcept override { return touchX(); }

  private:
    std::atomic<std::uint64_t> mTick{0};
};

// Snapshot time never goes backwards across step / start / stop / step / start / stop / step,
// also when the real-time runs skipped deadlines; every tick is in the trace once, in order.
TEST_F(SessionTest, TimeIsMonotonicAcrossRunsAndSteps) {
    StallingDevice dev;
    SessionParams p = params(CouplingMode::VC);
    p.traceCapacity = 1u << 14;
    p.servo.priority = 0;
    Session session(sScene, dev, p);
    std::uint64_t skipped = 0;
    auto realtime = [&](std::uint64_t ticks) {
        const std::uint64_t before = session.stats().ticks;
        session.start();
        for (int i = 0; i < 5000 && session.stats().ticks < before + ticks; ++i)
            std::this_thread::sleep_for(std::chrono::milliseconds(1));
        session.stop();
        skipped = session.stats().skipped;
    };
    for (int i = 0; i < 100; ++i) session.step();
    realtime(80);
    EXPECT_GT(skipped, 0u) << "the stalls must make the loop skip deadlines";
    const double lastRun = session.latest().timeSeconds;
    const Snapshot& after = session.step();
    EXPECT_NEAR(after.timeSeconds, lastRun + kT, 1e-12);
    for (int i = 0; i < 49; ++i) session.step();
    realtime(80);
    for (int i = 0; i < 10; ++i) session.step();

    Snapshot t;
    std::uint64_t count = 0;
    double previous = -1;
    while (session.popTrace(t)) {
        ASSERT_EQ(t.tick, count) << "trace in order, none lost";
        ASSERT_GT(t.timeSeconds, previous) << "tick " << t.tick;
        ASSERT_GE(t.timeSeconds - previous, kT * (1 - 1e-9)) << "tick " << t.tick;
        previous = t.timeSeconds;
        ++count;
    }
    EXPECT_EQ(session.traceDropped(), 0u);
    EXPECT_GT(count, 100u + 80 + 50 + 80 + 10 - 1);
}

// A real-time run: a viewer thread reads latest() and the trace, a producer thread sends
// commands, the controlling thread starts and stops. Every published snapshot is complete
// (finite, bounded), latest() never goes back in time, and the trace holds every tick
// exactly once (popped + dropped = ticks).
TEST_F(SessionTest, RealTimeRunWithViewerAndProducer) {
    PathDevice dev(
        {{0, at(0.0, -0.003, 0.0)}, {0.15, at(0.0, 0.002, 0.0)}, {0.4, at(0.005, 0.002, 0.0)}});
    SessionParams p = params(CouplingMode::AVCEC);
    p.traceCapacity = 1024;
    p.crossFadeSeconds = 0.02;
    p.servo.priority = 0;  // no SCHED_FIFO request in a test
    Session session(sScene, dev, p);
    std::atomic<bool> done{false};
    std::uint64_t popped = 0, lastTraceTick = 0, viewerReads = 0;
    bool traceInOrder = true, viewerMonotonic = true, allSafe = true;
    std::thread viewer([&] {
        std::uint64_t lastSeen = 0;
        Snapshot t;
        while (!done.load(std::memory_order_acquire)) {
            const Snapshot& s = session.latest();
            if (s.tick < lastSeen) viewerMonotonic = false;
            lastSeen = s.tick;
            if (!s.force.allFinite() || s.force.norm() > touchX().maxForceN) allSafe = false;
            ++viewerReads;
            while (session.popTrace(t)) {
                if (popped > 0 && t.tick <= lastTraceTick) traceInOrder = false;
                lastTraceTick = t.tick;
                ++popped;
            }
            session.latestRays();
            std::this_thread::sleep_for(std::chrono::microseconds(200));
        }
    });
    std::atomic<int> sent{0};
    std::thread producer([&] {
        Command c;
        c.kind = Command::Kind::SetCoupling;
        c.coupling = p.coupling;
        for (int i = 0; !done.load(std::memory_order_acquire); ++i) {
            c.kind = static_cast<Command::Kind>(i % 4);
            c.coupling.mode = kModes[static_cast<std::size_t>(i % 3)];
            c.flag = (i % 2) == 0;
            if (session.send(c)) sent.fetch_add(1);
            std::this_thread::sleep_for(std::chrono::milliseconds(3));
        }
    });
    session.start();
    EXPECT_TRUE(session.running());
    EXPECT_FALSE(session.realtime().message.empty());
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    session.stop();
    EXPECT_FALSE(session.running());
    done.store(true, std::memory_order_release);
    viewer.join();
    producer.join();
    Snapshot t;
    while (session.popTrace(t)) {
        if (popped > 0 && t.tick <= lastTraceTick) traceInOrder = false;
        lastTraceTick = t.tick;
        ++popped;
    }
    const ServoStats stats = session.stats();
    EXPECT_GT(stats.ticks, 30u);
    EXPECT_EQ(popped + session.traceDropped(), stats.ticks);
    EXPECT_TRUE(traceInOrder);
    EXPECT_TRUE(viewerMonotonic);
    EXPECT_TRUE(allSafe);
    EXPECT_GT(viewerReads, 10u);
    EXPECT_GT(sent.load(), 10);
    EXPECT_EQ(session.latest().tick + 1, stats.ticks);
    // Offline steps continue where the run stopped.
    const Snapshot& next = session.step();
    EXPECT_EQ(next.tick, stats.ticks);
}

}  // namespace
}  // namespace palp::haptics
