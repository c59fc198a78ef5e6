// Psychometric fits: maximum likelihood against psignifit 2.5.6 (Hill & Wichmann's engine,
// lambda fitted within [0, 0.06]) to its simplex's tolerance and against R's glm with psyphy's
// m-alternative links (lambda 0) to 1e-6; the parametric bootstrap's intervals cover the
// generating parameters at their nominal rate; thresholds, JNDs and bad input. Each oracle is
// skipped when missing (tools/test.sh refuses to run without them).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "palp/base/error.h"
#include "palp/perception/psychometric_fit.h"
#include "test_support.h"

namespace palp::perception {
namespace {

using Blocks = std::vector<ResponseBlock>;

/// Blocks of @p trials at @p levels with responses drawn from @p f.
Blocks simulate(const PsychometricFunction& f, const std::vector<double>& levels, int trials,
                std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    Blocks data;
    for (double x : levels) {
        std::binomial_distribution<int> draw(trials, psi(f, x));
        data.push_back({x, draw(rng), trials});
    }
    return data;
}

void writeBlocks(const std::filesystem::path& path, const Blocks& data) {
    std::ofstream out(path);
    out.precision(17);
    for (const ResponseBlock& b : data)
        out << b.level << ' ' << b.correct << ' ' << b.trials << '\n';
}

std::vector<double> readNumbers(const std::filesystem::path& path) {
    std::ifstream in(path);
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    for (char& c : text)
        if (c == ',') c = ' ';
    std::istringstream s(text);
    std::vector<double> v;
    double x;
    while (s >> x) v.push_back(x);
    return v;
}

const char* psignifitShape(PsychometricShape shape) {
    switch (shape) {
        case PsychometricShape::Weibull:
            return "Weibull";
        case PsychometricShape::Logistic:
            return "logistic";
        case PsychometricShape::CumulativeGaussian:
            return "cumulative Gaussian";
    }
    return "";
}

/// psignifit's fit: alpha, beta, gamma, lambda, then the thresholds at F = 0.2, 0.5, 0.8, then
/// the deviance.
struct PsignifitFit {
    PsychometricFunction f;
    double thresholds[3];
    double deviance;
};

PsignifitFit runPsignifit(const Blocks& data, PsychometricShape shape, int intervals,
                          double lambdaMax, double fixLambda = -1) {
    test::TempDir dir;
    writeBlocks(dir / "data.txt", data);
    std::ostringstream prefs;
    prefs << "#shape " << psignifitShape(shape) << "\n#n_intervals " << intervals
          << "\n#matrix_format xrn\n";
    if (fixLambda >= 0)
        prefs << "#fix_lambda " << std::setprecision(17) << fixLambda;
    else
        prefs << "#lambda_limits 0, " << lambdaMax;
    prefs << "\n#runs 0\n#verbose false\n#write_format %.15lg\n#write_pa_est "
          << (dir / "pa.txt").string() << "\n#write_th_est " << (dir / "th.txt").string()
          << "\n#write_st_est " << (dir / "st.txt").string() << "\n";
    test::writeFile(dir / "prefs.txt", prefs.str());
    const test::RunResult r = test::runCommand("psignifit '" + (dir / "data.txt").string() + "' '" +
                                               (dir / "prefs.txt").string() + "'");
    EXPECT_EQ(r.exitCode, 0) << r.output;
    const auto pa = readNumbers(dir / "pa.txt"), th = readNumbers(dir / "th.txt"),
               st = readNumbers(dir / "st.txt");
    PsignifitFit fit{};
    if (pa.size() < 4 || th.size() < 3 || st.empty()) {
        ADD_FAILURE() << "psignifit wrote " << pa.size() << " parameters, " << th.size()
                      << " thresholds, " << st.size() << " statistics: " << r.output;
        return fit;
    }
    fit.f = {shape, pa[0], pa[1], pa[2], pa[3]};
    for (int i = 0; i < 3; ++i) fit.thresholds[i] = th[static_cast<std::size_t>(i)];
    fit.deviance = st[0];
    return fit;
}

// psignifit's simplex with lambda free stops short of the optimum where the likelihood is flat:
// its log-likelihood up to 0.012 below ours, lambda within 1e-4, alpha and beta up to 0.5 %
// off, and, where the optimum has lambda at its lower limit 0, beta up to 3 % off (it stalls at
// lambda ~1e-6). So each data set is fitted by psignifit twice: with lambda free, where ours
// must be at least as likely, no more than kPsignifitStall more, and hold the same lambda to
// 1e-3; and with #fix_lambda at our lambda, where its two-parameter simplex converges and
// alpha, beta, the thresholds at its F cuts and the deviance must agree to 1e-3 (relative).
constexpr double kPsignifitTolerance = 1e-3;
constexpr double kPsignifitStall = 0.02;

struct Worst {
    double parameters = 0, thresholds = 0, deviance = 0, lambda = 0, likelihoodGap = 0;
    int lambdaAtZero = 0, cases = 0;
};

void compareWithPsignifit(const Blocks& data, PsychometricShape shape, int intervals,
                          Worst& worst) {
    FitOptions o;
    o.shape = shape;
    o.gamma = 1.0 / intervals;
    o.lambdaMax = 0.06;
    const PsychometricFit ours = fitPsychometric(data, o);
    const PsignifitFit free = runPsignifit(data, shape, intervals, o.lambdaMax);
    const double gap = ours.logLikelihood - logLikelihood(data, free.f);
    EXPECT_GE(gap, -1e-9) << "psignifit found a likelier function";
    EXPECT_LE(gap, kPsignifitStall);
    EXPECT_NEAR(ours.function.lambda, free.f.lambda, 1e-3);
    EXPECT_DOUBLE_EQ(free.f.gamma, o.gamma);
    worst.likelihoodGap = std::max(worst.likelihoodGap, gap);
    worst.lambda = std::max(worst.lambda, std::abs(ours.function.lambda - free.f.lambda));
    ++worst.cases;
    worst.lambdaAtZero += ours.function.lambda == 0;

    const PsignifitFit fixed = runPsignifit(data, shape, intervals, 0, ours.function.lambda);
    const auto near = [&](double a, double b, double& w, const char* what) {
        const double d = std::abs(a - b) / std::max(1.0, std::abs(b));
        w = std::max(w, d);
        EXPECT_LE(d, kPsignifitTolerance) << what << ": ours " << a << ", psignifit " << b;
    };
    near(ours.function.alpha, fixed.f.alpha, worst.parameters, "alpha");
    near(ours.function.beta, fixed.f.beta, worst.parameters, "beta");
    const double cuts[3] = {0.2, 0.5, 0.8};
    for (int i = 0; i < 3; ++i)
        near(thresholdAtF(ours.function, cuts[i]), fixed.thresholds[i], worst.thresholds,
             "threshold at F cut");
    near(ours.deviance, fixed.deviance, worst.deviance, "deviance");
}

TEST(PsychometricFitOracle, MatchesPsignifitOnFixedAndSimulatedData) {
    if (!test::haveProgram("psignifit")) GTEST_SKIP() << "psignifit not installed";
    Worst worst;
    // Fixed data: a 2AFC Weibull with a lapse at the top, a 2AFC logistic, a 4AFC Gaussian.
    compareWithPsignifit({{0.5, 21, 40},
                          {1, 23, 40},
                          {1.5, 27, 40},
                          {2, 33, 40},
                          {2.5, 36, 40},
                          {3, 37, 40},
                          {4, 37, 40}},
                         PsychometricShape::Weibull, 2, worst);
    compareWithPsignifit(
        {{-2, 15, 30}, {-1, 17, 30}, {0, 20, 30}, {1, 25, 30}, {2, 28, 30}, {3, 29, 30}},
        PsychometricShape::Logistic, 2, worst);
    compareWithPsignifit(
        {{1, 13, 50}, {2, 16, 50}, {3, 24, 50}, {4, 35, 50}, {5, 44, 50}, {6, 47, 50}},
        PsychometricShape::CumulativeGaussian, 4, worst);
    // Simulated: each shape, lapses 0 and 0.03, three seeds each.
    const std::vector<double> levels = {0.6, 0.9, 1.2, 1.6, 2.1, 2.8, 3.6};
    for (PsychometricShape shape : {PsychometricShape::Weibull, PsychometricShape::Logistic,
                                    PsychometricShape::CumulativeGaussian})
        for (double lambda : {0.0, 0.03})
            for (std::uint64_t seed : {1u, 2u, 3u}) {
                PsychometricFunction truth{
                    shape, 1.6, shape == PsychometricShape::Weibull ? 3.0 : 0.5, 0.5, lambda};
                compareWithPsignifit(simulate(truth, levels, 40, seed), shape, 2, worst);
            }
    std::printf(
        "psignifit, %d data sets (%d with lambda 0): lambda free: |diff| %.2g, its "
        "log-likelihood at most %.2g below ours; lambda fixed: max relative diff parameters "
        "%.2g, thresholds %.2g, deviance %.2g\n",
        worst.cases, worst.lambdaAtZero, worst.lambda, worst.likelihoodGap, worst.parameters,
        worst.thresholds, worst.deviance);
}

/// R's glm with psyphy's link for @p shape (mafc.cloglog, .logit, .probit with m = 2): the
/// coefficients (intercept, slope on log x for the Weibull, on x otherwise) and the deviance.
std::vector<double> runPsyphy(const Blocks& data, PsychometricShape shape) {
    test::TempDir dir;
    writeBlocks(dir / "data.txt", data);
    const char* link = shape == PsychometricShape::Weibull    ? "mafc.cloglog(2)"
                       : shape == PsychometricShape::Logistic ? "mafc.logit(2)"
                                                              : "mafc.probit(2)";
    const char* predictor = shape == PsychometricShape::Weibull ? "log(x)" : "x";
    std::ostringstream r;
    r << "suppressMessages(library(psyphy))\n"
      << "d <- read.table('" << (dir / "data.txt").string() << "', col.names = c('x', 'k', 'n'))\n"
      << "m <- glm(cbind(k, n - k) ~ " << predictor << ", family = binomial(" << link
      << "), data = d, control = glm.control(epsilon = 1e-15, maxit = 200))\n"
      << "write(sprintf('%.17g', c(coef(m), deviance(m))), '" << (dir / "out.txt").string()
      << "')\n";
    test::writeFile(dir / "fit.R", r.str());
    const test::RunResult run = test::runCommand("Rscript '" + (dir / "fit.R").string() + "'");
    EXPECT_EQ(run.exitCode, 0) << run.output;
    return readNumbers(dir / "out.txt");
}

TEST(PsychometricFitOracle, MatchesRsPsyphyWithoutLapses) {
    if (!test::haveProgram("Rscript")) GTEST_SKIP() << "Rscript not installed (r-cran-psyphy)";
    if (test::runCommand("Rscript -e 'library(psyphy)'").exitCode != 0)
        GTEST_SKIP() << "R package psyphy not installed (r-cran-psyphy)";
    double worst = 0;
    const std::vector<double> levels = {0.6, 0.9, 1.2, 1.6, 2.1, 2.8, 3.6};
    for (PsychometricShape shape : {PsychometricShape::Weibull, PsychometricShape::Logistic,
                                    PsychometricShape::CumulativeGaussian})
        for (std::uint64_t seed : {4u, 5u, 6u}) {
            PsychometricFunction truth{shape, 1.6, shape == PsychometricShape::Weibull ? 3.0 : 0.5,
                                       0.5, 0.02};
            const Blocks data = simulate(truth, levels, 30, seed);
            FitOptions o;
            o.shape = shape;
            o.lambdaMin = o.lambdaMax = 0;
            const PsychometricFit ours = fitPsychometric(data, o);
            const std::vector<double> r = runPsyphy(data, shape);
            ASSERT_EQ(r.size(), 3u);
            double alpha, beta;
            if (shape == PsychometricShape::Weibull) {
                beta = r[1];
                alpha = std::exp(-r[0] / r[1]);
            } else {
                beta = 1 / r[1];
                alpha = -r[0] / r[1];
            }
            for (auto [a, b] :
                 {std::pair{ours.function.alpha, alpha}, std::pair{ours.function.beta, beta},
                  std::pair{ours.deviance, r[2]}}) {
                EXPECT_NEAR(a, b, 1e-6 * std::max(1.0, std::abs(b))) << shapeName(shape) << seed;
                worst = std::max(worst, std::abs(a - b) / std::max(1.0, std::abs(b)));
            }
        }
    std::printf("psyphy (glm, lambda 0): max relative diff %.2g\n", worst);
}

TEST(PsychometricFit, BootstrapIntervalsCoverTheGeneratingParameters) {
    // 200 simulated experiments (a 2AFC Weibull, alpha 2, beta 3, no lapses, 7 levels x 50
    // trials), each fitted with lambda fixed at 0 and bootstrapped 200 times: the 90 %
    // percentile intervals of alpha, beta and the 75 % threshold hold the truth in 90 % +- 5 %
    // of them (the binomial sd of a coverage over 200 is 2.1 %).
    const PsychometricFunction truth{PsychometricShape::Weibull, 2, 3, 0.5, 0};
    const std::vector<double> levels = {1, 1.3, 1.6, 2, 2.4, 2.9, 3.5};
    FitOptions o;
    o.lambdaMin = o.lambdaMax = 0;
    BootstrapOptions b;
    b.samples = 200;
    b.coverage = 0.9;
    b.thresholdLevels = {0.75};
    const double truthThreshold = thresholdAt(truth, 0.75);
    int alphaIn = 0, betaIn = 0, thresholdIn = 0;
    const int experiments = 200;
    for (int e = 0; e < experiments; ++e) {
        const Blocks data = simulate(truth, levels, 50, 9000 + static_cast<std::uint64_t>(e));
        const PsychometricFit fit = fitPsychometric(data, o);
        b.seed = 77 + static_cast<std::uint64_t>(e);
        const BootstrapResult r = bootstrapPsychometric(data, fit, o, b);
        alphaIn += r.alpha.contains(truth.alpha);
        betaIn += r.beta.contains(truth.beta);
        thresholdIn += r.thresholds[0].contains(truthThreshold);
    }
    const double n = experiments;
    std::printf("bootstrap 90 %% coverage: alpha %.3f, beta %.3f, threshold %.3f\n", alphaIn / n,
                betaIn / n, thresholdIn / n);
    EXPECT_NEAR(alphaIn / n, 0.9, 0.05);
    EXPECT_NEAR(betaIn / n, 0.9, 0.05);
    EXPECT_NEAR(thresholdIn / n, 0.9, 0.05);
}

TEST(PsychometricFit, BootstrapIsSeededAndItsDevianceTestFlagsAWrongShape) {
    // The same seed, the same intervals; data from a steep logistic on a wide span fitted as a
    // Weibull with lambda 0 fits badly (p < 0.05), data from a Weibull fits (p > 0.05).
    const std::vector<double> levels = {0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4};
    FitOptions o;
    o.lambdaMin = o.lambdaMax = 0;
    BootstrapOptions b;
    b.samples = 300;
    const Blocks good = simulate({PsychometricShape::Weibull, 2, 3, 0.5, 0}, levels, 100, 3);
    const PsychometricFit fit = fitPsychometric(good, o);
    const BootstrapResult r1 = bootstrapPsychometric(good, fit, o, b);
    const BootstrapResult r2 = bootstrapPsychometric(good, fit, o, b);
    EXPECT_EQ(r1.alpha.lo, r2.alpha.lo);
    EXPECT_EQ(r1.thresholds[0].hi, r2.thresholds[0].hi);
    EXPECT_GT(r1.devianceP, 0.05);
    // A yes/no style function forced into a 2AFC fit with lambda 0: 20 % lapses at the top.
    const Blocks bad = simulate({PsychometricShape::Logistic, 2, 0.15, 0.5, 0.2}, levels, 100, 3);
    const PsychometricFit badFit = fitPsychometric(bad, o);
    const BootstrapResult r3 = bootstrapPsychometric(bad, badFit, o, b);
    std::printf("deviance p: Weibull data %.3f (D %.2f), lapsing logistic data %.4f (D %.2f)\n",
                r1.devianceP, fit.deviance, r3.devianceP, badFit.deviance);
    EXPECT_LT(r3.devianceP, 0.05);
}

TEST(Psychometric, ThresholdsJndAndWeberFraction) {
    const PsychometricFunction w{PsychometricShape::Weibull, 2, 3, 0.5, 0.02};
    for (double level : {0.6, 0.7071, 0.75, 0.9})
        EXPECT_NEAR(psi(w, thresholdAt(w, level)), level, 1e-14) << level;
    // F's cuts: the Weibull's median is alpha ln(2)^(1/beta).
    EXPECT_NEAR(thresholdAtF(w, 0.5), 2 * std::pow(std::log(2.0), 1 / 3.0), 1e-14);
    const PsychometricFunction g{PsychometricShape::CumulativeGaussian, 100, 10, 0, 0};
    const ComparisonJnd j = comparisonJnd(g);
    EXPECT_NEAR(j.pse, 100, 1e-12);
    EXPECT_NEAR(j.jnd, 10 * 0.67448975019608171, 1e-10);  // the Gaussian's quartile, sd 10
    EXPECT_NEAR(j.weberFraction, j.jnd / 100, 1e-15);
    EXPECT_NEAR(incrementJnd(w, 0.75), thresholdAt(w, 0.75), 0);
    // The slope at the threshold against a central difference.
    const double x = thresholdAt(g, 0.5), h = 1e-5;
    EXPECT_NEAR(slopeAt(g, x), (psi(g, x + h) - psi(g, x - h)) / (2 * h), 1e-9);
}

TEST(PsychometricFit, RefusesBadInputNamingTheField) {
    using test::expectThrowWith;
    FitOptions o;
    expectThrowWith<ValueError>([&] { fitPsychometric({}, o); }, {"data", "empty"});
    Blocks d = {{1, 10, 20}, {0, 12, 20}};
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); },
                                {"data[1] level", "> 0", "found 0"});
    d = {{1, 10, 20}, {std::nan(""), 12, 20}};
    o.shape = PsychometricShape::Logistic;
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); }, {"data[1] level", "nan"});
    d = {{1, 10, 20}, {2, 21, 20}};
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); }, {"data[1] correct", "21"});
    d = {{1, 0, 0}, {2, 1, 20}};
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); }, {"data[0] trials", "found 0"});
    d = {{1, 10, 20}, {1, 12, 20}};
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); },
                                {"data levels", "two distinct", "every block at 1"});
    d = {{1, 10, 20}, {2, 12, 20}};
    o.lambdaMax = -0.1;
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); }, {"fit lambdaMax", "-0.1"});
    o = {};
    o.gamma = std::nan("");
    expectThrowWith<ValueError>([&] { fitPsychometric(d, o); }, {"fit gamma", "nan"});
    o = {};
    const PsychometricFit fit = fitPsychometric(d, o);
    BootstrapOptions b;
    b.samples = -1;
    expectThrowWith<ValueError>([&] { bootstrapPsychometric(d, fit, o, b); },
                                {"bootstrap samples", "-1"});
    b = {};
    b.thresholdLevels = {0.3};
    expectThrowWith<ValueError>([&] { bootstrapPsychometric(d, fit, o, b); },
                                {"thresholdLevels[0]", "0.3"});
    const PsychometricFunction f{PsychometricShape::Weibull, -2, 3, 0.5, 0};
    expectThrowWith<ValueError>([&] { validatePsychometric("observer function", f); },
                                {"observer function alpha", "-2"});
    const PsychometricFunction g{PsychometricShape::Logistic, 1, 0, 0.5, 0};
    expectThrowWith<ValueError>([&] { validatePsychometric("f", g); }, {"f beta", "found 0"});
    expectThrowWith<ValueError>([&] { thresholdAt(g, 0.4); }, {"psi level", "0.4"});
    expectThrowWith<ValueError>([&] { weberFraction(1, 0); }, {"reference", "found 0"});
    expectThrowWith<ValueError>([&] { parseShape("shape", "probit"); }, {"shape", "'probit'"});
}

}  // namespace
}  // namespace palp::perception
