#pragma once
// Internal helpers shared by the NIfTI, NRRD and MetaImage readers (not installed).

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "header_parsers.h"
#include "raw_data.h"

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

}  // namespace palp::volume::detail
