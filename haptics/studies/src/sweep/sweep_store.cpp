// A sweep's directory: manifest, shards, resume and merge (sweep_store.h).
#include "palp/studies/sweep_store.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <thread>

#include "palp/base/atomic_file.h"
#include "palp/base/error.h"

namespace palp::haptics {

namespace store_impl {

namespace fs = std::filesystem;
using Json = nlohmann::json;

constexpr const char* kShardMagic = "# palp-sweep-shard 1";

std::uint64_t fnv1a(const std::string& s, std::uint64_t h = 0xcbf29ce484222325ull) {
    for (const char ch : s) {
        h ^= static_cast<unsigned char>(ch);
        h *= 0x100000001b3ull;
    }
    return h;
}

std::string hex(std::uint64_t h) {
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
    return buf;
}

std::string readAll(const fs::path& p, const char* what) {
    std::ifstream in(p, std::ios::binary);
    if (!in) throw IoError(p.string() + ": cannot read the " + what);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

void writeText(const fs::path& p, const std::string& what, const std::string& text) {
    writeFileAtomically(p, what, text.data(), text.size());
}

std::string header() {
    std::string h;
    for (const auto& c : sweepColumns()) h += (h.empty() ? "" : ",") + c.name;
    return h;
}

std::string shardName(const SampleRange& r) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "shard-%010lld-%010lld.csv", static_cast<long long>(r.first),
                  static_cast<long long>(r.end));
    return buf;
}

Json manifestJson(const SweepSpec& spec) {
    Json m;
    m["palp_sweep_manifest"] = 1;
    m["sweep"] = spec.id();
    m["palp_version"] = sweepPalpVersion();
    m["design"] = spec.design == SweepDesign::lhs ? "lhs" : "mc";
    m["seed"] = spec.seed;
    m["samples"] = spec.samples;
    m["ranges"] = Json::parse(spec.ranges.canonical);
    return m;
}

/// "key=value" fields of a shard's first or last line.
std::map<std::string, std::string> fields(const std::string& line) {
    std::map<std::string, std::string> f;
    std::istringstream in(line);
    std::string tok;
    while (in >> tok) {
        const auto eq = tok.find('=');
        if (eq != std::string::npos) f[tok.substr(0, eq)] = tok.substr(eq + 1);
    }
    return f;
}

std::int64_t toInt(const std::string& s, const fs::path& file, const char* field) {
    std::size_t used = 0;
    long long v = 0;
    try {
        v = std::stoll(s, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (s.empty() || used != s.size())
        throw FormatError(file.string() + ": field '" + field + "': expected an integer, found '" +
                          s + "'");
    return v;
}

/// Checks the shard at @p file against @p spec; returns its range.
SampleRange checkShard(const fs::path& file, const SweepSpec& spec) {
    const std::string text = readAll(file, "shard");
    std::istringstream in(text);
    std::string first, head, line;
    std::getline(in, first);
    if (first.rfind(kShardMagic, 0) != 0)
        throw FormatError(file.string() + ": first line: expected '" + kShardMagic +
                          " sweep=...', found '" + first.substr(0, 60) + "'");
    auto f = fields(first);
    if (f["sweep"] != spec.id())
        throw ValueError(file.string() + ": field 'sweep': expected " + spec.id() +
                         " (this directory's manifest), found '" + f["sweep"] +
                         "': a shard of another sweep");
    const SampleRange r{toInt(f["first"], file, "first"), toInt(f["end"], file, "end")};
    if (r.first < 0 || r.end <= r.first || r.end > spec.samples)
        throw FormatError(file.string() + ": fields 'first'/'end': expected 0 <= first < end <= " +
                          std::to_string(spec.samples) + ", found " + std::to_string(r.first) +
                          ", " + std::to_string(r.end));
    std::getline(in, head);
    if (head != header())
        throw FormatError(file.string() + ": line 2 (header): expected '" + header() +
                          "', found '" + head.substr(0, 80) + "'");
    std::string rows;
    std::int64_t count = 0;
    std::string last;
    const auto columns = sweepColumns().size();
    while (std::getline(in, line)) {
        if (line.rfind("# end", 0) == 0) {
            last = line;
            break;
        }
        const std::int64_t want = r.first + count;
        const auto comma = line.find(',');
        if (line.substr(0, comma) != std::to_string(want) ||
            static_cast<std::size_t>(std::count(line.begin(), line.end(), ',')) + 1 != columns)
            throw FormatError(file.string() + ": row " + std::to_string(count + 1) +
                              ": expected sample " + std::to_string(want) + " with " +
                              std::to_string(columns) + " fields, found '" + line.substr(0, 60) +
                              "'");
        rows += line + "\n";
        ++count;
    }
    if (last.empty())
        throw FormatError(file.string() +
                          ": field 'end': expected a last line '# end rows=N "
                          "fnv1a64=H', found none (truncated?)");
    auto e = fields(last);
    if (toInt(e["rows"], file, "rows") != r.size() || count != r.size())
        throw FormatError(file.string() + ": field 'rows': expected " + std::to_string(r.size()) +
                          " rows, found " + std::to_string(count) + " (the line says '" +
                          e["rows"] + "')");
    if (e["fnv1a64"] != hex(fnv1a(rows)))
        throw FormatError(file.string() + ": field 'fnv1a64': expected " + hex(fnv1a(rows)) +
                          " (the rows' hash), found '" + e["fnv1a64"] + "': the rows are corrupt");
    if (std::getline(in, line) && !line.empty())
        throw FormatError(file.string() + ": expected nothing after the '# end' line, found '" +
                          line.substr(0, 60) + "'");
    return r;
}

}  // namespace store_impl

using namespace store_impl;

SampleRange shardRange(const SweepSpec& spec, std::int64_t i, std::int64_t n) {
    if (n < 1 || i < 0 || i >= n)
        throw ValueError("--shard: expected i/n with 0 <= i < n, found " + std::to_string(i) + "/" +
                         std::to_string(n));
    const std::int64_t g = spec.groups();
    const std::int64_t g0 = g * i / n, g1 = g * (i + 1) / n;
    return {std::min(spec.samples, g0 * spec.groupSize()),
            std::min(spec.samples, g1 * spec.groupSize())};
}

void prepareSweepDir(const fs::path& dir, const SweepSpec& spec) {
    std::error_code ec;
    fs::create_directories(dir / "shards", ec);
    if (ec) throw IoError(dir.string() + ": cannot create the sweep directory: " + ec.message());
    const fs::path m = dir / "manifest.json";
    if (fs::exists(m)) {
        const SweepSpec have = readSweepManifest(dir);
        if (have.id() == spec.id()) return;
        std::string diff;
        if (have.seed != spec.seed)
            diff += " seed " + std::to_string(have.seed) + " vs " + std::to_string(spec.seed) + ";";
        if (have.samples != spec.samples)
            diff += " samples " + std::to_string(have.samples) + " vs " +
                    std::to_string(spec.samples) + ";";
        if (have.design != spec.design) diff += " design differs;";
        if (have.ranges.canonical != spec.ranges.canonical) diff += " ranges differ;";
        throw ValueError(m.string() + ": field 'sweep': this directory holds sweep " + have.id() +
                         ", not " + spec.id() + " (" + (diff.empty() ? " version" : diff) +
                         " ): use another directory");
    }
    writeText(m, "sweep manifest", manifestJson(spec).dump(2) + "\n");
}

SweepSpec readSweepManifest(const fs::path& dir) {
    const fs::path m = dir / "manifest.json";
    if (!fs::exists(m)) throw IoError(m.string() + ": no sweep manifest (not a sweep directory)");
    Json j;
    try {
        j = Json::parse(readAll(m, "sweep manifest"));
    } catch (const Json::parse_error& e) {
        throw FormatError(m.string() + ": not a JSON manifest: " + e.what());
    }
    auto need = [&](const char* key) -> const Json& {
        if (!j.is_object() || !j.contains(key))
            throw FormatError(m.string() + ": field '" + key + "' is missing");
        return j[key];
    };
    if (need("palp_sweep_manifest") != 1)
        throw FormatError(m.string() + ": field 'palp_sweep_manifest': expected 1, found " +
                          need("palp_sweep_manifest").dump());
    SweepSpec s;
    Json ranges = need("ranges");
    ranges["palp_sweep_ranges"] = 1;
    s.ranges = parseSweepRanges(ranges.dump(), m.string() + " (ranges)");
    const Json& design = need("design");
    if (design != "lhs" && design != "mc")
        throw FormatError(m.string() + ": field 'design': expected \"lhs\" or \"mc\", found " +
                          design.dump());
    s.design = design == "lhs" ? SweepDesign::lhs : SweepDesign::mc;
    if (!need("seed").is_number_unsigned() || !need("samples").is_number_integer())
        throw FormatError(m.string() + ": fields 'seed'/'samples': expected integers");
    s.seed = j["seed"].get<std::uint64_t>();
    s.samples = j["samples"].get<std::int64_t>();
    if (need("palp_version") != sweepPalpVersion())
        throw ValueError(m.string() + ": field 'palp_version': expected " + sweepPalpVersion() +
                         ", found " + j["palp_version"].dump() +
                         ": a sweep of another palp version");
    if (need("sweep") != s.id())
        throw FormatError(m.string() + ": field 'sweep': expected " + s.id() +
                          " (the hash of its ranges, design, seed and samples), found " +
                          j["sweep"].dump() + ": the manifest was edited");
    return s;
}

std::vector<ShardFile> listShards(const fs::path& dir, const SweepSpec& spec, bool strict,
                                  const std::function<void(const std::string&)>& warn) {
    std::vector<ShardFile> out;
    const fs::path sd = dir / "shards";
    if (!fs::is_directory(sd)) return out;
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(sd)) {
        const std::string n = e.path().filename().string();
        if (n.rfind("shard-", 0) == 0 && e.path().extension() == ".csv" &&
            n.find(".timing") == std::string::npos)
            files.push_back(e.path());
    }
    std::sort(files.begin(), files.end());
    for (const auto& f : files) {
        try {
            out.push_back({f, checkShard(f, spec)});
        } catch (const FormatError& e) {
            if (strict) throw;
            // Moved aside (not deleted: it may be evidence), so the recomputed range's shard
            // does not meet it at the merge.
            fs::path aside = f;
            aside += ".corrupt";
            std::error_code ec;
            fs::rename(f, aside, ec);
            if (warn)
                warn(std::string(e.what()) + " (moved to " + aside.filename().string() +
                     "; will be recomputed)");
        }
    }
    std::sort(out.begin(), out.end(),
              [](const ShardFile& a, const ShardFile& b) { return a.range.first < b.range.first; });
    return out;
}

std::vector<SampleRange> missingRanges(const SampleRange& want,
                                       const std::vector<ShardFile>& have) {
    std::vector<SampleRange> covered;
    for (const auto& h : have) covered.push_back(h.range);
    std::sort(covered.begin(), covered.end(),
              [](const SampleRange& a, const SampleRange& b) { return a.first < b.first; });
    std::vector<SampleRange> out;
    std::int64_t at = want.first;
    for (const auto& c : covered) {
        if (c.end <= at || c.first >= want.end) continue;
        if (c.first > at) out.push_back({at, std::min(c.first, want.end)});
        at = std::max(at, c.end);
    }
    if (at < want.end) out.push_back({at, want.end});
    return out;
}

void writeShard(const fs::path& dir, const SweepSpec& spec,
                const std::vector<SweepSampleResult>& results, const std::string& host) {
    if (results.empty()) return;
    const SampleRange r{results.front().index, results.back().index + 1};
    std::string rows, timing = "sample,host,async_s,reference_s\n";
    char buf[96];
    for (const auto& s : results) {
        rows += sweepRow(s) + "\n";
        std::snprintf(buf, sizeof buf, ",%.6f,%.6f\n", s.asyncSeconds, s.referenceSeconds);
        timing += std::to_string(s.index) + "," + host + buf;
    }
    const std::string text =
        std::string(kShardMagic) + " sweep=" + spec.id() + " first=" + std::to_string(r.first) +
        " end=" + std::to_string(r.end) + "\n" + header() + "\n" + rows +
        "# end rows=" + std::to_string(r.size()) + " fnv1a64=" + hex(fnv1a(rows)) + "\n";
    const fs::path p = dir / "shards" / shardName(r);
    // Timing first: a shard that exists always has its timing.
    writeText(fs::path(p).replace_extension(".timing.csv"), "sweep shard timing", timing);
    writeText(p, "sweep shard", text);
}

double runRange(const fs::path& dir, SweepRunner& runner, const SampleRange& range,
                std::int64_t chunk, const std::string& host,
                const std::function<void(std::int64_t)>& progress) {
    double total = 0.0;
    std::vector<SweepSampleResult> part;
    for (std::int64_t i = range.first; i < range.end; ++i) {
        part.push_back(runner.run(i));
        total += part.back().asyncSeconds + part.back().referenceSeconds;
        if (progress) progress(i);
        const bool boundary = (i + 1 - range.first) % chunk == 0;
        if (boundary || i + 1 == range.end) {
            writeShard(dir, runner.sampler().spec(), part, host);
            part.clear();
        }
    }
    return total;
}

std::int64_t mergeSweep(const fs::path& dir, const fs::path& table) {
    const SweepSpec spec = readSweepManifest(dir);
    const auto shards = listShards(dir, spec, true);
    std::int64_t at = 0;
    for (std::size_t k = 0; k < shards.size(); ++k) {
        const auto& s = shards[k];
        if (s.range.first < at)
            throw ValueError(s.path.string() + ": field 'first': samples " +
                             std::to_string(s.range.first) + ".." + std::to_string(at - 1) +
                             " are also in " + shards[k - 1].path.string() +
                             ": overlapping shards (remove one)");
        if (s.range.first > at)
            throw ValueError(dir.string() + ": samples " + std::to_string(at) + ".." +
                             std::to_string(s.range.first - 1) +
                             " are in no shard: run `palp sweep ... --resume` first");
        at = s.range.end;
    }
    if (at < spec.samples)
        throw ValueError(dir.string() + ": samples " + std::to_string(at) + ".." +
                         std::to_string(spec.samples - 1) +
                         " are in no shard: run `palp sweep ... --resume` first");
    std::string out = header() + "\n", timings = "sample,host,async_s,reference_s\n";
    std::set<std::string> hosts;
    for (const auto& s : shards) {
        const std::string text = readAll(s.path, "shard");
        const auto a = text.find('\n', text.find('\n') + 1) + 1;
        const auto b = text.rfind("# end");
        out += text.substr(a, b - a);
        const fs::path tp = fs::path(s.path).replace_extension(".timing.csv");
        if (fs::exists(tp)) {
            const std::string t = readAll(tp, "shard timing");
            std::istringstream in(t);
            std::string line;
            std::getline(in, line);
            while (std::getline(in, line)) {
                timings += line + "\n";
                const auto c1 = line.find(','), c2 = line.find(',', c1 + 1);
                if (c1 != std::string::npos && c2 != std::string::npos)
                    hosts.insert(line.substr(c1 + 1, c2 - c1 - 1));
            }
        }
    }
    Json side;
    side["palp_sweep_table"] = 1;
    side["palp_version"] = sweepPalpVersion();
    side["sweep"] = spec.id();
    side["design"] = spec.design == SweepDesign::lhs ? "lhs" : "mc";
    side["seed"] = spec.seed;
    side["samples"] = spec.samples;
    side["parameters"] = Json::parse(spec.ranges.canonical);
    side["generator"] =
        "Philox4x32-10 (Random123), key = seed, counter = (sample or group index, purpose)";
    side["input"] =
        "contact node of the top face pressed along -z by a (1 - cos 2 pi f t) / 2, "
        "a = strain x cube height, 1 ms ticks; bottom face fixed";
    side["reference"] = "whole fine mesh, explicit central difference below the stable step";
    Json cols = Json::array();
    for (const auto& c : sweepColumns())
        cols.push_back(
            {{"name", c.name}, {"unit", c.unit}, {"role", c.role}, {"description", c.description}});
    side["columns"] = cols;
    side["machine"] = {{"merged_on", sweepHostName()},
                       {"cpu", sweepCpuModel()},
                       {"hosts", Json(std::vector<std::string>(hosts.begin(), hosts.end()))}};
    fs::path sidecar = table, timingPath = table;
    sidecar.replace_extension(".json");
    timingPath.replace_extension(".timings.csv");
    writeText(table, "sweep table", out);
    writeText(sidecar, "sweep table sidecar", side.dump(2) + "\n");
    writeText(timingPath, "sweep timings", timings);
    return spec.samples;
}

std::string sweepHostName() {
    char buf[256] = {};
    if (gethostname(buf, sizeof buf - 1) != 0) return "unknown";
    return buf;
}

std::string sweepCpuModel() {
    std::ifstream in("/proc/cpuinfo");
    std::string line;
    while (std::getline(in, line)) {
        if (line.rfind("model name", 0) == 0) {
            const auto c = line.find(':');
            return c == std::string::npos ? line : line.substr(c + 2);
        }
    }
    return "unknown";
}

}  // namespace palp::haptics
