#pragma once
/// @file
/// Maximum-likelihood fits of psychometric functions to blocks of binary responses (Wichmann &
/// Hill 2001a), their parametric bootstrap (Wichmann & Hill 2001b) and goodness of fit.
///
/// The guess rate gamma is fixed (1/m in an m-alternative forced choice, 0 in a yes/no or
/// comparison design); the lapse rate lambda is fitted within [lambdaMin, lambdaMax] (fixed
/// when they are equal). The likelihood is maximised over the sigmoid's linear predictor
/// (sigmoid.h) by Newton's method with step halving, and over lambda by Brent's method on the
/// profile likelihood, the bounds included; the optimum agrees with psignifit 2.5.6 to its
/// simplex tolerance and with R's glm (psyphy's mafc links) to 1e-6
/// (tests/haptics/perception/test_psychometric_fit.cpp).
/// @par Threading
/// Pure functions; any thread.

#include <cstdint>
#include <span>
#include <vector>

#include "palp/perception/psychometric.h"

namespace palp::perception {

/// A block of trials at one level.
struct ResponseBlock {
    /// Stimulus level (> 0 for a Weibull fit).
    double level = 0;
    /// Correct (or "yes", "greater") responses, 0..trials.
    int correct = 0;
    /// Trials (>= 1).
    int trials = 0;
};

/// What to fit.
struct FitOptions {
    PsychometricShape shape = PsychometricShape::Weibull;
    /// The fixed guess rate, [0, 1).
    double gamma = 0.5;
    /// Bounds of the lapse rate, 0 <= lambdaMin <= lambdaMax < 1 - gamma (psignifit's
    /// #lambda_limits; equal to fix it).
    double lambdaMin = 0;
    double lambdaMax = 0.06;
};

/// @throw palp::ValueError naming the field ("fit lambdaMax") and the value found.
void validateFitOptions(const FitOptions& options);
/// @throw palp::ValueError for an empty data set, a block with a non-finite level (or <= 0 for
/// a Weibull), trials < 1, correct outside 0..trials, or fewer than two distinct levels; the
/// message names the block ("data[3] level").
void validateBlocks(std::span<const ResponseBlock> data, PsychometricShape shape);

/// A maximum-likelihood fit.
struct PsychometricFit {
    PsychometricFunction function;
    /// The binomial log-likelihood at the fit, without the binomial coefficients.
    double logLikelihood = 0;
    /// Deviance against the saturated model (psignifit's D).
    double deviance = 0;
    /// False when the Newton iterations hit their cap (e.g. data a step function separates:
    /// the slope grows without bound; the thresholds still settle).
    bool converged = true;
};

/// The maximum-likelihood psychometric function for @p data.
/// @throw palp::ValueError as validateBlocks() and validateFitOptions().
PsychometricFit fitPsychometric(std::span<const ResponseBlock> data, const FitOptions& options);

/// Deviance 2 sum(k ln(k / (n psi)) + (n - k) ln((n - k) / (n (1 - psi)))) of @p f on @p data.
double deviance(std::span<const ResponseBlock> data, const PsychometricFunction& f);
/// Binomial log-likelihood sum(k ln psi + (n - k) ln(1 - psi)) (no binomial coefficients).
double logLikelihood(std::span<const ResponseBlock> data, const PsychometricFunction& f);

/// A two-sided interval.
struct Interval {
    double lo = 0;
    double hi = 0;
    bool contains(double v) const { return v >= lo && v <= hi; }
};

/// What the bootstrap draws and reports.
struct BootstrapOptions {
    /// Simulated data sets (>= 1; 999 or more for 95 % intervals, Wichmann & Hill 2001b).
    int samples = 999;
    std::uint64_t seed = 1;
    /// The intervals' coverage, in (0, 1).
    double coverage = 0.95;
    /// psi levels whose thresholds get intervals (each in (gamma, 1 - lambdaMax)).
    std::vector<double> thresholdLevels{0.75};
};

/// A parametric bootstrap of a fit: data sets drawn from the fitted function at the original
/// levels and trial counts (std::mt19937_64 seeded by @p seed; the same seed, the same
/// results), each refitted; percentile intervals of the parameters and thresholds, and the
/// deviance's p-value.
struct BootstrapResult {
    Interval alpha, beta, lambda;
    /// One per BootstrapOptions::thresholdLevels.
    std::vector<Interval> thresholds;
    /// (1 + #{simulated deviance >= observed}) / (1 + samples): small when the function
    /// fits worse than data it generates.
    double devianceP = 1;
    /// Every refit, in the order drawn.
    std::vector<PsychometricFit> fits;
};

/// @throw palp::ValueError as fitPsychometric() and for options out of range.
BootstrapResult bootstrapPsychometric(std::span<const ResponseBlock> data,
                                      const PsychometricFit& fit, const FitOptions& options,
                                      const BootstrapOptions& bootstrap);

/// The @p q quantile (0..1) of @p values by linear interpolation between order statistics
/// (R's type 7); NaNs are ignored; NaN when none is left.
double sampleQuantile(std::vector<double> values, double q);

}  // namespace palp::perception
