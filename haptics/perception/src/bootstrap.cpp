#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "fit_detail.h"
#include "palp/base/validate.h"
#include "palp/perception/psychometric_fit.h"
#include "sigmoid.h"

namespace palp::perception {

double sampleQuantile(std::vector<double> values, double q) {
    std::erase_if(values, [](double v) { return std::isnan(v); });
    if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
    std::sort(values.begin(), values.end());
    const double h = (static_cast<double>(values.size()) - 1) * std::clamp(q, 0.0, 1.0);
    const auto lo = static_cast<std::size_t>(std::floor(h));
    const std::size_t hi = std::min(lo + 1, values.size() - 1);
    return values[lo] + (h - static_cast<double>(lo)) * (values[hi] - values[lo]);
}

BootstrapResult bootstrapPsychometric(std::span<const ResponseBlock> data,
                                      const PsychometricFit& fit, const FitOptions& options,
                                      const BootstrapOptions& bootstrap) {
    validateFitOptions(options);
    validateBlocks(data, options.shape);
    validatePsychometric("bootstrap fit function", fit.function);
    if (bootstrap.samples < 1)
        throwExpected("bootstrap samples", "an integer >= 1", std::to_string(bootstrap.samples));
    if (!(bootstrap.coverage > 0 && bootstrap.coverage < 1))
        throwExpected("bootstrap coverage", "a probability in (0, 1)",
                      formatValue(bootstrap.coverage));
    for (std::size_t i = 0; i < bootstrap.thresholdLevels.size(); ++i) {
        const double level = bootstrap.thresholdLevels[i];
        if (!(level > options.gamma && level < 1 - options.lambdaMax))
            throwExpected("bootstrap thresholdLevels[" + std::to_string(i) + "]",
                          "a psi level in (gamma, 1 - lambdaMax) = (" + formatValue(options.gamma) +
                              ", " + formatValue(1 - options.lambdaMax) + ")",
                          formatValue(level));
    }

    detail::FitProblem problem = detail::problemOf(data, options);
    std::vector<double> generating(data.size());
    for (std::size_t i = 0; i < data.size(); ++i) generating[i] = psi(fit.function, data[i].level);
    double start[2];
    detail::coefficientsOf(options.shape, fit.function.alpha, fit.function.beta, start[0],
                           start[1]);
    const double observedDeviance = deviance(data, fit.function);

    std::mt19937_64 rng(bootstrap.seed);
    BootstrapResult result;
    result.fits.reserve(static_cast<std::size_t>(bootstrap.samples));
    std::vector<ResponseBlock> simulated(data.begin(), data.end());
    int worse = 0;
    for (int s = 0; s < bootstrap.samples; ++s) {
        for (std::size_t i = 0; i < data.size(); ++i) {
            std::binomial_distribution<int> draw(data[i].trials, generating[i]);
            simulated[i].correct = draw(rng);
            problem.k[i] = simulated[i].correct;
        }
        PsychometricFit refit = detail::fitProblem(problem, options, start);
        refit.deviance = deviance(simulated, refit.function);
        if (refit.deviance >= observedDeviance) ++worse;
        result.fits.push_back(refit);
    }
    result.devianceP = (1.0 + worse) / (1.0 + bootstrap.samples);

    const double qLo = 0.5 * (1 - bootstrap.coverage), qHi = 0.5 * (1 + bootstrap.coverage);
    const auto interval = [&](auto&& value) {
        std::vector<double> v;
        v.reserve(result.fits.size());
        for (const PsychometricFit& f : result.fits) v.push_back(value(f));
        return Interval{sampleQuantile(v, qLo), sampleQuantile(std::move(v), qHi)};
    };
    result.alpha = interval([](const PsychometricFit& f) { return f.function.alpha; });
    result.beta = interval([](const PsychometricFit& f) { return f.function.beta; });
    result.lambda = interval([](const PsychometricFit& f) { return f.function.lambda; });
    for (double level : bootstrap.thresholdLevels)
        result.thresholds.push_back(
            interval([&](const PsychometricFit& f) { return thresholdAt(f.function, level); }));
    return result;
}

}  // namespace palp::perception
