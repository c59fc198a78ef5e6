#pragma once
// Test fixtures shared by the Session tests: the device spec they run on and a kinematic
// device whose hand follows keyframes exactly.

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

#include "palp/haptics/devices/device.h"
#include "palp/haptics/scene.h"
#include "palp/volume/phantom.h"

namespace palp::haptics::fixtures {

/// Servo period of the fixtures' devices, s.
inline constexpr double kT = 1e-3;

/// The 3D Systems Touch X spec from palp's table.
inline const DeviceSpec& touchX() {
    const DeviceSpec* s = findDeviceSpec("3D Systems Touch X");
    EXPECT_NE(s, nullptr);
    return *s;
}

/// A point in the world (or device) frame, m.
inline Eigen::Vector3d at(double x, double y, double z) { return Eigen::Vector3d(x, y, z); }

/// Builds the AVC phantom (1 mm voxels) into @p volume and its scene (skin at -500 HU, hard
/// meshes at 500 HU) into @p scene, for a fixture's SetUpTestSuite. One TBB thread: the
/// set-up's parallel loops then run on this thread, so that the ThreadSanitizer build reports
/// only what the session's own threads do (volume's TBB hand-offs are not annotated for it).
/// The result does not depend on the threads.
inline void buildAvcScene(volume::Volume*& volume, std::shared_ptr<Scene>& scene) {
    tbb::task_arena single(1);
    single.execute([&] {
        volume::PhantomSpec spec;
        spec.params.scene = volume::PhantomScene::Avc;
        spec.voxelSize = 1e-3;
        volume = new volume::Volume(volume::makePhantomVolume(spec));
        SceneOptions options;
        options.surfaceIso = -500;
        options.hardIso = 500;
        scene = Scene::fromVolume(*volume, options);
    });
}

/// A kinematic device: the hand follows a piecewise-linear path through keyframes exactly (the
/// force does not move it), so every tick's probe is known; tick i reads the path at i kT.
/// Before the first key it rests at the first, after the last at the last; on a segment the
/// velocity is the segment's slope (zero at rest). Optionally it reports NaN positions for a
/// range of ticks. read() allocates nothing (the keys are stored at construction).
class PathDevice final : public Device {
  public:
    struct Key {
        double t;           ///< s
        Eigen::Vector3d p;  ///< m
    };
    explicit PathDevice(std::vector<Key> keys, const DeviceSpec& spec = touchX())
        : mSpec(spec), mKeys(std::move(keys)) {
        EXPECT_FALSE(mKeys.empty());
    }
    /// Ticks [from, to) read @p x as the x coordinate (NaN by default; any absurd value).
    void corrupt(std::uint64_t from, std::uint64_t to,
                 double x = std::numeric_limits<double>::quiet_NaN()) {
        mNanFrom = from;
        mNanTo = to;
        mBadX = x;
    }
    DeviceState read() noexcept override {
        const double t = static_cast<double>(mTick) * kT;
        DeviceState s;
        sample(t, s.position, s.velocity);
        if (mTick >= mNanFrom && mTick < mNanTo) {
            s.position.x() = mBadX;
        }
        s.timestampSeconds = t;
        ++mTick;
        mLast = s;
        return s;
    }
    void write(const Eigen::Vector3d& f) noexcept override { mForce = f; }
    const DeviceSpec& spec() const noexcept override { return mSpec; }

    /// The path's position (m) and velocity (m/s) at @p t (s).
    void sample(double t, Eigen::Vector3d& p, Eigen::Vector3d& v) const noexcept {
        v.setZero();
        if (t <= mKeys.front().t) {
            p = mKeys.front().p;
            return;
        }
        for (std::size_t i = 1; i < mKeys.size(); ++i) {
            if (t <= mKeys[i].t) {
                const double s = (t - mKeys[i - 1].t) / (mKeys[i].t - mKeys[i - 1].t);
                p = mKeys[i - 1].p + s * (mKeys[i].p - mKeys[i - 1].p);
                v = (mKeys[i].p - mKeys[i - 1].p) / (mKeys[i].t - mKeys[i - 1].t);
                return;
            }
        }
        p = mKeys.back().p;
    }
    /// The last sample read().
    const DeviceState& last() const { return mLast; }
    /// The last force written, N (device frame).
    const Eigen::Vector3d& force() const { return mForce; }
    /// Time of the last key, s.
    double endTime() const { return mKeys.back().t; }

  private:
    DeviceSpec mSpec;
    std::vector<Key> mKeys;
    std::uint64_t mTick = 0;
    std::uint64_t mNanFrom = std::numeric_limits<std::uint64_t>::max(), mNanTo = 0;
    double mBadX = std::numeric_limits<double>::quiet_NaN();
    DeviceState mLast;
    Eigen::Vector3d mForce{Eigen::Vector3d::Zero()};
};

}  // namespace palp::haptics::fixtures
