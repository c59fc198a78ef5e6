// NRRD header parser: palp's own reading of teem's format description (NRRD0001..NRRD0005).
#include <Eigen/Core>
#include <array>
#include <cmath>
#include <limits>
#include <map>

#include "formats/header_parsers.h"
#include "formats/raw_data.h"
#include "formats/reader_util.h"
#include "palp/base/error.h"

namespace palp::volume {

namespace fs = std::filesystem;
using detail::lower;
using detail::quoteFound;
using detail::trim;

namespace {

struct Field {
    std::string value;
    int line = 0;
};

std::optional<ElementType> nrrdType(const std::string& t) {
    static const std::map<std::string, ElementType> kTypes = {
        {"signed char", ElementType::Int8},
        {"int8", ElementType::Int8},
        {"int8_t", ElementType::Int8},
        {"uchar", ElementType::UInt8},
        {"unsigned char", ElementType::UInt8},
        {"uint8", ElementType::UInt8},
        {"uint8_t", ElementType::UInt8},
        {"short", ElementType::Int16},
        {"short int", ElementType::Int16},
        {"signed short", ElementType::Int16},
        {"signed short int", ElementType::Int16},
        {"int16", ElementType::Int16},
        {"int16_t", ElementType::Int16},
        {"ushort", ElementType::UInt16},
        {"unsigned short", ElementType::UInt16},
        {"unsigned short int", ElementType::UInt16},
        {"uint16", ElementType::UInt16},
        {"uint16_t", ElementType::UInt16},
        {"int", ElementType::Int32},
        {"signed int", ElementType::Int32},
        {"int32", ElementType::Int32},
        {"int32_t", ElementType::Int32},
        {"uint", ElementType::UInt32},
        {"unsigned int", ElementType::UInt32},
        {"uint32", ElementType::UInt32},
        {"uint32_t", ElementType::UInt32},
        {"longlong", ElementType::Int64},
        {"long long", ElementType::Int64},
        {"long long int", ElementType::Int64},
        {"signed long long", ElementType::Int64},
        {"signed long long int", ElementType::Int64},
        {"int64", ElementType::Int64},
        {"int64_t", ElementType::Int64},
        {"ulonglong", ElementType::UInt64},
        {"unsigned long long", ElementType::UInt64},
        {"unsigned long long int", ElementType::UInt64},
        {"uint64", ElementType::UInt64},
        {"uint64_t", ElementType::UInt64},
        {"float", ElementType::Float32},
        {"double", ElementType::Float64},
    };
    const auto it = kTypes.find(t);
    if (it == kTypes.end()) return std::nullopt;
    return it->second;
}

/// Fields palp reads or knowingly ignores; anything else is refused.
bool knownField(const std::string& key) {
    static const char* const kKnown[] = {"dimension",
                                         "type",
                                         "sizes",
                                         "endian",
                                         "encoding",
                                         "content",
                                         "block size",
                                         "blocksize",
                                         "space",
                                         "space dimension",
                                         "space directions",
                                         "space origin",
                                         "space units",
                                         "spacings",
                                         "thicknesses",
                                         "axis mins",
                                         "axismins",
                                         "axis maxs",
                                         "axismaxs",
                                         "centers",
                                         "centerings",
                                         "labels",
                                         "units",
                                         "kinds",
                                         "min",
                                         "max",
                                         "old min",
                                         "oldmin",
                                         "old max",
                                         "oldmax",
                                         "data file",
                                         "datafile",
                                         "line skip",
                                         "lineskip",
                                         "byte skip",
                                         "byteskip",
                                         "number",
                                         "sample units",
                                         "sampleunits",
                                         "measurement frame"};
    for (const char* k : kKnown) {
        if (key == k) return true;
    }
    return false;
}

class Parser {
  public:
    Parser(const std::map<std::string, Field>& fields, const std::string& name)
        : mFields(fields), mName(name) {}

    const Field* find(const char* a, const char* b = nullptr) const {
        auto it = mFields.find(a);
        if (it != mFields.end()) return &it->second;
        if (b) {
            it = mFields.find(b);
            if (it != mFields.end()) return &it->second;
        }
        return nullptr;
    }

    [[noreturn]] void fail(const Field& f, const std::string& key,
                           const std::string& expected) const {
        throw FormatError(mName + ": line " + std::to_string(f.line) + ": expected '" + key + "' " +
                          expected + ", found " + quoteFound(f.value));
    }

    std::int64_t integer(const Field& f, const std::string& key, std::int64_t lo,
                         std::int64_t hi) const {
        const auto v = detail::toInt(f.value);
        if (!v || *v < lo || *v > hi) {
            fail(f, key,
                 "with an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
        }
        return *v;
    }

    /// Exactly @p n doubles (NaN allowed).
    std::vector<double> doubles(const Field& f, const std::string& key, int n) const {
        const auto w = detail::words(f.value);
        std::vector<double> out;
        for (const auto& tok : w) {
            const auto v = detail::toDouble(tok);
            if (!v) fail(f, key, "with " + std::to_string(n) + " numbers");
            out.push_back(*v);
        }
        if (static_cast<int>(out.size()) != n)
            fail(f, key, "with " + std::to_string(n) + " numbers");
        return out;
    }

    /// Exactly @p n words.
    std::vector<std::string> strings(const Field& f, const std::string& key, int n) const {
        const auto w = detail::words(f.value);
        if (static_cast<int>(w.size()) != n) fail(f, key, "with " + std::to_string(n) + " values");
        std::vector<std::string> out;
        for (const auto& s : w) out.push_back(lower(s));
        return out;
    }

    /// Parses "(a,b,c)" with @p n components starting at @p pos; advances pos.
    std::optional<std::vector<double>> vector(std::string_view s, std::size_t& pos, int n) const {
        while (pos < s.size() && std::isspace(static_cast<unsigned char>(s[pos])) != 0) ++pos;
        if (pos >= s.size() || s[pos] != '(') return std::nullopt;
        const std::size_t close = s.find(')', pos);
        if (close == std::string_view::npos) return std::nullopt;
        std::string_view inner = s.substr(pos + 1, close - pos - 1);
        pos = close + 1;
        std::vector<double> out;
        std::size_t b = 0;
        for (;;) {
            const std::size_t comma = inner.find(',', b);
            const auto v = detail::toDouble(
                inner.substr(b, comma == std::string_view::npos ? inner.size() - b : comma - b));
            if (!v) return std::nullopt;
            out.push_back(*v);
            if (comma == std::string_view::npos) break;
            b = comma + 1;
            if (static_cast<int>(out.size()) > n) return std::nullopt;
        }
        if (static_cast<int>(out.size()) != n) return std::nullopt;
        return out;
    }

  private:
    const std::map<std::string, Field>& mFields;
    const std::string& mName;
};

/// Reads the magic line and the fields of @p text into @p h (version, blank-line end, header
/// size); returns the fields by lower-case name.
std::map<std::string, Field> readFields(std::string_view text, const std::string& name,
                                        NrrdHeader& h) {
    std::size_t pos = 0;
    int lineNo = 0;
    auto nextLine = [&](std::string_view& line) {
        if (pos >= text.size()) return false;
        const std::size_t e = text.find('\n', pos);
        const std::size_t end = e == std::string_view::npos ? text.size() : e;
        line = text.substr(pos, end - pos);
        pos = e == std::string_view::npos ? text.size() : e + 1;
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        ++lineNo;
        return true;
    };

    std::string_view line;
    if (!nextLine(line) || line.size() != 8 || line.substr(0, 7) != "NRRD000" || line[7] < '1' ||
        line[7] > '5') {
        throw FormatError(name + ": line 1: expected the magic 'NRRD0001' to 'NRRD0005', found " +
                          quoteFound(line.substr(0, std::min<std::size_t>(line.size(), 16))));
    }
    h.version = line[7] - '0';

    std::map<std::string, Field> fields;
    while (nextLine(line)) {
        if (line.empty()) {
            h.blankLineEnd = true;
            break;
        }
        if (line.front() == '#') continue;
        const std::size_t kv = line.find(":=");
        const std::size_t colon = line.find(": ");
        if (kv != std::string_view::npos && (colon == std::string_view::npos || kv < colon))
            continue;
        if (colon == std::string_view::npos) {
            throw FormatError(
                name + ": line " + std::to_string(lineNo) +
                ": expected a 'field: value' line, a 'key:=value' pair or a '#' comment, found " +
                quoteFound(line));
        }
        const std::string key = lower(trim(line.substr(0, colon)));
        if (!knownField(key)) {
            throw FormatError(name + ": line " + std::to_string(lineNo) +
                              ": expected a NRRD field, found " + quoteFound(key));
        }
        if (fields.count(key) != 0) {
            throw FormatError(name + ": line " + std::to_string(lineNo) +
                              ": expected each field once, found '" + key + "' again");
        }
        fields[key] = Field{std::string(trim(line.substr(colon + 2))), lineNo};
    }
    h.headerBytes = pos;
    return fields;
}

/// The field @p key (or its alias @p alt). @throw FormatError when it is missing.
const Field& requireField(const Parser& p, const std::string& name, const char* key,
                          const char* alt = nullptr) {
    const Field* f = p.find(key, alt);
    if (!f) {
        throw FormatError(name + ": expected a '" + std::string(key) +
                          "' field in the NRRD header, found none");
    }
    return *f;
}

/// Dimension, type, sizes, encoding, endian and content.
void parseLayout(const Parser& p, const std::string& name, NrrdHeader& h) {
    auto require = [&](const char* key) -> const Field& { return requireField(p, name, key); };
    const Field& fDim = require("dimension");
    h.dimension = static_cast<int>(p.integer(fDim, "dimension", 1, kMaxAxes));
    const int n = h.dimension;

    const Field& fType = require("type");
    const auto type = nrrdType(lower(fType.value));
    if (!type) {
        p.fail(
            fType, "type",
            "with a scalar type (int8, uint8, int16, uint16, int32, uint32, int64, uint64, float, "
            "double or a C spelling of them)");
    }
    h.type = *type;

    const Field& fSizes = require("sizes");
    for (const auto& tok : detail::words(fSizes.value)) {
        const auto v = detail::toInt(tok);
        if (!v || *v <= 0)
            p.fail(fSizes, "sizes", "with " + std::to_string(n) + " positive integers");
        h.sizes.push_back(*v);
    }
    if (static_cast<int>(h.sizes.size()) != n)
        p.fail(fSizes, "sizes", "with " + std::to_string(n) + " positive integers");

    const Field& fEnc = require("encoding");
    h.encodingGiven = true;
    {
        const std::string e = lower(fEnc.value);
        if (e == "raw") {
            h.encoding = NrrdEncoding::Raw;
        } else if (e == "gzip" || e == "gz") {
            h.encoding = NrrdEncoding::Gzip;
        } else if (e == "ascii" || e == "text" || e == "txt") {
            h.encoding = NrrdEncoding::Ascii;
        } else {
            p.fail(fEnc, "encoding", "with raw, gzip or ascii (palp does not read bzip2 or hex)");
        }
    }

    if (const Field* f = p.find("endian")) {
        const std::string e = lower(f->value);
        if (e == "little") {
            h.endian = ByteOrder::Little;
        } else if (e == "big") {
            h.endian = ByteOrder::Big;
        } else {
            p.fail(*f, "endian", "with little or big");
        }
        h.endianGiven = true;
    } else if (elementSize(h.type) > 1 && h.encoding != NrrdEncoding::Ascii) {
        throw FormatError(name + ": expected an 'endian' field for type " +
                          elementTypeName(h.type) + " with " + lower(fEnc.value) +
                          " encoding, found none");
    }

    if (const Field* f = p.find("content")) h.content = f->value;
}

/// The space (its name, dimension and the axis flips to LPS).
void parseSpace(const Parser& p, NrrdHeader& h) {
    if (const Field* f = p.find("space")) {
        const std::string s = lower(f->value);
        struct SpaceDef {
            const char* longName;
            const char* shortName;
            double sx, sy;
            int dim;
        };
        static const SpaceDef kSpaces[] = {
            {"right-anterior-superior", "ras", -1, -1, 3},
            {"left-anterior-superior", "las", 1, -1, 3},
            {"left-posterior-superior", "lps", 1, 1, 3},
            {"right-anterior-superior-time", "rast", -1, -1, 4},
            {"left-anterior-superior-time", "last", 1, -1, 4},
            {"left-posterior-superior-time", "lpst", 1, 1, 4},
            {"3d-right-handed", "3drh", 1, 1, 3},
            {"3d-right-handed-time", "3drht", 1, 1, 4},
            {"scanner-xyz", "scanner-xyz", 1, 1, 3},
            {"scanner-xyz-time", "scanner-xyz-time", 1, 1, 4},
        };
        bool found = false;
        for (const SpaceDef& d : kSpaces) {
            if (s == d.longName || s == d.shortName) {
                h.toLps = Eigen::Vector3d(d.sx, d.sy, 1);
                h.spaceDimension = d.dim;
                h.space = d.longName;
                found = true;
                break;
            }
        }
        if (!found) {
            p.fail(*f, "space",
                   "with right-anterior-superior, left-anterior-superior, left-posterior-superior "
                   "(or RAS, LAS, LPS, their -time variants), 3D-right-handed or scanner-xyz");
        }
    }
    if (const Field* f = p.find("space dimension")) {
        const auto d = static_cast<int>(p.integer(*f, "space dimension", 3, 4));
        if (h.spaceDimension != 0 && d != h.spaceDimension) {
            p.fail(*f, "space dimension",
                   "equal to the dimension of space '" + h.space + "' (" +
                       std::to_string(h.spaceDimension) + ")");
        }
        h.spaceDimension = d;
    }
}

/// Space directions, origin and units.
void parseSpaceGeometry(const Parser& p, NrrdHeader& h) {
    const int n = h.dimension;
    if (const Field* f = p.find("space directions")) {
        if (h.spaceDimension == 0) {
            p.fail(*f, "space directions", "after a 'space' or 'space dimension' field");
        }
        std::string_view s = f->value;
        std::size_t q = 0;
        for (int a = 0; a < n; ++a) {
            while (q < s.size() && std::isspace(static_cast<unsigned char>(s[q])) != 0) ++q;
            if (s.substr(q, 4) == "none") {
                h.spaceDirections.emplace_back(std::nullopt);
                q += 4;
                continue;
            }
            const auto v = p.vector(s, q, h.spaceDimension);
            if (!v) {
                p.fail(*f, "space directions",
                       "with " + std::to_string(n) + " vectors of " +
                           std::to_string(h.spaceDimension) + " numbers or 'none'");
            }
            const Eigen::Vector3d d((*v)[0], (*v)[1], (*v)[2]);
            if (!d.allFinite()) p.fail(*f, "space directions", "with finite vectors");
            h.spaceDirections.emplace_back(d);
        }
        if (!trim(s.substr(std::min(q, s.size()))).empty()) {
            p.fail(*f, "space directions", "with exactly " + std::to_string(n) + " entries");
        }
    }
    if (const Field* f = p.find("space origin")) {
        if (h.spaceDimension == 0)
            p.fail(*f, "space origin", "after a 'space' or 'space dimension' field");
        std::size_t q = 0;
        const auto v = p.vector(f->value, q, h.spaceDimension);
        if (!v || !trim(std::string_view(f->value).substr(q)).empty()) {
            p.fail(*f, "space origin",
                   "with one vector of " + std::to_string(h.spaceDimension) + " numbers");
        }
        h.spaceOrigin = Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]);
        if (!h.spaceOrigin->allFinite()) p.fail(*f, "space origin", "with finite numbers");
    }
    if (const Field* f = p.find("space units")) {
        if (h.spaceDimension == 0)
            p.fail(*f, "space units", "after a 'space' or 'space dimension' field");
        std::vector<std::string> units;
        std::string_view s = f->value;
        std::size_t q = 0;
        while (q < s.size()) {
            const std::size_t open = s.find('"', q);
            if (open == std::string_view::npos) break;
            const std::size_t close = s.find('"', open + 1);
            if (close == std::string_view::npos) p.fail(*f, "space units", "with quoted units");
            units.push_back(lower(s.substr(open + 1, close - open - 1)));
            q = close + 1;
        }
        if (static_cast<int>(units.size()) != h.spaceDimension) {
            p.fail(*f, "space units", "with " + std::to_string(h.spaceDimension) + " quoted units");
        }
        double scale = 0;
        for (int i = 0; i < 3; ++i) {
            const std::string& u = units[static_cast<std::size_t>(i)];
            double s1 = 0;
            if (u == "mm" || u.empty()) {
                s1 = 1e-3;
            } else if (u == "m") {
                s1 = 1;
            } else if (u == "cm") {
                s1 = 1e-2;
            } else if (u == "um" || u == "micron" || u == "microns") {
                s1 = 1e-6;
            } else {
                p.fail(*f, "space units", "with mm, cm, m or um");
            }
            if (i > 0 && s1 != scale)
                p.fail(*f, "space units", "with the same unit on all three axes");
            scale = s1;
        }
        h.spaceUnitsToMetres = scale;
    }
}

/// Per-axis fields (spacings, mins, maxs, thicknesses, centerings, kinds) and where the data is.
void parseAxesAndData(const Parser& p, NrrdHeader& h) {
    const int n = h.dimension;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    h.spacingsGiven = p.find("spacings") != nullptr;
    h.spacings = h.spacingsGiven ? p.doubles(*p.find("spacings"), "spacings", n)
                                 : std::vector<double>(static_cast<std::size_t>(n), nan);
    const Field* fMin = p.find("axis mins", "axismins");
    h.axisMins = fMin ? p.doubles(*fMin, "axis mins", n)
                      : std::vector<double>(static_cast<std::size_t>(n), nan);
    const Field* fMax = p.find("axis maxs", "axismaxs");
    h.axisMaxs = fMax ? p.doubles(*fMax, "axis maxs", n)
                      : std::vector<double>(static_cast<std::size_t>(n), nan);
    h.axisRangeGiven = fMin != nullptr && fMax != nullptr;
    if (const Field* f = p.find("thicknesses")) (void)p.doubles(*f, "thicknesses", n);
    if (const Field* f = p.find("centerings", "centers"))
        h.centerings = p.strings(*f, "centerings", n);
    if (const Field* f = p.find("kinds")) {
        // Kinds may be quoted and may contain spaces in theory ("2D-symmetric-matrix" has none);
        // palp only needs to tell spatial from non-spatial axes.
        h.kinds = p.strings(*f, "kinds", n);
    }
    if (const Field* f = p.find("data file", "datafile")) {
        const std::string v = f->value;
        if (v.empty()) p.fail(*f, "data file", "with a file name");
        if (v.rfind("LIST", 0) == 0) {
            p.fail(*f, "data file", "with a single file name (palp does not read the LIST form)");
        }
        if (v.find('%') != std::string::npos && detail::words(v).size() > 1) {
            p.fail(*f, "data file",
                   "with a single file name (palp does not read the printf-style multi-file form)");
        }
        h.dataFile = v;
    }
    if (const Field* f = p.find("line skip", "lineskip")) {
        h.lineSkip = p.integer(*f, "line skip", 0, std::numeric_limits<std::int32_t>::max());
    }
    if (const Field* f = p.find("byte skip", "byteskip")) {
        h.byteSkip = p.integer(*f, "byte skip", -1, std::numeric_limits<std::int64_t>::max() / 4);
        if (h.byteSkip == -1 && h.encoding != NrrdEncoding::Raw) {
            p.fail(*f, "byte skip", "of -1 only with raw encoding");
        }
    }
}

}  // namespace

NrrdHeader parseNrrdHeader(std::string_view text, const std::string& name) {
    NrrdHeader h;
    const std::map<std::string, Field> fields = readFields(text, name, h);
    const Parser p(fields, name);
    parseLayout(p, name, h);
    parseSpace(p, h);
    parseSpaceGeometry(p, h);
    parseAxesAndData(p, h);
    return h;
}

}  // namespace palp::volume
