#pragma once
// Internal helpers shared by the NIfTI, NRRD and MetaImage readers (not installed).

#include <Eigen/Core>
#include <Eigen/LU>
#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "formats/header_parsers.h"
#include "formats/raw_data.h"
#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::volume::detail {

/// The first bytes of @p path (at most kMaxHeaderBytes) as text for a header parser; the size
/// is checked against the file before anything is read.
inline std::string readHeaderPrefix(const std::filesystem::path& path) {
    const std::uint64_t size = fileSize(path);
    const std::vector<std::byte> bytes =
        readFileRange(path, 0, std::min<std::uint64_t>(size, kMaxHeaderBytes));
    return std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size());
}

inline std::string_view trim(std::string_view s) {
    auto isWs = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
    while (!s.empty() && isWs(s.front())) s.remove_prefix(1);
    while (!s.empty() && isWs(s.back())) s.remove_suffix(1);
    return s;
}

inline std::string lower(std::string_view s) {
    std::string out(s);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

/// Splits on white space.
inline std::vector<std::string_view> words(std::string_view s) {
    std::vector<std::string_view> out;
    std::size_t i = 0;
    while (i < s.size()) {
        while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i])) != 0) ++i;
        const std::size_t b = i;
        while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i])) == 0) ++i;
        if (i > b) out.push_back(s.substr(b, i - b));
    }
    return out;
}

/// Whole-token double (accepts nan/inf as from_chars does).
inline std::optional<double> toDouble(std::string_view s) {
    s = trim(s);
    if (!s.empty() && s.front() == '+') s.remove_prefix(1);
    double v = 0;
    const auto res = std::from_chars(s.data(), s.data() + s.size(), v);
    if (s.empty() || res.ec != std::errc() || res.ptr != s.data() + s.size()) return std::nullopt;
    return v;
}

/// Whole-token signed integer.
inline std::optional<std::int64_t> toInt(std::string_view s) {
    s = trim(s);
    if (!s.empty() && s.front() == '+') s.remove_prefix(1);
    std::int64_t v = 0;
    const auto res = std::from_chars(s.data(), s.data() + s.size(), v);
    if (s.empty() || res.ec != std::errc() || res.ptr != s.data() + s.size()) return std::nullopt;
    return v;
}

/// Shortens a found value for messages.
inline std::string quoteFound(std::string_view s) {
    constexpr std::size_t kMax = 60;
    std::string out = "'";
    for (const char c : s.substr(0, kMax)) {
        out += std::isprint(static_cast<unsigned char>(c)) != 0 ? c : '?';
    }
    if (s.size() > kMax) out += "...";
    return out + "'";
}

/// Checks a reader's index-to-world affine (metres, LPS) before it becomes slices: every axis
/// step (its length without overflow, so 1e300 shows as 1e300) is a voxel spacing
/// (bounds::kSpacing, shown in mm), the three steps span space (no zero, NaN or parallel column:
/// the grid has a volume), and the origin is a position (bounds::kPosition). Messages name the file
/// and the header fields the values came from.
/// @throw FormatError `<file>: <field>: expected ..., found ...` (the file is at fault).
inline void checkAffine(const std::string& name, std::string_view spacingField,
                        std::string_view directionField, std::string_view originField,
                        const Eigen::Matrix3d& axes, const Eigen::Vector3d& origin) try {
    for (int c = 0; c < 3; ++c) {
        palp::requireWithin(
            name + ": " + std::string(spacingField) + " (axis " + std::to_string(c) + " step)",
            axes.col(c).stableNorm(), bounds::kSpacing, {1e3, "mm"});
    }
    // |det| over the product of the column lengths: 1 for orthogonal axes, 0 for a flat grid.
    const double volume = std::abs(axes.determinant());
    const double lengths =
        axes.col(0).stableNorm() * axes.col(1).stableNorm() * axes.col(2).stableNorm();
    if (!(volume > 1e-6 * lengths)) {
        std::string found;
        for (int c = 0; c < 3; ++c) {
            found += (c ? ", (" : "(") + formatValue(axes(0, c) * 1e3) + " " +
                     formatValue(axes(1, c) * 1e3) + " " + formatValue(axes(2, c) * 1e3) + ")";
        }
        throwExpected(name + ": " + std::string(directionField),
                      "three independent axis directions", "the steps " + found + " mm");
    }
    for (int r = 0; r < 3; ++r) {
        palp::requireWithin(
            name + ": " + std::string(originField) + " (coordinate " + std::to_string(r) + ")",
            origin[r], bounds::kPosition, {1e3, "mm"});
    }
} catch (const ValueError& e) {
    throw FormatError(e.what());
}

}  // namespace palp::volume::detail
