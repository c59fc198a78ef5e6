// The 2IFC study runner on simulated observers that palpate the stiffness phantom: the log
// refits (by this test's own reading and its own staircase) to the thresholds the runner
// reported; a study interrupted and resumed from its log gives the trial sequence of an
// uninterrupted run; the touch modes rank as paper III found when the observers carry its
// Weber fractions; the rendered stiffness follows the CL box's transition profiles, so a
// gradient-sensitive observer ranks them as paper IV found.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <sstream>

#include "palp/perception/observer.h"
#include "palp/perception/psychometric_fit.h"
#include "palp/studies/study_runner.h"
#include "palp/studies/study_stimuli.h"
#include "palp/volume/phantom.h"
#include "study_fixture.h"

namespace palp::haptics {
namespace {

using namespace study_test;

struct Row {
    std::string condition;
    double level = 0;
    int order = 0, response = 0;
    bool correct = false;
    std::string line;  ///< the row without its time column
};

/// The log's rows, read with nothing of palp's (the CSV as a spreadsheet would see it).
std::vector<Row> readRows(const fs::path& log) {
    std::istringstream in(slurp(log));
    std::string line;
    std::vector<Row> rows;
    bool columns = false;
    while (std::getline(in, line)) {
        if (line.empty() || line[0] == '#') continue;
        if (!columns) {
            columns = true;  // study,participant,trial,condition,...
            continue;
        }
        std::vector<std::string> c(1);
        for (char ch : line) {
            if (ch == ',') {
                c.emplace_back();
            } else {
                c.back().push_back(ch);
            }
        }
        EXPECT_EQ(c.size(), 16u) << line;
        Row r;
        r.condition = c[3];
        r.level = std::stod(c[5]);
        r.order = std::stoi(c[6]);
        r.response = std::stoi(c[11]);
        r.correct = c[12] == "1";
        EXPECT_EQ(r.correct, r.response == r.order) << line;
        c[14].clear();  // time_utc
        for (const auto& s : c) r.line += s + ",";
        rows.push_back(r);
    }
    return rows;
}

/// Levitt's 1-up-2-down with the 1-up-1-down start, steps by reversal count, linear, bounded:
/// the reversal levels of @p correct from @p start.
std::vector<double> reversals(const std::vector<bool>& correct, const std::vector<double>& levels,
                              double start, const std::vector<double>& steps, double lo,
                              double hi) {
    std::vector<double> out;
    double level = start;
    int run = 0, last = 0;
    for (std::size_t i = 0; i < correct.size(); ++i) {
        EXPECT_NEAR(levels[i], level, 1e-9) << "trial " << i;  // the runner presented this
        const int n = out.empty() ? 1 : 2;
        int dir = 0;
        if (correct[i]) {
            if (++run >= n) dir = -1, run = 0;
        } else {
            dir = +1, run = 0;
        }
        if (dir != 0) {
            if (last != 0 && dir != last) out.push_back(level);
            last = dir;
            const double step = steps[std::min(out.size(), steps.size() - 1)];
            level = std::clamp(level + dir * step, lo, hi);
        }
    }
    return out;
}

TEST(StudyRunner, TheLogRefitsToTheThresholdsTheRunnerReported) {
    const fs::path d = tempDir("refit");
    spit(d / "s.json", smallStudy(40).dump());
    const StudySpec spec = loadStudySpec(d / "s.json");
    auto stimuli = std::make_shared<StudyStimuli>(spec);
    StudyRunner runner(spec, 1);
    std::vector<TrialRecord> records;
    {
        StudyLog log = StudyLog::create(d / "log.csv", runner.logHeader());
        const StudyResponder sim = simulatedResponder(stimuli);
        EXPECT_EQ(runStudyTrials(runner, sim, log), 80);
    }
    EXPECT_TRUE(runner.finished());
    StudyLogHeader h;
    records = readStudyLog(d / "log.csv", h);
    const auto reported = analyseStudy(spec, records);
    const auto rows = readRows(d / "log.csv");
    ASSERT_EQ(rows.size(), 80u);
    std::printf("%d palpation sessions for 80 trials\n", stimuli->sessionsRun());
    for (std::size_t c = 0; c < spec.conditions.size(); ++c) {
        std::map<double, perception::ResponseBlock> blocks;
        std::vector<bool> correct;
        std::vector<double> levels;
        for (const Row& r : rows) {
            if (r.condition != spec.conditions[c].name) continue;
            auto& b = blocks[r.level];
            b.level = r.level;
            b.trials += 1;
            b.correct += r.correct;
            correct.push_back(r.correct);
            levels.push_back(r.level);
        }
        std::vector<perception::ResponseBlock> data;
        for (const auto& [l, b] : blocks) data.push_back(b);
        perception::FitOptions fo;  // Weibull, gamma 0.5, lambda in [0, 0.06]: the study's
        const auto fit = perception::fitPsychometric(data, fo);
        const double jnd = perception::thresholdAt(fit.function, std::sqrt(0.5));
        const auto& r = reported[c];
        ASSERT_TRUE(r.fit.has_value());
        EXPECT_NEAR(jnd, r.fitThreshold, 1e-9 * jnd) << spec.conditions[c].name;
        const auto rev = reversals(correct, levels, 30, {8, 4, 2}, 0.5, 80);
        ASSERT_GT(rev.size(), 2u);
        double mean = 0;
        for (std::size_t i = 2; i < rev.size(); ++i) mean += rev[i];
        mean /= static_cast<double>(rev.size() - 2);
        EXPECT_EQ(r.reversals, static_cast<int>(rev.size()));
        EXPECT_NEAR(r.procedureThreshold, mean, 1e-9);
        EXPECT_TRUE(r.fitInterval.contains(r.fitThreshold));
        std::printf(
            "%s: %d trials, %zu reversals, JND reversals %.2f %%, fit %.2f %% [%.2f, %.2f] "
            "(observer W %.2f %%)\n",
            r.name.c_str(), r.trials, rev.size(), mean, jnd, r.fitInterval.lo, r.fitInterval.hi,
            100 * spec.conditions[c].observer.weber.weberFraction);
    }
    // The comparison felt (1 + level) times as stiff as the reference: the coupling scales and
    // nothing clamps it. Not exactly: the stiffer coupling holds the hand back a little, which
    // moves where the rays meet the hard layer (0.2 % at 30 % in a continuous press).
    double worst = 0;
    for (const TrialRecord& t : records) {
        const double ref = t.comparisonInterval == 1 ? t.felt2 : t.felt1;
        const double cmp = t.comparisonInterval == 1 ? t.felt1 : t.felt2;
        worst = std::max(worst, std::abs(cmp / ref / (1 + t.levelPercent / 100) - 1));
    }
    std::printf("felt ratio against 1 + level: worst relative difference %.2e\n", worst);
    EXPECT_LT(worst, 0.01);
}

TEST(StudyRunner, AnInterruptedStudyResumesWithTheSameTrialSequence) {
    const fs::path d = tempDir("resume");
    spit(d / "s.json", smallStudy(30).dump());
    const StudySpec spec = loadStudySpec(d / "s.json");
    {
        StudyRunner whole(spec, 2);
        StudyLog log = StudyLog::create(d / "whole.csv", whole.logHeader());
        runStudyTrials(whole, simulatedResponder(std::make_shared<StudyStimuli>(spec)), log);
        EXPECT_TRUE(whole.finished());
    }
    {
        StudyRunner first(spec, 2);
        StudyLog log = StudyLog::create(d / "cut.csv", first.logHeader());
        // Interrupted mid-condition: 17 trials, then the process is gone.
        EXPECT_EQ(runStudyTrials(first, simulatedResponder(std::make_shared<StudyStimuli>(spec)),
                                 log, 17),
                  17);
        EXPECT_FALSE(first.finished());
    }
    {
        StudyRunner second(spec, 2);  // a new process: fresh stimuli, sessions run again
        std::vector<TrialRecord> done;
        StudyLog log = StudyLog::resume(d / "cut.csv", second.logHeader(), done);
        ASSERT_EQ(done.size(), 17u);
        second.replay(done, "cut.csv");
        runStudyTrials(second, simulatedResponder(std::make_shared<StudyStimuli>(spec)), log);
        EXPECT_TRUE(second.finished());
    }
    const auto whole = readRows(d / "whole.csv"), cut = readRows(d / "cut.csv");
    ASSERT_EQ(whole.size(), 60u);
    ASSERT_EQ(cut.size(), whole.size());
    int comparisonFirst = 0;
    for (std::size_t i = 0; i < whole.size(); ++i) {
        EXPECT_EQ(cut[i].line, whole[i].line) << "trial " << i;
        comparisonFirst += whole[i].order == 1;
    }
    // The interval order is drawn, not fixed.
    EXPECT_GT(comparisonFirst, 15);
    EXPECT_LT(comparisonFirst, 45);
}

/// Runs @p n simulated participants (0..n-1) of @p spec, each to its own log in @p dir; @return
/// each participant's logged trials, read back from the log.
std::vector<std::vector<TrialRecord>> runParticipants(const StudySpec& spec,
                                                      const std::shared_ptr<StudyStimuli>& stimuli,
                                                      const fs::path& dir, int n) {
    std::vector<std::vector<TrialRecord>> out;
    for (int p = 0; p < n; ++p) {
        StudyRunner runner(spec, p);
        char name[32];  // (not "p" + to_string: GCC 12 -O3 warns falsely on that concatenation)
        std::snprintf(name, sizeof name, "p%d.csv", p);
        StudyLog l = StudyLog::create(dir / name, runner.logHeader());
        runStudyTrials(runner, simulatedResponder(stimuli), l);
        StudyLogHeader h;
        out.push_back(readStudyLog(dir / name, h));
    }
    return out;
}

TEST(StudyRunner, ObserversWithPaperIIIWeberFractionsRankTheTouchModesAsTheThesisFound) {
    // Six simulated participants (two whole Williams squares over three conditions), each
    // palpating the phantom in all three touch modes; the observers carry paper III's mean JNDs
    // (continuous pressure 5.23 %, discontinuous 12.91 %, lateral sweep 15.77 %).
    Json j = Json::parse(R"({
      "study": "paper3", "seed": 3, "reference_stiffness": 100,
      "procedure": {"start_level": 20, "step_sizes": [4, 2, 1], "min_level": 0.5,
                    "max_level": 60, "max_trials": 80, "max_reversals": 0, "drop_first": 4},
      "fit": {"bootstrap": 0},
      "conditions": [
        {"name": "CP", "touch": "continuous-pressure"},
        {"name": "DP", "touch": "discontinuous-pressure"},
        {"name": "CL", "touch": "lateral-sweep"}]})");
    const fs::path d = tempDir("rank");
    spit(d / "s.json", j.dump());
    const StudySpec spec = loadStudySpec(d / "s.json");
    auto stimuli = std::make_shared<StudyStimuli>(spec);
    std::vector<TrialRecord> all;
    std::vector<double> reversalMean(3, 0);
    constexpr int kParticipants = 12;
    for (const auto& trials : runParticipants(spec, stimuli, d, kParticipants)) {
        const auto r = analyseStudy(spec, trials);
        for (std::size_t c = 0; c < 3; ++c)
            reversalMean[c] += r[c].procedureThreshold / kParticipants;
        all.insert(all.end(), trials.begin(), trials.end());
    }
    const auto pooled = analyseStudy(spec, all);
    std::printf("%d sessions for %zu trials\n", stimuli->sessionsRun(), all.size());
    for (std::size_t c = 0; c < 3; ++c) {
        const double w = 100 * spec.conditions[c].observer.weber.weberFraction;
        std::printf("%s: pooled fit JND %.2f %%, mean reversal JND %.2f %% (thesis %.2f %%)\n",
                    pooled[c].name.c_str(), pooled[c].fitThreshold, reversalMean[c], w);
        // The palpation passes the increment through unchanged, so the observers' JND comes
        // back (the fitted Weibull against their log-normal noise: within 20 %).
        EXPECT_NEAR(pooled[c].fitThreshold, w, 0.2 * w) << pooled[c].name;
        EXPECT_NEAR(reversalMean[c], w, 0.25 * w) << pooled[c].name;
    }
    EXPECT_LT(pooled[0].fitThreshold, pooled[1].fitThreshold);  // CP < DP
    EXPECT_LT(pooled[1].fitThreshold, pooled[2].fitThreshold);  // DP < lateral sweep
    EXPECT_LT(reversalMean[0], reversalMean[1]);
    EXPECT_LT(reversalMean[1], reversalMean[2]);
}

TEST(StudyRunner, TheRenderedSweepFollowsEachTransitionAndTheGradientObserverRanksThemAsPaperIV) {
    // A lateral sweep across the CL box feels the stiffness the phantom's profile gives (the
    // scene's accumulate rays read the field under the finger), so the peak normalised gradient
    // felt is the profile's own through the observer's 2 mm window: about 1 / w (linear),
    // pi / (2 w) (cosine) and a / (w tanh a) (tanh, a = 3), w = 10 mm. A first-hit surface at
    // 200 HU felt all three as the same step (413 / 489 / 464 /m).
    Json j = Json::parse(R"({
      "study": "paper4", "seed": 7, "reference_stiffness": 100,
      "procedure": {"start_level": 20, "step_sizes": [4, 2, 1], "min_level": 0.5,
                    "max_level": 60, "max_trials": 80, "max_reversals": 0, "drop_first": 4},
      "fit": {"bootstrap": 0},
      "conditions": [
        {"name": "tanh", "touch": "lateral-sweep", "profile": "tanh",
         "observer": {"kind": "gradient"}},
        {"name": "cosine", "touch": "lateral-sweep", "profile": "cosine",
         "observer": {"kind": "gradient"}},
        {"name": "linear", "touch": "lateral-sweep", "profile": "linear",
         "observer": {"kind": "gradient"}}]})");
    const fs::path d = tempDir("paper4");
    spit(d / "s.json", j.dump());
    const StudySpec spec = loadStudySpec(d / "s.json");
    auto stimuli = std::make_shared<StudyStimuli>(spec);
    const double window = spec.conditions[0].observer.gradient.windowM;
    EXPECT_EQ(window, 2e-3);
    const volume::TransitionProfile profiles[3] = {volume::TransitionProfile::Tanh,
                                                   volume::TransitionProfile::Cosine,
                                                   volume::TransitionProfile::Linear};
    const double thesis[3] = {10.86, 14.7, 17.95};
    double predicted[3] = {};
    for (std::size_t c = 0; c < 3; ++c) {
        const IntervalFelt& f = stimuli->feel(static_cast<int>(c), 0);
        const auto [lo, hi] = std::minmax_element(f.profileNpm.begin(), f.profileNpm.end());
        // Soft to hard tissue: 1.25 k_s to 3.25 k_s (coupling_defaults.h).
        EXPECT_NEAR(*lo, 125, 15) << spec.conditions[c].name;
        EXPECT_NEAR(*hi, 325, 30) << spec.conditions[c].name;
        // The phantom's own profile over 30 mm, sampled every 0.05 mm, through the same window.
        std::vector<double> xs, ks;
        for (double x = -0.015; x <= 0.015; x += 5e-5) {
            xs.push_back(x);
            ks.push_back(volume::transitionProfile(profiles[c], x + 0.005, 0.010, 3));
        }
        const double truth = perception::peakNormalisedGradient({xs, ks}, window);
        const double g = perception::peakNormalisedGradient({f.profileM, f.profileNpm}, window);
        EXPECT_NEAR(g, truth, 0.1 * truth) << spec.conditions[c].name;
        predicted[c] =
            100 *
            perception::GradientObserver(spec.conditions[c].observer.gradient, 0).weberFraction(g);
        EXPECT_NEAR(predicted[c], thesis[c], 0.15 * thesis[c]) << spec.conditions[c].name;
        // The comparison scales the whole field: same profile, k times (1 + level / 100).
        const IntervalFelt& comp = stimuli->feel(static_cast<int>(c), 20);
        EXPECT_NEAR(*std::max_element(comp.profileNpm.begin(), comp.profileNpm.end()), 1.2 * *hi,
                    0.01 * *hi);
    }
    EXPECT_LT(predicted[0], predicted[1]);
    EXPECT_LT(predicted[1], predicted[2]);

    // Twelve simulated participants, pooled per condition: tanh < cosine < linear.
    std::vector<TrialRecord> all;
    for (const auto& trials : runParticipants(spec, stimuli, d, 12))
        all.insert(all.end(), trials.begin(), trials.end());
    const auto pooled = analyseStudy(spec, all);
    for (std::size_t c = 0; c < 3; ++c) {
        std::printf("%s: predicted %.2f %%, pooled fit JND %.2f %% (thesis %.2f %%)\n",
                    pooled[c].name.c_str(), predicted[c], pooled[c].fitThreshold, thesis[c]);
        EXPECT_NEAR(pooled[c].fitThreshold, predicted[c], 0.25 * predicted[c]) << pooled[c].name;
    }
    EXPECT_LT(pooled[0].fitThreshold, pooled[1].fitThreshold);
    EXPECT_LT(pooled[1].fitThreshold, pooled[2].fitThreshold);
}

}  // namespace
}  // namespace palp::haptics
