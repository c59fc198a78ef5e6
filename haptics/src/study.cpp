#include "palp/haptics/study.h"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <type_traits>

#include "palp/base/error.h"

#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STBI_WRITE_NO_STDIO
#include <stb/stb_image_write.h>

namespace palp::haptics {

namespace fs = std::filesystem;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

CouplingParams commonDefaults() {
    CouplingParams p;
    p.mode = CouplingMode::AVC;
    p.source = RaySource::VolumeFirstHit;
    p.bundle.length = 0.040;
    p.bundle.ringCount = 0;
    p.bundle.sobelAngle = 0.1;
    p.bundle.surfaceOffset = 1e-3;
    p.firstHit.threshold = 500;
    p.firstHit.step = 0.5e-3;
    p.accumulate.sigma = kernels::TransferFunction::step(500.0f, 1000.0f);
    p.accumulate.tauStop = 3;
    p.accumulate.step = 0.5e-3;
    p.baseStiffness = 300;
    p.referenceLength = 0.040;
    p.maxMultiplier = 8;
    p.maxStiffness = 2400;
    return p;
}

// Writes @p bytes to a temporary file next to @p path, then renames it into place.
void writeFileAtomically(const fs::path& path, const std::string& what, const char* data,
                         std::size_t size) {
    const fs::path dir = path.has_parent_path() ? path.parent_path() : fs::path(".");
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) {
        throw IoError(path.string() + ": expected an existing directory '" + dir.string() +
                      "' for the " + what + ", found none");
    }
    fs::path tmp = path;
    tmp += ".tmp" + std::to_string(::getpid());
    {
        std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
        if (!out) throw IoError(tmp.string() + ": cannot open for writing the " + what);
        out.write(data, static_cast<std::streamsize>(size));
        out.close();
        if (!out) {
            fs::remove(tmp, ec);
            throw IoError(tmp.string() + ": expected to write " + std::to_string(size) +
                          " bytes of the " + what + ", the write failed");
        }
    }
    fs::rename(tmp, path, ec);
    if (ec) {
        std::error_code ignored;
        fs::remove(tmp, ignored);
        throw IoError(path.string() + ": could not rename the finished " + what +
                      " into place: " + ec.message());
    }
}

bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }

// Pressing on a surface: the proxy is held back from the probe (D above 1 um) or sits on a
// constraint. The distance also counts ticks in which the proxy changes constraint planes.
bool inContact(const Snapshot& s) { return s.contactCount > 0 || s.distance > 1e-6; }

}  // namespace

// ---------------------------------------------------------------------------------------------

CouplingParams sceneCouplingDefaults(volume::PhantomScene scene) {
    CouplingParams p = commonDefaults();
    switch (scene) {
        case volume::PhantomScene::Avc:
            p.mode = CouplingMode::AVC;
            p.source = RaySource::VolumeAccumulate;
            break;
        case volume::PhantomScene::Avcec:
            p.mode = CouplingMode::AVCEC;
            p.referenceLength = 0.020;
            break;
        case volume::PhantomScene::Bone:
            p.mode = CouplingMode::AVCEC;
            break;
        case volume::PhantomScene::Stiffness:
            p.mode = CouplingMode::AVC;
            p.firstHit.threshold = 200;
            break;
    }
    return p;
}

CouplingParams scanCouplingDefaults() {
    CouplingParams p = commonDefaults();
    p.firstHit.threshold = 300;
    return p;
}

CouplingParams clampToDevice(CouplingParams params, const DeviceSpec& device,
                             double periodSeconds) {
    double limit = params.maxStiffness;
    if (device.maxStiffnessNpm > 0) limit = std::min(limit, device.maxStiffnessNpm);
    if (device.maxDampingNspm > 0 && periodSeconds > 0) {
        // Colgate's sampled-wall bound b > k T / 2: stay 10 % inside it.
        limit = std::min(limit, 0.9 * 2.0 * device.maxDampingNspm / periodSeconds);
    }
    params.maxStiffness = limit;
    params.baseStiffness = std::min(params.baseStiffness, limit);
    return params;
}

// ---------------------------------------------------------------------------------------------

std::vector<Snapshot> runOffline(Session& session, std::uint64_t ticks, std::uint64_t every) {
    if (every == 0) {
        throw ValueError("runOffline: expected a snapshot interval 'every' >= 1, found 0");
    }
    std::vector<Snapshot> out;
    out.reserve(static_cast<std::size_t>(ticks / every + 1));
    for (std::uint64_t i = 0; i < ticks; ++i) {
        const Snapshot& s = session.step();
        if (i % every == 0 || i + 1 == ticks) out.push_back(s);
    }
    return out;
}

double trajectoryDuration(const Trajectory& trajectory, int passes) noexcept {
    const double n = std::max(passes, 1);
    return std::visit(
        [n](const auto& t) -> double {
            using T = std::decay_t<decltype(t)>;
            if constexpr (std::is_same_v<T, PressTrajectory>) {
                return 2 * t.pressSeconds + t.holdSeconds;
            } else if constexpr (std::is_same_v<T, SweepTrajectory>) {
                return t.approachSeconds + n * (t.lengthM / t.speedMps + t.turnSeconds);
            } else if constexpr (std::is_same_v<T, RasterTrajectory>) {
                return t.durationSeconds();
            } else if constexpr (std::is_same_v<T, CircleTrajectory>) {
                return t.approachSeconds + n / t.frequencyHz;
            } else {
                return t.growSeconds + n / t.frequencyHz;
            }
        },
        trajectory);
}

RunSummary summarize(std::span<const Snapshot> snapshots) noexcept {
    RunSummary r;
    if (snapshots.empty()) return r;
    r.ticks = snapshots.size();
    r.seconds = snapshots.back().timeSeconds - snapshots.front().timeSeconds;
    r.minObserverEnergy = std::numeric_limits<double>::infinity();
    r.minStiffness = std::numeric_limits<double>::infinity();
    r.maxStiffness = 0;
    double raySum = 0;
    std::uint64_t rayTicks = 0, contacts = 0;
    for (const Snapshot& s : snapshots) {
        r.maxForceN = std::max(r.maxForceN, s.force.norm());
        r.minObserverEnergy = std::min(r.minObserverEnergy, s.observerEnergy);
        if (s.rays > 0) {
            raySum += s.rays;
            ++rayTicks;
        }
        r.maxRays = std::max(r.maxRays, s.rays);
        if (inContact(s)) {
            ++contacts;
            r.minStiffness = std::min(r.minStiffness, s.stiffness);
            r.maxStiffness = std::max(r.maxStiffness, s.stiffness);
        }
        if (s.faulted) ++r.faultedTicks;
        if (s.clamped) ++r.clampedTicks;
    }
    r.finalObserverEnergy = snapshots.back().observerEnergy;
    r.meanRays = rayTicks ? raySum / static_cast<double>(rayTicks) : 0.0;
    r.contactFraction = static_cast<double>(contacts) / static_cast<double>(snapshots.size());
    if (contacts == 0) r.minStiffness = 0;
    return r;
}

// ---------------------------------------------------------------------------------------------

int MapPlane::cols() const noexcept {
    return std::max(1, static_cast<int>(std::lround(extentU / pixelM)));
}
int MapPlane::rows() const noexcept {
    return std::max(1, static_cast<int>(std::lround(extentV / pixelM)));
}

bool MapPlane::pixelOf(const Eigen::Vector3d& world, int& col, int& row) const noexcept {
    const Eigen::Vector3d r = world - centre;
    const double a = (r.dot(u) + 0.5 * cols() * pixelM) / pixelM;
    const double b = (r.dot(v) + 0.5 * rows() * pixelM) / pixelM;
    if (!(a >= 0 && b >= 0 && a < cols() && b < rows())) return false;
    col = static_cast<int>(a);
    row = static_cast<int>(b);
    return true;
}

Eigen::Vector3d MapPlane::pixelCentre(int col, int row) const noexcept {
    return centre + ((col + 0.5) * pixelM - 0.5 * cols() * pixelM) * u +
           ((row + 0.5) * pixelM - 0.5 * rows() * pixelM) * v;
}

void validateMapPlane(const MapPlane& plane) {
    auto bad = [](const std::string& field, const std::string& expected, double found) {
        std::ostringstream s;
        s << "map plane: expected " << field << " " << expected << ", found " << found;
        throw ValueError(s.str());
    };
    if (!finite(plane.centre)) bad("centre", "finite", plane.centre.norm());
    if (!(std::abs(plane.u.norm() - 1) < 1e-6)) bad("|u|", "1", plane.u.norm());
    if (!(std::abs(plane.v.norm() - 1) < 1e-6)) bad("|v|", "1", plane.v.norm());
    if (!(std::abs(plane.u.dot(plane.v)) < 1e-6)) bad("u . v", "0", plane.u.dot(plane.v));
    if (!(plane.pixelM > 0 && std::isfinite(plane.pixelM)))
        bad("pixel size (m)", "> 0", plane.pixelM);
    if (!(plane.extentU > 0 && std::isfinite(plane.extentU)))
        bad("extentU (m)", "> 0", plane.extentU);
    if (!(plane.extentV > 0 && std::isfinite(plane.extentV)))
        bad("extentV (m)", "> 0", plane.extentV);
    if (plane.extentU / plane.pixelM > 4096 || plane.extentV / plane.pixelM > 4096) {
        bad("at most 4096 pixels along a side: extent / pixel", "<= 4096",
            std::max(plane.extentU, plane.extentV) / plane.pixelM);
    }
}

const char* mapQuantityName(MapQuantity quantity) noexcept {
    switch (quantity) {
        case MapQuantity::Stiffness:
            return "stiffness";
        case MapQuantity::Force:
            return "force";
        case MapQuantity::Energy:
            return "energy";
    }
    return "?";
}

MapQuantity parseMapQuantity(const std::string& name) {
    if (name == "stiffness") return MapQuantity::Stiffness;
    if (name == "force") return MapQuantity::Force;
    if (name == "energy") return MapQuantity::Energy;
    throw ValueError("map quantity: expected stiffness, force or energy, found '" + name + "'");
}

double mapValue(const Snapshot& s, MapQuantity quantity) noexcept {
    switch (quantity) {
        case MapQuantity::Stiffness:
            return s.stiffness;
        case MapQuantity::Force:
            return s.force.norm();
        case MapQuantity::Energy:
            return s.energyForce.norm() + s.proxyForce.norm();
    }
    return kNaN;
}

ScalarMap::ScalarMap(const MapPlane& plane) : mPlane(plane) {
    validateMapPlane(plane);
    mCols = plane.cols();
    mRows = plane.rows();
    const auto n = static_cast<std::size_t>(mCols) * static_cast<std::size_t>(mRows);
    mSum.assign(n, 0.0);
    mCount.assign(n, 0);
}

void ScalarMap::add(const Eigen::Vector3d& world, double value) noexcept {
    int c = 0, r = 0;
    if (!std::isfinite(value) || !mPlane.pixelOf(world, c, r)) return;
    const auto i =
        static_cast<std::size_t>(r) * static_cast<std::size_t>(mCols) + static_cast<std::size_t>(c);
    mSum[i] += value;
    ++mCount[i];
}

double ScalarMap::at(int col, int row) const noexcept {
    if (col < 0 || row < 0 || col >= mCols || row >= mRows) return kNaN;
    const auto i = static_cast<std::size_t>(row) * static_cast<std::size_t>(mCols) +
                   static_cast<std::size_t>(col);
    return mCount[i] ? mSum[i] / mCount[i] : kNaN;
}

std::uint32_t ScalarMap::count(int col, int row) const noexcept {
    if (col < 0 || row < 0 || col >= mCols || row >= mRows) return 0;
    return mCount[static_cast<std::size_t>(row) * static_cast<std::size_t>(mCols) +
                  static_cast<std::size_t>(col)];
}

void ScalarMap::set(int col, int row, double value) noexcept {
    if (col < 0 || row < 0 || col >= mCols || row >= mRows) return;
    const auto i = static_cast<std::size_t>(row) * static_cast<std::size_t>(mCols) +
                   static_cast<std::size_t>(col);
    mSum[i] = value;
    mCount[i] = 1;
}

void ScalarMap::fillGaps(int passes) {
    for (int p = 0; p < passes; ++p) {
        std::vector<std::pair<int, int>> cells;
        std::vector<double> values;
        for (int r = 0; r < mRows; ++r) {
            for (int c = 0; c < mCols; ++c) {
                if (count(c, r)) continue;
                double sum = 0;
                int n = 0;
                for (int dr = -1; dr <= 1; ++dr) {
                    for (int dc = -1; dc <= 1; ++dc) {
                        const double x = at(c + dc, r + dr);
                        if (std::isfinite(x)) {
                            sum += x;
                            ++n;
                        }
                    }
                }
                if (n) {
                    cells.emplace_back(c, r);
                    values.push_back(sum / n);
                }
            }
        }
        if (cells.empty()) return;
        for (std::size_t i = 0; i < cells.size(); ++i)
            set(cells[i].first, cells[i].second, values[i]);
    }
}

void ScalarMap::range(double& lo, double& hi) const noexcept {
    lo = std::numeric_limits<double>::infinity();
    hi = -lo;
    for (int r = 0; r < mRows; ++r) {
        for (int c = 0; c < mCols; ++c) {
            const double x = at(c, r);
            if (std::isfinite(x)) {
                lo = std::min(lo, x);
                hi = std::max(hi, x);
            }
        }
    }
    if (lo > hi) lo = hi = kNaN;
}

std::vector<double> ScalarMap::finiteValues() const {
    std::vector<double> out;
    for (int r = 0; r < mRows; ++r) {
        for (int c = 0; c < mCols; ++c) {
            const double x = at(c, r);
            if (std::isfinite(x)) out.push_back(x);
        }
    }
    return out;
}

const char* mapAnchorName(MapAnchor anchor) noexcept {
    return anchor == MapAnchor::Proxy ? "proxy" : "ray-end";
}

MapAnchor parseMapAnchor(const std::string& name) {
    if (name == "proxy") return MapAnchor::Proxy;
    if (name == "ray-end") return MapAnchor::RayEnd;
    throw ValueError("map anchor: expected proxy or ray-end, found '" + name + "'");
}

ScalarMap binSnapshots(std::span<const Snapshot> snapshots, const MapPlane& plane,
                       MapQuantity quantity, bool contactOnly, MapAnchor anchor) {
    ScalarMap map(plane);
    for (const Snapshot& s : snapshots) {
        if (contactOnly && !(inContact(s) && (s.rays > 0 || s.mode == CouplingMode::VC))) continue;
        Eigen::Vector3d at = s.proxy;
        if (anchor == MapAnchor::RayEnd) {
            const Eigen::Vector3d d = s.probe - s.proxy;
            const double n = d.norm();
            if (!(n > 0) || !std::isfinite(s.rayLength)) continue;
            at = s.proxy + (s.rayLength / n) * d;
        }
        map.add(at, mapValue(s, quantity));
    }
    return map;
}

double otsuThreshold(const ScalarMap& map) {
    const std::vector<double> values = map.finiteValues();
    if (values.empty()) return kNaN;
    const auto [mn, mx] = std::minmax_element(values.begin(), values.end());
    const double lo = *mn, hi = *mx;
    if (!(hi > lo)) return kNaN;
    constexpr int kBins = 256;
    std::array<double, kBins> hist{};
    for (double x : values) {
        const int b = std::min(kBins - 1, static_cast<int>((x - lo) / (hi - lo) * kBins));
        hist[static_cast<std::size_t>(b)] += 1;
    }
    const double total = static_cast<double>(values.size());
    double sumAll = 0;
    for (int b = 0; b < kBins; ++b) sumAll += b * hist[static_cast<std::size_t>(b)];
    double w0 = 0, sum0 = 0, best = -1;
    int bestFirst = 0, bestLast = 0;
    for (int b = 0; b < kBins - 1; ++b) {
        w0 += hist[static_cast<std::size_t>(b)];
        sum0 += b * hist[static_cast<std::size_t>(b)];
        const double w1 = total - w0;
        if (w0 == 0 || w1 == 0) continue;
        const double m0 = sum0 / w0, m1 = (sumAll - sum0) / w1;
        const double between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if (between > best * (1 + 1e-12)) {
            best = between;
            bestFirst = bestLast = b;
        } else if (between >= best * (1 - 1e-12)) {
            bestLast = b;  // empty bins between the classes: a plateau of equal variance
        }
    }
    // The middle of the plateau (the gap between the classes), at a bin edge.
    return lo + (0.5 * (bestFirst + bestLast) + 1) * (hi - lo) / kBins;
}

Mask thresholdMap(const ScalarMap& map, double threshold) {
    Mask m(static_cast<std::size_t>(map.cols()) * static_cast<std::size_t>(map.rows()), 0);
    for (int r = 0; r < map.rows(); ++r) {
        for (int c = 0; c < map.cols(); ++c) {
            const double x = map.at(c, r);
            m[static_cast<std::size_t>(r) * static_cast<std::size_t>(map.cols()) +
              static_cast<std::size_t>(c)] = (std::isfinite(x) && x >= threshold) ? 1 : 0;
        }
    }
    return m;
}

Mask rasterizeMask(const MapPlane& plane,
                   const std::function<bool(const Eigen::Vector3d&)>& inside) {
    validateMapPlane(plane);
    const int cols = plane.cols(), rows = plane.rows();
    Mask m(static_cast<std::size_t>(cols) * static_cast<std::size_t>(rows), 0);
    for (int r = 0; r < rows; ++r) {
        for (int c = 0; c < cols; ++c) {
            m[static_cast<std::size_t>(r) * static_cast<std::size_t>(cols) +
              static_cast<std::size_t>(c)] = inside(plane.pixelCentre(c, r)) ? 1 : 0;
        }
    }
    return m;
}

double intersectionOverUnion(const Mask& a, const Mask& b) {
    if (a.size() != b.size()) {
        throw ValueError("intersectionOverUnion: expected masks of the same size, found " +
                         std::to_string(a.size()) + " and " + std::to_string(b.size()) + " pixels");
    }
    std::size_t both = 0, either = 0;
    for (std::size_t i = 0; i < a.size(); ++i) {
        both += (a[i] && b[i]) ? 1u : 0u;
        either += (a[i] || b[i]) ? 1u : 0u;
    }
    return either ? static_cast<double>(both) / static_cast<double>(either) : 1.0;
}

int pickLargest(std::span<const double> scores, double relativeTolerance, std::uint64_t seed) {
    double best = -std::numeric_limits<double>::infinity();
    bool any = false;
    for (double s : scores) {
        if (std::isfinite(s)) {
            best = std::max(best, s);
            any = true;
        }
    }
    if (!any) return -1;
    const double cut = best - std::abs(relativeTolerance) * std::abs(best);
    std::vector<int> tied;
    for (std::size_t i = 0; i < scores.size(); ++i) {
        if (std::isfinite(scores[i]) && scores[i] >= cut) tied.push_back(static_cast<int>(i));
    }
    if (tied.size() == 1) return tied.front();
    std::mt19937_64 rng(seed);
    std::uniform_int_distribution<std::size_t> pick(0, tied.size() - 1);
    return tied[pick(rng)];
}

// ---------------------------------------------------------------------------------------------

namespace {

std::array<std::uint8_t, 3> heat(double s) {
    // Black -> red -> yellow -> white, piecewise linear in thirds.
    s = std::clamp(s, 0.0, 1.0);
    const auto c = [](double x) {
        return static_cast<std::uint8_t>(std::lround(255.0 * std::clamp(x, 0.0, 1.0)));
    };
    return {c(3 * s), c(3 * s - 1), c(3 * s - 2)};
}

void appendBytes(void* context, void* data, int size) {
    auto* out = static_cast<std::string*>(context);
    out->append(static_cast<const char*>(data), static_cast<std::size_t>(size));
}

}  // namespace

void writeMapPng(const fs::path& path, const ScalarMap& map, const PngOptions& options) {
    if (options.scale < 1 || options.scale > 16) {
        throw ValueError("map PNG: expected a scale of 1-16, found " +
                         std::to_string(options.scale));
    }
    double lo = options.lo, hi = options.hi;
    double mn = 0, mx = 0;
    map.range(mn, mx);
    if (!std::isfinite(lo)) lo = mn;
    if (!std::isfinite(hi)) hi = mx;
    const double span = (std::isfinite(lo) && std::isfinite(hi) && hi > lo) ? hi - lo : 1.0;
    const bool rgb = options.colorMap == ColorMap::Heat;
    const int channels = rgb ? 3 : 1;
    const int scale = options.scale;
    const int width = map.cols() * scale, height = map.rows() * scale;
    std::vector<std::uint8_t> pixels(static_cast<std::size_t>(width) *
                                     static_cast<std::size_t>(height) *
                                     static_cast<std::size_t>(channels));
    for (int y = 0; y < height; ++y) {
        const int row = map.rows() - 1 - y / scale;  // image row 0 = largest v
        for (int x = 0; x < width; ++x) {
            const double value = map.at(x / scale, row);
            std::uint8_t* p =
                &pixels[(static_cast<std::size_t>(y) * static_cast<std::size_t>(width) +
                         static_cast<std::size_t>(x)) *
                        static_cast<std::size_t>(channels)];
            if (!std::isfinite(value)) {
                if (rgb) {
                    p[0] = 0;
                    p[1] = 0;
                    p[2] = 64;
                } else {
                    p[0] = 0;
                }
                continue;
            }
            const double s = std::isfinite(lo) ? (value - lo) / span : 0.0;
            if (rgb) {
                const auto c = heat(s);
                p[0] = c[0];
                p[1] = c[1];
                p[2] = c[2];
            } else {
                p[0] = static_cast<std::uint8_t>(std::lround(255.0 * std::clamp(s, 0.0, 1.0)));
            }
        }
    }
    std::string bytes;
    if (!stbi_write_png_to_func(appendBytes, &bytes, width, height, channels, pixels.data(),
                                width * channels)) {
        throw IoError(path.string() + ": expected to encode a " + std::to_string(width) + "x" +
                      std::to_string(height) + " PNG, the encoder failed");
    }
    writeFileAtomically(path, "map PNG", bytes.data(), bytes.size());
}

void writeTraceCsv(const fs::path& path, std::span<const Snapshot> snapshots) {
    std::string text =
        "t,tick,probe_x,probe_y,probe_z,proxy_x,proxy_y,proxy_z,force_x,force_y,force_z,"
        "stiffness,ray_length,distance,energy_force_x,energy_force_y,energy_force_z,"
        "proxy_force_x,proxy_force_y,proxy_force_z,coupling_energy,observer_energy,"
        "added_damping,contacts,rays,sticking,gate_open,faulted,clamped\n";
    text.reserve(text.size() + snapshots.size() * 360);
    char line[1024];
    for (const Snapshot& s : snapshots) {
        const int n = std::snprintf(
            line, sizeof line,
            "%.6f,%llu,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.6g,%.9g,%.9g,%.6g,%.6g,%.6g,"
            "%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%d,%d,%d,%d,%d,%d\n",
            s.timeSeconds, static_cast<unsigned long long>(s.tick), s.probe.x(), s.probe.y(),
            s.probe.z(), s.proxy.x(), s.proxy.y(), s.proxy.z(), s.force.x(), s.force.y(),
            s.force.z(), s.stiffness, s.rayLength, s.distance, s.energyForce.x(), s.energyForce.y(),
            s.energyForce.z(), s.proxyForce.x(), s.proxyForce.y(), s.proxyForce.z(),
            s.couplingEnergy, s.observerEnergy, s.addedDamping, s.contactCount, s.rays,
            s.sticking ? 1 : 0, s.gateOpen ? 1 : 0, s.faulted ? 1 : 0, s.clamped ? 1 : 0);
        if (n > 0) text.append(line, std::min(static_cast<std::size_t>(n), sizeof line - 1));
    }
    writeFileAtomically(path, "trace CSV", text.data(), text.size());
}

}  // namespace palp::haptics
