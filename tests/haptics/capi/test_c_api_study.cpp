// A perception study through the C API (palp/palp_study.h), as a viewer runs one: each interval
// rendered by palp_study_interval_session on a host device (callbacks; here a SimulatedDevice on
// the condition's touch path behind them, as a host's bridge would do), answered with scripted
// responses. The responses of a simulated run give the same log through the C API, and the
// stiffness the host device rendered in each interval is what the simulated hand felt.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "host_bridge.h"
#include "palp/haptics/devices/simulated_device.h"
#include "palp/palp_study.h"
#include "palp/studies/study_runner.h"
#include "palp/studies/study_stimuli.h"
#include "palp/studies/touch_modes.h"
#include "test_support.h"

namespace ph = palp::haptics;
namespace fs = std::filesystem;

namespace {

using palp::test::Bridge;
using palp::test::bridgeRead;
using palp::test::bridgeWrite;

const char* kStudy = R"({"study": "capi", "seed": 11, "reference_stiffness": 100,
  "procedure": {"start_level": 20, "step_sizes": [4, 2, 1], "max_trials": 8,
                "max_reversals": 0, "drop_first": 2},
  "fit": {"bootstrap": 0},
  "conditions": [{"name": "DP", "touch": "discontinuous-pressure"},
                 {"name": "CL", "touch": "lateral-sweep", "profile": "tanh",
                  "observer": {"kind": "gradient"}}]})";

/// The log's rows without the columns a person's run fills differently (felt_1, felt_2,
/// response_seconds, time_utc, trace).
std::vector<std::string> rows(const fs::path& p) {
    std::ifstream in(p);
    std::vector<std::string> out;
    for (std::string line; std::getline(in, line);) {
        if (line.empty() || line[0] == '#' || line.rfind("study,", 0) == 0) continue;
        std::string kept;
        int column = 0;
        for (char c : line) {
            if (c == ',') ++column;
            if (column < 9 || column == 11 || column == 12) kept += c;
        }
        out.push_back(kept);
    }
    return out;
}

TEST(CApiStudy, AViewersRunWithTheSimulatedAnswersLogsTheSimulatedRunAndRendersWhatItFelt) {
    palp::test::TempDir tmp;
    const fs::path study = tmp / "s.json";
    std::ofstream(study) << kStudy;

    // The simulated run: observers palpating the phantom.
    const ph::StudySpec spec = ph::loadStudySpec(study);
    auto stimuli = std::make_shared<ph::StudyStimuli>(spec);
    {
        ph::StudyRunner runner(spec, 2);
        ph::StudyLog log = ph::StudyLog::create(tmp / "simulated.csv", runner.logHeader());
        ph::runStudyTrials(runner, ph::simulatedResponder(stimuli), log);
    }
    ph::StudyLogHeader header;
    const auto simulated = ph::readStudyLog(tmp / "simulated.csv", header);
    ASSERT_EQ(simulated.size(), 16u);

    // The viewer: the same participant, its device on the touch path, the same answers.
    palp_study* s = nullptr;
    ASSERT_EQ(palp_study_open(study.c_str(), (tmp / "viewer.csv").c_str(), 2, 0, &s), PALP_OK)
        << palp_last_error();
    std::size_t t = 0;
    while (!palp_study_finished(s)) {
        palp_study_trial trial;
        ASSERT_EQ(palp_study_next(s, &trial), PALP_OK) << palp_last_error();
        ASSERT_LT(t, simulated.size());
        const ph::StudyCondition& c = spec.conditions[static_cast<std::size_t>(trial.condition)];
        EXPECT_EQ(std::string(trial.condition_name), c.name);
        EXPECT_DOUBLE_EQ(trial.interval_stiffness[trial.comparison_interval - 1],
                         100 * (1 + trial.level_percent / 100));
        EXPECT_DOUBLE_EQ(trial.interval_stiffness[2 - trial.comparison_interval], 100);
        const ph::TouchPath path = ph::touchPath(c.touch, {c.depthM, c.speedMps});
        for (int i = 1; i <= 2; ++i) {
            ph::SimulatedDevice hand(*ph::findDeviceSpec(spec.device), path.trajectory,
                                     ph::HandModel{}, 1e-3);
            Bridge bridge{&hand};
            palp_device_callbacks cb;
            palp_device_callbacks_default(&cb);
            ASSERT_EQ(palp_device_spec_from_class(spec.device.c_str(), &cb.spec), PALP_OK);
            cb.read_state = bridgeRead;
            cb.write_force = bridgeWrite;
            cb.user = &bridge;
            palp_session* session = nullptr;
            ASSERT_EQ(palp_study_interval_session(s, i, &cb, &session), PALP_OK)
                << palp_last_error();
            const auto ticks = static_cast<int>(std::ceil(path.seconds / 1e-3));
            double sum = 0;
            int contact = 0;
            palp_snapshot snap;
            for (int k = 0; k < ticks; ++k) {
                ASSERT_EQ(palp_session_step(session, 1, &snap), PALP_OK);
                if (snap.time < path.pressedFrom) continue;
                if (snap.contact_count == 0 && !(snap.distance > 1e-6)) continue;
                sum += snap.stiffness;
                ++contact;
            }
            palp_session_release(session);
            const double level = i == trial.comparison_interval ? trial.level_percent : 0.0;
            const ph::IntervalFelt& felt = stimuli->feel(trial.condition, level);
            ASSERT_EQ(contact, felt.contactTicks) << c.name << " interval " << i;
            EXPECT_NEAR(sum / contact, felt.meanStiffnessNpm, 1e-9 * felt.meanStiffnessNpm)
                << c.name << " interval " << i;
        }
        ASSERT_EQ(palp_study_answer(s, simulated[t].response, 0.8, nullptr), PALP_OK)
            << palp_last_error();
        ++t;
    }
    EXPECT_EQ(t, simulated.size());
    palp_study_result results[4];
    int count = 0;
    ASSERT_EQ(palp_study_results(s, results, 4, &count), PALP_OK);
    EXPECT_EQ(count, 2);
    EXPECT_EQ(results[0].trials + results[1].trials, 16);
    palp_study_close(s);
    EXPECT_EQ(rows(tmp / "viewer.csv"), rows(tmp / "simulated.csv"));

    // Reopened with resume on the finished log: nothing more to present.
    ASSERT_EQ(palp_study_open(study.c_str(), (tmp / "viewer.csv").c_str(), -1, 1, &s), PALP_OK)
        << palp_last_error();
    EXPECT_EQ(palp_study_finished(s), 1);
    palp_study_trial none;
    EXPECT_EQ(palp_study_next(s, &none), PALP_ERROR_INVALID_ARGUMENT);
    palp_study_close(s);
}

TEST(CApiStudy, RefusalsNameTheFieldAndLeaveTheLog) {
    palp::test::TempDir tmp;
    const fs::path study = tmp / "s.json";
    std::ofstream(study) << kStudy;
    palp_study* s = nullptr;
    EXPECT_EQ(palp_study_open(nullptr, "x.csv", 0, 0, &s), PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("study_file"), std::string::npos);
    EXPECT_EQ(palp_study_open((tmp / "none.json").c_str(), (tmp / "l.csv").c_str(), 0, 0, &s),
              PALP_ERROR_IO);
    EXPECT_FALSE(fs::exists(tmp / "l.csv"));
    ASSERT_EQ(palp_study_open(study.c_str(), (tmp / "l.csv").c_str(), 0, 0, &s), PALP_OK);
    EXPECT_EQ(palp_study_answer(s, 3, 0.5, nullptr), PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("response: expected 1 or 2"), std::string::npos)
        << palp_last_error();
    EXPECT_EQ(palp_study_answer(s, 1, std::nan(""), nullptr), PALP_ERROR_INVALID_ARGUMENT);
    palp_device_callbacks cb;
    palp_device_callbacks_default(&cb);
    cb.read_state = bridgeRead;
    palp_session* session = nullptr;
    EXPECT_EQ(palp_study_interval_session(s, 3, &cb, &session), PALP_ERROR_INVALID_ARGUMENT);
    EXPECT_NE(std::string(palp_last_error()).find("study interval: expected 1 or 2, found 3"),
              std::string::npos)
        << palp_last_error();
    EXPECT_EQ(session, nullptr);
    ASSERT_EQ(palp_study_answer(s, 1, 0.5, "a.csv;b.csv"), PALP_OK);
    palp_study_close(s);
    // A new log over an existing one is refused and the log is left as it was.
    std::ifstream in(tmp / "l.csv");
    const std::string before((std::istreambuf_iterator<char>(in)), {});
    EXPECT_EQ(palp_study_open(study.c_str(), (tmp / "l.csv").c_str(), 0, 0, &s), PALP_ERROR_IO);
    EXPECT_NE(std::string(palp_last_error()).find("the study log exists"), std::string::npos)
        << palp_last_error();
    std::ifstream again(tmp / "l.csv");
    EXPECT_EQ(std::string((std::istreambuf_iterator<char>(again)), {}), before);
}

}  // namespace
