// The study file's checks (each refusal names the file and the field), the Latin square, and
// the log's refusals: an existing log is never overwritten, a log of another study or of a
// changed study file is not resumed, and the file is left byte for byte as it was.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <set>

#include "palp/base/error.h"
#include "palp/studies/study_log.h"
#include "palp/studies/study_runner.h"
#include "palp/studies/study_spec.h"
#include "study_fixture.h"

namespace palp::haptics {
namespace {

using namespace study_test;

/// The message of the ValueError loading @p j (written to @p dir / name) throws; "" if none.
std::string refusal(const Json& j, const fs::path& dir, const std::string& name = "s.json") {
    spit(dir / name, j.dump());
    try {
        loadStudySpec(dir / name);
    } catch (const ValueError& e) {
        return e.what();
    }
    return "";
}

TEST(StudySpec, TheSmallStudyLoadsWithItsDefaults) {
    const fs::path d = tempDir("spec_ok");
    spit(d / "s.json", smallStudy().dump());
    const StudySpec s = loadStudySpec(d / "s.json");
    EXPECT_EQ(s.id, "small");
    ASSERT_EQ(s.conditions.size(), 2u);
    EXPECT_EQ(s.conditions[0].touch, TouchMode::ContinuousPressure);
    EXPECT_DOUBLE_EQ(s.conditions[0].observer.weber.weberFraction, 0.0523);  // paper III
    EXPECT_DOUBLE_EQ(s.conditions[1].observer.weber.weberFraction, 0.1577);
    EXPECT_EQ(s.conditions[1].profile, volume::TransitionProfile::Tanh);
    EXPECT_EQ(s.conditions[0].mode, CouplingMode::AVC);  // the stiffness scene's coupling
    EXPECT_EQ(s.friction, 0.0);  // the rays read the field under the finger (docs/studies.md)
    EXPECT_DOUBLE_EQ(s.conditions[1].observer.gradient.windowM, 2e-3);
    EXPECT_EQ(s.procedure.staircase.maxTrials, 40);
    EXPECT_NEAR(procedureTarget(s.procedure), std::sqrt(0.5), 1e-12);
    EXPECT_EQ(s.digest.size(), 16u);
    // The digest follows the content, not the file's name or spacing.
    spit(d / "t.json", smallStudy().dump(4));
    EXPECT_EQ(loadStudySpec(d / "t.json").digest, s.digest);
    spit(d / "u.json", smallStudy(41).dump());
    EXPECT_NE(loadStudySpec(d / "u.json").digest, s.digest);
}

TEST(StudySpec, RefusalsNameTheFileAndTheField) {
    const fs::path d = tempDir("spec_bad");
    const std::string file = (d / "s.json").string();
    struct Case {
        const char* why;
        Json study;
        std::string field;
    };
    std::vector<Case> cases;
    Json j = smallStudy();
    j["conditions"][1]["touch"] = "rubbing";
    cases.push_back({"unknown touch mode", j, "conditions[1].touch"});
    j = smallStudy();
    j["conditions"][0]["wieght"] = 1;
    cases.push_back({"unknown condition field", j, "conditions[0].wieght: unknown field"});
    j = smallStudy();
    j["conditions"][0]["mode"] = "spring";
    cases.push_back({"unknown coupling mode", j, "conditions[0].mode: expected vc, avc or avcec"});
    j = smallStudy();
    j["friction"] = -0.1;
    cases.push_back({"negative friction", j, "friction: expected a number in [0, 2]"});
    j = smallStudy();
    j["conditions"][0]["observer"] = {{"kind", "gradient"}, {"window_mm", -1}};
    cases.push_back({"negative observer window", j, "window_mm"});
    j = smallStudy();
    j["conditions"][1]["name"] = "CP";
    cases.push_back({"two conditions of one name", j, "conditions[1].name"});
    j = smallStudy();
    j["procedure"]["max_trials"] = -5;
    cases.push_back({"negative trial count", j, "procedure.max_trials"});
    j = smallStudy();
    j["procedure"]["start_level"] = "NaN";
    cases.push_back({"NaN level (a string)", j, "procedure.start_level"});
    j = smallStudy();
    j["procedure"]["step_sizes"][1] = -4;
    cases.push_back({"negative step", j, "procedure.step_sizes[1]"});
    j = smallStudy();
    j["conditions"][0]["observer"] = {{"weber_fraction", 0}};
    cases.push_back({"zero Weber fraction", j, "conditions[0].observer.weber_fraction"});
    j = smallStudy();
    j["conditions"][0]["observer"] = {{"kind", "gradient"}};
    cases.push_back({"gradient observer on a press", j, "conditions[0].observer.kind"});
    j = smallStudy();
    j["reference_stiffness"] = 400;  // 400 (1.8) 8 > the Touch X's 1480 N/m
    cases.push_back({"stiffer than the device", j, "reference_stiffness"});
    j = smallStudy();
    j["conditions"] = Json::array();
    cases.push_back({"no condition", j, "conditions"});
    j = smallStudy();
    j["study"] = "a,b";
    cases.push_back({"a study id that breaks the CSV", j, "study"});
    for (const Case& c : cases) {
        const std::string m = refusal(c.study, d);
        SCOPED_TRACE(c.why);
        std::printf("%s: %s\n", c.why, m.c_str());
        EXPECT_NE(m.find(file + ": "), std::string::npos) << m;
        EXPECT_NE(m.find(c.field), std::string::npos) << m;
    }
    // NaN as JSON writers outside the standard write it (Python's json.dumps).
    std::string text = smallStudy().dump();
    const std::string from = "\"start_level\":30";
    text.replace(text.find(from), from.size(), "\"start_level\":NaN");
    spit(d / "nan.json", text);
    try {
        loadStudySpec(d / "nan.json");
        ADD_FAILURE() << "a NaN level was accepted";
    } catch (const ValueError& e) {
        const std::string m = e.what();
        EXPECT_NE(m.find((d / "nan.json").string() +
                         ": start_level: expected a finite number, found NaN"),
                  std::string::npos)
            << m;
    }
}

TEST(StudySpec, LatinSquareRowsBalancePositionsAndNeighbours) {
    for (int n : {2, 3, 4, 5, 6}) {
        const int rows = n % 2 == 0 ? n : 2 * n;
        std::vector<std::vector<int>> position(static_cast<std::size_t>(n),
                                               std::vector<int>(static_cast<std::size_t>(n)));
        std::map<std::pair<int, int>, int> pairs;
        for (int r = 0; r < rows; ++r) {
            const auto row = latinSquareRow(n, r);
            ASSERT_EQ(std::set<int>(row.begin(), row.end()).size(), static_cast<std::size_t>(n));
            for (std::size_t p = 0; p < row.size(); ++p)
                position[static_cast<std::size_t>(row[p])][p] += 1;
            for (std::size_t p = 0; p + 1 < row.size(); ++p) pairs[{row[p], row[p + 1]}] += 1;
            EXPECT_EQ(latinSquareRow(n, r + rows), row);  // participants wrap round
        }
        for (const auto& c : position)
            for (int k : c) EXPECT_EQ(k, rows / n) << "n " << n;
        // Every ordered pair of neighbours equally often (Williams' carry-over balance).
        EXPECT_EQ(pairs.size(), static_cast<std::size_t>(n * (n - 1))) << "n " << n;
        for (const auto& [p, k] : pairs) EXPECT_EQ(k, rows / n) << "n " << n;
    }
}

TEST(StudyLog, AnExistingLogIsNeverOverwritten) {
    const fs::path d = tempDir("log_exists");
    spit(d / "log.csv", "a finished study\n");
    StudyLogHeader h{"small", "0123456789abcdef", 0, 11};
    try {
        StudyLog::create(d / "log.csv", h);
        ADD_FAILURE() << "an existing log was accepted";
    } catch (const IoError& e) {
        EXPECT_NE(std::string(e.what()).find((d / "log.csv").string()), std::string::npos);
    }
    EXPECT_EQ(slurp(d / "log.csv"), "a finished study\n");
}

TEST(StudyLog, ALogOfAnotherStudyIsNotResumedAndStaysAsItWas) {
    const fs::path d = tempDir("log_other");
    spit(d / "s.json", smallStudy().dump());
    const StudySpec spec = loadStudySpec(d / "s.json");
    StudyRunner runner(spec, 0);
    {
        StudyLog log = StudyLog::create(d / "log.csv", runner.logHeader());
        TrialAnswer a;
        a.response = 1;
        log.append(runner.record(runner.next(), a));
    }
    const std::string before = slurp(d / "log.csv");
    const auto refused = [&](const StudyLogHeader& h, const std::string& field) {
        std::vector<TrialRecord> t;
        try {
            StudyLog::resume(d / "log.csv", h, t);
            ADD_FAILURE() << "resumed under " << field;
        } catch (const ValueError& e) {
            const std::string m = e.what();
            EXPECT_NE(m.find((d / "log.csv").string() + ": " + field + ": expected"),
                      std::string::npos)
                << m;
        }
        EXPECT_EQ(slurp(d / "log.csv"), before);
    };
    StudyLogHeader h = runner.logHeader();
    h.study = "other";
    refused(h, "study");
    h = runner.logHeader();
    h.digest = "ffffffffffffffff";  // the study file was edited
    refused(h, "digest");
    h = runner.logHeader();
    h.participant = 3;
    refused(h, "participant");
    // The same header resumes, and the trial replays.
    std::vector<TrialRecord> t;
    StudyLog::resume(d / "log.csv", runner.logHeader(), t);
    ASSERT_EQ(t.size(), 1u);
    StudyRunner again(spec, 0);
    again.replay(t, "log.csv");
    EXPECT_EQ(again.trialsDone(), 1);
    // A row cut short (the trial was being written when the run died) is refused, not
    // overwritten.
    spit(d / "cut.csv", before + "small,0,1,CP,1,2");
    StudyLogHeader found;
    EXPECT_THROW(readStudyLog(d / "cut.csv", found), FormatError);
    EXPECT_EQ(slurp(d / "cut.csv"), before + "small,0,1,CP,1,2");
    // A log whose trials are not the study's sequence (an edited level) is refused on replay.
    std::vector<TrialRecord> edited = t;
    edited[0].levelPercent += 1;
    StudyRunner third(spec, 0);
    try {
        third.replay(edited, "log.csv");
        ADD_FAILURE() << "an edited log replayed";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("log.csv: trial 0: level_percent"), std::string::npos)
            << e.what();
    }
}

}  // namespace
}  // namespace palp::haptics
