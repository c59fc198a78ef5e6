#pragma once
/// @file
/// Recorded device motion: a CSV log format, a recorder that writes it, and a device that
/// replays it.
///
/// CSV format (one header line, then one row per tick, SI units):
///   `t,x,y,z,vx,vy,vz,buttons,fx,fy,fz`
/// t in seconds (strictly increasing), position m, velocity m/s, buttons as an integer bit set,
/// the force rendered at that tick in N (ignored on playback).
///
/// Numbers are written in the shortest form that reads back to the same double (std::to_chars),
/// so a log reads back to exactly the doubles that were recorded. On reading, fields may carry
/// surrounding spaces, a trailing '\r' (CRLF files) is ignored, and blank lines are skipped;
/// numbers must be finite and buttons an unsigned 32-bit integer.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <vector>

#include "palp/haptics/devices/device.h"

namespace palp::haptics {

/// One recorded tick.
struct DeviceSample {
    DeviceState state;
    Eigen::Vector3d force{Eigen::Vector3d::Zero()};
};

/// Reads a device log. @throw palp::IoError (cannot open) or palp::FormatError naming the file,
/// the line and what was expected (wrong header, wrong column count, a non-number, time not
/// increasing) ; refuses files over @p maxRows rows before storing them.
/// The file is read twice (so it must be a regular file, not a pipe): once to count its rows
/// (nothing stored), then to parse them into a vector reserved to that count. A log with a header
/// and no rows gives an empty vector. Messages read `<file>:<line>: expected ..., found ...`.
std::vector<DeviceSample> readDeviceLog(const std::filesystem::path& path,
                                        std::size_t maxRows = 10'000'000);

/// Records samples into a preallocated buffer on the servo thread (record() is real-time
/// safe) and writes the CSV afterwards (temporary file renamed into place).
///
/// @par Threading
/// record() from one thread (the servo thread); write(), samples() and clear() from any thread
/// once recording has stopped (the caller orders the two, e.g. by joining the servo thread).
class DeviceRecorder {
  public:
    /// Allocates all @p capacity rows up front, so record() never allocates.
    explicit DeviceRecorder(std::size_t capacity);
    /// Appends one row (state.timestampSeconds is the t column); returns false (and drops it)
    /// when full. @par Real-time noexcept.
    bool record(const DeviceState& state, const Eigen::Vector3d& force) noexcept;
    std::size_t size() const noexcept { return mSize; }
    std::size_t capacity() const noexcept { return mRows.size(); }
    /// The rows recorded so far.
    std::span<const DeviceSample> samples() const noexcept { return {mRows.data(), mSize}; }
    /// Forgets the rows (keeps the capacity). @par Real-time noexcept.
    void clear() noexcept { mSize = 0; }
    /// Writes the header and the rows to a temporary file beside @p path (palp::AtomicFile),
    /// then renames it onto @p path, so @p path is either the old file or the complete new one.
    /// @throw palp::ValueError naming the file and row, before creating anything, when the rows
    /// would not read back (a non-finite number, time not strictly increasing).
    /// @throw palp::IoError naming the file when its directory is missing or it cannot be
    /// written or renamed (the temporary file is removed).
    void write(const std::filesystem::path& path) const;

  private:
    std::vector<DeviceSample> mRows;
    std::size_t mSize = 0;
};

/// Replays a log: each read() returns the next sample (linearly interpolated at the device's
/// own period when the log's rate differs), then holds the last one. write() stores the force
/// (appliedForce(), clamped to spec().maxForceN like SimulatedDevice) but does not change the
/// motion.
///
/// Timing: the n-th read() (n = 0, 1, ...) is at t_n = log[0].t + n periodSeconds. When t_n is
/// within 1e-6 periodSeconds of a log time, that sample is returned exactly (a log recorded
/// at the same period replays bit for bit despite rounding in the recorded times). Otherwise
/// position and velocity are interpolated linearly between the samples around t_n, buttons
/// come from the earlier one, and the timestamp is t_n. Once t_n is past the last sample, the
/// last position and buttons are held with zero velocity (a resting hand), timestamp t_n.
///
/// @par Threading
/// Like any Device: read() and write() from the servo thread only.
/// @par Real-time
/// read() and write() are noexcept and allocation-free; read() finds the next sample by a short
/// forward scan then binary search, O(log(samples per period)).
class PlaybackDevice final : public Device {
  public:
    /// @throw palp::ValueError for an empty log, a non-positive (or non-finite) period, or log
    /// times that are not finite and strictly increasing (naming the sample).
    PlaybackDevice(const DeviceSpec& spec, std::vector<DeviceSample> log, double periodSeconds);
    DeviceState read() noexcept override;
    void write(const Eigen::Vector3d& forceN) noexcept override;
    const DeviceSpec& spec() const noexcept override { return mSpec; }
    const Eigen::Vector3d& appliedForce() const noexcept { return mForce; }
    /// True once the last sample has been passed: read() has returned it (or a time after it).
    bool finished() const noexcept { return mFinished; }
    /// The log being replayed.
    std::span<const DeviceSample> log() const noexcept { return mLog; }

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
