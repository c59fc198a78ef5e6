// `palp study` end to end: a study stopped by --max-trials and resumed gives the log of an
// uninterrupted run; --analyse refits a log to the JNDs the run reported; the plot's three files;
// refusals (an existing log, a log of another study, a bad study file) name the file and the
// field and leave the log as it was. And `palp palpate --trajectory` with paper III's touch
// modes over the stiffness phantom.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "serve_address.h"
#include "test_support.h"

namespace {

using palp::test::runCommand;
namespace fs = std::filesystem;

nlohmann::json jsonOf(const std::string& output) {
    const auto brace = output.find('{'), last = output.rfind('}');
    if (brace == std::string::npos || last < brace) return nlohmann::json::object();
    const auto j = nlohmann::json::parse(output.substr(brace, last - brace + 1), nullptr, false);
    return j.is_discarded() ? nlohmann::json::object() : j;
}

std::string slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), {});
}

/// The log's rows without the time column (the 15th).
std::vector<std::string> rows(const fs::path& p) {
    std::istringstream in(slurp(p));
    std::vector<std::string> out;
    std::string line;
    while (std::getline(in, line)) {
        if (line.empty() || line[0] == '#' || line.rfind("study,", 0) == 0) continue;
        std::string kept;
        int column = 0;
        for (char c : line) {
            if (c == ',') ++column;
            if (column != 14 || c == ',') kept += c;
        }
        out.push_back(kept);
    }
    return out;
}

const char* kStudy = R"({"study": "cli", "seed": 5, "reference_stiffness": 100,
  "procedure": {"start_level": 20, "step_sizes": [4, 2, 1], "max_trials": 24,
                "max_reversals": 0, "drop_first": 2},
  "fit": {"bootstrap": 40},
  "conditions": [{"name": "DP", "touch": "discontinuous-pressure"},
                 {"name": "CL", "touch": "lateral-sweep", "profile": "cosine"}]})";

TEST(StudyCli, ResumedEqualsUninterruptedAndTheLogRefitsToTheReport) {
    palp::test::TempDir tmp;
    const fs::path study = tmp / "s.json";
    std::ofstream(study) << kStudy;
    const std::string palp = palp::test::palpTool().string() + " study " + study.string();
    const auto whole =
        runCommand(palp + " --log " + (tmp / "whole.csv").string() +
                   " --participant 1 --json --plot " + (tmp / "psy").string() + " 2>/dev/null");
    ASSERT_EQ(whole.exitCode, 0) << whole.output;
    const auto cut = runCommand(palp + " --log " + (tmp / "cut.csv").string() +
                                " --participant 1 --max-trials 19 2>&1");
    EXPECT_EQ(cut.exitCode, 3) << cut.output;  // stopped early, resumable
    EXPECT_NE(cut.output.find("--resume"), std::string::npos) << cut.output;
    const auto resumed = runCommand(palp + " --resume " + (tmp / "cut.csv").string() +
                                    " --participant 1 --json 2>/dev/null");
    ASSERT_EQ(resumed.exitCode, 0) << resumed.output;
    const auto a = rows(tmp / "whole.csv"), b = rows(tmp / "cut.csv");
    ASSERT_EQ(a.size(), 48u);
    EXPECT_EQ(a, b);
    // --analyse refits the log alone to what the run reported.
    const auto refit =
        runCommand(palp + " --analyse " + (tmp / "whole.csv").string() + " --json 2>/dev/null");
    ASSERT_EQ(refit.exitCode, 0) << refit.output;
    const auto jw = jsonOf(whole.output), jr = jsonOf(refit.output), jc = jsonOf(resumed.output);
    ASSERT_EQ(jw["conditions"].size(), 2u) << whole.output;
    for (std::size_t c = 0; c < 2; ++c) {
        for (const char* k : {"jnd_fit_percent", "jnd_procedure_percent"}) {
            EXPECT_DOUBLE_EQ(jw["conditions"][c][k].get<double>(),
                             jr["conditions"][c][k].get<double>())
                << k;
            EXPECT_DOUBLE_EQ(jw["conditions"][c][k].get<double>(),
                             jc["conditions"][c][k].get<double>())
                << k;
        }
        EXPECT_EQ(jw["conditions"][c]["trials"], 24);
    }
    EXPECT_EQ(jw["order"], "CL, DP");  // participant 1: the Latin square's second row
    for (const char* ext : {".png", ".svg", ".pdf"}) {
        EXPECT_GT(fs::file_size(tmp / ("psy" + std::string(ext))), 1000u) << ext;
    }
}

/// The mean rendered stiffness over a trace's contact ticks (N/m) and their count.
std::pair<double, int> contactStiffness(const fs::path& trace) {
    std::istringstream in(slurp(trace));
    std::string line;
    std::getline(in, line);
    int kCol = -1, contactCol = -1, col = 0;
    std::istringstream head(line);
    for (std::string name; std::getline(head, name, ','); ++col) {
        if (name == "stiffness") kCol = col;
        if (name == "contacts") contactCol = col;
    }
    double sum = 0;
    int n = 0;
    while (std::getline(in, line)) {
        std::vector<std::string> c;
        std::istringstream cells(line);
        for (std::string v; std::getline(cells, v, ',');) c.push_back(v);
        if (kCol < 0 || contactCol < 0 || c.size() <= static_cast<std::size_t>(kCol)) break;
        if (std::stoi(c[static_cast<std::size_t>(contactCol)]) == 0) continue;
        sum += std::stod(c[static_cast<std::size_t>(kCol)]);
        ++n;
    }
    return {n ? sum / n : 0.0, n};
}

TEST(StudyCli, APersonsDeviceFeelsEachIntervalAndTheAnswersAreLogged) {
    // The person: `palp bridge-sim` pressing the DP box again and again over UDP (a real
    // socket, the servo thread on each interval), answering 1, 2, 1, 2 on stdin.
    palp::test::TempDir tmp;
    const fs::path study = tmp / "s.json";
    std::ofstream(study) << R"({"study": "device", "seed": 3, "reference_stiffness": 100,
      "procedure": {"start_level": 20, "step_sizes": [4, 2, 1], "max_trials": 4},
      "fit": {"bootstrap": 0},
      "conditions": [{"name": "DP", "touch": "discontinuous-pressure"}]})";
    const std::string palp = palp::test::palpTool().string();
    const std::string err = (tmp / "study.err").string();
    const auto r = runCommand(
        "printf '1\\n2\\n1\\n2\\n' | " + palp + " study " + study.string() + " --log " +
        (tmp / "log.csv").string() +
        " --responder terminal --device-listen 127.0.0.1:0 --interval-seconds 0.8 "
        "--servo-priority 0 --trace-dir " +
        tmp.path().string() + " --json > " + (tmp / "out.json").string() + " 2> " + err +
        " & serve=$!; " + palp::test::shellAwaitServeAddress(err, "palp study") + palp +
        " bridge-sim --connect $addr --from -50,-4,0 --depth 7 --press-seconds 0.15 --hold 0.3 "
        "--rest 0.2 --seconds 9 --device '3D Systems Touch X' > /dev/null; wait $serve; s=$?; "
        "cat " +
        err + "; exit $s");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("interval 2: touch now"), std::string::npos) << r.output;
    std::istringstream in(slurp(tmp / "log.csv"));
    std::string line;
    int trial = 0, reference = 0, comparison = 0;
    std::vector<double> base;  // each contact interval's mean k / (1 + level / 100)
    while (std::getline(in, line)) {
        if (line.empty() || line[0] == '#' || line.rfind("study,", 0) == 0) continue;
        std::vector<std::string> c;
        std::istringstream cells(line);
        for (std::string v; std::getline(cells, v, ',');) c.push_back(v);
        ASSERT_EQ(c.size(), 16u) << line;
        EXPECT_EQ(std::stoi(c[11]), trial % 2 + 1) << line;  // the answers typed
        const double level = std::stod(c[5]);
        const int comparisonInterval = std::stoi(c[6]);
        const std::string traces = c[15];
        const auto semi = traces.find(';');
        ASSERT_NE(semi, std::string::npos) << line;
        for (int i = 1; i <= 2; ++i) {
            const auto [k, n] =
                contactStiffness(i == 1 ? traces.substr(0, semi) : traces.substr(semi + 1));
            if (n < 50) continue;  // the hand was pressed in when the interval began
            const bool isComparison = i == comparisonInterval;
            (isComparison ? comparison : reference) += 1;
            base.push_back(k / (1 + (isComparison ? level : 0) / 100));
            // The log's felt column is what the interval rendered.
            EXPECT_NEAR(std::stod(c[i == 1 ? 9 : 10]), k, 1e-6 * k) << line;
        }
        ++trial;
    }
    EXPECT_EQ(trial, 4);
    // The comparison renders the reference's stiffness times (1 + level / 100): every interval
    // felt comes back to one reference stiffness (the DP box's 3.25 k_s, within the ray's
    // rendering of it).
    ASSERT_GE(reference, 1) << r.output;
    ASSERT_GE(comparison, 1) << r.output;
    const auto [lo, hi] = std::minmax_element(base.begin(), base.end());
    EXPECT_LT(*hi / *lo, 1.01);
    EXPECT_NEAR(*lo, 325, 20);
}

TEST(StudyCli, RefusalsNameTheFileAndFieldAndLeaveTheLog) {
    palp::test::TempDir tmp;
    const fs::path study = tmp / "s.json";
    std::ofstream(study) << kStudy;
    const std::string palp = palp::test::palpTool().string() + " study ";
    const fs::path log = tmp / "log.csv";
    ASSERT_EQ(runCommand(palp + study.string() + " --log " + log.string() + " --max-trials 3 2>&1")
                  .exitCode,
              3);
    const std::string before = slurp(log);
    // --log onto an existing log.
    auto r = runCommand(palp + study.string() + " --log " + log.string() + " 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find(log.string() + ": the study log exists"), std::string::npos)
        << r.output;
    // --resume under another study (the same file but another id).
    nlohmann::json other = nlohmann::json::parse(kStudy);
    other["study"] = "another";
    std::ofstream(tmp / "o.json") << other.dump();
    r = runCommand(palp + (tmp / "o.json").string() + " --resume " + log.string() + " 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find(log.string() + ": study: expected 'another'"), std::string::npos)
        << r.output;
    // --resume after the study file was edited (its digest changed).
    other["study"] = "cli";
    other["procedure"]["max_trials"] = 30;
    std::ofstream(tmp / "e.json") << other.dump();
    r = runCommand(palp + (tmp / "e.json").string() + " --resume " + log.string() + " 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find(log.string() + ": digest: expected"), std::string::npos) << r.output;
    EXPECT_EQ(slurp(log), before);
    // A bad study file: named with its field, no log created.
    other = nlohmann::json::parse(kStudy);
    other["procedure"]["max_trials"] = -1;
    std::ofstream(tmp / "b.json") << other.dump();
    r = runCommand(palp + (tmp / "b.json").string() + " --log " + (tmp / "new.csv").string() +
                   " 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find((tmp / "b.json").string() + ": procedure.max_trials: expected"),
              std::string::npos)
        << r.output;
    EXPECT_FALSE(fs::exists(tmp / "new.csv"));
    // A device address that cannot be bound: refused before any log is created.
    r = runCommand(palp + study.string() + " --log " + (tmp / "new.csv").string() +
                   " --responder terminal --device-listen nonsense 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("--device-listen 'nonsense': expected host:port"), std::string::npos)
        << r.output;
    EXPECT_FALSE(fs::exists(tmp / "new.csv"));
    r = runCommand(palp + study.string() + " --log " + (tmp / "new.csv").string() +
                   " --device-listen 127.0.0.1:0 2>&1");  // the simulated responder
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("--device-listen: expected --responder terminal"), std::string::npos)
        << r.output;
    EXPECT_FALSE(fs::exists(tmp / "new.csv"));
}

TEST(PalpateTouchModes, RunOverTheStiffnessPhantomOnly) {
    const std::string palp = palp::test::palpTool().string() + " palpate --phantom ";
    // The lateral sweep crosses the CL box's transition: soft tissue (k_s 300 N/m), then the
    // hard side (8 k_s asked, the Touch's 1020 N/m rendered).
    auto r = runCommand(palp + "stiffness --trajectory lateral-sweep --json 2>/dev/null");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    auto j = jsonOf(r.output);
    EXPECT_EQ(j["trajectory"], "lateral-sweep");
    EXPECT_NEAR(j["stiffness_min_npm"].get<double>(), 300, 1);
    EXPECT_GT(j["stiffness_max_npm"].get<double>(), 3 * j["stiffness_min_npm"].get<double>())
        << r.output;
    r = runCommand(palp + "stiffness --trajectory continuous-pressure --json 2>/dev/null");
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_GT(jsonOf(r.output)["max_force_n"].get<double>(), 0.1) << r.output;
    r = runCommand(palp + "avc --trajectory continuous-pressure 2>&1");
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("--trajectory continuous-pressure: expected --phantom stiffness"),
              std::string::npos)
        << r.output;
}

}  // namespace
