// The error lookup table: parse, check, write and interpolate (error_table.h).
#include "palp/haptics/tissue/error_table.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "palp/base/error.h"

namespace palp::haptics {

namespace error_table_impl {

using Json = nlohmann::json;

constexpr std::size_t kMaxAxes = 16;

constexpr std::array<const char*, kErrorVarCount> kNames = {
    "strain", "frequency", "youngs", "poisson", "density", "damping", "lod", "primary", "rate"};

std::string number(double v) {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.15g", v);
    return buf;
}

[[noreturn]] void refuse(const std::string& source, const std::string& field,
                         const std::string& expected, const std::string& found) {
    throw ValueError(source + ": " + field + ": expected " + expected + ", found " + found);
}

[[noreturn]] void malformed(const std::string& source, const std::string& field,
                            const std::string& expected, const std::string& found) {
    throw FormatError(source + ": " + field + ": expected " + expected + ", found " + found);
}

std::string describe(const Json& j) {
    if (j.is_null()) return "null";
    std::string s = j.dump();
    if (s.size() > 40) s = s.substr(0, 37) + "...";
    return std::string(j.type_name()) + " " + s;
}

const Json& field(const Json& obj, const char* name, const std::string& source,
                  const std::string& path) {
    const auto it = obj.find(name);
    if (it == obj.end()) malformed(source, path + name, "a field", "none");
    return *it;
}

double numberAt(const Json& j, const std::string& source, const std::string& path) {
    if (!j.is_number()) malformed(source, path, "a number", describe(j));
    return j.get<double>();
}

}  // namespace error_table_impl

using namespace error_table_impl;

const char* errorVarName(ErrorVar v) noexcept { return kNames[static_cast<std::size_t>(v)]; }

ErrorTable::ErrorTable(std::vector<Axis> axes, std::vector<double> errorPercent,
                       const std::string& source)
    : mAxes(std::move(axes)), mValues(std::move(errorPercent)) {
    if (mAxes.empty() || mAxes.size() > kMaxAxes)
        refuse(source, "axes", "1 to 16 axes", std::to_string(mAxes.size()));
    std::size_t count = 1;
    std::uint32_t seen = 0;
    for (std::size_t a = 0; a < mAxes.size(); ++a) {
        const Axis& ax = mAxes[a];
        const std::string at = "axes[" + std::to_string(a) + "]";
        const std::uint32_t bit = 1u << static_cast<unsigned>(ax.var);
        if (seen & bit)
            refuse(source, at + ".name", "each variable once",
                   std::string(errorVarName(ax.var)) + " again");
        seen |= bit;
        if (ax.values.size() < 2)
            refuse(source, at + ".values", "at least 2 values", std::to_string(ax.values.size()));
        for (std::size_t i = 0; i < ax.values.size(); ++i) {
            const std::string vi = at + ".values[" + std::to_string(i) + "]";
            if (!std::isfinite(ax.values[i]))
                refuse(source, vi, "a finite number", number(ax.values[i]));
            if (i > 0 && !(ax.values[i] > ax.values[i - 1]))
                refuse(source, vi, "a value above " + number(ax.values[i - 1]) + " (increasing)",
                       number(ax.values[i]));
        }
        count *= ax.values.size();
    }
    if (mValues.size() != count)
        refuse(source, "error_percent", std::to_string(count) + " values (the grid's nodes)",
               std::to_string(mValues.size()));
    for (std::size_t i = 0; i < mValues.size(); ++i) {
        if (!(std::isfinite(mValues[i]) && mValues[i] >= 0))
            refuse(source, "error_percent[" + std::to_string(i) + "]", "a finite percentage >= 0",
                   number(mValues[i]));
    }
    mStride.assign(mAxes.size(), 1);
    for (std::size_t a = mAxes.size() - 1; a > 0; --a)
        mStride[a - 1] = mStride[a] * mAxes[a].values.size();
}

const ErrorTable::Axis* ErrorTable::axis(ErrorVar v) const noexcept {
    for (const Axis& a : mAxes)
        if (a.var == v) return &a;
    return nullptr;
}

ErrorEstimate ErrorTable::estimate(const ErrorPoint& x) const noexcept {
    ErrorEstimate out;
    // Per axis: the lower node of the cell and the weight of the upper one.
    std::array<std::size_t, kMaxAxes> lower{};
    std::array<double, kMaxAxes> t{};
    const std::size_t n = mAxes.size();
    for (std::size_t a = 0; a < n; ++a) {
        const std::vector<double>& v = mAxes[a].values;
        double c = x[errorIndex(mAxes[a].var)];
        if (!std::isfinite(c)) return out;
        if (c < v.front() || c > v.back()) {
            out.clampedAxes |= 1u << a;
            c = std::clamp(c, v.front(), v.back());
        }
        std::size_t i = 0;
        while (i + 2 < v.size() && c >= v[i + 1]) ++i;
        lower[a] = i;
        t[a] = (c - v[i]) / (v[i + 1] - v[i]);
    }
    double sum = 0;
    for (std::uint32_t corner = 0; corner < (1u << n); ++corner) {
        double w = 1;
        std::size_t index = 0;
        for (std::size_t a = 0; a < n; ++a) {
            const bool up = (corner >> a) & 1u;
            w *= up ? t[a] : 1 - t[a];
            index += (lower[a] + (up ? 1 : 0)) * mStride[a];
        }
        if (w != 0) sum += w * mValues[index];
    }
    out.percent = sum;
    return out;
}

ErrorTable ErrorTable::parse(const std::string& text, const std::string& source) {
    Json j;
    try {
        j = Json::parse(text);
    } catch (const Json::exception& e) {  // a syntax error, or a number that overflows
        malformed(source, "(file)", "JSON", std::string("an error: ") + e.what());
    }
    if (!j.is_object()) malformed(source, "(file)", "a JSON object", describe(j));
    const Json& version = field(j, "palp_error_table", source, "");
    if (!version.is_number_integer() || version.get<long long>() != 1)
        malformed(source, "palp_error_table", "format version 1", describe(version));
    std::vector<Axis> axes;
    const Json& ja = field(j, "axes", source, "");
    if (!ja.is_array()) malformed(source, "axes", "an array", describe(ja));
    for (std::size_t a = 0; a < ja.size(); ++a) {
        const std::string at = "axes[" + std::to_string(a) + "].";
        if (!ja[a].is_object())
            malformed(source, at.substr(0, at.size() - 1), "an object", describe(ja[a]));
        const Json& name = field(ja[a], "name", source, at);
        if (!name.is_string()) malformed(source, at + "name", "a string", describe(name));
        Axis axis;
        bool known = false;
        for (int v = 0; v < kErrorVarCount; ++v) {
            if (name.get<std::string>() == kNames[static_cast<std::size_t>(v)]) {
                axis.var = static_cast<ErrorVar>(v);
                known = true;
            }
        }
        if (!known)
            malformed(source, at + "name",
                      "one of strain, frequency, youngs, poisson, density, damping, lod, "
                      "primary, rate",
                      describe(name));
        const Json& values = field(ja[a], "values", source, at);
        if (!values.is_array()) malformed(source, at + "values", "an array", describe(values));
        for (std::size_t i = 0; i < values.size(); ++i)
            axis.values.push_back(
                numberAt(values[i], source, at + "values[" + std::to_string(i) + "]"));
        axes.push_back(std::move(axis));
    }
    const Json& jv = field(j, "error_percent", source, "");
    if (!jv.is_array()) malformed(source, "error_percent", "an array", describe(jv));
    std::vector<double> values;
    values.reserve(jv.size());
    for (std::size_t i = 0; i < jv.size(); ++i)
        values.push_back(numberAt(jv[i], source, "error_percent[" + std::to_string(i) + "]"));
    ErrorTable table(std::move(axes), std::move(values), source);
    const Json& response = field(j, "response", source, "");
    if (!response.is_string() ||
        (response != "err_peak" && response != "err_rms" && response != "err_max"))
        malformed(source, "response", "err_peak, err_rms or err_max", describe(response));
    table.response = response.get<std::string>();
    table.quantile = numberAt(field(j, "quantile", source, ""), source, "quantile");
    if (!(table.quantile > 0 && table.quantile < 1))
        refuse(source, "quantile", "a value in (0, 1)", number(table.quantile));
    const Json& coupling = field(j, "coupling", source, "");
    if (!coupling.is_number_integer() || (coupling != 0 && coupling != 1))
        malformed(source, "coupling", "0 (plain) or 1 (condensed)", describe(coupling));
    table.coupling = coupling.get<int>();
    if (const auto p = j.find("provenance"); p != j.end()) {
        if (!p->is_object()) malformed(source, "provenance", "an object", describe(*p));
        table.provenance = p->dump();
    }
    return table;
}

ErrorTable ErrorTable::load(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw IoError(path.string() + ": cannot be read");
    std::ostringstream s;
    s << in.rdbuf();
    if (!in.good() && !in.eof()) throw IoError(path.string() + ": read failed");
    return parse(s.str(), path.string());
}

std::string ErrorTable::toJson() const {
    std::string s = "{\"palp_error_table\": 1, \"response\": \"" + response +
                    "\", \"quantile\": " + number(quantile) +
                    ", \"coupling\": " + std::to_string(coupling) + ",\n \"axes\": [";
    for (std::size_t a = 0; a < mAxes.size(); ++a) {
        s += a ? ",\n   " : "\n   ";
        s += "{\"name\": \"" + std::string(errorVarName(mAxes[a].var)) + "\", \"values\": [";
        for (std::size_t i = 0; i < mAxes[a].values.size(); ++i)
            s += (i ? ", " : "") + number(mAxes[a].values[i]);
        s += "]}";
    }
    s += "],\n \"error_percent\": [";
    for (std::size_t i = 0; i < mValues.size(); ++i) {
        char buf[40];
        std::snprintf(buf, sizeof buf, "%.9g", mValues[i]);
        s += (i ? (i % 12 ? ", " : ",\n  ") : "") + std::string(buf);
    }
    s += "],\n \"provenance\": " + Json::parse(provenance).dump(1) + "}\n";
    return s;
}

}  // namespace palp::haptics
