// QUEST against Psychtoolbox's Quest*.m (Debian psychtoolbox-3-common) run by octave-cli: the
// same prior and likelihood, the same intensities and responses, and after every trial the
// posterior mean, mode, sd and quantiles agree to 1e-9. Skipped (naming what is missing) without
// octave-cli or /usr/share/psychtoolbox-3/Quest; tools/test.sh refuses to run without them.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/perception/quest.h"
#include "test_support.h"

namespace palp::perception {
namespace {

const char* const kQuestDir = "/usr/share/psychtoolbox-3/Quest";

struct Trial {
    double intensity;
    bool correct;
};

/// Estimates after one trial: mean, mode, sd, quantile at quantileOrder(), at 0.025, at 0.975.
using Estimates = std::array<double, 6>;

Estimates estimates(const Quest& q) {
    return {q.mean(),          q.mode(),         q.sd(), q.quantile(q.quantileOrder()),
            q.quantile(0.025), q.quantile(0.975)};
}

/// Runs @p trials through Psychtoolbox's QuestCreate / QuestUpdate in Octave and returns its
/// quantile order and the estimates after each trial.
std::vector<Estimates> octaveQuest(const QuestParams& p, const std::vector<Trial>& trials,
                                   double& quantileOrder) {
    test::TempDir dir;
    {
        std::ofstream t(dir / "trials.txt");
        t.precision(17);
        for (const Trial& tr : trials) t << tr.intensity << ' ' << (tr.correct ? 1 : 0) << '\n';
    }
    char create[512];
    std::snprintf(create, sizeof create,
                  "q = QuestCreate(%.17g, %.17g, %.17g, %.17g, %.17g, %.17g, %.17g, %.17g);",
                  p.tGuess, p.tGuessSd, p.pThreshold, p.beta, p.delta, p.gamma, p.grain, p.range);
    const std::string script = std::string("addpath('") + kQuestDir + "');\n" + create + "\n" +
                               "q.warnPdf = 0;\n"
                               "d = dlmread('" +
                               (dir / "trials.txt").string() +
                               "');\n"
                               "f = fopen('" +
                               (dir / "out.txt").string() +
                               "', 'w');\n"
                               "fprintf(f, '%.17g\\n', q.quantileOrder);\n"
                               "for k = 1:rows(d)\n"
                               "  q = QuestUpdate(q, d(k, 1), d(k, 2));\n"
                               "  fprintf(f, '%.17g %.17g %.17g %.17g %.17g %.17g\\n', "
                               "QuestMean(q), QuestMode(q), QuestSd(q), QuestQuantile(q), "
                               "QuestQuantile(q, 0.025), QuestQuantile(q, 0.975));\n"
                               "end\n"
                               "fclose(f);\n";
    test::writeFile(dir / "quest.m", script);
    const test::RunResult r = test::runCommand("cd '" + dir.path().string() +
                                               "' && octave-cli --quiet --no-history quest.m");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    std::ifstream in(dir / "out.txt");
    std::vector<Estimates> out;
    in >> quantileOrder;
    Estimates e;
    while (in >> e[0] >> e[1] >> e[2] >> e[3] >> e[4] >> e[5]) out.push_back(e);
    return out;
}

/// A run: intensities chosen by palp's Quest (with @p placement), answered by an observer whose
/// threshold is @p trueThreshold under QUEST's own model; every @p outlierEvery-th intensity is
/// thrown far outside the grid (clamped into the likelihood table on both sides).
std::vector<Trial> simulate(const QuestParams& p, QuestPlacement placement, double trueThreshold,
                            int count, int outlierEvery, std::uint64_t seed,
                            std::vector<Estimates>& ours) {
    Quest q(p);
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(0, 1);
    std::vector<Trial> trials;
    for (int i = 0; i < count; ++i) {
        double x = q.next(placement);
        if (outlierEvery > 0 && i % outlierEvery == outlierEvery - 1)
            x = p.tGuess + (i % 2 == 0 ? 1 : -1) * (p.range + 1.234);
        const bool correct = u(rng) < q.pCorrect(x, trueThreshold);
        q.update(x, correct);
        trials.push_back({x, correct});
        ours.push_back(estimates(q));
    }
    return trials;
}

void compareWithPsychtoolbox(const QuestParams& p, QuestPlacement placement, double trueThreshold,
                             int count, int outlierEvery, std::uint64_t seed) {
    std::vector<Estimates> ours;
    const std::vector<Trial> trials =
        simulate(p, placement, trueThreshold, count, outlierEvery, seed, ours);
    double order = 0;
    const std::vector<Estimates> theirs = octaveQuest(p, trials, order);
    ASSERT_EQ(theirs.size(), ours.size());
    EXPECT_NEAR(Quest(p).quantileOrder(), order, 1e-12);
    double worst = 0;
    const char* names[] = {"mean", "mode", "sd", "quantile", "quantile 0.025", "quantile 0.975"};
    for (std::size_t t = 0; t < ours.size(); ++t)
        for (std::size_t k = 0; k < 6; ++k) {
            EXPECT_NEAR(ours[t][k], theirs[t][k], 1e-9) << names[k] << " after trial " << t + 1;
            worst = std::max(worst, std::abs(ours[t][k] - theirs[t][k]));
        }
    std::printf("QUEST vs Psychtoolbox: %zu trials, max |diff| %.3g (final mean %.6f sd %.6f)\n",
                ours.size(), worst, ours.back()[0], ours.back()[2]);
}

#define PALP_REQUIRE_QUEST_ORACLE()                                                   \
    if (!test::haveProgram("octave-cli")) GTEST_SKIP() << "octave-cli not installed"; \
    if (!std::filesystem::exists(std::string(kQuestDir) + "/QuestCreate.m"))          \
    GTEST_SKIP() << kQuestDir << " not found (psychtoolbox-3-common)"

TEST(QuestOracle, DefaultsWithQuantilePlacementMatchPsychtoolbox) {
    PALP_REQUIRE_QUEST_ORACLE();
    QuestParams p;
    p.tGuess = -1;
    p.tGuessSd = 2;
    compareWithPsychtoolbox(p, QuestPlacement::Quantile, -1.5, 60, 0, 11);
}

TEST(QuestOracle, FinerGridMeanPlacementAndFourAlternativesMatchPsychtoolbox) {
    PALP_REQUIRE_QUEST_ORACLE();
    QuestParams p;
    p.tGuess = 0.3;
    p.tGuessSd = 0.5;
    p.pThreshold = 0.75;
    p.beta = 2;
    p.delta = 0.02;
    p.gamma = 0.25;
    p.grain = 0.005;
    p.range = 3;
    compareWithPsychtoolbox(p, QuestPlacement::Mean, 0.1, 50, 0, 12);
}

TEST(QuestOracle, YesNoModePlacementAndIntensitiesOffTheGridMatchPsychtoolbox) {
    PALP_REQUIRE_QUEST_ORACLE();
    QuestParams p;
    p.tGuess = 1;
    p.tGuessSd = 1;
    p.pThreshold = 0.5;
    p.beta = 3;
    p.delta = 0.05;
    p.gamma = 0;
    p.grain = 0.02;
    p.range = 4;
    compareWithPsychtoolbox(p, QuestPlacement::Mode, 1.4, 40, 7, 13);
}

TEST(Quest, ConvergesOnTheTrueThresholdAndStopsOnItsInterval) {
    // 200 seeded runs of 80 trials against QUEST's own model: the final mean is unbiased to
    // within 0.02 log units and the final sd matches the spread of the means across runs within
    // 25 % (the posterior is calibrated).
    QuestParams p;
    p.tGuess = -1;
    p.tGuessSd = 1;
    p.maxTrials = 80;
    double sum = 0, sumSq = 0, sdSum = 0;
    const int runs = 200;
    const double truth = -1.3;
    for (int run = 0; run < runs; ++run) {
        Quest q(p);
        std::mt19937_64 rng(500 + static_cast<std::uint64_t>(run));
        std::uniform_real_distribution<double> u(0, 1);
        while (!q.finished()) {
            const double x = q.next();
            q.update(x, u(rng) < q.pCorrect(x, truth));
        }
        sum += q.mean();
        sumSq += q.mean() * q.mean();
        sdSum += q.sd();
    }
    const double mean = sum / runs, spread = std::sqrt(sumSq / runs - mean * mean);
    std::printf("QUEST 80 trials x %d runs: mean %.4f (truth %.2f), spread %.4f, mean sd %.4f\n",
                runs, mean, truth, spread, sdSum / runs);
    EXPECT_NEAR(mean, truth, 0.02);
    EXPECT_NEAR(sdSum / runs, spread, 0.25 * spread);

    QuestParams w = p;
    w.maxTrials = 500;
    w.maxIntervalWidth = 0.3;
    Quest q(w);
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(0, 1);
    while (!q.finished()) {
        const double x = q.next();
        q.update(x, u(rng) < q.pCorrect(x, truth));
    }
    const auto [lo, hi] = q.credibleInterval(0.95);
    EXPECT_LE(hi - lo, 0.3);
    EXPECT_LT(q.trialCount(), 500);
}

TEST(Quest, RefusesBadParametersNamingTheField) {
    using test::expectThrowWith;
    QuestParams p;
    p.tGuessSd = -1;
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest tGuessSd", "-1"});
    p = {};
    p.grain = 0;
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest grain", "found 0"});
    p = {};
    p.beta = std::nan("");
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest beta", "nan"});
    p = {};
    p.gamma = 0.9;
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest gamma", "0.9"});
    p = {};
    p.delta = 1;
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest delta", "found 1"});
    p = {};
    p.range = 1e9;
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest range / grain", "1e+11"});
    p = {};
    p.pThreshold = 0.999;  // above the likelihood's top, 1 - delta (1 - gamma) = 0.995
    expectThrowWith<ValueError>([&] { Quest q(p); }, {"quest pThreshold", "0.999"});
    Quest q(QuestParams{});
    expectThrowWith<ValueError>([&] { q.update(std::nan(""), true); }, {"quest intensity", "nan"});
    expectThrowWith<ValueError>([&] { q.quantile(1.5); }, {"quantile order", "1.5"});
}

}  // namespace
}  // namespace palp::perception
