// The study log: append-only CSV with a header, read back for a refit or a resume.
#include "palp/studies/study_log.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include "palp/base/error.h"

namespace palp::haptics {

namespace {

constexpr const char* kMagic = "# palp study log 1";
constexpr const char* kColumns =
    "study,participant,trial,condition,condition_trial,level_percent,comparison_interval,"
    "reference_stiffness_npm,comparison_stiffness_npm,felt_1,felt_2,response,correct,"
    "response_seconds,time_utc,trace";
constexpr int kColumnCount = 16;

std::string num(double v) {
    if (std::isnan(v)) return "nan";
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

std::vector<std::string> splitCsv(const std::string& line) {
    std::vector<std::string> out(1);
    for (char c : line) {
        if (c == ',') {
            out.emplace_back();
        } else {
            out.back() += c;
        }
    }
    return out;
}

[[noreturn]] void bad(const std::filesystem::path& p, int line, const std::string& what) {
    throw FormatError(p.string() + ":" + std::to_string(line) + ": " + what);
}

double toDouble(const std::filesystem::path& p, int line, const char* column,
                const std::string& s) {
    if (s == "nan") return std::nan("");
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(s.c_str(), &end);
    if (s.empty() || *end != '\0' || errno == ERANGE || !std::isfinite(v))
        bad(p, line, std::string(column) + ": expected a number, found '" + s + "'");
    return v;
}

long long toInt(const std::filesystem::path& p, int line, const char* column, const std::string& s,
                long long lo, long long hi) {
    char* end = nullptr;
    errno = 0;
    const long long v = std::strtoll(s.c_str(), &end, 10);
    if (s.empty() || *end != '\0' || errno == ERANGE || v < lo || v > hi)
        bad(p, line,
            std::string(column) + ": expected an integer in [" + std::to_string(lo) + ", " +
                std::to_string(hi) + "], found '" + s + "'");
    return v;
}

std::string headerText(const StudyLogHeader& h) {
    std::ostringstream o;
    o << kMagic << "\n# study " << h.study << "\n# digest " << h.digest << "\n# participant "
      << h.participant << "\n# seed " << h.seed << "\n"
      << kColumns << "\n";
    return o.str();
}

}  // namespace

const char* studyLogColumns() noexcept { return kColumns; }

std::vector<TrialRecord> readStudyLog(const std::filesystem::path& path, StudyLogHeader& header) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw IoError(path.string() + ": cannot read the study log");
    std::ostringstream ss;
    ss << in.rdbuf();
    const std::string all = ss.str();
    if (!all.empty() && all.back() != '\n') {
        int lines = 1;
        for (char c : all) lines += c == '\n' ? 1 : 0;
        bad(path, lines,
            "the last row is cut short (no end of line): the trial it logs was not finished; "
            "remove that line to resume");
    }
    std::istringstream text(all);
    std::string line;
    int n = 0;
    const auto next = [&]() -> bool {
        if (!std::getline(text, line)) return false;
        ++n;
        return true;
    };
    if (!next() || line != kMagic) bad(path, 1, "expected '" + std::string(kMagic) + "'");
    bool haveStudy = false, haveDigest = false, haveParticipant = false, haveSeed = false;
    for (;;) {
        if (!next()) bad(path, n, "expected the column line, found the end of the file");
        if (line.rfind("# ", 0) != 0) break;
        const auto sp = line.find(' ', 2);
        const std::string key =
            line.substr(2, sp == std::string::npos ? std::string::npos : sp - 2);
        const std::string value = sp == std::string::npos ? "" : line.substr(sp + 1);
        if (key == "study") {
            header.study = value;
            haveStudy = true;
        } else if (key == "digest") {
            header.digest = value;
            haveDigest = true;
        } else if (key == "participant") {
            header.participant = static_cast<int>(toInt(path, n, "participant", value, 0, 1 << 30));
            haveParticipant = true;
        } else if (key == "seed") {
            char* end = nullptr;
            header.seed = std::strtoull(value.c_str(), &end, 10);
            if (value.empty() || *end != '\0')
                bad(path, n, "seed: expected an integer, found '" + value + "'");
            haveSeed = true;
        }
    }
    if (!haveStudy || !haveDigest || !haveParticipant || !haveSeed)
        bad(path, n, "expected a header with study, digest, participant and seed");
    if (line != kColumns) bad(path, n, "expected the columns '" + std::string(kColumns) + "'");
    std::vector<TrialRecord> out;
    while (next()) {
        const auto c = splitCsv(line);
        if (static_cast<int>(c.size()) != kColumnCount)
            bad(path, n,
                "expected " + std::to_string(kColumnCount) + " columns, found " +
                    std::to_string(c.size()));
        if (c[0] != header.study)
            bad(path, n,
                "study: expected '" + header.study + "' (the header's), found '" + c[0] + "'");
        TrialRecord r;
        r.trial = static_cast<int>(toInt(path, n, "trial", c[2], 0, 1 << 30));
        r.conditionName = c[3];
        r.condition = -1;
        r.conditionTrial = static_cast<int>(toInt(path, n, "condition_trial", c[4], 0, 1 << 30));
        r.levelPercent = toDouble(path, n, "level_percent", c[5]);
        r.comparisonInterval = static_cast<int>(toInt(path, n, "comparison_interval", c[6], 1, 2));
        r.referenceStiffnessNpm = toDouble(path, n, "reference_stiffness_npm", c[7]);
        r.comparisonStiffnessNpm = toDouble(path, n, "comparison_stiffness_npm", c[8]);
        r.felt1 = toDouble(path, n, "felt_1", c[9]);
        r.felt2 = toDouble(path, n, "felt_2", c[10]);
        r.response = static_cast<int>(toInt(path, n, "response", c[11], 1, 2));
        r.correct = toInt(path, n, "correct", c[12], 0, 1) == 1;
        if (r.correct != (r.response == r.comparisonInterval))
            bad(path, n,
                "correct: expected " + std::to_string(r.response == r.comparisonInterval) +
                    " (response " + c[11] + ", comparison in interval " + c[6] + "), found " +
                    c[12]);
        r.responseSeconds = toDouble(path, n, "response_seconds", c[13]);
        r.timeUtc = c[14];
        r.trace = c[15];
        if (r.trial != static_cast<int>(out.size()))
            bad(path, n, "trial: expected " + std::to_string(out.size()) + ", found " + c[2]);
        out.push_back(std::move(r));
    }
    return out;
}

StudyLog::StudyLog(std::filesystem::path path, std::FILE* file, StudyLogHeader header)
    : mPath(std::move(path)), mFile(file), mHeader(std::move(header)) {}

StudyLog::StudyLog(StudyLog&& other) noexcept
    : mPath(std::move(other.mPath)), mFile(other.mFile), mHeader(std::move(other.mHeader)) {
    other.mFile = nullptr;
}

StudyLog::~StudyLog() {
    if (mFile) std::fclose(mFile);
}

StudyLog StudyLog::create(const std::filesystem::path& path, const StudyLogHeader& header) {
    // "x": exclusive creation, so an existing log (a finished study, another participant's) is
    // refused rather than truncated, even when two runs race for the name.
    std::FILE* f = std::fopen(path.c_str(), "wx");
    if (!f) {
        const int e = errno;
        if (e == EEXIST)
            throw IoError(path.string() +
                          ": the study log exists; give --resume to continue it or another name");
        throw IoError(path.string() + ": cannot create the study log: " + std::strerror(e));
    }
    StudyLog log(path, f, header);
    const std::string h = headerText(header);
    if (std::fwrite(h.data(), 1, h.size(), f) != h.size() || std::fflush(f) != 0 ||
        ::fsync(fileno(f)) != 0)
        throw IoError(path.string() + ": cannot write the study log: " + std::strerror(errno));
    return log;
}

StudyLog StudyLog::resume(const std::filesystem::path& path, const StudyLogHeader& expected,
                          std::vector<TrialRecord>& trials) {
    StudyLogHeader found;
    trials = readStudyLog(path, found);
    const auto refuse = [&](const char* field, const std::string& want, const std::string& got) {
        throw ValueError(path.string() + ": " + field + ": expected " + want + ", found " + got +
                         ": this log belongs to another study or participant; it is left as it "
                         "was");
    };
    if (found.study != expected.study)
        refuse("study", "'" + expected.study + "'", "'" + found.study + "'");
    if (found.digest != expected.digest)
        refuse("digest", expected.digest + " (the study file as it is now)",
               found.digest + " (the study file was changed since the log began)");
    if (found.participant != expected.participant)
        refuse("participant", std::to_string(expected.participant),
               std::to_string(found.participant));
    if (found.seed != expected.seed)
        refuse("seed", std::to_string(expected.seed), std::to_string(found.seed));
    std::FILE* f = std::fopen(path.c_str(), "a");
    if (!f)
        throw IoError(path.string() + ": cannot append to the study log: " + std::strerror(errno));
    return StudyLog(path, f, found);
}

void StudyLog::append(const TrialRecord& r) {
    std::ostringstream o;
    o << mHeader.study << ',' << mHeader.participant << ',' << r.trial << ',' << r.conditionName
      << ',' << r.conditionTrial << ',' << num(r.levelPercent) << ',' << r.comparisonInterval << ','
      << num(r.referenceStiffnessNpm) << ',' << num(r.comparisonStiffnessNpm) << ',' << num(r.felt1)
      << ',' << num(r.felt2) << ',' << r.response << ',' << (r.correct ? 1 : 0) << ','
      << num(r.responseSeconds) << ',' << r.timeUtc << ',' << r.trace << '\n';
    const std::string row = o.str();
    if (std::fwrite(row.data(), 1, row.size(), mFile) != row.size() || std::fflush(mFile) != 0 ||
        ::fsync(fileno(mFile)) != 0)
        throw IoError(mPath.string() + ": cannot append to the study log: " + std::strerror(errno));
}

}  // namespace palp::haptics
