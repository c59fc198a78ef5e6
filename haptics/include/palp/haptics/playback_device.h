#pragma once
/// @file
/// Recorded device motion: a CSV log format, a recorder that writes it, and a device that
/// replays it.
///
/// CSV format (one header line, then one row per tick, SI units):
///   `t,x,y,z,vx,vy,vz,buttons,fx,fy,fz`
/// t in seconds (strictly increasing), position m, velocity m/s, buttons as an integer bit set,
/// the force rendered at that tick in N (ignored on playback).

#include <cstdint>
#include <filesystem>
#include <memory>
#include <vector>

#include "palp/haptics/device.h"

namespace palp::haptics {

/// One recorded tick.
struct DeviceSample {
    DeviceState state;
    Eigen::Vector3d force{Eigen::Vector3d::Zero()};
};

/// Reads a device log. @throw palp::IoError (cannot open) or palp::FormatError naming the file,
/// the line and what was expected (wrong header, wrong column count, a non-number, time not
/// increasing) ; refuses files over @p maxRows rows before storing them.
std::vector<DeviceSample> readDeviceLog(const std::filesystem::path& path,
                                        std::size_t maxRows = 10'000'000);

/// Records samples into a preallocated buffer on the servo thread (record() is real-time
/// safe) and writes the CSV afterwards (temporary file renamed into place).
class DeviceRecorder {
  public:
    explicit DeviceRecorder(std::size_t capacity);
    /// Appends one row; returns false (and drops it) when full. @par Real-time noexcept.
    bool record(const DeviceState& state, const Eigen::Vector3d& force) noexcept;
    std::size_t size() const noexcept { return mSize; }
    /// @throw palp::IoError naming the file.
    void write(const std::filesystem::path& path) const;

  private:
    std::vector<DeviceSample> mRows;
    std::size_t mSize = 0;
};

/// Replays a log: each read() returns the next sample (linearly interpolated at the device's
/// own period when the log's rate differs), then holds the last one. write() stores the force
/// (appliedForce()) but does not change the motion.
class PlaybackDevice final : public Device {
  public:
    /// @throw palp::ValueError for an empty log or a non-positive period.
    PlaybackDevice(const DeviceSpec& spec, std::vector<DeviceSample> log, double periodSeconds);
    DeviceState read() noexcept override;
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const DeviceSpec& spec() const noexcept override { return mSpec; }
    const Eigen::Vector3d& appliedForce() const noexcept { return mForce; }
    /// True once the last sample has been passed.
    bool finished() const noexcept { return mFinished; }

  private:
    DeviceSpec mSpec;
    std::vector<DeviceSample> mLog;
    double mPeriod;
    std::uint64_t mTick = 0;
    std::size_t mCursor = 0;
    bool mFinished = false;
    Eigen::Vector3d mForce{Eigen::Vector3d::Zero()};
};

}  // namespace palp::haptics
