// Materials from the scan by a table: parse, check, look up (material_table.h).

#include "palp/haptics/tissue/material_table.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/validate.h"

namespace palp::haptics {

namespace {

/// The columns a table may have; a range table has lo and hi, a label table label.
enum Column { kName, kLo, kHi, kLabel, kYoungs, kPoisson, kDensity, kSource, kColumns };
constexpr std::array<std::string_view, kColumns> kColumnNames = {
    "name", "lo", "hi", "label", "youngs_pa", "poisson", "density_kg_m3", "source"};

std::string_view trim(std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
        s.remove_suffix(1);
    return s;
}

/// The fields of one CSV line (double quotes around a field; "" inside them is a quote).
/// @throw palp::FormatError at an unclosed quote.
std::vector<std::string> splitFields(std::string_view line, const std::string& where) {
    std::vector<std::string> out;
    std::string field;
    bool quoted = false, wasQuoted = false;
    for (std::size_t i = 0; i < line.size(); ++i) {
        const char c = line[i];
        if (quoted) {
            if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
                field += '"';
                ++i;
            } else if (c == '"') {
                quoted = false;
            } else {
                field += c;
            }
        } else if (c == '"' && trim(field).empty()) {
            quoted = wasQuoted = true;
            field.clear();
        } else if (c == ',') {
            out.emplace_back(wasQuoted ? field : std::string(trim(field)));
            field.clear();
            wasQuoted = false;
        } else {
            field += c;
        }
    }
    if (quoted) throw FormatError(where + ": expected a closing '\"', found the end of the line");
    out.emplace_back(wasQuoted ? field : std::string(trim(field)));
    return out;
}

/// @p text as a number; "nan" and the like are numbers here, refused by the range checks.
/// @throw palp::FormatError naming @p what when it is not a number.
double number(const std::string& text, const std::string& what) {
    const char* begin = text.c_str();
    char* end = nullptr;
    const double v = std::strtod(begin, &end);
    if (text.empty() || end == begin || *end != '\0')
        throw FormatError(what + ": expected a number, found '" + text + "'");
    return v;
}

std::string rowName(const MaterialRow& r) {
    return "line " + std::to_string(r.line) + " (row '" + r.name + "')";
}

/// Every value of @p r in its range. @throw palp::ValueError naming the row and column.
void checkRow(const MaterialRow& r, MaterialTableKind kind, const std::string& origin) {
    const std::string at = origin + " " + rowName(r) + " ";
    if (kind == MaterialTableKind::ranges) {
        requireWithin(at + "lo", r.lo, bounds::kVolumeValue);
        requireWithin(at + "hi", r.hi, bounds::kVolumeValue);
        if (!(r.lo < r.hi))
            throwExpected(at + "lo, hi", "lo < hi (the row covers lo <= value < hi)",
                          formatValue(r.lo) + ", " + formatValue(r.hi));
    } else {
        requireWithin(at + "label", r.lo, bounds::kVolumeValue);
    }
    requireWithin(at + "youngs_pa", r.youngsModulus, bounds::kYoungsModulus);
    requireWithin(at + "poisson", r.poissonRatio, bounds::kPoissonRatio);
    requireWithin(at + "density_kg_m3", r.density, bounds::kDensity);
}

/// Rows after the first differ in neither nu nor density; ranges do not overlap, labels and
/// names do not repeat. @p rows sorted by lo. @throw palp::ValueError naming both rows.
void checkTogether(const std::vector<MaterialRow>& rows, MaterialTableKind kind,
                   const std::string& origin) {
    // The first row in the file sets the body's nu and density.
    const MaterialRow& first = *std::min_element(
        rows.begin(), rows.end(),
        [](const MaterialRow& a, const MaterialRow& b) { return a.line < b.line; });
    for (const MaterialRow& r : rows) {
        const std::string at = origin + " " + rowName(r) + " ";
        if (r.poissonRatio != first.poissonRatio)
            throwExpected(at + "poisson",
                          formatValue(first.poissonRatio) + ", the Poisson ratio of " +
                              rowName(first) +
                              " (palp's solvers take one Poisson ratio per body: the linear "
                              "element scales one unit stiffness by each element's modulus)",
                          formatValue(r.poissonRatio));
        if (r.density != first.density)
            throwExpected(at + "density_kg_m3",
                          formatValue(first.density) + " kg/m^3, the density of " + rowName(first) +
                              " (palp's solvers take one density per body: one lumped nodal "
                              "mass per element volume)",
                          formatValue(r.density) + " kg/m^3");
    }
    for (std::size_t i = 0; i < rows.size(); ++i) {
        for (std::size_t j = i + 1; j < rows.size(); ++j) {
            if (rows[i].name == rows[j].name)
                throwExpected(origin + " " + rowName(rows[j]) + " name", "a name no other row has",
                              "the name of " + rowName(rows[i]));
        }
    }
    for (std::size_t i = 0; i + 1 < rows.size(); ++i) {
        const MaterialRow &a = rows[i], &b = rows[i + 1];
        if (kind == MaterialTableKind::labels && a.lo == b.lo)
            throwExpected(origin + " " + rowName(b) + " label", "a label no other row has",
                          formatValue(b.lo) + ", the label of " + rowName(a));
        if (kind == MaterialTableKind::ranges && b.lo < a.hi)
            throwExpected(origin + " " + rowName(b) + " lo",
                          "a range that overlaps no other row's: at least " + formatValue(a.hi) +
                              ", where " + rowName(a) + " [" + formatValue(a.lo) + ", " +
                              formatValue(a.hi) + ") ends",
                          formatValue(b.lo));
    }
}

}  // namespace

MaterialTable MaterialTable::parse(std::string_view text, std::string origin) {
    MaterialTable t;
    t.mOrigin = std::move(origin);
    const std::string& o = t.mOrigin;
    std::array<int, kColumns> at{};
    at.fill(-1);
    const auto column = [&at](int c) -> int& { return at[static_cast<std::size_t>(c)]; };
    std::size_t columns = 0;
    bool header = false;
    int lineNo = 0;
    std::size_t pos = 0;
    if (text.substr(0, 3) == "\xEF\xBB\xBF") pos = 3;  // a UTF-8 byte order mark
    while (pos <= text.size()) {
        const std::size_t eol = std::min(text.find('\n', pos), text.size());
        const std::string_view line = trim(text.substr(pos, eol - pos));
        pos = eol + 1;
        ++lineNo;
        if (line.empty() || line.front() == '#') continue;
        const std::string where = o + " line " + std::to_string(lineNo);
        const std::vector<std::string> fields = splitFields(line, where);
        if (!header) {
            for (std::size_t i = 0; i < fields.size(); ++i) {
                const auto known = std::find(kColumnNames.begin(), kColumnNames.end(), fields[i]);
                if (known == kColumnNames.end())
                    throwExpected(where + " (header) column " + std::to_string(i + 1),
                                  "one of name, lo, hi, label, youngs_pa, poisson, "
                                  "density_kg_m3, source",
                                  "'" + fields[i] + "'");
                const auto c = static_cast<std::size_t>(known - kColumnNames.begin());
                if (at[c] >= 0)
                    throw FormatError(where + " (header): expected each column once, found '" +
                                      fields[i] + "' twice");
                at[c] = static_cast<int>(i);
            }
            const bool labels = column(kLabel) >= 0;
            t.mKind = labels ? MaterialTableKind::labels : MaterialTableKind::ranges;
            if (labels && (column(kLo) >= 0 || column(kHi) >= 0))
                throw FormatError(where +
                                  " (header): expected either 'label' (a label table) or 'lo' "
                                  "and 'hi' (a range table), found both");
            for (int c = 0; c < kColumns; ++c) {
                const bool needed = c == kLabel ? labels : (c == kLo || c == kHi) ? !labels : true;
                if (needed && column(c) < 0)
                    throw FormatError(where + " (header): expected the columns " +
                                      (labels ? "name, label" : "name, lo, hi") +
                                      ", youngs_pa, poisson, density_kg_m3, source, found no '" +
                                      std::string(kColumnNames[static_cast<std::size_t>(c)]) + "'");
            }
            columns = fields.size();
            header = true;
            continue;
        }
        if (fields.size() != columns)
            throw FormatError(where + ": expected " + std::to_string(columns) +
                              " fields (as the header), found " + std::to_string(fields.size()));
        const auto field = [&](Column c) -> const std::string& {
            return fields[static_cast<std::size_t>(column(c))];
        };
        MaterialRow r;
        r.line = lineNo;
        r.name = field(kName);
        if (r.name.empty()) throw FormatError(where + " name: expected a name, found none");
        const std::string rowAt = where + " (row '" + r.name + "') ";
        if (t.mKind == MaterialTableKind::ranges) {
            r.lo = number(field(kLo), rowAt + "lo");
            r.hi = number(field(kHi), rowAt + "hi");
        } else {
            r.lo = r.hi = number(field(kLabel), rowAt + "label");
        }
        r.youngsModulus = number(field(kYoungs), rowAt + "youngs_pa");
        r.poissonRatio = number(field(kPoisson), rowAt + "poisson");
        r.density = number(field(kDensity), rowAt + "density_kg_m3");
        r.source = field(kSource);
        if (r.source.empty())
            throw FormatError(rowAt +
                              "source: expected where the numbers come from (a reference, a "
                              "measurement), found none");
        checkRow(r, t.mKind, o);
        t.mRows.push_back(std::move(r));
    }
    if (!header) throw FormatError(o + ": expected a header line and rows, found none");
    if (t.mRows.empty())
        throw FormatError(o + ": expected at least one row after the header, found none");
    std::stable_sort(t.mRows.begin(), t.mRows.end(),
                     [](const MaterialRow& a, const MaterialRow& b) { return a.lo < b.lo; });
    checkTogether(t.mRows, t.mKind, o);
    return t;
}

MaterialTable MaterialTable::load(const std::filesystem::path& file) {
    std::ifstream in(file, std::ios::binary);
    if (!in) throw IoError(file.string() + ": expected a readable material table, found none");
    std::ostringstream s;
    s << in.rdbuf();
    if (!in.good() && !in.eof()) throw IoError(file.string() + ": read failed");
    return parse(s.str(), file.string());
}

std::shared_ptr<const MaterialTable> MaterialTable::named(const std::string& nameOrFile) {
    if (nameOrFile == "ct") return std::make_shared<const MaterialTable>(builtInCt());
    return std::make_shared<const MaterialTable>(load(nameOrFile));
}

double MaterialTable::softestModulus() const noexcept {
    double e = mRows.front().youngsModulus;
    for (const MaterialRow& r : mRows) e = std::min(e, r.youngsModulus);
    return e;
}

double MaterialTable::stiffestModulus() const noexcept {
    double e = mRows.front().youngsModulus;
    for (const MaterialRow& r : mRows) e = std::max(e, r.youngsModulus);
    return e;
}

const MaterialRow* MaterialTable::find(double value) const noexcept {
    // Few rows: a linear scan over the sorted rows.
    for (const MaterialRow& r : mRows) {
        if (mKind == MaterialTableKind::labels) {
            if (static_cast<float>(r.lo) == static_cast<float>(value)) return &r;
        } else if (value >= r.lo && value < r.hi) {
            return &r;
        }
    }
    return nullptr;
}

double MaterialTable::youngsAt(double value) const {
    if (const MaterialRow* r = find(value)) return r->youngsModulus;
    std::ostringstream expected;
    expected << "a row covering every tissue cell's value (rows: ";
    for (std::size_t i = 0; i < mRows.size(); ++i) {
        const MaterialRow& r = mRows[i];
        if (i > 0) expected << ", ";
        if (mKind == MaterialTableKind::labels) {
            expected << formatValue(r.lo);
        } else {
            expected << '[' << formatValue(r.lo) << ", " << formatValue(r.hi) << ')';
        }
    }
    expected << "; a cell is tissue above the tissue threshold and bone above the bone threshold)";
    throwExpected(mOrigin, expected.str(), "none for the value " + formatValue(value));
}

void applyMaterialTable(const std::shared_ptr<const MaterialTable>& table,
                        fem::VoxelizeOptions& voxelize, fem::ElasticMaterial& material) {
    // A bone cell's nodes are all fixed, so its stiffness never acts; it still counts in the
    // explicit step's frequency bound, which the softest modulus never raises.
    const double bone = voxelize.boneThreshold;
    const double softest = table->softestModulus();
    voxelize.youngsFromValue = [table, bone, softest](double value) {
        return value > bone ? softest : table->youngsAt(value);
    };
    voxelize.nearestValue = table->kind() == MaterialTableKind::labels;
    material.poissonRatio = table->poissonRatio();
    material.density = table->density();
    material.youngsModulus = table->softestModulus();
}

}  // namespace palp::haptics
