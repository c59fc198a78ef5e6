#include "palp/perception/observer.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "palp/base/validate.h"
#include "sigmoid.h"

namespace palp::perception {

namespace {

void requireLapse(std::string_view what, double v) {
    if (!(v >= 0 && v < 1)) throwExpected(what, "a probability in [0, 1)", formatValue(v));
}

/// 0 or 1: the interval whose noisy log-percept is larger, or a coin flip on a lapse.
int noisyChoice(std::mt19937_64& rng, double first, double second, double sigmaFirst,
                double sigmaSecond, double lapseRate) {
    std::uniform_real_distribution<double> uniform(0, 1);
    std::normal_distribution<double> noise(0, 1);
    // Draw the same numbers whether or not the observer lapses, so runs stay aligned.
    const double lapse = uniform(rng), coin = uniform(rng);
    const double a = std::log(first) + sigmaFirst * noise(rng);
    const double b = std::log(second) + sigmaSecond * noise(rng);
    if (lapse < lapseRate) return coin < 0.5 ? 0 : 1;
    return b > a ? 1 : 0;
}

/// `name[i]`, built by appends (GCC 12 warns falsely on "[" + std::string&&).
std::string indexed(std::string_view name, std::size_t i) {
    std::string s(name);
    s += '[';
    s += std::to_string(i);
    s += ']';
    return s;
}

void requireFelt(std::string_view what, double v) {
    requirePositive(what, v, "(a felt stiffness or force)");
}

}  // namespace

PsychometricObserver::PsychometricObserver(const PsychometricFunction& f, std::uint64_t seed)
    : mF(f), mRng(seed) {
    validatePsychometric("observer function", f);
}

bool PsychometricObserver::respond(double level) {
    std::uniform_real_distribution<double> uniform(0, 1);
    return uniform(mRng) < psi(mF, level);
}

double weberNoiseSd(double weberFraction, double criterionLevel) {
    requirePositive("weber observer weberFraction", weberFraction);
    if (!(criterionLevel > 0.5 && criterionLevel < 1))
        throwExpected("weber observer criterionLevel", "a probability in (0.5, 1)",
                      formatValue(criterionLevel));
    return std::log1p(weberFraction) /
           (std::numbers::sqrt2 * detail::normalQuantile(criterionLevel));
}

WeberObserver::WeberObserver(const WeberObserverParams& params, std::uint64_t seed)
    : mParams(params),
      mSigma(weberNoiseSd(params.weberFraction, params.criterionLevel)),
      mRng(seed) {
    requireLapse("weber observer lapseRate", params.lapseRate);
}

int WeberObserver::chooseGreater(double first, double second) {
    requireFelt("weber observer first", first);
    requireFelt("weber observer second", second);
    return noisyChoice(mRng, first, second, mSigma, mSigma, mParams.lapseRate);
}

double WeberObserver::pCorrect(double increment) const {
    const double z = std::log1p(increment) / (mSigma * std::numbers::sqrt2);
    const double p = 0.5 * std::erfc(-z / std::numbers::sqrt2);
    return mParams.lapseRate * 0.5 + (1 - mParams.lapseRate) * p;
}

double peakNormalisedGradient(const FeltProfile& profile, double windowM) {
    const auto& x = profile.positionM;
    const auto& k = profile.stiffnessNpm;
    if (x.size() != k.size())
        throwExpected("felt profile stiffnessNpm",
                      std::to_string(x.size()) + " samples (one per position)",
                      std::to_string(k.size()));
    if (x.size() < 2)
        throwExpected("felt profile positionM", "at least 2 samples", std::to_string(x.size()));
    for (std::size_t i = 0; i < x.size(); ++i) {
        // The names are built only for a message: a trial may feel thousands of samples.
        if (!std::isfinite(x[i])) requireFinite(indexed("felt profile positionM", i), x[i], "m");
        if (!(k[i] >= 0 && std::isfinite(k[i])))
            requireNonNegative(indexed("felt profile stiffnessNpm", i), k[i], "N/m");
        if (i > 0 && !(x[i] > x[i - 1]))
            throwExpected(indexed("felt profile positionM", i),
                          "a position > the one before, " + formatValue(x[i - 1]) + " m",
                          formatValue(x[i]));
    }
    if (!(windowM >= 0 && std::isfinite(windowM)))
        throwExpected("felt profile window", "a finite length >= 0 m", formatValue(windowM));
    const auto [lo, hi] = std::minmax_element(k.begin(), k.end());
    const double height = *hi - *lo;
    if (height <= 0) return 0;
    double peak = 0;
    const double h = 0.5 * windowM;
    if (h <= 0 || x.back() - x.front() <= windowM) {
        if (h > 0) return std::abs(k.back() - k.front()) / (x.back() - x.front()) / height;
        for (std::size_t i = 1; i < x.size(); ++i)
            peak = std::max(peak, std::abs(k[i] - k[i - 1]) / (x[i] - x[i - 1]));
        return peak / height;
    }
    // k at u by linear interpolation; j walks forward with u.
    auto at = [&](double u, std::size_t& j) {
        while (j + 2 < x.size() && x[j + 1] < u) ++j;
        const double t = (u - x[j]) / (x[j + 1] - x[j]);
        return k[j] + (k[j + 1] - k[j]) * t;
    };
    std::size_t jl = 0, jr = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
        if (x[i] - h < x.front() || x[i] + h > x.back()) continue;
        peak = std::max(peak, std::abs(at(x[i] + h, jr) - at(x[i] - h, jl)) / windowM);
    }
    return peak / height;
}

GradientObserver::GradientObserver(const GradientObserverParams& params, std::uint64_t seed)
    : mParams(params), mRng(seed) {
    requirePositive("gradient observer weberAtReference", params.weberAtReference);
    requirePositive("gradient observer referenceGradientPerM", params.referenceGradientPerM, "1/m");
    requireNonNegative("gradient observer exponent", params.exponent);
    requirePositive("gradient observer minWeber", params.minWeber);
    if (!(params.maxWeber >= params.minWeber) || !std::isfinite(params.maxWeber))
        throwExpected("gradient observer maxWeber",
                      "a finite value >= minWeber = " + formatValue(params.minWeber),
                      formatValue(params.maxWeber));
    weberNoiseSd(params.weberAtReference, params.criterionLevel);  // checks criterionLevel
    requireLapse("gradient observer lapseRate", params.lapseRate);
    requireNonNegative("gradient observer windowM", params.windowM, "m");
}

double GradientObserver::weberFraction(double gradientPerM) const {
    if (!(gradientPerM > 0)) return mParams.maxWeber;
    const double w = mParams.weberAtReference *
                     std::pow(mParams.referenceGradientPerM / gradientPerM, mParams.exponent);
    return std::clamp(w, mParams.minWeber, mParams.maxWeber);
}

int GradientObserver::chooseGreater(const FeltProfile& first, const FeltProfile& second) {
    const double w1 = weberFraction(peakNormalisedGradient(first, mParams.windowM));
    const double w2 = weberFraction(peakNormalisedGradient(second, mParams.windowM));
    const double k1 = *std::max_element(first.stiffnessNpm.begin(), first.stiffnessNpm.end());
    const double k2 = *std::max_element(second.stiffnessNpm.begin(), second.stiffnessNpm.end());
    requireFelt("gradient observer first profile's peak", k1);
    requireFelt("gradient observer second profile's peak", k2);
    return noisyChoice(mRng, k1, k2, weberNoiseSd(w1, mParams.criterionLevel),
                       weberNoiseSd(w2, mParams.criterionLevel), mParams.lapseRate);
}

}  // namespace palp::perception
