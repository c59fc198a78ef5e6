#include "tree_manifest.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"
#include "palp/volume/convert.h"

namespace palp::tool {

namespace fs = std::filesystem;

namespace {

constexpr const char* kMagicLine = "# palp convert-tree manifest 1";
constexpr const char* kColumns =
    "output\tstatus\tinput\tseries_uid\tformat\tsource_files\tsource_bytes\tbytes\tmessage";
constexpr std::size_t kFieldCount = 9;

std::string escapeField(const std::string& s) {
    std::string out;
    out.reserve(s.size());
    for (const char c : s) {
        switch (c) {
            case '\\':
                out += "\\\\";
                break;
            case '\t':
                out += "\\t";
                break;
            case '\n':
                out += "\\n";
                break;
            case '\r':
                out += "\\r";
                break;
            default:
                out += c;
        }
    }
    return out;
}

std::string unescapeField(const std::string& s) {
    std::string out;
    out.reserve(s.size());
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (s[i] != '\\' || i + 1 == s.size()) {
            out += s[i];
            continue;
        }
        const char n = s[++i];
        out += n == 't' ? '\t' : n == 'n' ? '\n' : n == 'r' ? '\r' : n;
    }
    return out;
}

std::vector<std::string> splitTabs(const std::string& line) {
    std::vector<std::string> fields;
    std::size_t at = 0;
    for (;;) {
        const std::size_t tab = line.find('\t', at);
        fields.push_back(line.substr(at, tab == std::string::npos ? std::string::npos : tab - at));
        if (tab == std::string::npos) return fields;
        at = tab + 1;
    }
}

[[noreturn]] void refuseLine(const fs::path& path, std::size_t lineNo, const std::string& expected,
                             const std::string& found) {
    throw FormatError(path.string() + ":" + std::to_string(lineNo) + ": expected " + expected +
                      ", found " + found);
}

std::uint64_t parseCount(const fs::path& path, std::size_t lineNo, const char* column,
                         const std::string& text) {
    std::uint64_t v = 0;
    std::size_t used = 0;
    try {
        if (!text.empty() && text.front() != '-') v = std::stoull(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (used == 0 || used != text.size())
        refuseLine(path, lineNo, std::string("a count of ") + column, "'" + text + "'");
    return v;
}

TreeStatus parseStatus(const fs::path& path, std::size_t lineNo, const std::string& text) {
    for (const TreeStatus s :
         {TreeStatus::Done, TreeStatus::Refused, TreeStatus::Failed, TreeStatus::Skipped}) {
        if (text == statusName(s)) return s;
    }
    refuseLine(path, lineNo, "a status done, refused, failed or skipped", "'" + text + "'");
}

/// "# KEY\tVALUE" -> VALUE, or nullopt-like empty flag.
bool headerValue(const std::string& line, const std::string& key, std::string& value) {
    const std::string prefix = "# " + key + "\t";
    if (line.compare(0, prefix.size(), prefix) != 0) return false;
    value = line.substr(prefix.size());
    return true;
}

}  // namespace

const char* statusName(TreeStatus s) {
    switch (s) {
        case TreeStatus::Done:
            return "done";
        case TreeStatus::Refused:
            return "refused";
        case TreeStatus::Failed:
            return "failed";
        case TreeStatus::Skipped:
            return "skipped";
    }
    return "failed";
}

std::string manifestName(std::int64_t index, std::int64_t count) {
    if (count == 0) return "manifest.tsv";
    return "manifest.shard-" + std::to_string(index) + "-of-" + std::to_string(count) + ".tsv";
}

void writeManifest(const fs::path& path, const Manifest& m) {
    std::string text = kMagicLine;
    text += "\n# options\t" + escapeField(m.options) + "\n# shard\t" + m.shard + "\n# series\t" +
            std::to_string(m.series) + " of " + std::to_string(m.found) + "\n" + kColumns + "\n";
    for (const ManifestRow& r : m.rows) {
        text += escapeField(r.output) + '\t' + statusName(r.status) + '\t' + escapeField(r.input) +
                '\t' + escapeField(r.seriesUid) + '\t' + r.format + '\t' +
                std::to_string(r.sourceFiles) + '\t' + std::to_string(r.sourceBytes) + '\t' +
                std::to_string(r.bytes) + '\t' + escapeField(r.message) + '\n';
    }
    writeFileAtomically(path, "manifest", text.data(), text.size());
}

Manifest readManifest(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw IoError(path.string() + ": expected a readable manifest, found none");
    Manifest m;
    std::string line;
    std::size_t lineNo = 0;
    bool columns = false;
    while (std::getline(in, line)) {
        ++lineNo;
        if (lineNo == 1) {
            if (line != kMagicLine)
                refuseLine(path, 1, std::string("'") + kMagicLine + "'", "'" + line + "'");
            continue;
        }
        if (!columns) {
            std::string v;
            if (headerValue(line, "options", v)) {
                m.options = unescapeField(v);
            } else if (headerValue(line, "shard", v)) {
                m.shard = v;
            } else if (headerValue(line, "series", v)) {
                const std::size_t of = v.find(" of ");
                if (of == std::string::npos) refuseLine(path, lineNo, "'K of T'", "'" + v + "'");
                m.series = parseCount(path, lineNo, "series", v.substr(0, of));
                m.found = parseCount(path, lineNo, "series found", v.substr(of + 4));
            } else if (line == kColumns) {
                columns = true;
            } else {
                refuseLine(path, lineNo, "a '# options', '# shard', '# series' or column line",
                           "'" + line + "'");
            }
            continue;
        }
        const std::vector<std::string> f = splitTabs(line);
        if (f.size() != kFieldCount) {
            refuseLine(path, lineNo, std::to_string(kFieldCount) + " tab-separated fields",
                       std::to_string(f.size()));
        }
        ManifestRow r;
        r.output = unescapeField(f[0]);
        r.status = parseStatus(path, lineNo, f[1]);
        r.input = unescapeField(f[2]);
        r.seriesUid = unescapeField(f[3]);
        r.format = f[4];
        r.sourceFiles = parseCount(path, lineNo, "source_files", f[5]);
        r.sourceBytes = parseCount(path, lineNo, "source_bytes", f[6]);
        r.bytes = parseCount(path, lineNo, "bytes", f[7]);
        r.message = unescapeField(f[8]);
        m.rows.push_back(std::move(r));
    }
    if (!columns) refuseLine(path, lineNo + 1, "the column line", "the end of the file");
    return m;
}

std::vector<fs::path> listManifests(const fs::path& outDir) {
    std::vector<fs::path> out;
    std::error_code ec;
    for (fs::directory_iterator it(outDir, ec), end; !ec && it != end; it.increment(ec)) {
        const std::string name = it->path().filename().string();
        const bool shard = name.rfind("manifest.shard-", 0) == 0 && name.size() > 19 &&
                           name.compare(name.size() - 4, 4, ".tsv") == 0;
        if (name == "manifest.tsv" || shard) out.push_back(it->path());
    }
    std::sort(out.begin(), out.end());
    return out;
}

bool outputIsValid(const fs::path& outDir, const ManifestRow& row, std::string& why) {
    if (row.status != TreeStatus::Done) {
        why = std::string("listed as ") + statusName(row.status);
        return false;
    }
    const fs::path out = outDir / row.output;
    std::error_code ec;
    const std::uintmax_t size = fs::file_size(out, ec);
    if (ec) {
        why = "output missing";
        return false;
    }
    if (size != row.bytes) {
        why = "output of " + std::to_string(size) + " bytes, the manifest says " +
              std::to_string(row.bytes);
        return false;
    }
    if (volume::detectFormat(out) != volume::Format::Vdb) {
        why = "output is not an OpenVDB file";
        return false;
    }
    return true;
}

namespace {

/// "i/N" -> (i, N); false when @p shard is not of that form.
bool shardOf(const std::string& shard, std::int64_t& i, std::int64_t& n) {
    long long a = 0, b = 0;
    if (std::sscanf(shard.c_str(), "%lld/%lld", &a, &b) != 2 || b < 1 || a < 0 || a >= b)
        return false;
    i = a;
    n = b;
    return true;
}

}  // namespace

int mergeManifests(const fs::path& outDir, bool quiet) {
    std::map<std::int64_t, std::map<std::int64_t, std::pair<fs::path, Manifest>>> byCount;
    for (const fs::path& p : listManifests(outDir)) {
        if (p.filename() == "manifest.tsv") continue;
        Manifest m = readManifest(p);
        std::int64_t i = 0, n = 0;
        if (!shardOf(m.shard, i, n) || p.filename() != manifestName(i, n)) {
            throw FormatError(p.string() + ": expected '# shard\t" +
                              p.filename().string().substr(15) + "' as its name says, found '" +
                              m.shard + "'");
        }
        byCount[n][i] = {p, std::move(m)};
    }
    if (byCount.empty()) {
        throw ValueError(outDir.string() +
                         ": expected shard manifests (manifest.shard-I-of-N.tsv) to merge, "
                         "found none");
    }
    if (byCount.size() > 1) {
        std::string counts;
        for (const auto& [n, shards] : byCount)
            counts += (counts.empty() ? "" : ", ") + std::to_string(n);
        throw ValueError(outDir.string() +
                         ": expected the shard manifests of one shard count, found counts " +
                         counts + " (remove those of the other runs)");
    }
    const auto& [count, shards] = *byCount.begin();
    Manifest merged;
    merged.options = shards.begin()->second.second.options;
    merged.found = shards.begin()->second.second.found;
    int problems = 0;
    const auto say = [&](const std::string& text) {
        ++problems;
        std::fprintf(stderr, "palp convert-tree merge: %s\n", text.c_str());
    };
    for (std::int64_t i = 0; i < count; ++i) {
        const auto at = shards.find(i);
        if (at == shards.end()) {
            say("shard " + std::to_string(i) + "/" + std::to_string(count) +
                ": no manifest (its task has not run or wrote nothing); run it (with --resume)");
            continue;
        }
        const auto& [path, m] = at->second;
        if (m.options != merged.options || m.found != merged.found) {
            throw ValueError(path.string() + ": expected options '" + merged.options + "' and " +
                             std::to_string(merged.found) + " series found, as " +
                             shards.begin()->second.first.string() + " gives, found '" + m.options +
                             "' and " + std::to_string(m.found));
        }
        if (m.rows.size() != m.series) {
            say(path.string() + ": " + std::to_string(m.rows.size()) + " of its " +
                std::to_string(m.series) +
                " series listed (interrupted?); run the shard again with --resume");
        }
        merged.series += m.series;
        merged.rows.insert(merged.rows.end(), m.rows.begin(), m.rows.end());
    }
    std::sort(merged.rows.begin(), merged.rows.end(),
              [](const ManifestRow& a, const ManifestRow& b) {
                  return a.output != b.output ? a.output < b.output : a.input < b.input;
              });
    std::map<TreeStatus, std::uint64_t> tally;
    for (const ManifestRow& r : merged.rows) {
        ++tally[r.status];
        std::string why;
        if (r.status == TreeStatus::Done && !outputIsValid(outDir, r, why))
            say(r.output + " is listed as done but is not valid: " + why);
    }
    const fs::path out = outDir / manifestName(0, 0);
    writeManifest(out, merged);
    if (!quiet) {
        std::printf(
            "palp convert-tree merge: %zu shard manifests into %s: %zu of %llu series listed: "
            "%llu done, %llu refused, %llu failed, %llu skipped\n",
            shards.size(), out.c_str(), merged.rows.size(),
            static_cast<unsigned long long>(merged.found),
            static_cast<unsigned long long>(tally[TreeStatus::Done]),
            static_cast<unsigned long long>(tally[TreeStatus::Refused]),
            static_cast<unsigned long long>(tally[TreeStatus::Failed]),
            static_cast<unsigned long long>(tally[TreeStatus::Skipped]));
    }
    if (tally[TreeStatus::Failed] > 0) return 2;
    return problems > 0 || tally[TreeStatus::Refused] > 0 ? 1 : 0;
}

}  // namespace palp::tool
