#include "palp/perception/psychometric_fit.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "fit_detail.h"
#include "palp/base/validate.h"
#include "sigmoid.h"

namespace palp::perception {

namespace detail {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

/// psi and 1 - psi (without cancellation) at one predictor value.
struct PsiAt {
    double psi, psiC;
    SigmoidAt s;
};

PsiAt psiAt(const FitProblem& p, double lambda, double eta) {
    PsiAt r;
    r.s = sigmoidAtEta(p.shape, eta);
    const double a = 1 - p.gamma - lambda;
    r.psi = p.gamma + a * r.s.F;
    r.psiC = a * r.s.Fc + lambda;
    return r;
}

}  // namespace

double negLogLikelihood(const FitProblem& p, double lambda, double c0, double c1) {
    double nll = 0;
    for (std::size_t i = 0; i < p.t.size(); ++i) {
        const PsiAt v = psiAt(p, lambda, c0 + c1 * p.t[i]);
        const double k = p.k[i], miss = p.n[i] - p.k[i];
        if (k > 0) nll -= v.psi > 0 ? k * std::log(v.psi) : -kInf;
        if (miss > 0) nll -= v.psiC > 0 ? miss * std::log(v.psiC) : -kInf;
    }
    return std::isnan(nll) ? kInf : nll;
}

bool newtonFit(const FitProblem& p, double lambda, double& c0, double& c1, double& nll) {
    nll = negLogLikelihood(p, lambda, c0, c1);
    const double a = 1 - p.gamma - lambda;
    for (int iter = 0; iter < 300; ++iter) {
        // Gradient and Hessian of the negative log-likelihood in (c0, c1); Fisher's expected
        // information where the observed Hessian is not positive definite.
        double g0 = 0, g1 = 0, h00 = 0, h01 = 0, h11 = 0, f00 = 0, f01 = 0, f11 = 0;
        for (std::size_t i = 0; i < p.t.size(); ++i) {
            const double t = p.t[i];
            const PsiAt v = psiAt(p, lambda, c0 + c1 * t);
            if (!(v.psi > 0 && v.psiC > 0)) continue;
            const double k = p.k[i], miss = p.n[i] - p.k[i];
            const double dpsi = a * v.s.dF, d2psi = a * v.s.d2F;
            const double u = k / v.psi - miss / v.psiC;
            const double w = k / (v.psi * v.psi) + miss / (v.psiC * v.psiC);
            const double gEta = -u * dpsi;
            const double hEta = w * dpsi * dpsi - u * d2psi;
            const double fEta = p.n[i] * dpsi * dpsi / (v.psi * v.psiC);
            g0 += gEta;
            g1 += gEta * t;
            h00 += hEta;
            h01 += hEta * t;
            h11 += hEta * t * t;
            f00 += fEta;
            f01 += fEta * t;
            f11 += fEta * t * t;
        }
        double det = h00 * h11 - h01 * h01;
        if (!(h00 > 0 && det > 0)) {
            h00 = f00;
            h01 = f01;
            h11 = f11;
            det = h00 * h11 - h01 * h01;
            if (!(h00 > 0 && det > 0)) return false;
        }
        const double s0 = -(h11 * g0 - h01 * g1) / det;
        const double s1 = -(h00 * g1 - h01 * g0) / det;
        if (!std::isfinite(s0) || !std::isfinite(s1)) return false;
        // Step halving until the likelihood does not fall.
        double step = 1, next = kInf;
        for (int h = 0; h < 60; ++h, step *= 0.5) {
            next = negLogLikelihood(p, lambda, c0 + step * s0, c1 + step * s1);
            if (next <= nll) break;
        }
        if (!(next <= nll)) return true;  // no descent left: at the optimum to rounding
        c0 += step * s0;
        c1 += step * s1;
        const bool small = std::abs(step * s0) <= 1e-13 * (1 + std::abs(c0)) &&
                           std::abs(step * s1) <= 1e-13 * (1 + std::abs(c1));
        nll = next;
        if (small) return true;
    }
    return false;
}

void gridStart(const FitProblem& p, double lambda, double& c0, double& c1) {
    const auto [lo, hi] = std::minmax_element(p.t.begin(), p.t.end());
    const double span = *hi - *lo;
    double best = kInf;
    for (int i = 0; i <= 10; ++i) {
        const double centre = *lo - 0.25 * span + 1.5 * span * i / 10;
        for (double width : {0.05, 0.1, 0.2, 0.4, 0.8, 1.6, 3.2}) {
            const double b1 = 4 / (width * span), b0 = -b1 * centre;
            const double v = negLogLikelihood(p, lambda, b0, b1);
            if (v < best) {
                best = v;
                c0 = b0;
                c1 = b1;
            }
        }
    }
}

double brentMinimize(const std::function<double(double)>& f, double a, double b, double tol,
                     double& fmin) {
    // Brent (1973), "localmin": golden-section steps, parabolic ones where they fall inside
    // the bracket and shrink it fast enough.
    const double golden = 0.5 * (3 - std::sqrt(5.0));
    const double sqrtEps = std::sqrt(std::numeric_limits<double>::epsilon());
    double x = a + golden * (b - a), w = x, v = x;
    double fx = f(x), fw = fx, fv = fx;
    double d = 0, e = 0;
    for (int iter = 0; iter < 200; ++iter) {
        const double m = 0.5 * (a + b);
        const double tol1 = sqrtEps * std::abs(x) + tol / 3, tol2 = 2 * tol1;
        if (std::abs(x - m) <= tol2 - 0.5 * (b - a)) break;
        double p = 0, q = 0, r = 0;
        if (std::abs(e) > tol1) {
            r = (x - w) * (fx - fv);
            q = (x - v) * (fx - fw);
            p = (x - v) * q - (x - w) * r;
            q = 2 * (q - r);
            if (q > 0)
                p = -p;
            else
                q = -q;
            r = e;
            e = d;
        }
        if (std::abs(p) < std::abs(0.5 * q * r) && p > q * (a - x) && p < q * (b - x)) {
            d = p / q;
            const double u = x + d;
            if (u - a < tol2 || b - u < tol2) d = x < m ? tol1 : -tol1;
        } else {
            e = (x < m ? b : a) - x;
            d = golden * e;
        }
        const double u = x + (std::abs(d) >= tol1 ? d : (d > 0 ? tol1 : -tol1));
        const double fu = f(u);
        if (fu <= fx) {
            (u < x ? b : a) = x;
            v = w;
            fv = fw;
            w = x;
            fw = fx;
            x = u;
            fx = fu;
        } else {
            (u < x ? a : b) = u;
            if (fu <= fw || w == x) {
                v = w;
                fv = fw;
                w = u;
                fw = fu;
            } else if (fu <= fv || v == x || v == w) {
                v = u;
                fv = fu;
            }
        }
    }
    fmin = fx;
    return x;
}

FitProblem problemOf(std::span<const ResponseBlock> data, const FitOptions& options) {
    FitProblem p;
    p.shape = options.shape;
    p.gamma = options.gamma;
    for (const ResponseBlock& b : data) {
        p.t.push_back(predictorOf(options.shape, b.level));
        p.k.push_back(b.correct);
        p.n.push_back(b.trials);
    }
    return p;
}

PsychometricFit fitProblem(const FitProblem& p, const FitOptions& options, const double* start) {
    const double lambdaStart = 0.5 * (options.lambdaMin + options.lambdaMax);
    double c0 = 0, c1 = 1;
    gridStart(p, lambdaStart, c0, c1);
    if (start != nullptr && negLogLikelihood(p, lambdaStart, start[0], start[1]) <
                                negLogLikelihood(p, lambdaStart, c0, c1)) {
        c0 = start[0];
        c1 = start[1];
    }
    struct Best {
        double nll = kInf, lambda = 0, c0 = 0, c1 = 0;
        bool converged = true;
    } best;
    // The profile likelihood over lambda: each evaluation refits (c0, c1), warm-started from
    // the previous one.
    double w0 = c0, w1 = c1;
    const auto profile = [&](double lambda) {
        double b0 = w0, b1 = w1, nll = kInf;
        const bool ok = newtonFit(p, lambda, b0, b1, nll);
        if (std::isfinite(b0) && std::isfinite(b1)) {
            w0 = b0;
            w1 = b1;
        }
        if (nll < best.nll) best = {nll, lambda, b0, b1, ok};
        return nll;
    };
    if (options.lambdaMax > options.lambdaMin) {
        double fmin = 0;
        brentMinimize(profile, options.lambdaMin, options.lambdaMax, 1e-11, fmin);
        profile(options.lambdaMin);  // Brent never evaluates the ends, where lambda often is
        profile(options.lambdaMax);
    } else {
        profile(options.lambdaMin);
    }
    PsychometricFit fit;
    fit.function.shape = options.shape;
    fit.function.gamma = options.gamma;
    fit.function.lambda = best.lambda;
    parametersOf(options.shape, best.c0, best.c1, fit.function.alpha, fit.function.beta);
    fit.logLikelihood = -best.nll;
    fit.converged = best.converged;
    return fit;
}

}  // namespace detail

void validateFitOptions(const FitOptions& options) {
    if (!(options.gamma >= 0 && options.gamma < 1))
        throwExpected("fit gamma", "a guess rate in [0, 1)", formatValue(options.gamma));
    if (!(options.lambdaMin >= 0 && options.lambdaMin < 1 - options.gamma))
        throwExpected(
            "fit lambdaMin",
            "a lapse rate in [0, 1 - gamma) = [0, " + formatValue(1 - options.gamma) + ")",
            formatValue(options.lambdaMin));
    if (!(options.lambdaMax >= options.lambdaMin && options.lambdaMax < 1 - options.gamma))
        throwExpected("fit lambdaMax",
                      "a lapse rate in [lambdaMin, 1 - gamma) = [" +
                          formatValue(options.lambdaMin) + ", " + formatValue(1 - options.gamma) +
                          ")",
                      formatValue(options.lambdaMax));
}

void validateBlocks(std::span<const ResponseBlock> data, PsychometricShape shape) {
    if (data.empty()) throwExpected("data", "at least two blocks of trials", "an empty data set");
    for (std::size_t i = 0; i < data.size(); ++i) {
        const std::string name = "data[" + std::to_string(i) + "]";
        const ResponseBlock& b = data[i];
        if (shape == PsychometricShape::Weibull)
            requirePositive(name + " level", b.level, "(a Weibull's levels are > 0)");
        else
            requireFinite(name + " level", b.level);
        if (b.trials < 1)
            throwExpected(name + " trials", "an integer >= 1", std::to_string(b.trials));
        if (b.correct < 0 || b.correct > b.trials)
            throwExpected(name + " correct", "an integer in [0, " + std::to_string(b.trials) + "]",
                          std::to_string(b.correct));
    }
    const auto distinct = std::find_if(data.begin(), data.end(), [&](const ResponseBlock& b) {
        return b.level != data.front().level;
    });
    if (distinct == data.end())
        throwExpected("data levels", "at least two distinct levels",
                      "every block at " + formatValue(data.front().level));
}

PsychometricFit fitPsychometric(std::span<const ResponseBlock> data, const FitOptions& options) {
    validateFitOptions(options);
    validateBlocks(data, options.shape);
    PsychometricFit fit = detail::fitProblem(detail::problemOf(data, options), options, nullptr);
    fit.deviance = deviance(data, fit.function);
    return fit;
}

double logLikelihood(std::span<const ResponseBlock> data, const PsychometricFunction& f) {
    double ll = 0;
    for (const ResponseBlock& b : data) {
        double p, pc;
        detail::psiAndComplement(f, b.level, p, pc);
        if (b.correct > 0) ll += b.correct * std::log(p);
        if (b.trials > b.correct) ll += (b.trials - b.correct) * std::log(pc);
    }
    return ll;
}

double deviance(std::span<const ResponseBlock> data, const PsychometricFunction& f) {
    double d = 0;
    for (const ResponseBlock& b : data) {
        double p, pc;
        detail::psiAndComplement(f, b.level, p, pc);
        const double n = b.trials, k = b.correct, miss = n - k;
        if (k > 0) d += k * std::log(k / (n * p));
        if (miss > 0) d += miss * std::log(miss / (n * pc));
    }
    return 2 * d;
}

}  // namespace palp::perception
