// `palp study` end to end: a study stopped by --max-trials and resumed gives the log of an
// uninterrupted run; --analyse refits a log to the JNDs the run reported; the plot's three files;
// refusals (an existing log, a log of another study, a bad study file) name the file and the
// field and leave the log as it was. And `palp palpate --trajectory` with paper III's touch
// modes over the stiffness phantom.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

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
