// The sweep's ranges file and its sampler (sweep_design.h).
#include "palp/studies/sweep_design.h"

#include <Random123/philox.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <numeric>
#include <sstream>

#include "palp/base/error.h"

namespace palp::haptics {

namespace design_impl {

using Json = nlohmann::json;

constexpr std::array<SweepVarInfo, kSweepVarCount> kInfo{{
    {"strain", "1", "input strain amplitude", true},
    {"frequency", "Hz", "input frequency (Hz)", true},
    {"contact", "rank", "contact node (rank from centre)", true},
    {"youngs", "Pa", "Young's modulus E (Pa)", true},
    {"poisson", "1", "Poisson's ratio", true},
    {"density", "kg/m^3", "density (kg/m^3)", true},
    {"damping", "1/s", "mass damping alpha (1/s)", true},
    {"lod", "cells", "secondary level of detail (cells)", false},
    {"primary", "nodes", "primary size (seed nodes)", false},
    {"rate", "Hz", "secondary rate (Hz)", false},
    {"coupling", "1", "coupling (0 plain, 1 condensed)", false},
}};

/// Physical bounds of each variable (inclusive unless noted in the check).
struct Bounds {
    double lo, hi;
};
constexpr std::array<Bounds, kSweepVarCount> kBounds{{
    {1e-4, 0.3},    // strain
    {0.1, 200.0},   // frequency, Hz
    {0, 1e6},       // contact rank (checked against the mesh too)
    {1.0, 1e9},     // E, Pa
    {0.0, 0.49},    // nu
    {1.0, 1e5},     // density
    {0.0, 1e4},     // damping alpha
    {1, 4},         // lod
    {1, 1e6},       // primary seeds (checked against the mesh too)
    {1.0, 1000.0},  // secondary rate, Hz (at most the servo rate)
    {0, 1},         // coupling
}};

std::string describe(const Json& j) {
    std::string s = j.dump();
    if (s.size() > 60) s = s.substr(0, 57) + "...";
    return std::string(j.type_name()) + " " + s;
}

[[noreturn]] void refuse(const std::string& source, const std::string& field,
                         const std::string& expected, const std::string& found) {
    throw ValueError(source + ": field '" + field + "': expected " + expected + ", found " + found);
}

double number(const Json& j, const std::string& source, const std::string& field) {
    if (!j.is_number())
        throw FormatError(source + ": field '" + field + "': expected a number, found " +
                          describe(j));
    const double v = j.get<double>();
    if (!std::isfinite(v)) refuse(source, field, "a finite number", describe(j));
    return v;
}

std::string fmt(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.10g", v);
    return buf;
}

const Json& member(const Json& obj, const char* key, const std::string& source,
                   const std::string& where) {
    const auto it = obj.find(key);
    const std::string field = where.empty() ? key : where + "." + key;
    if (it == obj.end()) throw FormatError(source + ": field '" + field + "' is missing");
    return *it;
}

void checkKeys(const Json& obj, std::initializer_list<const char*> allowed,
               const std::string& source, const std::string& where) {
    for (auto it = obj.begin(); it != obj.end(); ++it) {
        bool ok = false;
        for (const char* a : allowed) ok = ok || it.key() == a;
        if (!ok) {
            std::string list;
            for (const char* a : allowed) list += std::string(list.empty() ? "" : ", ") + a;
            refuse(source, where.empty() ? it.key() : where + "." + it.key(), "one of " + list,
                   "an unknown key");
        }
    }
}

bool isInteger(double v) { return std::floor(v) == v; }

SweepRange parseRange(const Json& spec, int var, const SweepRanges& r, const std::string& source) {
    const std::string field = std::string("variables.") + kInfo[static_cast<std::size_t>(var)].name;
    if (!spec.is_object())
        throw FormatError(source + ": field '" + field +
                          "': expected an object ({\"value\": x}, {\"min\": a, \"max\": b} or "
                          "{\"values\": [...]}), found " +
                          describe(spec));
    checkKeys(spec, {"value", "min", "max", "scale", "integer", "values"}, source, field);
    SweepRange out;
    const bool hasValue = spec.contains("value"), hasValues = spec.contains("values");
    const bool hasRange = spec.contains("min") || spec.contains("max");
    if (int(hasValue) + int(hasValues) + int(hasRange) != 1)
        refuse(source, field, "exactly one of 'value', 'min'/'max' or 'values'", spec.dump());
    if (hasValue) {
        out.kind = SweepRange::Kind::fixed;
        out.min = out.max = number(spec["value"], source, field + ".value");
        out.values = {out.min};
    } else if (hasValues) {
        const Json& v = spec["values"];
        if (!v.is_array() || v.empty())
            refuse(source, field + ".values", "a non-empty array of numbers", describe(v));
        for (std::size_t i = 0; i < v.size(); ++i)
            out.values.push_back(
                number(v[i], source, field + ".values[" + std::to_string(i) + "]"));
        auto sorted = out.values;
        std::sort(sorted.begin(), sorted.end());
        if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end())
            refuse(source, field + ".values", "distinct values", v.dump());
        out.kind = SweepRange::Kind::values;
        out.min = sorted.front();
        out.max = sorted.back();
    } else {
        out.min = number(member(spec, "min", source, field), source, field + ".min");
        out.max = number(member(spec, "max", source, field), source, field + ".max");
        if (out.min == out.max)
            refuse(source, field, "a non-empty range (min < max; use {\"value\": x} to fix it)",
                   "min = max = " + fmt(out.min));
        if (out.min > out.max)
            refuse(source, field, "min < max",
                   "an inverted range, min " + fmt(out.min) + " > max " + fmt(out.max));
        out.kind = SweepRange::Kind::uniform;
        if (spec.contains("scale")) {
            const Json& s = spec["scale"];
            if (!s.is_string() || (s != "log" && s != "linear"))
                refuse(source, field + ".scale", "\"log\" or \"linear\"", describe(s));
            if (s == "log") {
                if (out.min <= 0)
                    refuse(source, field + ".min", "> 0 on a log scale", fmt(out.min));
                out.kind = SweepRange::Kind::logUniform;
            }
        }
        if (spec.contains("integer")) {
            const Json& s = spec["integer"];
            if (!s.is_boolean()) refuse(source, field + ".integer", "true or false", describe(s));
            if (s.get<bool>()) {
                if (out.kind == SweepRange::Kind::logUniform)
                    refuse(source, field, "either \"integer\" or a log scale", "both");
                if (!isInteger(out.min) || !isInteger(out.max))
                    refuse(source, field, "integer ends", fmt(out.min) + " .. " + fmt(out.max));
                out.kind = SweepRange::Kind::integer;
            }
        }
    }
    // Physical and mesh bounds on every value the range can give.
    std::vector<double> ends =
        out.kind == SweepRange::Kind::values ? out.values : std::vector<double>{out.min, out.max};
    const auto v = static_cast<SweepVar>(var);
    const bool discrete = v == SweepVar::contact || v == SweepVar::lod || v == SweepVar::primary ||
                          v == SweepVar::coupling;
    if (discrete &&
        (out.kind == SweepRange::Kind::uniform || out.kind == SweepRange::Kind::logUniform))
        refuse(source, field,
               "integers ({\"min\": a, \"max\": b, \"integer\": true} or "
               "{\"values\": [...]})",
               "a continuous range");
    const int cells = r.meshNodes - 1;
    for (double e : ends) {
        if (discrete && !isInteger(e)) refuse(source, field, "integer values", fmt(e));
        if (e < kBounds[static_cast<std::size_t>(var)].lo ||
            e > kBounds[static_cast<std::size_t>(var)].hi)
            refuse(source, field,
                   "values in [" + fmt(kBounds[static_cast<std::size_t>(var)].lo) + ", " +
                       fmt(kBounds[static_cast<std::size_t>(var)].hi) + "] " +
                       kInfo[static_cast<std::size_t>(var)].unit,
                   fmt(e));
        if (v == SweepVar::lod && (e == 3 || cells % static_cast<int>(e) != 0))
            refuse(source, field,
                   "a level of detail of 1, 2 or 4 dividing the " + std::to_string(cells) +
                       " cells a side",
                   fmt(e));
        if (v == SweepVar::contact && e >= static_cast<double>(r.contactNodes().size()))
            refuse(source, field,
                   "a contact rank below " + std::to_string(r.contactNodes().size()) +
                       " (interior top-face nodes)",
                   fmt(e));
        if (v == SweepVar::primary && e > static_cast<double>(r.meshNodes * r.meshNodes))
            refuse(source, field,
                   "at most " + std::to_string(r.meshNodes * r.meshNodes) + " primary seeds",
                   fmt(e));
        if (v == SweepVar::rate && e > 1000.0)
            refuse(source, field, "a secondary rate up to the 1000 Hz servo rate", fmt(e));
    }
    return out;
}

}  // namespace design_impl

using namespace design_impl;

const SweepVarInfo& sweepVarInfo(SweepVar v) { return kInfo[static_cast<std::size_t>(v)]; }
const SweepVarInfo& sweepVarInfo(int v) { return kInfo.at(static_cast<std::size_t>(v)); }

double SweepRange::at(double u) const {
    switch (kind) {
        case Kind::fixed:
            return min;
        case Kind::uniform:
            return min + u * (max - min);
        case Kind::logUniform:
            return std::exp(std::log(min) + u * (std::log(max) - std::log(min)));
        case Kind::integer: {
            const double n = max - min + 1.0;
            return std::min(max, min + std::floor(u * n));
        }
        case Kind::values: {
            const auto n = values.size();
            const auto i = std::min(n - 1, static_cast<std::size_t>(u * static_cast<double>(n)));
            return values[i];
        }
    }
    return min;
}

bool SweepRange::varies() const {
    return kind != Kind::fixed && !(kind == Kind::values && values.size() == 1);
}

std::vector<int> SweepRanges::contactNodes() const {
    const int n = meshNodes;
    std::vector<std::pair<double, int>> nodes;
    const double c = 0.5 * (n - 1);
    for (int j = 1; j < n - 1; ++j)
        for (int i = 1; i < n - 1; ++i)
            nodes.emplace_back(std::hypot(i - c, j - c), i + n * (j + n * (n - 1)));
    std::sort(nodes.begin(), nodes.end());
    std::vector<int> out;
    for (const auto& p : nodes) out.push_back(p.second);
    return out;
}

SweepRanges parseSweepRanges(const std::string& text, const std::string& source) {
    Json j;
    try {
        j = Json::parse(text);
    } catch (const Json::exception& e) {
        throw FormatError(source + ": not a JSON ranges file: " + e.what());
    }
    if (!j.is_object())
        throw FormatError(source + ": expected a JSON object, found " + describe(j));
    checkKeys(j,
              {"palp_sweep_ranges", "mesh", "duration_s", "adaptivity_per_reference", "variables"},
              source, "");
    const Json& ver = member(j, "palp_sweep_ranges", source, "");
    if (!ver.is_number_integer() || ver.get<int>() != 1)
        refuse(source, "palp_sweep_ranges", "format version 1", describe(ver));
    SweepRanges r;
    const Json& mesh = member(j, "mesh", source, "");
    if (!mesh.is_object()) throw FormatError(source + ": field 'mesh': expected an object");
    checkKeys(mesh, {"nodes", "spacing_mm"}, source, "mesh");
    const double nodes = number(member(mesh, "nodes", source, "mesh"), source, "mesh.nodes");
    if (!isInteger(nodes) || nodes < 5 || nodes > 65)
        refuse(source, "mesh.nodes", "an integer in [5, 65]", fmt(nodes));
    r.meshNodes = static_cast<int>(nodes);
    const double spacing =
        number(member(mesh, "spacing_mm", source, "mesh"), source, "mesh.spacing_mm");
    if (spacing < 0.1 || spacing > 100)
        refuse(source, "mesh.spacing_mm", "[0.1, 100] mm", fmt(spacing));
    r.spacingM = spacing * 1e-3;
    r.durationS = number(member(j, "duration_s", source, ""), source, "duration_s");
    if (r.durationS < 0.01 || r.durationS > 60)
        refuse(source, "duration_s", "[0.01, 60] s", fmt(r.durationS));
    const double k = number(member(j, "adaptivity_per_reference", source, ""), source,
                            "adaptivity_per_reference");
    if (!isInteger(k) || k < 1 || k > 1000)
        refuse(source, "adaptivity_per_reference", "an integer in [1, 1000]", fmt(k));
    r.adaptivityPerReference = static_cast<int>(k);
    const Json& vars = member(j, "variables", source, "");
    if (!vars.is_object())
        throw FormatError(source + ": field 'variables': expected an object, found " +
                          describe(vars));
    for (auto it = vars.begin(); it != vars.end(); ++it) {
        bool known = false;
        for (const auto& info : kInfo) known = known || it.key() == info.name;
        if (!known) {
            std::string list;
            for (const auto& info : kInfo)
                list += std::string(list.empty() ? "" : ", ") + info.name;
            refuse(source, "variables." + it.key(), "a known variable (" + list + ")",
                   "an unknown variable");
        }
    }
    Json canon = Json::object();
    canon["mesh"] = {{"nodes", r.meshNodes}, {"spacing_mm", spacing}};
    canon["duration_s"] = r.durationS;
    canon["adaptivity_per_reference"] = r.adaptivityPerReference;
    for (int v = 0; v < kSweepVarCount; ++v) {
        const auto it = vars.find(kInfo[static_cast<std::size_t>(v)].name);
        if (it == vars.end())
            throw ValueError(source + ": field 'variables." +
                             kInfo[static_cast<std::size_t>(v)].name +
                             "' is missing: every variable needs a range or a value");
        r.vars[static_cast<std::size_t>(v)] = parseRange(*it, v, r, source);
        canon["variables"][kInfo[static_cast<std::size_t>(v)].name] = *it;
    }
    r.canonical = canon.dump();
    return r;
}

SweepRanges loadSweepRanges(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw IoError(path.string() + ": cannot read the ranges file");
    std::ostringstream s;
    s << in.rdbuf();
    return parseSweepRanges(s.str(), path.string());
}

std::int64_t SweepSpec::groupSize() const { return ranges.adaptivityPerReference; }
std::int64_t SweepSpec::groups() const { return (samples + groupSize() - 1) / groupSize(); }

const char* sweepPalpVersion() { return "0.1.0"; }

std::string SweepSpec::id() const {
    const std::string text = ranges.canonical + "|" + (design == SweepDesign::lhs ? "lhs" : "mc") +
                             "|" + std::to_string(seed) + "|" + std::to_string(samples) + "|" +
                             sweepPalpVersion();
    std::uint64_t h = 0xcbf29ce484222325ull;
    for (const char ch : text) {
        h ^= static_cast<unsigned char>(ch);
        h *= 0x100000001b3ull;
    }
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
    return buf;
}

std::array<std::uint32_t, 4> philox(std::array<std::uint32_t, 2> key,
                                    std::array<std::uint32_t, 4> counter) {
    r123::Philox4x32 gen;
    const r123::Philox4x32::key_type k = {{key[0], key[1]}};
    const r123::Philox4x32::ctr_type c = {{counter[0], counter[1], counter[2], counter[3]}};
    const auto r = gen(c, k);
    return {r[0], r[1], r[2], r[3]};
}

double unitOpen(std::uint64_t x) { return (static_cast<double>(x >> 12) + 0.5) * 0x1p-52; }

namespace design_impl {

// Stream purposes (the counter's third word): a sample's draw of variable v, and the step of
// variable v's Latin hypercube permutation.
constexpr std::uint32_t kDraw = 0x00010000u;
constexpr std::uint32_t kShuffle = 0x00020000u;

/// High 64 bits of a 64 x 64 bit product (portable, no __int128).
std::uint64_t mulHigh(std::uint64_t a, std::uint64_t b) {
    const std::uint64_t aLo = a & 0xffffffffu, aHi = a >> 32, bLo = b & 0xffffffffu, bHi = b >> 32;
    const std::uint64_t ll = aLo * bLo, lh = aLo * bHi, hl = aHi * bLo, hh = aHi * bHi;
    const std::uint64_t mid = (ll >> 32) + (lh & 0xffffffffu) + (hl & 0xffffffffu);
    return hh + (lh >> 32) + (hl >> 32) + (mid >> 32);
}

std::array<std::uint32_t, 2> keyOf(std::uint64_t seed) {
    return {static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32)};
}

std::uint64_t word(std::uint64_t seed, std::uint32_t purpose, std::uint64_t index) {
    const auto r = philox(keyOf(seed), {static_cast<std::uint32_t>(index),
                                        static_cast<std::uint32_t>(index >> 32), purpose, 0u});
    return (std::uint64_t{r[0]} << 32) | r[1];
}

}  // namespace design_impl

SweepSampler::SweepSampler(const SweepSpec& spec) : mSpec(spec) {
    if (spec.samples < 1 || spec.samples > 1'000'000'000)
        throw ValueError("sweep: samples: expected 1 to 1e9, found " +
                         std::to_string(spec.samples));
    if (spec.design != SweepDesign::lhs) return;
    for (int v = 0; v < kSweepVarCount; ++v) {
        if (!spec.ranges.vars[static_cast<std::size_t>(v)].varies()) continue;
        const std::int64_t n =
            kInfo[static_cast<std::size_t>(v)].perGroup ? spec.groups() : spec.samples;
        auto& p = mPermutation[static_cast<std::size_t>(v)];
        p.resize(static_cast<std::size_t>(n));
        std::iota(p.begin(), p.end(), 0u);
        // Fisher-Yates from the top; step i draws j in [0, i] by a 64x64 -> 128 multiply (bias
        // below n / 2^64).
        for (std::int64_t i = n - 1; i > 0; --i) {
            const std::uint64_t w = word(spec.seed, kShuffle | static_cast<std::uint32_t>(v),
                                         static_cast<std::uint64_t>(i));
            const auto j = static_cast<std::int64_t>(mulHigh(w, static_cast<std::uint64_t>(i + 1)));
            std::swap(p[static_cast<std::size_t>(i)], p[static_cast<std::size_t>(j)]);
        }
    }
}

std::array<double, kSweepVarCount> SweepSampler::sample(std::int64_t index) const {
    if (index < 0 || index >= mSpec.samples)
        throw ValueError("sweep: sample index " + std::to_string(index) + " outside [0, " +
                         std::to_string(mSpec.samples) + ")");
    std::array<double, kSweepVarCount> x{};
    const std::int64_t group = index / mSpec.groupSize();
    for (int v = 0; v < kSweepVarCount; ++v) {
        const SweepRange& r = mSpec.ranges.vars[static_cast<std::size_t>(v)];
        if (!r.varies()) {
            x[static_cast<std::size_t>(v)] = r.at(0.5);
            continue;
        }
        const std::int64_t draw = kInfo[static_cast<std::size_t>(v)].perGroup ? group : index;
        const double u = unitOpen(word(mSpec.seed, kDraw | static_cast<std::uint32_t>(v),
                                       static_cast<std::uint64_t>(draw)));
        if (mSpec.design == SweepDesign::mc) {
            x[static_cast<std::size_t>(v)] = r.at(u);
        } else {
            const auto n = static_cast<double>(mPermutation[static_cast<std::size_t>(v)].size());
            const double stratum =
                mPermutation[static_cast<std::size_t>(v)][static_cast<std::size_t>(draw)];
            x[static_cast<std::size_t>(v)] = r.at(std::min((stratum + u) / n, 1.0 - 0x1p-53));
        }
    }
    return x;
}

}  // namespace palp::haptics
