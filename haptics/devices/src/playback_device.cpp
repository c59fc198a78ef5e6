#include "palp/haptics/devices/playback_device.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "palp/haptics/rendering/safety.h"

namespace palp::haptics {
namespace {

constexpr std::string_view kHeader = "t,x,y,z,vx,vy,vz,buttons,fx,fy,fz";
constexpr std::array<std::string_view, 11> kColumns = {"t",  "x",       "y",  "z",  "vx", "vy",
                                                       "vz", "buttons", "fx", "fy", "fz"};

std::string_view trim(std::string_view s) noexcept {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r')) {
        s.remove_suffix(1);
    }
    return s;
}

std::string formatDouble(double x) {
    std::array<char, 32> buffer{};
    std::snprintf(buffer.data(), buffer.size(), "%.17g", x);
    return buffer.data();
}

/// Shortens a quoted excerpt of bad input so a binary file does not flood the message.
std::string excerpt(std::string_view s) {
    constexpr std::size_t kMax = 60;
    std::string quoted(1, '\'');
    quoted.append(s.substr(0, kMax));
    if (s.size() > kMax) quoted.append("...");
    quoted.push_back('\'');
    return quoted;
}

[[noreturn]] void formatError(const std::filesystem::path& path, std::size_t line,
                              const std::string& what) {
    throw FormatError(path.string() + ":" + std::to_string(line) + ": " + what);
}

double parseDouble(std::string_view field, const std::filesystem::path& path, std::size_t line,
                   std::string_view column) {
    const std::string_view f = trim(field);
    double value = 0.0;
    const char* end = f.data() + f.size();
    const auto [ptr, ec] = std::from_chars(f.data(), end, value);
    if (f.empty() || ec != std::errc() || ptr != end) {
        formatError(
            path, line,
            "expected a number in column '" + std::string(column) + "', found " + excerpt(f));
    }
    if (!std::isfinite(value)) {
        formatError(path, line,
                    "expected a finite number in column '" + std::string(column) + "', found " +
                        excerpt(f));
    }
    return value;
}

std::uint32_t parseButtons(std::string_view field, const std::filesystem::path& path,
                           std::size_t line) {
    const std::string_view f = trim(field);
    std::uint32_t value = 0;
    const char* end = f.data() + f.size();
    const auto [ptr, ec] = std::from_chars(f.data(), end, value);
    if (f.empty() || ec != std::errc() || ptr != end) {
        formatError(path, line,
                    "expected an unsigned 32-bit integer in column 'buttons', found " + excerpt(f));
    }
    return value;
}

bool blank(std::string_view s) noexcept { return trim(s).empty(); }

std::ifstream openLog(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        throw IoError(path.string() +
                      ": cannot open device log for reading: " + std::strerror(errno));
    }
    return in;
}

}  // namespace

std::vector<DeviceSample> readDeviceLog(const std::filesystem::path& path, std::size_t maxRows) {
    if (std::filesystem::is_directory(path)) {
        throw IoError(path.string() + ": expected a device log file, found a directory");
    }
    // Pass 1: count the rows without storing any.
    std::size_t rows = 0;
    {
        std::ifstream in = openLog(path);
        std::string line;
        std::size_t lineNumber = 0;
        bool header = true;
        while (std::getline(in, line)) {
            ++lineNumber;
            if (header) {
                header = false;
                continue;
            }
            if (blank(line)) continue;
            if (++rows > maxRows) {
                formatError(path, lineNumber,
                            "expected at most " + std::to_string(maxRows) +
                                " rows, found more (refused before reading them)");
            }
        }
        if (in.bad()) throw IoError(path.string() + ": read error while counting rows");
    }

    std::ifstream in = openLog(path);
    std::string line;
    if (!std::getline(in, line)) {
        formatError(path, 1,
                    "expected the header '" + std::string(kHeader) + "', found an empty file");
    }
    if (trim(line) != kHeader) {
        formatError(path, 1,
                    "expected the header '" + std::string(kHeader) + "', found " + excerpt(line));
    }
    std::vector<DeviceSample> samples;
    samples.reserve(rows);
    std::size_t lineNumber = 1;
    std::array<std::string_view, kColumns.size()> fields;
    while (std::getline(in, line)) {
        ++lineNumber;
        if (blank(line)) continue;
        if (samples.size() == rows) {
            // The file grew between the passes.
            formatError(path, lineNumber,
                        "expected " + std::to_string(rows) +
                            " rows (counted on the first pass), found more");
        }
        std::string_view rest(line);
        std::size_t count = 0;
        while (true) {
            const std::size_t comma = rest.find(',');
            if (count < fields.size()) fields[count] = rest.substr(0, comma);
            ++count;
            if (comma == std::string_view::npos) break;
            rest.remove_prefix(comma + 1);
        }
        if (count != fields.size()) {
            formatError(path, lineNumber,
                        "expected " + std::to_string(fields.size()) +
                            " comma-separated columns, found " + std::to_string(count));
        }
        DeviceSample s;
        s.state.timestampSeconds = parseDouble(fields[0], path, lineNumber, kColumns[0]);
        for (int i = 0; i < 3; ++i) {
            const auto k = static_cast<std::size_t>(i);
            s.state.position[i] = parseDouble(fields[1 + k], path, lineNumber, kColumns[1 + k]);
            s.state.velocity[i] = parseDouble(fields[4 + k], path, lineNumber, kColumns[4 + k]);
            s.force[i] = parseDouble(fields[8 + k], path, lineNumber, kColumns[8 + k]);
        }
        s.state.buttons = parseButtons(fields[7], path, lineNumber);
        if (!samples.empty() &&
            !(s.state.timestampSeconds > samples.back().state.timestampSeconds)) {
            formatError(path, lineNumber,
                        "expected t strictly increasing (greater than " +
                            formatDouble(samples.back().state.timestampSeconds) + "), found " +
                            formatDouble(s.state.timestampSeconds));
        }
        samples.push_back(s);
    }
    if (in.bad()) throw IoError(path.string() + ": read error");
    return samples;
}

DeviceRecorder::DeviceRecorder(std::size_t capacity) : mRows(capacity) {}

bool DeviceRecorder::record(const DeviceState& state, const Eigen::Vector3d& force) noexcept {
    if (mSize >= mRows.size()) return false;
    DeviceSample& row = mRows[mSize++];
    row.state = state;
    row.force = force;
    return true;
}

void DeviceRecorder::write(const std::filesystem::path& path) const {
    // Refuse rows that readDeviceLog would refuse, before touching the disk.
    for (std::size_t i = 0; i < mSize; ++i) {
        const DeviceSample& s = mRows[i];
        const bool finite = std::isfinite(s.state.timestampSeconds) &&
                            s.state.position.allFinite() && s.state.velocity.allFinite() &&
                            s.force.allFinite();
        if (!finite) {
            throw ValueError(path.string() + ": row " + std::to_string(i + 1) +
                             ": expected finite numbers, found a NaN or infinity");
        }
        if (i > 0 && !(s.state.timestampSeconds > mRows[i - 1].state.timestampSeconds)) {
            throw ValueError(path.string() + ": row " + std::to_string(i + 1) +
                             ": expected t strictly increasing (greater than " +
                             formatDouble(mRows[i - 1].state.timestampSeconds) + "), found " +
                             formatDouble(s.state.timestampSeconds));
        }
    }

    // The rows go to a temporary file that replaces @p path only once complete; on any
    // failure the AtomicFile removes it, so nothing half-written is left behind.
    AtomicFile file(path, "device log");
    const std::filesystem::path& tmp = file.tempPath();
    std::FILE* out = std::fopen(tmp.c_str(), "wb");
    if (out == nullptr) {
        throw IoError(path.string() + ": cannot create temporary file " + tmp.string() + ": " +
                      std::strerror(errno));
    }
    bool ok = std::fprintf(out, "%.*s\n", static_cast<int>(kHeader.size()), kHeader.data()) > 0;
    // std::to_chars gives the shortest text that reads back to the same double, so the round
    // trip is exact and the file stays small (0.001 rather than 0.0010000000000000000208).
    std::array<char, 11 * 32> row{};
    for (std::size_t i = 0; ok && i < mSize; ++i) {
        const DeviceState& st = mRows[i].state;
        const Eigen::Vector3d& f = mRows[i].force;
        const std::array<double, 10> values = {
            st.timestampSeconds, st.position.x(), st.position.y(), st.position.z(), st.velocity.x(),
            st.velocity.y(),     st.velocity.z(), f.x(),           f.y(),           f.z()};
        char* p = row.data();
        char* const end = row.data() + row.size();
        for (std::size_t k = 0; k < values.size(); ++k) {
            if (k == 7) {  // the buttons column sits between velocity and force
                p = std::to_chars(p, end, st.buttons).ptr;
                *p++ = ',';
            }
            p = std::to_chars(p, end, values[k]).ptr;  // at most 24 characters each
            *p++ = (k + 1 == values.size()) ? '\n' : ',';
        }
        const auto length = static_cast<std::size_t>(p - row.data());
        ok = std::fwrite(row.data(), 1, length, out) == length;
    }
    const int writeErrno = ok ? 0 : errno;  // a stale errno from earlier calls must not show
    ok = (std::fflush(out) == 0) && ok;
    ok = (std::fclose(out) == 0) && ok;
    if (!ok) {
        throw IoError(path.string() + ": cannot write device log (via " + tmp.string() +
                      "): " + std::strerror(writeErrno != 0 ? writeErrno : errno));
    }
    file.commit();
}

PlaybackDevice::PlaybackDevice(const DeviceSpec& spec, std::vector<DeviceSample> log,
                               double periodSeconds)
    : mSpec(spec), mLog(std::move(log)), mPeriod(periodSeconds) {
    if (mLog.empty()) {
        throw ValueError("PlaybackDevice: expected at least one log sample, found none");
    }
    if (!(periodSeconds > 0.0) || !std::isfinite(periodSeconds)) {
        throw ValueError("PlaybackDevice: expected a positive period, found " +
                         formatDouble(periodSeconds) + " s");
    }
    for (std::size_t i = 0; i < mLog.size(); ++i) {
        const double t = mLog[i].state.timestampSeconds;
        if (!std::isfinite(t)) {
            throw ValueError("PlaybackDevice: log sample " + std::to_string(i) +
                             ": expected a finite time, found " + formatDouble(t));
        }
        if (i > 0 && !(t > mLog[i - 1].state.timestampSeconds)) {
            throw ValueError("PlaybackDevice: log sample " + std::to_string(i) +
                             ": expected t strictly increasing (greater than " +
                             formatDouble(mLog[i - 1].state.timestampSeconds) + "), found " +
                             formatDouble(t));
        }
    }
}

DeviceState PlaybackDevice::read() noexcept {
    const double t0 = mLog.front().state.timestampSeconds;
    const double t = t0 + static_cast<double>(mTick) * mPeriod;
    ++mTick;
    const double snap = 1e-6 * mPeriod;
    const std::size_t last = mLog.size() - 1;
    auto time = [this](std::size_t i) noexcept { return mLog[i].state.timestampSeconds; };

    // Advance the cursor to the last sample at or before t + snap: a few steps forward, then a
    // binary search over the rest (the log may be much denser than the playback period).
    constexpr int kLinearSteps = 8;
    for (int k = 0; k < kLinearSteps && mCursor < last && time(mCursor + 1) <= t + snap; ++k) {
        ++mCursor;
    }
    if (mCursor < last && time(mCursor + 1) <= t + snap) {
        const auto begin = mLog.begin() + static_cast<std::ptrdiff_t>(mCursor + 1);
        const auto it = std::upper_bound(
            begin, mLog.end(), t + snap,
            [](double value, const DeviceSample& s) { return value < s.state.timestampSeconds; });
        mCursor = static_cast<std::size_t>(it - mLog.begin()) - 1;
    }

    const DeviceSample& a = mLog[mCursor];
    if (std::abs(t - time(mCursor)) <= snap) {
        if (mCursor == last) mFinished = true;
        return a.state;
    }
    if (mCursor == last) {
        mFinished = true;
        DeviceState held = a.state;
        held.velocity.setZero();
        held.timestampSeconds = t;
        return held;
    }
    const DeviceSample& b = mLog[mCursor + 1];
    const double w = (t - time(mCursor)) / (time(mCursor + 1) - time(mCursor));
    DeviceState s;
    s.position = a.state.position + w * (b.state.position - a.state.position);
    s.velocity = a.state.velocity + w * (b.state.velocity - a.state.velocity);
    s.buttons = a.state.buttons;
    s.timestampSeconds = t;
    return s;
}

void PlaybackDevice::write(const Eigen::Vector3d& forceN) noexcept {
    mForce = clampForce(forceN, mSpec.maxForceN);
}

}  // namespace palp::haptics
