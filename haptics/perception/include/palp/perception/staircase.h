#pragma once
/// @file
/// Adaptive up-down staircases: Levitt's (1971) transformed rules (n-down m-up), Kaernbach's
/// (1991) weighted up-down and their combination (Garcia-Perez 1998), with the initial
/// one-up-one-down rule until the first reversal, step sizes that change at reversals, linear,
/// log10 or decibel steps, bounds, stopping rules and the threshold from reversals.
///
/// Levels are stimulus intensities where larger is easier: @p down consecutive correct
/// responses lower the level, @p up consecutive incorrect ones raise it; a response of the other
/// kind restarts the count. A reversal is a step in the direction opposite to the step before;
/// its level is the level of the trial whose response made the turn (a peak or a valley).
/// Deterministic: the staircase draws no random numbers (a simulated observer does).
/// @par Threading
/// One staircase per thread; const members may be called concurrently.

#include <span>
#include <string_view>
#include <vector>

namespace palp::perception {

/// How a step size moves the level.
enum class StepScale {
    Linear,   ///< level +- step (in the level's units)
    Log10,    ///< level * 10^(+-step); levels > 0
    Decibel,  ///< level * 10^(+-step / 20); levels > 0
};

/// What a staircase does; validateStaircase() states the ranges.
struct StaircaseParams {
    /// The first trial's level (> 0 for Log10 and Decibel steps).
    double startLevel = 1;
    /// Consecutive correct responses that lower the level (>= 1).
    int down = 2;
    /// Consecutive incorrect responses that raise the level (>= 1).
    int up = 1;
    /// Step up / step down (> 0). 1 for Levitt's rules; p / (1 - p) for Kaernbach's weighted
    /// up-down with one-up-one-down, which then tracks psi = p.
    double upDownRatio = 1;
    /// The down step while r reversals have happened is stepSizes[min(r, size - 1)], in the
    /// scale's units (level units, log10 units, dB); each > 0, at least one.
    std::vector<double> stepSizes{1};
    StepScale scale = StepScale::Linear;
    /// Levitt's start: one-up-one-down until the first reversal, then the n-down m-up rule.
    bool oneUpOneDownUntilFirstReversal = true;
    /// Bounds of the level; a step past one stops at it; min < max. (Log10 and Decibel steps
    /// multiply, so their levels stay > 0 whatever minLevel is.)
    double minLevel = -1e300;
    double maxLevel = 1e300;
    /// Stop after this many trials (>= 1).
    int maxTrials = 100;
    /// Stop once this many reversals have happened (0: no reversal limit).
    int maxReversals = 0;
};

/// @throw palp::ValueError naming the field ("staircase stepSizes[1]"), what was expected and
/// the value found: non-finite or non-positive steps, ratio, counts; a start outside the
/// bounds; levels <= 0 with log10 or dB steps.
void validateStaircase(const StaircaseParams& params);

/// The probability of a correct response the rule converges to: where the expected step is
/// zero for the response-count chain (for one-up n-down with ratio r, p^n = r / (1 + r):
/// 0.7071 for 1-up-2-down, 0.7937 for 1-up-3-down, p for Kaernbach's ratio p / (1 - p)).
double staircaseTarget(int down, int up, double upDownRatio);

/// One trial as the staircase saw it.
struct StaircaseTrial {
    double level = 0;
    bool correct = false;
    /// -1 the response lowered the level, +1 raised it, 0 neither.
    int step = 0;
    bool reversal = false;
};

/// A transformed / weighted up-down staircase.
class Staircase {
  public:
    /// @throw palp::ValueError as validateStaircase().
    explicit Staircase(StaircaseParams params);

    /// The level to present next.
    double level() const { return mLevel; }
    /// Records the response to the trial at level(); moves the level.
    /// @throw palp::ValueError once finished().
    void update(bool correct);
    /// True once maxTrials trials or maxReversals reversals are done.
    bool finished() const;

    int trialCount() const { return static_cast<int>(mTrials.size()); }
    int reversalCount() const { return static_cast<int>(mReversals.size()); }
    /// The levels of the reversals, in order.
    std::span<const double> reversalLevels() const { return mReversals; }
    std::span<const StaircaseTrial> trials() const { return mTrials; }
    const StaircaseParams& params() const { return mParams; }

    /// thresholdFromReversals() over this staircase's reversals, averaged in its scale.
    double threshold(int dropFirst, int useLast = 0) const;

  private:
    double stepped(double level, double signedStep) const;

    StaircaseParams mParams;
    double mLevel = 0;
    int mCorrectRun = 0;
    int mWrongRun = 0;
    int mLastStep = 0;
    std::vector<StaircaseTrial> mTrials;
    std::vector<double> mReversals;
};

/// The threshold as the field takes it from a staircase: drop the first @p dropFirst
/// reversals, then average the last @p useLast of the rest (all of them when 0). With Log10 or
/// Decibel steps the mean is geometric (the mean of the logs), as the steps are.
/// @throw palp::ValueError when fewer than one reversal remains, or @p dropFirst / @p useLast
/// are negative, or a level is <= 0 for a geometric mean.
double thresholdFromReversals(std::span<const double> reversals, int dropFirst, int useLast,
                              StepScale scale);

}  // namespace palp::perception
