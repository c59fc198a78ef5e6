#pragma once
/// @file
/// QUEST (Watson & Pelli 1983): a Bayesian adaptive threshold procedure. The threshold T (in
/// log10 units of intensity, as in the paper) has a Gaussian prior; each response multiplies
/// the posterior by the likelihood of a Weibull psychometric function in log units,
///
///     p(x) = delta gamma + (1 - delta) (1 - (1 - gamma) exp(-10^(beta (x - T + eps)))),
///
/// where x is the trial's intensity, delta the lapse rate (a blunder), gamma the guess rate and
/// eps the offset that puts p(T) = pThreshold. The posterior lives on a grid of `grain` steps
/// about the prior's mean; the likelihood is tabulated on the grid of differences x - T, as
/// Psychtoolbox's Quest does (which palp's results match to 1e-9, tests/haptics/perception).
///
/// Estimates: the posterior mean (King-Smith et al. 1994, Pelli 1989), its mode (Watson &
/// Pelli's maximum a posteriori), its sd, and quantiles; the next trial's intensity is by
/// default the quantile of order Pelli's (1987) ideal quantileOrder().
/// @par Threading
/// One Quest per thread; const members may be called concurrently.

#include <utility>
#include <vector>

namespace palp::perception {

/// What a QUEST run assumes; validateQuest() states the ranges.
struct QuestParams {
    /// Prior mean of the threshold, log10 units.
    double tGuess = 0;
    /// Prior sd, log10 units (> 0).
    double tGuessSd = 2;
    /// The probability correct that defines the threshold, in (gamma, 1).
    double pThreshold = 0.82;
    /// Weibull slope (> 0; 3.5 in Watson & Pelli).
    double beta = 3.5;
    /// Lapse rate, [0, 1).
    double delta = 0.01;
    /// Guess rate, [0, pThreshold).
    double gamma = 0.5;
    /// Grid step, log10 units (> 0).
    double grain = 0.01;
    /// Width of the posterior grid, log10 units (> 0): 2 ceil(range / grain / 2) + 1 points
    /// about tGuess. Intensities more than range / 2 from tGuess use the likelihood at the
    /// table's end.
    double range = 5;
    /// Stop after this many trials (>= 1).
    int maxTrials = 40;
    /// Stop early once the central credible interval holding @p intervalMass of the posterior
    /// is at most this wide (log10 units; 0: never).
    double maxIntervalWidth = 0;
    /// The mass of that interval, in (0, 1).
    double intervalMass = 0.95;
};

/// @throw palp::ValueError naming the field ("quest grain"), what was expected and the value
/// found; also when the grid is over 1e6 points or the likelihood never crosses pThreshold.
void validateQuest(const QuestParams& params);

/// How the next trial's intensity is chosen.
enum class QuestPlacement {
    Quantile,  ///< quantile(quantileOrder()) (Pelli 1987)
    Mean,      ///< the posterior mean (King-Smith et al. 1994)
    Mode,      ///< the posterior mode (Watson & Pelli 1983)
};

class Quest {
  public:
    /// @throw palp::ValueError as validateQuest().
    explicit Quest(const QuestParams& params);

    /// Multiplies the posterior by the likelihood of @p correct at @p intensity (log10 units;
    /// infinite ones are clamped to +-1e10) and renormalises it.
    /// @throw palp::ValueError for a NaN intensity.
    void update(double intensity, bool correct);

    /// Posterior mean of the threshold (log10 units).
    double mean() const;
    /// Posterior mode (the first grid point of the largest density).
    double mode() const;
    /// Posterior sd.
    double sd() const;
    /// The threshold below which the posterior holds @p order of its mass, interpolated
    /// linearly in the cumulative sum; the grid's end when @p order lies beyond it.
    /// @throw palp::ValueError unless @p order is in [0, 1].
    double quantile(double order) const;
    /// Pelli's (1987) quantile order that makes each trial most informative for this
    /// likelihood (about 0.5 for the defaults).
    double quantileOrder() const { return mQuantileOrder; }
    /// The central interval holding @p mass of the posterior: quantiles (1 -+ mass) / 2.
    std::pair<double, double> credibleInterval(double mass) const;
    /// The intensity to test next.
    double next(QuestPlacement placement = QuestPlacement::Quantile) const;
    /// The modelled probability of a correct response at @p intensity if the threshold were
    /// @p threshold (both log10 units), from the tabulated likelihood.
    double pCorrect(double intensity, double threshold) const;

    int trialCount() const { return mTrials; }
    /// True after maxTrials trials, or once the credible interval is narrow enough.
    bool finished() const;
    const QuestParams& params() const { return mParams; }
    /// The grid (threshold - tGuess, log10 units) and the normalised posterior on it.
    const std::vector<double>& grid() const { return mX; }
    const std::vector<double>& posterior() const { return mPdf; }

  private:
    QuestParams mParams;
    int mHalf = 0;             // grid indices -mHalf..mHalf
    std::vector<double> mX;    // grid offsets i * grain
    std::vector<double> mPdf;  // posterior on the grid
    std::vector<double> mP;    // p at differences d = j * grain, j = -2 mHalf..2 mHalf
    double mQuantileOrder = 0.5;
    int mTrials = 0;
};

}  // namespace palp::perception
