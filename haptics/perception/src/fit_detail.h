#pragma once
// The fit's internals, shared by psychometric_fit.cpp and bootstrap.cpp.

#include <functional>
#include <span>
#include <vector>

#include "palp/perception/psychometric_fit.h"

namespace palp::perception::detail {

/// The data in the linear predictor's terms: t = predictorOf(level), k correct of n.
struct FitProblem {
    PsychometricShape shape = PsychometricShape::Weibull;
    double gamma = 0.5;
    std::vector<double> t, k, n;
};

FitProblem problemOf(std::span<const ResponseBlock> data, const FitOptions& options);
/// -log-likelihood at (lambda, c0, c1); +inf where a block's observed outcome is impossible.
double negLogLikelihood(const FitProblem& p, double lambda, double c0, double c1);
/// Newton's method in (c0, c1) at a fixed lambda from the given start; false when it hit its
/// iteration cap or met a singular Hessian and Fisher information.
bool newtonFit(const FitProblem& p, double lambda, double& c0, double& c1, double& nll);
/// The best of a grid of centres and widths over the levels' span.
void gridStart(const FitProblem& p, double lambda, double& c0, double& c1);
/// Brent's minimiser of @p f on [a, b] to about @p tol; the minimum's value in @p fmin.
double brentMinimize(const std::function<double(double)>& f, double a, double b, double tol,
                     double& fmin);
/// The fit (without its deviance); @p start, when given, the (c0, c1) to try besides the grid.
PsychometricFit fitProblem(const FitProblem& p, const FitOptions& options, const double* start);

/// psi(x) and 1 - psi(x), the latter without cancellation.
void psiAndComplement(const PsychometricFunction& f, double x, double& p, double& pc);

}  // namespace palp::perception::detail
