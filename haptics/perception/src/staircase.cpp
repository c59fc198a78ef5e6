#include "palp/perception/staircase.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>

#include "palp/base/validate.h"

namespace palp::perception {

namespace {

constexpr std::string_view kStair = "staircase ";

std::string field(std::string_view name) { return std::string(kStair) + std::string(name); }

void requireCount(std::string_view name, int v, int min) {
    if (v < min)
        throwExpected(field(name), "an integer >= " + std::to_string(min), std::to_string(v));
}

/// P(a run of n correct responses comes before a run of m incorrect ones), from a fresh count:
/// p^(n-1) (1 - q^m) / (p^(n-1) + q^(m-1) - p^(n-1) q^(m-1)), q = 1 - p.
double downFirst(double p, int n, int m) {
    const double q = 1 - p;
    const double pn = std::pow(p, n - 1), qm = std::pow(q, m - 1);
    return pn * (1 - qm * q) / (pn + qm - pn * qm);
}

}  // namespace

void validateStaircase(const StaircaseParams& params) {
    requireCount("down", params.down, 1);
    requireCount("up", params.up, 1);
    requirePositive(field("upDownRatio"), params.upDownRatio);
    if (params.stepSizes.empty()) throwExpected(field("stepSizes"), "at least one step", "none");
    for (std::size_t i = 0; i < params.stepSizes.size(); ++i)
        requirePositive(field("stepSizes[" + std::to_string(i) + "]"), params.stepSizes[i]);
    if (std::isnan(params.minLevel)) throwExpected(field("minLevel"), "a number", "nan");
    if (!(params.maxLevel > params.minLevel))
        throwExpected(field("maxLevel"), "a value > minLevel = " + formatValue(params.minLevel),
                      formatValue(params.maxLevel));
    requireInRange(field("startLevel"), params.startLevel, params.minLevel, params.maxLevel);
    if (params.scale != StepScale::Linear && !(params.startLevel > 0))
        throwExpected(field("startLevel"), "a level > 0 for log10 or dB steps",
                      formatValue(params.startLevel));
    requireCount("maxTrials", params.maxTrials, 1);
    requireCount("maxReversals", params.maxReversals, 0);
}

double staircaseTarget(int down, int up, double upDownRatio) {
    if (down < 1) throwExpected("staircase down", "an integer >= 1", std::to_string(down));
    if (up < 1) throwExpected("staircase up", "an integer >= 1", std::to_string(up));
    requirePositive("staircase upDownRatio", upDownRatio);
    // The expected step is zero where P(down) Sdown = P(up) Sup, P(down) = r / (1 + r); the
    // probability of a down step grows with p, so bisect.
    const double want = upDownRatio / (1 + upDownRatio);
    double lo = 0, hi = 1;
    for (int i = 0; i < 200 && hi - lo > 1e-15; ++i) {
        const double mid = 0.5 * (lo + hi);
        (downFirst(mid, down, up) < want ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi);
}

Staircase::Staircase(StaircaseParams params) : mParams(std::move(params)) {
    validateStaircase(mParams);
    mLevel = mParams.startLevel;
    mTrials.reserve(static_cast<std::size_t>(mParams.maxTrials));
}

bool Staircase::finished() const {
    return trialCount() >= mParams.maxTrials ||
           (mParams.maxReversals > 0 && reversalCount() >= mParams.maxReversals);
}

double Staircase::stepped(double level, double signedStep) const {
    double next = level;
    switch (mParams.scale) {
        case StepScale::Linear:
            next = level + signedStep;
            break;
        case StepScale::Log10:
            next = level * std::pow(10.0, signedStep);
            break;
        case StepScale::Decibel:
            next = level * std::pow(10.0, signedStep / 20);
            break;
    }
    return std::clamp(next, mParams.minLevel, mParams.maxLevel);
}

void Staircase::update(bool correct) {
    if (finished())
        throwExpected("staircase update", "a staircase that has not finished",
                      std::to_string(trialCount()) + " trials and " +
                          std::to_string(reversalCount()) + " reversals");
    StaircaseTrial t;
    t.level = mLevel;
    t.correct = correct;
    const bool initial = mParams.oneUpOneDownUntilFirstReversal && mReversals.empty();
    const int down = initial ? 1 : mParams.down;
    const int up = initial ? 1 : mParams.up;
    if (correct) {
        mWrongRun = 0;
        if (++mCorrectRun >= down) {
            t.step = -1;
            mCorrectRun = 0;
        }
    } else {
        mCorrectRun = 0;
        if (++mWrongRun >= up) {
            t.step = +1;
            mWrongRun = 0;
        }
    }
    if (t.step != 0) {
        if (mLastStep != 0 && t.step != mLastStep) {
            t.reversal = true;
            mReversals.push_back(mLevel);
        }
        // The step size for the number of reversals so far, this one included.
        const std::size_t r = std::min(mReversals.size(), mParams.stepSizes.size() - 1);
        const double size = mParams.stepSizes[r] * (t.step > 0 ? mParams.upDownRatio : 1.0);
        mLevel = stepped(mLevel, t.step * size);
        mLastStep = t.step;
    }
    mTrials.push_back(t);
}

double Staircase::threshold(int dropFirst, int useLast) const {
    return thresholdFromReversals(mReversals, dropFirst, useLast, mParams.scale);
}

double thresholdFromReversals(std::span<const double> reversals, int dropFirst, int useLast,
                              StepScale scale) {
    if (dropFirst < 0)
        throwExpected("reversals to drop", "an integer >= 0", std::to_string(dropFirst));
    if (useLast < 0)
        throwExpected("reversals to average", "an integer >= 0 (0: all)", std::to_string(useLast));
    const auto n = static_cast<int>(reversals.size());
    if (n <= dropFirst)
        throwExpected("reversals", "more than the " + std::to_string(dropFirst) + " dropped",
                      std::to_string(n));
    const int first = useLast > 0 ? std::max(dropFirst, n - useLast) : dropFirst;
    const bool geometric = scale != StepScale::Linear;
    double sum = 0;
    for (int i = first; i < n; ++i) {
        const double v = reversals[static_cast<std::size_t>(i)];
        if (geometric && !(v > 0))
            throwExpected("reversal level", "a level > 0 for a geometric mean", formatValue(v));
        sum += geometric ? std::log(v) : v;
    }
    const double mean = sum / (n - first);
    return geometric ? std::exp(mean) : mean;
}

}  // namespace palp::perception
