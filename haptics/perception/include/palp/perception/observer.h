#pragma once
/// @file
/// Simulated observers for virtual studies. They take what they felt as numbers (a stiffness,
/// a force, a stiffness profile along the path) and answer as a participant would, drawing
/// their noise from their own seeded std::mt19937_64; they know nothing of sessions or devices.
///
/// * PsychometricObserver answers a trial at a level correctly with probability psi(level):
///   the observer with a known psychometric function that a staircase's convergence is
///   checked on.
/// * WeberObserver compares two intervals with Weber-fraction noise: it perceives ln(k) + N(0,
///   sigma^2) of each felt value k and names the interval that felt greater. sigma is set so
///   that a relative increment of weberFraction is told apart with probability
///   criterionLevel: P(correct | increment d) = Phi(ln(1 + d) / (sigma sqrt 2)), sigma =
///   ln(1 + W) / (sqrt 2 Phi^-1(criterionLevel)); criterionLevel 0.7071 makes W the JND a
///   one-up-two-down staircase measures (ALGORITHMS.md section 8).
/// * GradientObserver feels a stiffness profile along its path and is the more precise the
///   steeper the profile's transition: its Weber fraction is W(g) = weberAtReference
///   (referenceGradient / g)^exponent, clamped to [minWeber, maxWeber], g the peak of
///   |dk/dx| / (k_max - k_min) along the path (1/m: the transition's steepness whatever its
///   height). It compares the profiles' largest stiffness, each with the noise of its own W.
/// @par Threading
/// One observer per thread (each owns its generator).

#include <cstdint>
#include <random>
#include <span>

#include "palp/perception/psychometric.h"

namespace palp::perception {

/// Answers correctly with probability psi(level).
class PsychometricObserver {
  public:
    /// @throw palp::ValueError as validatePsychometric("observer function", f).
    PsychometricObserver(const PsychometricFunction& f, std::uint64_t seed);
    bool respond(double level);
    const PsychometricFunction& function() const { return mF; }

  private:
    PsychometricFunction mF;
    std::mt19937_64 mRng;
};

struct WeberObserverParams {
    /// The relative increment told apart with probability criterionLevel (> 0, e.g. 0.0523).
    double weberFraction = 0.1;
    /// In (0.5, 1).
    double criterionLevel = 0.70710678118654752;
    /// Probability of a random answer (a lapse), [0, 1).
    double lapseRate = 0;
};

/// The sd of ln(perceived) that gives @p weberFraction at @p criterionLevel.
/// @throw palp::ValueError naming the field for values out of range.
double weberNoiseSd(double weberFraction, double criterionLevel);

class WeberObserver {
  public:
    /// @throw palp::ValueError naming the field ("weber observer weberFraction").
    WeberObserver(const WeberObserverParams& params, std::uint64_t seed);
    /// 0 when the first interval felt greater, 1 the second. @p first and @p second are what
    /// was felt (a stiffness in N/m, a force in N: any positive quantity of one kind).
    /// @throw palp::ValueError unless both are finite and > 0.
    int chooseGreater(double first, double second);
    /// P(choosing the greater) for a relative increment @p increment (lapses included).
    double pCorrect(double increment) const;
    double noiseSd() const { return mSigma; }

  private:
    WeberObserverParams mParams;
    double mSigma = 0;
    std::mt19937_64 mRng;
};

struct GradientObserverParams {
    /// Weber fraction at the reference gradient (> 0).
    double weberAtReference = 0.1795;
    /// The gradient where W = weberAtReference, 1/m (> 0; 1 / width for a linear ramp).
    double referenceGradientPerM = 50;
    /// How fast W falls as the gradient grows (>= 0; 0: W does not depend on it).
    double exponent = 0.5;
    /// Bounds of W (0 < minWeber <= maxWeber).
    double minWeber = 0.01;
    double maxWeber = 1;
    double criterionLevel = 0.70710678118654752;
    double lapseRate = 0;
    /// The length over which the observer resolves a slope, m (>= 0): the gradient at x is
    /// (k(x + h) - k(x - h)) / 2h with h = windowM / 2, so the scan's voxel noise between
    /// neighbouring samples is not taken for a transition. 0: between neighbouring samples.
    double windowM = 0;
};

/// A stiffness profile felt along a path: positions (m, increasing) and stiffness (N/m).
struct FeltProfile {
    std::span<const double> positionM;
    std::span<const double> stiffnessNpm;
};

/// The peak of |dk/dx| / (max k - min k) over the profile's segments, 1/m (0 for a flat one).
/// With @p windowM > 0 the slope at each sample x is (k(x + h) - k(x - h)) / 2h, h = windowM / 2,
/// k linearly interpolated between samples, where both ends lie on the profile (a profile
/// shorter than the window: the slope between its ends).
/// @throw palp::ValueError for fewer than two samples, spans of different lengths,
/// non-increasing positions, non-finite / negative stiffness or a negative or non-finite window.
double peakNormalisedGradient(const FeltProfile& profile, double windowM = 0);

class GradientObserver {
  public:
    /// @throw palp::ValueError naming the field ("gradient observer exponent").
    GradientObserver(const GradientObserverParams& params, std::uint64_t seed);
    /// W for a profile of peak normalised gradient @p gradientPerM (maxWeber for a flat one).
    double weberFraction(double gradientPerM) const;
    /// 0 when the first profile felt stiffer, 1 the second.
    /// @throw palp::ValueError as peakNormalisedGradient().
    int chooseGreater(const FeltProfile& first, const FeltProfile& second);

  private:
    GradientObserverParams mParams;
    std::mt19937_64 mRng;
};

}  // namespace palp::perception
