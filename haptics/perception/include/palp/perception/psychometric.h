#pragma once
/// @file
/// Psychometric functions psi(x) = gamma + (1 - gamma - lambda) F(x; alpha, beta): a sigmoid F
/// (Weibull, logistic or cumulative Gaussian) scaled between the guess rate gamma (0.5 in a
/// two-alternative forced choice) and 1 - lambda, lambda being the lapse rate (Wichmann & Hill
/// 2001a). The parameterisation is psignifit's, so fits and thresholds compare one to one:
///
///     Weibull              F = 1 - exp(-(x / alpha)^beta)        x > 0; alpha, beta > 0
///     logistic             F = 1 / (1 + exp(-(x - alpha) / beta)) beta > 0
///     cumulative Gaussian  F = Phi((x - alpha) / beta)            beta > 0 (the sd)
///
/// x is in the stimulus's own units (a level, an increment as a fraction of the reference).
/// psignifit's "cuts" are levels of F; thresholdAt() takes levels of psi, thresholdAtF() of F.
/// Pure functions; any thread.

#include <string>
#include <string_view>

namespace palp::perception {

/// The sigmoid F of a psychometric function.
enum class PsychometricShape { Weibull, Logistic, CumulativeGaussian };

/// "weibull", "logistic", "gaussian".
std::string_view shapeName(PsychometricShape shape);
/// The shape named by shapeName() (also "cumulative gaussian" / "normal" for the Gaussian).
/// @throw palp::ValueError naming @p what for any other name.
PsychometricShape parseShape(std::string_view what, std::string_view name);

/// One psychometric function: the sigmoid, its two parameters, the guess and lapse rates.
struct PsychometricFunction {
    PsychometricShape shape = PsychometricShape::Weibull;
    /// Weibull: the scale, F(alpha) = 1 - 1/e; logistic and Gaussian: the location, F(alpha)
    /// = 0.5. In the stimulus's units.
    double alpha = 1;
    /// Weibull: the exponent (dimensionless); logistic: the scale, Gaussian: the sd (in the
    /// stimulus's units). > 0.
    double beta = 3;
    /// Guess rate, the lower asymptote, in [0, 1).
    double gamma = 0.5;
    /// Lapse rate: 1 - lambda is the upper asymptote; gamma + lambda < 1.
    double lambda = 0;
};

/// Checks @p f's fields; @p what prefixes the field names ("observer function alpha").
/// @throw palp::ValueError naming the field, what was expected and the value found.
void validatePsychometric(std::string_view what, const PsychometricFunction& f);

/// F(x) in [0, 1]. For the Weibull, F = 0 at x <= 0.
double sigmoid(const PsychometricFunction& f, double x);
/// psi(x) = gamma + (1 - gamma - lambda) F(x): the probability of a correct (or "yes",
/// "greater") response at level @p x.
double psi(const PsychometricFunction& f, double x);
/// The level where F = @p fLevel (psignifit's threshold at a cut), @p fLevel in (0, 1).
/// @throw palp::ValueError when @p fLevel is outside (0, 1).
double thresholdAtF(const PsychometricFunction& f, double fLevel);
/// The level where psi = @p psiLevel, @p psiLevel in (gamma, 1 - lambda).
/// @throw palp::ValueError when @p psiLevel is outside that range.
double thresholdAt(const PsychometricFunction& f, double psiLevel);
/// dpsi/dx at @p x (per unit of the stimulus).
double slopeAt(const PsychometricFunction& f, double x);

/// An increment design (two-alternative forced choice, the comparison is the reference plus x):
/// the just noticeable difference is the increment detected at @p psiLevel (0.7071 for what a
/// one-up-two-down staircase tracks, 0.75 for the midpoint of a 2AFC function).
double incrementJnd(const PsychometricFunction& f, double psiLevel);

/// A comparison design (x is the comparison's value, psi the proportion of "comparison
/// greater"): the point of subjective equality psi^-1(0.5), the JND (psi^-1(0.75) -
/// psi^-1(0.25)) / 2 and the Weber fraction JND / PSE.
struct ComparisonJnd {
    double pse = 0;
    double jnd = 0;
    double weberFraction = 0;
};
/// @throw palp::ValueError when 0.25 or 0.75 lie outside (gamma, 1 - lambda).
ComparisonJnd comparisonJnd(const PsychometricFunction& f);

/// @p jnd / @p reference. @throw palp::ValueError naming "reference" unless it is finite > 0.
double weberFraction(double jnd, double reference);

}  // namespace palp::perception
