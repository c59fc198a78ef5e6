#pragma once
// The sigmoids as functions of a linear predictor eta, the form the fits work in:
//   Weibull             eta = beta (ln x - ln alpha), F = 1 - exp(-exp(eta))  (complementary
//                       log-log, what R's mafc.cloglog links)
//   logistic            eta = (x - alpha) / beta,     F = 1 / (1 + exp(-eta))
//   cumulative Gaussian eta = (x - alpha) / beta,     F = Phi(eta)
// so eta = c0 + c1 t with t = ln x (Weibull) or x, and the fit is a binomial model on (c0, c1).

#include "palp/perception/psychometric.h"

namespace palp::perception::detail {

/// F, 1 - F (computed without cancellation), dF/deta and d2F/deta2 at one eta.
struct SigmoidAt {
    double F = 0;
    double Fc = 1;
    double dF = 0;
    double d2F = 0;
};
SigmoidAt sigmoidAtEta(PsychometricShape shape, double eta);
/// The eta where F = @p F, @p F in (0, 1).
double etaOfF(PsychometricShape shape, double F);
/// The predictor t of a level: ln x for the Weibull (-inf at x <= 0), x otherwise.
double predictorOf(PsychometricShape shape, double x);
/// The level of a predictor value (the inverse of predictorOf).
double levelOf(PsychometricShape shape, double t);
/// Phi^-1(p), p in (0, 1), to about 1 ulp (Acklam's rational start and a Halley step).
double normalQuantile(double p);

/// (alpha, beta) -> (c0, c1) and back.
void coefficientsOf(PsychometricShape shape, double alpha, double beta, double& c0, double& c1);
void parametersOf(PsychometricShape shape, double c0, double c1, double& alpha, double& beta);

}  // namespace palp::perception::detail
