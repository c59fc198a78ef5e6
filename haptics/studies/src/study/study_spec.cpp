// Reading a study file: every field checked, every refusal naming the file and the field.
#include "palp/studies/study_spec.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <sstream>

#include "palp/base/error.h"
#include "palp/haptics/devices/device.h"

namespace palp::haptics {

namespace {

using Json = nlohmann::json;

/// One JSON object being read: its path in the file ("conditions[1].observer") and the keys
/// read so far, so that what is left over can be refused as unknown.
class Fields {
  public:
    Fields(const Json& j, std::string path, const std::string& source)
        : mJ(j), mPath(std::move(path)), mSource(source) {
        if (!mJ.is_object()) fail("", "an object", mJ.dump());
    }

    [[noreturn]] void fail(const std::string& key, const std::string& expected,
                           const std::string& found) const {
        throw ValueError(mSource + ": " + name(key) + ": expected " + expected + ", found " +
                         found);
    }
    std::string name(const std::string& key) const {
        if (key.empty()) return mPath.empty() ? "the study" : mPath;
        return mPath.empty() ? key : mPath + "." + key;
    }
    bool has(const std::string& key) {
        mKnown.insert(key);
        return mJ.contains(key);
    }
    const Json& at(const std::string& key) {
        mKnown.insert(key);
        return mJ.at(key);
    }

    /// A finite number in [lo, hi] (NaN, an infinity, a string: refused).
    double number(const std::string& key, double fallback, double lo, double hi,
                  const char* unit = "") {
        if (!has(key)) return fallback;
        const Json& v = mJ.at(key);
        std::ostringstream want;
        want << "a number in [" << lo << ", " << hi << "]" << (*unit ? " " : "") << unit;
        if (!v.is_number()) fail(key, want.str(), v.dump());
        const double x = v.get<double>();
        if (!std::isfinite(x) || x < lo || x > hi) fail(key, want.str(), v.dump());
        return x;
    }
    int integer(const std::string& key, int fallback, int lo, int hi) {
        if (!has(key)) return fallback;
        const Json& v = mJ.at(key);
        const std::string want =
            "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
        if (!v.is_number_integer()) fail(key, want, v.dump());
        const auto x = v.get<long long>();
        if (x < lo || x > hi) fail(key, want, v.dump());
        return static_cast<int>(x);
    }
    std::string text(const std::string& key, const std::string& fallback) {
        if (!has(key)) return fallback;
        const Json& v = mJ.at(key);
        if (!v.is_string()) fail(key, "a string", v.dump());
        return v.get<std::string>();
    }
    bool flag(const std::string& key, bool fallback) {
        if (!has(key)) return fallback;
        const Json& v = mJ.at(key);
        if (!v.is_boolean()) fail(key, "true or false", v.dump());
        return v.get<bool>();
    }
    /// Refuses the keys never asked for.
    void done() const {
        for (auto it = mJ.begin(); it != mJ.end(); ++it) {
            if (mKnown.count(it.key()) == 0) {
                std::string known;
                for (const auto& k : mKnown) known += (known.empty() ? "" : ", ") + k;
                throw ValueError(mSource + ": " + name(it.key()) +
                                 ": unknown field (expected one of " + known + ")");
            }
        }
    }
    const std::string& path() const { return mPath; }

  private:
    const Json& mJ;
    std::string mPath;
    const std::string& mSource;
    std::set<std::string> mKnown;
};

bool plainName(const std::string& s) {
    if (s.empty() || s.size() > 64) return false;
    for (char c : s) {
        const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') ||
                        (c >= '0' && c <= '9') || c == '-' || c == '_' || c == '.';
        if (!ok) return false;
    }
    return true;
}

std::string inQuotes(const std::string& s) { return "'" + s + "'"; }

StudyObserver readObserver(Fields& f, TouchMode touch) {
    StudyObserver o;
    o.kind = f.text("kind", "weber");
    if (o.kind != "weber" && o.kind != "gradient")
        f.fail("kind", "weber or gradient", inQuotes(o.kind));
    const std::string felt = f.text("felt", "stiffness");
    if (felt == "stiffness") {
        o.felt = FeltQuantity::Stiffness;
    } else if (felt == "force") {
        o.felt = FeltQuantity::Force;
    } else {
        f.fail("felt", "stiffness or force", inQuotes(felt));
    }
    o.weber.weberFraction = f.number("weber_fraction", thesisWeberFraction(touch), 1e-4, 10);
    o.weber.criterionLevel = f.number("criterion_level", o.weber.criterionLevel, 0.5001, 0.9999);
    o.weber.lapseRate = f.number("lapse_rate", 0, 0, 0.5);
    o.gradient.weberAtReference = f.number("weber_at_reference", 0.1795, 1e-4, 10);
    o.gradient.referenceGradientPerM = f.number("reference_gradient", 100, 1e-3, 1e6, "1/m");
    o.gradient.exponent = f.number("exponent", 0.442, 0, 10);  // calibrated, algorithms.md 14
    o.gradient.minWeber = f.number("min_weber", 0.01, 1e-4, 10);
    o.gradient.maxWeber = f.number("max_weber", 1, 1e-4, 10);
    o.gradient.windowM = f.number("window_mm", 2, 0, 20, "mm") * 1e-3;
    if (o.gradient.maxWeber < o.gradient.minWeber)
        f.fail("max_weber", ">= min_weber", std::to_string(o.gradient.maxWeber));
    o.gradient.criterionLevel = o.weber.criterionLevel;
    o.gradient.lapseRate = o.weber.lapseRate;
    if (o.kind == "gradient" && touch != TouchMode::LateralSweep)
        f.fail("kind", "weber for a pressure mode (gradient needs lateral-sweep)", "'gradient'");
    f.done();
    return o;
}

StudyCondition readCondition(Fields& f) {
    StudyCondition c;
    c.name = f.text("name", "");
    if (!plainName(c.name))
        f.fail("name", "1-64 letters, digits, '-', '_' or '.'", inQuotes(c.name));
    const std::string touch = f.text("touch", "");
    if (!isTouchModeName(touch))
        f.fail("touch", "continuous-pressure, discontinuous-pressure or lateral-sweep",
               inQuotes(touch));
    c.touch = parseTouchMode("touch", touch);
    const std::string profile = f.text("profile", "linear");
    try {
        c.profile = volume::parseProfile(profile);
    } catch (const ValueError&) {
        f.fail("profile", "linear, cosine or tanh", inQuotes(profile));
    }
    c.depthM = f.number("depth_mm", 0, 0, 20, "mm") * 1e-3;
    c.speedMps = f.number("speed_mm_s", 0, 0, 1000, "mm/s") * 1e-3;
    const std::string mode = f.text("mode", "avc");
    if (mode == "vc") {
        c.mode = CouplingMode::VC;
    } else if (mode == "avc") {
        c.mode = CouplingMode::AVC;
    } else if (mode == "avcec") {
        c.mode = CouplingMode::AVCEC;
    } else {
        f.fail("mode", "vc, avc or avcec", inQuotes(mode));
    }
    return c;
}

void readStaircase(Fields& f, perception::StaircaseParams& s) {
    s.startLevel = f.number("start_level", 30, 1e-6, 1e6, "%");
    s.down = f.integer("down", 2, 1, 10);
    s.up = f.integer("up", 1, 1, 10);
    s.upDownRatio = f.number("up_down_ratio", 1, 1e-3, 1e3);
    s.stepSizes = {8, 4, 2};
    if (f.has("step_sizes")) {
        const Json& v = f.at("step_sizes");
        if (!v.is_array() || v.empty())
            f.fail("step_sizes", "a non-empty array of numbers > 0", v.dump());
        s.stepSizes.clear();
        for (std::size_t i = 0; i < v.size(); ++i) {
            const std::string key = "step_sizes[" + std::to_string(i) + "]";
            if (!v[i].is_number() || !(v[i].get<double>() > 0) ||
                !std::isfinite(v[i].get<double>()))
                f.fail(key, "a finite number > 0", v[i].dump());
            s.stepSizes.push_back(v[i].get<double>());
        }
    }
    const std::string scale = f.text("scale", "linear");
    if (scale == "linear") {
        s.scale = perception::StepScale::Linear;
    } else if (scale == "log10") {
        s.scale = perception::StepScale::Log10;
    } else if (scale == "db") {
        s.scale = perception::StepScale::Decibel;
    } else {
        f.fail("scale", "linear, log10 or db", inQuotes(scale));
    }
    s.oneUpOneDownUntilFirstReversal = f.flag("one_up_one_down_start", true);
    s.minLevel = f.number("min_level", 0.5, 0, 1e6, "%");
    s.maxLevel = f.number("max_level", 80, 0, 1e6, "%");
    if (!(s.maxLevel > s.minLevel)) f.fail("max_level", "> min_level", std::to_string(s.maxLevel));
    if (s.startLevel < s.minLevel || s.startLevel > s.maxLevel)
        f.fail("start_level", "a level in [min_level, max_level]", std::to_string(s.startLevel));
    s.maxTrials = f.integer("max_trials", 80, 1, 100000);
    s.maxReversals = f.integer("max_reversals", 12, 0, 100000);
}

void readQuest(Fields& f, StudyProcedure& p) {
    perception::QuestParams& q = p.quest;
    q.tGuess = std::log10(f.number("guess_level", 15, 1e-3, 1e4, "%"));
    q.tGuessSd = f.number("guess_sd", 0.5, 1e-3, 10, "log10 units");
    q.pThreshold = f.number("p_threshold", 0.7071, 0.51, 0.99);
    q.beta = f.number("beta", 3.5, 0.1, 100);
    q.delta = f.number("delta", 0.01, 0, 0.5);
    q.gamma = 0.5;
    q.grain = f.number("grain", 0.01, 1e-4, 1);
    q.range = f.number("range", 5, 0.1, 20);
}

StudyProcedure readProcedure(Fields& f) {
    StudyProcedure p;
    const std::string method = f.text("method", "staircase");
    if (method == "staircase") {
        p.method = StudyMethod::Staircase;
    } else if (method == "quest") {
        p.method = StudyMethod::Quest;
    } else {
        f.fail("method", "staircase or quest", inQuotes(method));
    }
    readStaircase(f, p.staircase);
    p.minLevel = p.staircase.minLevel;
    p.maxLevel = p.staircase.maxLevel;
    p.dropFirst = f.integer("drop_first", 4, 0, 1000);
    p.useLast = f.integer("use_last", 0, 0, 1000);
    p.quest.maxTrials = p.staircase.maxTrials;
    p.quest.maxIntervalWidth = 0;
    return p;
}

/// FNV-1a (64 bit) of @p s, as 16 hex digits.
std::string digestOf(const std::string& s) {
    std::uint64_t h = 1469598103934665603ull;
    for (char c : s) {
        h ^= static_cast<unsigned char>(c);
        h *= 1099511628211ull;
    }
    char buf[17];
    std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(h));
    return buf;
}

}  // namespace

StudySpec parseStudySpec(std::string_view text, const std::string& source) {
    Json j;
    try {
        j = Json::parse(text);
    } catch (const Json::parse_error& e) {
        // JSON has no NaN or infinity; name the field that holds one (as Python's json writes
        // them) rather than the parser's position alone.
        static const std::regex kNonFinite(
            "\"([A-Za-z0-9_]+)\"\\s*:\\s*(-?(NaN|nan|Infinity|inf))");
        std::match_results<std::string_view::const_iterator> m;
        if (std::regex_search(text.begin(), text.end(), m, kNonFinite)) {
            throw ValueError(source + ": " + m[1].str() + ": expected a finite number, found " +
                             m[2].str());
        }
        throw ValueError(source + ": expected JSON, found a syntax error: " + e.what());
    }
    StudySpec s;
    s.source = source;
    Fields f(j, "", source);
    s.id = f.text("study", "");
    if (!plainName(s.id)) f.fail("study", "1-64 letters, digits, '-', '_' or '.'", inQuotes(s.id));
    const double seed = f.number("seed", 1, 0, 9007199254740992.0);
    if (seed != std::floor(seed)) f.fail("seed", "an integer >= 0", std::to_string(seed));
    s.seed = static_cast<std::uint64_t>(seed);
    s.referenceStiffnessNpm = f.number("reference_stiffness", 100, 1, 5000, "N/m");
    s.device = f.text("device", s.device);
    const DeviceSpec* device = findDeviceSpec(s.device);
    if (device == nullptr)
        f.fail("device", "a device palp knows (palp info --devices)", inQuotes(s.device));
    s.voxelM = f.number("voxel_mm", 1, 0.25, 2, "mm") * 1e-3;
    s.friction = f.number("friction", 0, 0, 2);

    // The procedure first: the conditions' checks need its largest level.
    if (!f.has("procedure")) f.fail("procedure", "an object", "nothing");
    {
        Fields p(f.at("procedure"), "procedure", source);
        s.procedure = readProcedure(p);
        if (s.procedure.method == StudyMethod::Quest && p.has("quest")) {
            Fields q(p.at("quest"), "procedure.quest", source);
            readQuest(q, s.procedure);
            q.done();
        } else if (p.has("quest")) {
            // A staircase study may keep its QUEST settings for later; they are checked.
            Fields q(p.at("quest"), "procedure.quest", source);
            StudyProcedure unused;
            readQuest(q, unused);
            q.done();
        } else if (s.procedure.method == StudyMethod::Quest) {
            const Json none = Json::object();
            Fields q(none, "procedure.quest", source);
            readQuest(q, s.procedure);
        }
        p.done();
        try {
            perception::validateStaircase(s.procedure.staircase);
            if (s.procedure.method == StudyMethod::Quest)
                perception::validateQuest(s.procedure.quest);
        } catch (const ValueError& e) {
            throw ValueError(source + ": procedure: " + e.what());
        }
    }
    if (f.has("fit")) {
        Fields fit(f.at("fit"), "fit", source);
        const std::string shape = fit.text("shape", "weibull");
        try {
            s.fit.shape = perception::parseShape("fit.shape", shape);
        } catch (const ValueError&) {
            fit.fail("shape", "weibull, logistic or gaussian", inQuotes(shape));
        }
        s.fit.lambdaMax = fit.number("lambda_max", 0.06, 0, 0.49);
        s.fit.bootstrap = fit.integer("bootstrap", 200, 0, 100000);
        s.fit.coverage = fit.number("coverage", 0.95, 0.5, 0.999);
        fit.done();
    }

    if (!f.has("conditions") || !f.at("conditions").is_array() || f.at("conditions").empty())
        f.fail("conditions", "a non-empty array of conditions",
               f.has("conditions") ? f.at("conditions").dump() : "nothing");
    const Json& conds = f.at("conditions");
    std::set<std::string> names;
    for (std::size_t i = 0; i < conds.size(); ++i) {
        Fields c(conds[i], "conditions[" + std::to_string(i) + "]", source);
        StudyCondition cond = readCondition(c);
        if (c.has("observer")) {
            Fields o(c.at("observer"), c.name("observer"), source);
            cond.observer = readObserver(o, cond.touch);
        } else {
            const Json none = Json::object();
            Fields o(none, c.name("observer"), source);
            cond.observer = readObserver(o, cond.touch);
        }
        c.done();
        if (!names.insert(cond.name).second)
            c.fail("name", "a name no other condition has", inQuotes(cond.name));
        s.conditions.push_back(std::move(cond));
    }
    f.done();

    // The largest comparison must be renderable: k_s (1 + max level) m_max within the device.
    const double mMax = 8;  // sceneCouplingDefaults' maxMultiplier
    const double top = s.referenceStiffnessNpm * (1 + s.procedure.maxLevel / 100) * mMax;
    if (top > device->maxStiffnessNpm) {
        std::ostringstream m;
        m << source << ": reference_stiffness: expected at most "
          << device->maxStiffnessNpm / ((1 + s.procedure.maxLevel / 100) * mMax) << " N/m (the "
          << s.device << "'s " << device->maxStiffnessNpm
          << " N/m must hold the comparison at procedure.max_level " << s.procedure.maxLevel
          << " % over the phantom's hardest box, 8 k_s), found " << s.referenceStiffnessNpm;
        throw ValueError(m.str());
    }
    s.digest = digestOf(j.dump());
    return s;
}

StudySpec loadStudySpec(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw IoError(path.string() + ": cannot read the study file");
    std::ostringstream ss;
    ss << in.rdbuf();
    return parseStudySpec(ss.str(), path.string());
}

double procedureTarget(const StudyProcedure& procedure) {
    if (procedure.method == StudyMethod::Quest) return procedure.quest.pThreshold;
    const auto& s = procedure.staircase;
    return perception::staircaseTarget(s.down, s.up, s.upDownRatio);
}

std::vector<int> latinSquareRow(int n, int row) {
    std::vector<int> out;
    if (n <= 0) return out;
    const int rows = n % 2 == 0 ? n : 2 * n;
    row = ((row % rows) + rows) % rows;
    const int shift = row % n;
    // Williams: 0, 1, n-1, 2, n-2, ... shifted by the row.
    for (int j = 0; j < n; ++j) {
        const int base = j == 0 ? 0 : (j % 2 == 1 ? (j + 1) / 2 : n - j / 2);
        out.push_back((base + shift) % n);
    }
    if (row >= n) std::reverse(out.begin(), out.end());
    return out;
}

}  // namespace palp::haptics
