#include "palp/perception/quest.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "palp/base/validate.h"

namespace palp::perception {

namespace {

constexpr double kEps = std::numeric_limits<double>::epsilon();
constexpr double kMaxGridPoints = 1e6;

/// Linear interpolation of y(x) at @p xi over strictly increasing @p x: within the interval
/// [x[k], x[k+1]] that holds xi (the last one at the right end), y[k] + s (y[k+1] - y[k]) with
/// s = (xi - x[k]) / (x[k+1] - x[k]). NaN outside [x.front(), x.back()].
double interpolate(const std::vector<double>& x, const std::vector<double>& y, double xi) {
    if (x.size() < 2 || !(xi >= x.front() && xi <= x.back()))
        return std::numeric_limits<double>::quiet_NaN();
    auto k = static_cast<std::size_t>(std::upper_bound(x.begin(), x.end(), xi) - x.begin());
    k = std::clamp<std::size_t>(k, 1, x.size() - 1) - 1;
    const double s = (xi - x[k]) / (x[k + 1] - x[k]);
    return s * (y[k + 1] - y[k]) + y[k];
}

double questLikelihood(const QuestParams& q, double x) {
    return q.delta * q.gamma +
           (1 - q.delta) * (1 - (1 - q.gamma) * std::exp(-std::pow(10.0, q.beta * x)));
}

}  // namespace

void validateQuest(const QuestParams& q) {
    requireFinite("quest tGuess", q.tGuess, "(log10 units)");
    requirePositive("quest tGuessSd", q.tGuessSd, "(log10 units)");
    if (!(q.pThreshold > 0 && q.pThreshold < 1))
        throwExpected("quest pThreshold", "a probability in (0, 1)", formatValue(q.pThreshold));
    requirePositive("quest beta", q.beta);
    if (!(q.delta >= 0 && q.delta < 1))
        throwExpected("quest delta", "a lapse rate in [0, 1)", formatValue(q.delta));
    if (!(q.gamma >= 0 && q.gamma < q.pThreshold))
        throwExpected("quest gamma",
                      "a guess rate in [0, pThreshold) = [0, " + formatValue(q.pThreshold) + ")",
                      formatValue(q.gamma));
    requirePositive("quest grain", q.grain, "(log10 units)");
    requirePositive("quest range", q.range, "(log10 units)");
    if (!(q.range / q.grain <= kMaxGridPoints))
        throwExpected("quest range / grain", "at most " + formatValue(kMaxGridPoints) + " points",
                      formatValue(q.range / q.grain));
    if (q.maxTrials < 1)
        throwExpected("quest maxTrials", "an integer >= 1", std::to_string(q.maxTrials));
    requireNonNegative("quest maxIntervalWidth", q.maxIntervalWidth, "(log10 units, 0: none)");
    if (!(q.intervalMass > 0 && q.intervalMass < 1))
        throwExpected("quest intervalMass", "a probability in (0, 1)", formatValue(q.intervalMass));
}

Quest::Quest(const QuestParams& params) : mParams(params) {
    validateQuest(mParams);
    const QuestParams& q = mParams;
    mHalf = static_cast<int>(std::ceil(q.range / q.grain / 2));
    const int dim = 2 * mHalf;

    // The prior: a Gaussian about tGuess on the grid, normalised.
    mX.resize(static_cast<std::size_t>(dim + 1));
    mPdf.resize(mX.size());
    double sum = 0;
    for (int i = -mHalf; i <= mHalf; ++i) {
        const auto k = static_cast<std::size_t>(i + mHalf);
        mX[k] = i * q.grain;
        const double z = mX[k] / q.tGuessSd;
        mPdf[k] = std::exp(-0.5 * (z * z));
        sum += mPdf[k];
    }
    for (double& p : mPdf) p = p / sum;

    // The likelihood on differences x - T = j grain, j = -dim..dim, shifted so that
    // p(0) = pThreshold: eps from the table's strictly increasing points, interpolated.
    std::vector<double> d(static_cast<std::size_t>(2 * dim + 1)), p(d.size());
    for (int j = -dim; j <= dim; ++j) {
        const auto k = static_cast<std::size_t>(j + dim);
        d[k] = j * q.grain;
        p[k] = questLikelihood(q, d[k]);
    }
    const double pLo = std::min(p.front(), p.back()), pHi = std::max(p.front(), p.back());
    if (!(pLo <= q.pThreshold && pHi >= q.pThreshold))
        throwExpected("quest pThreshold",
                      "a probability the likelihood reaches on the grid, in [" + formatValue(pLo) +
                          ", " + formatValue(pHi) + "]",
                      formatValue(q.pThreshold));
    std::vector<double> pRising, dRising;
    for (std::size_t k = 0; k + 1 < p.size(); ++k)
        if (p[k + 1] != p[k]) {
            pRising.push_back(p[k]);
            dRising.push_back(d[k]);
        }
    const double shift = interpolate(pRising, dRising, q.pThreshold);
    if (!std::isfinite(shift))
        throwExpected("quest likelihood",
                      "a point where p = pThreshold = " + formatValue(q.pThreshold),
                      "none on the grid (beta, grain or range too small)");
    mP.resize(d.size());
    for (std::size_t k = 0; k < d.size(); ++k) mP[k] = questLikelihood(q, d[k] + shift);

    // Pelli's (1987) ideal quantile order for this likelihood's asymptotes.
    const double pL = mP.front(), pH = mP.back();
    double pE = pH * std::log(pH + kEps) - pL * std::log(pL + kEps) +
                (1 - pH + kEps) * std::log(1 - pH + kEps) -
                (1 - pL + kEps) * std::log(1 - pL + kEps);
    pE = 1 / (1 + std::exp(pE / (pL - pH)));
    mQuantileOrder = (pE - pL) / (pH - pL);
}

void Quest::update(double intensity, bool correct) {
    if (std::isnan(intensity)) throwExpected("quest intensity", "a number (log10 units)", "nan");
    const double clamped = std::clamp(intensity, -1e10, 1e10);
    // The trial's offset from tGuess in grid steps, kept inside the table.
    const double steps = std::round((clamped - mParams.tGuess) / mParams.grain);
    const int r = static_cast<int>(std::clamp(steps, double(-mHalf), double(mHalf)));
    const int dim = 2 * mHalf;
    double sum = 0;
    for (int i = -mHalf; i <= mHalf; ++i) {
        const auto k = static_cast<std::size_t>(i + mHalf);
        const double pc = mP[static_cast<std::size_t>(r - i + dim)];
        mPdf[k] = mPdf[k] * (correct ? pc : 1 - pc);
        sum += mPdf[k];
    }
    for (double& p : mPdf) p = p / sum;
    ++mTrials;
}

double Quest::mean() const {
    double s = 0, sx = 0;
    for (std::size_t k = 0; k < mPdf.size(); ++k) {
        sx += mPdf[k] * mX[k];
        s += mPdf[k];
    }
    return mParams.tGuess + sx / s;
}

double Quest::mode() const {
    const auto it = std::max_element(mPdf.begin(), mPdf.end());
    return mX[static_cast<std::size_t>(it - mPdf.begin())] + mParams.tGuess;
}

double Quest::sd() const {
    double s = 0, sx = 0, sxx = 0;
    for (std::size_t k = 0; k < mPdf.size(); ++k) {
        s += mPdf[k];
        sx += mPdf[k] * mX[k];
        sxx += mPdf[k] * (mX[k] * mX[k]);
    }
    const double m = sx / s;
    return std::sqrt(sxx / s - m * m);
}

double Quest::quantile(double order) const {
    if (!(order >= 0 && order <= 1))
        throwExpected("quest quantile order", "a value in [0, 1]", formatValue(order));
    std::vector<double> cum(mPdf.size());
    double s = 0;
    for (std::size_t k = 0; k < mPdf.size(); ++k) cum[k] = s += mPdf[k];
    if (order < cum.front()) return mParams.tGuess + mX.front();
    if (order > cum.back()) return mParams.tGuess + mX.back();
    // The points where the cumulative mass still rises (the first always), interpolated.
    std::vector<double> c, x;
    c.reserve(cum.size());
    x.reserve(cum.size());
    for (std::size_t k = 0; k < cum.size(); ++k)
        if (k == 0 || cum[k] > cum[k - 1]) {
            c.push_back(cum[k]);
            x.push_back(mX[k]);
        }
    if (c.size() < 2) return mParams.tGuess + x.front();
    return mParams.tGuess + interpolate(c, x, order * cum.back());
}

std::pair<double, double> Quest::credibleInterval(double mass) const {
    if (!(mass > 0 && mass < 1))
        throwExpected("quest interval mass", "a probability in (0, 1)", formatValue(mass));
    return {quantile(0.5 * (1 - mass)), quantile(0.5 * (1 + mass))};
}

double Quest::next(QuestPlacement placement) const {
    switch (placement) {
        case QuestPlacement::Mean:
            return mean();
        case QuestPlacement::Mode:
            return mode();
        case QuestPlacement::Quantile:
            break;
    }
    return quantile(mQuantileOrder);
}

double Quest::pCorrect(double intensity, double threshold) const {
    const double steps = std::round((intensity - threshold) / mParams.grain);
    const int dim = 2 * mHalf;
    const int j = static_cast<int>(std::clamp(steps, double(-dim), double(dim)));
    return mP[static_cast<std::size_t>(j + dim)];
}

bool Quest::finished() const {
    if (mTrials >= mParams.maxTrials) return true;
    if (mParams.maxIntervalWidth > 0) {
        const auto [lo, hi] = credibleInterval(mParams.intervalMass);
        return hi - lo <= mParams.maxIntervalWidth;
    }
    return false;
}

}  // namespace palp::perception
