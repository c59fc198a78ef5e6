// Device logs (playback_device.h): recording a simulated hand, the CSV format (exact round
// trip, errors that name the file and the line, no file left by a failed write), playback at
// the recorded and at other periods, and no allocation per recorded or played tick.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "alloc_counter.h"
#include "palp/base/error.h"
#include "palp/haptics/devices/playback_device.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/haptics/devices/trajectory.h"
#include "trajectory_fixtures.h"

namespace palp::haptics {
namespace {

using tfix::kT;
using tfix::touch;

class DeviceLog : public ::testing::Test {
  protected:
    void SetUp() override {
        mDir = std::filesystem::temp_directory_path() /
               ("palp_test_trajectory_" + std::to_string(::getpid()));
        std::filesystem::create_directories(mDir);
    }
    void TearDown() override { std::filesystem::remove_all(mDir); }

    std::filesystem::path write(const std::string& name, const std::string& text) {
        const std::filesystem::path p = mDir / name;
        std::ofstream(p, std::ios::binary) << text;
        return p;
    }
    /// Files in the directory other than @p keep.
    std::size_t strayFiles(const std::set<std::string>& keep) {
        std::size_t n = 0;
        for (const auto& e : std::filesystem::directory_iterator(mDir)) {
            if (!keep.count(e.path().filename().string())) ++n;
        }
        return n;
    }

    std::filesystem::path mDir;
};

/// Records @p ticks of a circling hand under a spring force, with changing buttons.
DeviceRecorder recordCircle(int ticks) {
    CircleTrajectory c;
    c.approachSeconds = 0.1;
    SimulatedDevice dev(touch(), c, HandModel{}, kT);
    DeviceRecorder rec(static_cast<std::size_t>(ticks));
    for (int n = 0; n < ticks; ++n) {
        DeviceState s = dev.read();
        s.buttons = static_cast<std::uint32_t>((n / 100) % 4);
        const Eigen::Vector3d f(0.0, -200.0 * std::max(0.0, s.position.y()), 0.0);
        dev.write(f);
        EXPECT_TRUE(rec.record(s, dev.appliedForce()));
    }
    return rec;
}

TEST_F(DeviceLog, RoundTripIsExactAndPlaybackReproducesTheRecording) {
    const DeviceRecorder rec = recordCircle(1500);
    ASSERT_EQ(rec.size(), 1500u);
    EXPECT_FALSE(DeviceRecorder(rec).record(DeviceState{}, Eigen::Vector3d::Zero()));  // full
    const std::filesystem::path path = mDir / "run.csv";
    rec.write(path);
    EXPECT_EQ(strayFiles({"run.csv"}), 0u);  // the temporary file was renamed away

    const std::vector<DeviceSample> log = readDeviceLog(path);
    ASSERT_EQ(log.size(), rec.size());
    for (std::size_t i = 0; i < log.size(); ++i) {
        const DeviceSample& a = rec.samples()[i];
        ASSERT_EQ(log[i].state.timestampSeconds, a.state.timestampSeconds) << i;
        ASSERT_EQ(log[i].state.position, a.state.position) << i;
        ASSERT_EQ(log[i].state.velocity, a.state.velocity) << i;
        ASSERT_EQ(log[i].state.buttons, a.state.buttons) << i;
        ASSERT_EQ(log[i].force, a.force) << i;
    }

    // Same period: every read() is the recorded state, bit for bit (recorded times are
    // n * 1e-3, which differ from t_0 + n * 1e-3 by rounding).
    PlaybackDevice play(touch(), log, kT);
    for (std::size_t i = 0; i < log.size(); ++i) {
        EXPECT_FALSE(play.finished());
        const DeviceState s = play.read();
        ASSERT_EQ(s.position, log[i].state.position) << i;
        ASSERT_EQ(s.velocity, log[i].state.velocity) << i;
        ASSERT_EQ(s.buttons, log[i].state.buttons) << i;
        ASSERT_EQ(s.timestampSeconds, log[i].state.timestampSeconds) << i;
        play.write(Eigen::Vector3d(0.0, 0.0, 10.0));
    }
    EXPECT_TRUE(play.finished());
    EXPECT_NEAR(play.appliedForce().z(), touch().maxForceN, 1e-12);  // clamped
    // Then it holds the last position, at rest, with time going on.
    const DeviceState held = play.read();
    EXPECT_EQ(held.position, log.back().state.position);
    EXPECT_EQ(held.velocity, Eigen::Vector3d::Zero());
    EXPECT_EQ(held.buttons, log.back().state.buttons);
    EXPECT_NEAR(held.timestampSeconds, log.back().state.timestampSeconds + kT, 1e-12);
}

TEST_F(DeviceLog, PlaybackAtAnotherPeriodInterpolates) {
    // A log at 1 ms of linear motion with a quadratic coordinate: linear interpolation
    // reproduces the linear one exactly and the quadratic one to h^2 / 8 curvature.
    std::vector<DeviceSample> log;
    for (int n = 0; n <= 1000; ++n) {
        DeviceSample s;
        const double t = 0.5 + n * kT;
        s.state.timestampSeconds = t;
        s.state.position = Eigen::Vector3d(0.01 + 0.02 * t, t * t, -0.03 * t);
        s.state.velocity = Eigen::Vector3d(0.02, 2.0 * t, -0.03);
        s.state.buttons = n < 500 ? 0u : 1u;
        log.push_back(s);
    }
    for (double period : {0.25e-3, 0.7e-3, 20e-3}) {  // finer, irregular, and coarse (search)
        PlaybackDevice play(touch(), log, period);
        int n = 0;
        while (!play.finished()) {
            const DeviceState s = play.read();
            const double t = 0.5 + n * period;
            ASSERT_NEAR(s.timestampSeconds, t, 1e-12);
            ++n;
            if (t > 1.5 + 1e-9) {  // past the last sample: held, at rest
                EXPECT_EQ(s.position, log.back().state.position);
                EXPECT_EQ(s.velocity, Eigen::Vector3d::Zero());
                continue;
            }
            ASSERT_NEAR(s.position.x(), 0.01 + 0.02 * t, 1e-15);
            ASSERT_NEAR(s.position.z(), -0.03 * t, 1e-15);
            ASSERT_NEAR(s.velocity.y(), 2.0 * t, 1e-12);
            // Interpolating t^2 over a 1 ms step overestimates by at most (1 ms)^2 / 4.
            EXPECT_LE(s.position.y() - t * t, 0.25 * kT * kT + 1e-15);
            EXPECT_GE(s.position.y() - t * t, -1e-15);
            // Buttons come from the sample at or before t.
            const int before = static_cast<int>(std::floor((t - 0.5) / kT + 1e-6));
            EXPECT_EQ(s.buttons, before < 500 ? 0u : 1u) << "t = " << t;
        }
        // The last read() is the last sample (1.5 s) or the first time past it.
        EXPECT_EQ(n, static_cast<int>(std::ceil(1.0 / period - 1e-6)) + 1) << period;
    }
}

TEST_F(DeviceLog, BadFilesNameTheFileAndTheLine) {
    const std::string header = "t,x,y,z,vx,vy,vz,buttons,fx,fy,fz\n";
    const std::string row1 = "0.001,0,0,0,0,0,0,0,0,0,0\n";
    struct Case {
        std::string name, text, line, what;
    };
    const std::vector<Case> cases = {
        {"empty.csv", "", ":1:", "header"},
        {"header.csv", "t,x,y,z,vx,vy,vz,fx,fy,fz\n" + row1, ":1:", "header"},
        {"few.csv", header + row1 + "0.002,0,0,0,0,0,0,0,0,0\n", ":3:", "11 comma-separated"},
        {"many.csv", header + "0.002,0,0,0,0,0,0,0,0,0,0,0\n", ":2:", "found 12"},
        {"word.csv", header + row1 + "0.002,0,abc,0,0,0,0,0,0,0,0\n", ":3:", "column 'y'"},
        {"empty_field.csv", header + "0.002,0,0,0,,0,0,0,0,0,0\n", ":2:", "column 'vx'"},
        {"nan.csv", header + row1 + "0.002,0,0,0,0,0,0,0,nan,0,0\n", ":3:", "finite"},
        {"inf.csv", header + "inf,0,0,0,0,0,0,0,0,0,0\n", ":2:", "finite"},
        {"buttons.csv", header + "0.002,0,0,0,0,0,0,-1,0,0,0\n", ":2:", "buttons"},
        {"equal_t.csv", header + row1 + row1, ":3:", "strictly increasing"},
        {"back_t.csv", header + row1 + "\n0.0005,0,0,0,0,0,0,0,0,0,0\n", ":4:", "increasing"},
        {"rows.csv", header + row1 + "0.002,0,0,0,0,0,0,0,0,0,0\n0.003,0,0,0,0,0,0,0,0,0,0\n",
         ":4:", "at most 2 rows"},
    };
    for (const Case& c : cases) {
        const std::filesystem::path p = write(c.name, c.text);
        try {
            (void)readDeviceLog(p, 2);
            ADD_FAILURE() << c.name << ": no error";
        } catch (const FormatError& e) {
            const std::string msg = e.what();
            EXPECT_NE(msg.find(p.string() + c.line), std::string::npos) << msg;
            EXPECT_NE(msg.find(c.what), std::string::npos) << msg;
            EXPECT_NE(msg.find("expected"), std::string::npos) << msg;
        }
    }
    EXPECT_THROW((void)readDeviceLog(mDir / "missing.csv"), IoError);
    EXPECT_THROW((void)readDeviceLog(mDir), IoError);

    // Accepted: CRLF, spaces around fields, blank lines, a header with no rows.
    const std::filesystem::path ok =
        write("ok.csv",
              "t,x,y,z,vx,vy,vz,buttons,fx,fy,fz\r\n 0.5 ,1e-3,2,3,4,5,6, 7 ,8,9,10\r\n"
              "\r\n0.75,-0,0,0,0,0,0,0,0,0,0\r\n");
    const std::vector<DeviceSample> log = readDeviceLog(ok, 2);
    ASSERT_EQ(log.size(), 2u);
    EXPECT_EQ(log[0].state.position.x(), 1e-3);
    EXPECT_EQ(log[0].state.buttons, 7u);
    EXPECT_EQ(log[0].force.z(), 10.0);
    EXPECT_EQ(log[1].state.timestampSeconds, 0.75);
    EXPECT_TRUE(readDeviceLog(write("none.csv", header)).empty());
}

TEST_F(DeviceLog, FailedWritesLeaveNoFile) {
    DeviceRecorder rec(4);
    DeviceState s;
    s.timestampSeconds = 0.001;
    rec.record(s, Eigen::Vector3d::Zero());
    EXPECT_THROW(rec.write(mDir / "no_such_dir" / "run.csv"), IoError);

    s.timestampSeconds = 0.001;  // not increasing
    rec.record(s, Eigen::Vector3d::Zero());
    const std::filesystem::path target = mDir / "run.csv";
    try {
        rec.write(target);
        ADD_FAILURE() << "no error";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("run.csv: row 2"), std::string::npos) << e.what();
    }
    DeviceRecorder nan(1);
    s.position.x() = std::nan("");
    nan.record(s, Eigen::Vector3d::Zero());
    EXPECT_THROW(nan.write(target), ValueError);
    EXPECT_EQ(strayFiles({}), 0u);  // neither the target nor a temporary file

    // A failed write keeps an earlier good file whole.
    DeviceRecorder good(1);
    s.position.x() = 0.25;
    good.record(s, Eigen::Vector3d::Zero());
    good.write(target);
    EXPECT_THROW(nan.write(target), ValueError);
    ASSERT_EQ(readDeviceLog(target).size(), 1u);
    EXPECT_EQ(readDeviceLog(target)[0].state.position.x(), 0.25);
    EXPECT_EQ(strayFiles({"run.csv"}), 0u);
}

TEST(PlaybackDevice, RefusesAnEmptyLogABadPeriodAndUnorderedTimes) {
    EXPECT_THROW(PlaybackDevice(touch(), {}, kT), ValueError);
    std::vector<DeviceSample> log(2);
    log[0].state.timestampSeconds = 0.0;
    log[1].state.timestampSeconds = 1.0;
    EXPECT_THROW(PlaybackDevice(touch(), log, 0.0), ValueError);
    EXPECT_THROW(PlaybackDevice(touch(), log, std::nan("")), ValueError);
    log[1].state.timestampSeconds = 0.0;
    EXPECT_THROW(PlaybackDevice(touch(), log, kT), ValueError);
    // One sample: returned, then held.
    log.resize(1);
    log[0].state.position = Eigen::Vector3d(1, 2, 3);
    PlaybackDevice one(touch(), log, kT);
    EXPECT_EQ(one.read().position, log[0].state.position);
    EXPECT_TRUE(one.finished());
    EXPECT_EQ(one.read().position, log[0].state.position);
}

TEST(DeviceLogRealTime, RecordReadAndWriteDoNotAllocate) {
    std::vector<DeviceSample> log(3000);
    for (std::size_t i = 0; i < log.size(); ++i) {
        log[i].state.timestampSeconds = 1e-4 * static_cast<double>(i);  // 10 kHz log
        log[i].state.position.x() = std::sin(1e-3 * static_cast<double>(i));
    }
    DeviceRecorder rec(2000);
    for (double period : {kT, 0.37e-3, 20e-3}) {
        PlaybackDevice play(touch(), log, period);
        Device& d = play;
        rec.clear();
        const std::uint64_t before = test::allocationCount();
        for (int n = 0; n < 2000; ++n) {
            const DeviceState s = d.read();
            d.write(Eigen::Vector3d(0.0, 1.0, 0.0));
            rec.record(s, play.appliedForce());
        }
        EXPECT_EQ(test::allocationCount(), before) << "period " << period;
        EXPECT_EQ(rec.size(), 2000u);
    }
}

}  // namespace
}  // namespace palp::haptics
