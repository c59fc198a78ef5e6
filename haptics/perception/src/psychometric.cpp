#include "palp/perception/psychometric.h"

#include <cctype>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include "fit_detail.h"
#include "palp/base/validate.h"
#include "sigmoid.h"

namespace palp::perception {

namespace detail {

SigmoidAt sigmoidAtEta(PsychometricShape shape, double eta) {
    SigmoidAt s;
    switch (shape) {
        case PsychometricShape::Weibull: {
            // F = 1 - exp(-e), e = exp(eta); dF = e exp(-e); d2F = dF (1 - e).
            if (eta > 700) {  // exp(eta) would overflow; F is 1 to double precision
                s.F = 1;
                s.Fc = 0;
                break;
            }
            const double e = std::exp(eta);
            s.Fc = std::exp(-e);
            s.F = -std::expm1(-e);
            s.dF = e * s.Fc;
            s.d2F = s.dF * (1 - e);
            break;
        }
        case PsychometricShape::Logistic: {
            if (eta >= 0) {
                const double z = std::exp(-eta);
                s.F = 1 / (1 + z);
                s.Fc = z / (1 + z);
            } else {
                const double z = std::exp(eta);
                s.F = z / (1 + z);
                s.Fc = 1 / (1 + z);
            }
            s.dF = s.F * s.Fc;
            s.d2F = s.dF * (s.Fc - s.F);
            break;
        }
        case PsychometricShape::CumulativeGaussian: {
            s.F = 0.5 * std::erfc(-eta / std::numbers::sqrt2);
            s.Fc = 0.5 * std::erfc(eta / std::numbers::sqrt2);
            s.dF = std::exp(-0.5 * eta * eta) / std::sqrt(2 * std::numbers::pi);
            s.d2F = -eta * s.dF;
            break;
        }
    }
    return s;
}

double normalQuantile(double p) {
    if (!(p > 0 && p < 1)) return std::numeric_limits<double>::quiet_NaN();
    // Acklam's rational approximation (relative error 1.15e-9) ...
    static constexpr double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,
                                   -2.759285104469687e+02, 1.383577518672690e+02,
                                   -3.066479806614716e+01, 2.506628277459239e+00};
    static constexpr double b[] = {-5.447609879822406e+01, 1.615858368580409e+02,
                                   -1.556989798598866e+02, 6.680131188771972e+01,
                                   -1.328068155288572e+01};
    static constexpr double c[] = {-7.784894002430293e-03, -3.223964580411365e-01,
                                   -2.400758277161838e+00, -2.549732539343734e+00,
                                   4.374664141464968e+00,  2.938163982698783e+00};
    static constexpr double d[] = {7.784695709041462e-03, 3.224671290700398e-01,
                                   2.445134137142996e+00, 3.754408661907416e+00};
    const double lo = 0.02425;
    double x;
    if (p < lo) {
        const double q = std::sqrt(-2 * std::log(p));
        x = (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
            ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1);
    } else if (p <= 1 - lo) {
        const double q = p - 0.5, r = q * q;
        x = (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
            (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1);
    } else {
        const double q = std::sqrt(-2 * std::log1p(-p));
        x = -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
            ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1);
    }
    // ... refined by Halley steps on Phi(x) - p (the residual from the nearer tail).
    for (int i = 0; i < 2; ++i) {
        const double e = x <= 0 ? 0.5 * std::erfc(-x / std::numbers::sqrt2) - p
                                : (1 - p) - 0.5 * std::erfc(x / std::numbers::sqrt2);
        const double u = e * std::sqrt(2 * std::numbers::pi) * std::exp(0.5 * x * x);
        x -= u / (1 + 0.5 * x * u);
    }
    return x;
}

double etaOfF(PsychometricShape shape, double F) {
    switch (shape) {
        case PsychometricShape::Weibull:
            return std::log(-std::log1p(-F));
        case PsychometricShape::Logistic:
            return std::log(F) - std::log1p(-F);
        case PsychometricShape::CumulativeGaussian:
            return normalQuantile(F);
    }
    return std::numeric_limits<double>::quiet_NaN();
}

double predictorOf(PsychometricShape shape, double x) {
    if (shape != PsychometricShape::Weibull) return x;
    return x > 0 ? std::log(x) : -std::numeric_limits<double>::infinity();
}

double levelOf(PsychometricShape shape, double t) {
    return shape == PsychometricShape::Weibull ? std::exp(t) : t;
}

void coefficientsOf(PsychometricShape shape, double alpha, double beta, double& c0, double& c1) {
    if (shape == PsychometricShape::Weibull) {
        c1 = beta;
        c0 = -beta * std::log(alpha);
    } else {
        c1 = 1 / beta;
        c0 = -alpha / beta;
    }
}

void parametersOf(PsychometricShape shape, double c0, double c1, double& alpha, double& beta) {
    if (shape == PsychometricShape::Weibull) {
        beta = c1;
        alpha = std::exp(-c0 / c1);
    } else {
        beta = 1 / c1;
        alpha = -c0 / c1;
    }
}

void psiAndComplement(const PsychometricFunction& f, double x, double& p, double& pc) {
    SigmoidAt s;
    if (!(f.shape == PsychometricShape::Weibull && x <= 0)) {
        double c0, c1;
        coefficientsOf(f.shape, f.alpha, f.beta, c0, c1);
        s = sigmoidAtEta(f.shape, c0 + c1 * predictorOf(f.shape, x));
    }
    const double a = 1 - f.gamma - f.lambda;
    p = f.gamma + a * s.F;
    pc = a * s.Fc + f.lambda;
}

}  // namespace detail

std::string_view shapeName(PsychometricShape shape) {
    switch (shape) {
        case PsychometricShape::Weibull:
            return "weibull";
        case PsychometricShape::Logistic:
            return "logistic";
        case PsychometricShape::CumulativeGaussian:
            return "gaussian";
    }
    return "?";
}

PsychometricShape parseShape(std::string_view what, std::string_view name) {
    std::string lower(name);
    for (char& ch : lower) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    if (lower == "weibull") return PsychometricShape::Weibull;
    if (lower == "logistic") return PsychometricShape::Logistic;
    if (lower == "gaussian" || lower == "cumulative gaussian" || lower == "normal")
        return PsychometricShape::CumulativeGaussian;
    throwExpected(what, "weibull, logistic or gaussian", "'" + std::string(name) + "'");
}

void validatePsychometric(std::string_view what, const PsychometricFunction& f) {
    const std::string w(what);
    if (f.shape == PsychometricShape::Weibull)
        requirePositive(w + " alpha", f.alpha);
    else
        requireFinite(w + " alpha", f.alpha);
    requirePositive(w + " beta", f.beta);
    if (!(f.gamma >= 0 && f.gamma < 1))
        throwExpected(w + " gamma", "a guess rate in [0, 1)", formatValue(f.gamma));
    if (!(f.lambda >= 0 && f.lambda < 1 - f.gamma))
        throwExpected(w + " lambda",
                      "a lapse rate in [0, 1 - gamma) = [0, " + formatValue(1 - f.gamma) + ")",
                      formatValue(f.lambda));
}

double sigmoid(const PsychometricFunction& f, double x) {
    if (f.shape == PsychometricShape::Weibull && x <= 0) return 0;
    double c0, c1;
    detail::coefficientsOf(f.shape, f.alpha, f.beta, c0, c1);
    return detail::sigmoidAtEta(f.shape, c0 + c1 * detail::predictorOf(f.shape, x)).F;
}

double psi(const PsychometricFunction& f, double x) {
    return f.gamma + (1 - f.gamma - f.lambda) * sigmoid(f, x);
}

double thresholdAtF(const PsychometricFunction& f, double fLevel) {
    if (!(fLevel > 0 && fLevel < 1))
        throwExpected("F level", "a value in (0, 1)", formatValue(fLevel));
    double c0, c1;
    detail::coefficientsOf(f.shape, f.alpha, f.beta, c0, c1);
    return detail::levelOf(f.shape, (detail::etaOfF(f.shape, fLevel) - c0) / c1);
}

double thresholdAt(const PsychometricFunction& f, double psiLevel) {
    const double hi = 1 - f.lambda;
    if (!(psiLevel > f.gamma && psiLevel < hi))
        throwExpected("psi level",
                      "a value in (gamma, 1 - lambda) = (" + formatValue(f.gamma) + ", " +
                          formatValue(hi) + ")",
                      formatValue(psiLevel));
    return thresholdAtF(f, (psiLevel - f.gamma) / (1 - f.gamma - f.lambda));
}

double slopeAt(const PsychometricFunction& f, double x) {
    if (f.shape == PsychometricShape::Weibull && x <= 0) return 0;
    double c0, c1;
    detail::coefficientsOf(f.shape, f.alpha, f.beta, c0, c1);
    const double dF = detail::sigmoidAtEta(f.shape, c0 + c1 * detail::predictorOf(f.shape, x)).dF;
    const double dEtaDx = f.shape == PsychometricShape::Weibull ? c1 / x : c1;
    return (1 - f.gamma - f.lambda) * dF * dEtaDx;
}

double incrementJnd(const PsychometricFunction& f, double psiLevel) {
    return thresholdAt(f, psiLevel);
}

ComparisonJnd comparisonJnd(const PsychometricFunction& f) {
    ComparisonJnd j;
    j.pse = thresholdAt(f, 0.5);
    j.jnd = 0.5 * (thresholdAt(f, 0.75) - thresholdAt(f, 0.25));
    j.weberFraction = weberFraction(j.jnd, j.pse);
    return j;
}

double weberFraction(double jnd, double reference) {
    requirePositive("reference", reference);
    return jnd / reference;
}

}  // namespace palp::perception
