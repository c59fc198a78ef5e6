#include "palp/fem/explicit_solver.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <string>

#include "palp/base/bounds.h"
#include "palp/base/error.h"
#include "palp/base/parallel.h"
#include "palp/base/validate.h"

namespace palp::fem {

namespace {

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && \
    !defined(__SANITIZE_THREAD__) && !defined(__SANITIZE_ADDRESS__)
#define PALP_FEM_CLONES \
    __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define PALP_FEM_CLONES
#endif

/// Central-difference update of every dof of [begin, end), in place over u(n-1):
/// `up = (dt2 (f - k) + twoM u - prevCoef up) invDen`. Dense (no index list) so it vectorises.
PALP_FEM_CLONES
void centralDifference(std::size_t begin, std::size_t end, double dt2, const double* __restrict f,
                       const double* __restrict k, const double* __restrict u,
                       const double* __restrict twoM, const double* __restrict prevCoef,
                       const double* __restrict invDen, double* __restrict up) noexcept {
    for (std::size_t d = begin; d < end; ++d) {
        up[d] = (dt2 * (f[d] - k[d]) + twoM[d] * u[d] - prevCoef[d] * up[d]) * invDen[d];
    }
}

/// True when all @p n values are finite: no exponent field is all ones. Integer OR-reduction,
/// so it vectorises without reassociating floating-point sums.
PALP_FEM_CLONES
bool allFinite(const double* __restrict x, std::size_t n) noexcept {
    constexpr std::uint64_t kExponent = 0x7ff0000000000000ull;
    std::uint64_t bad = 0;
    for (std::size_t d = 0; d < n; ++d) {
        const std::uint64_t bits = std::bit_cast<std::uint64_t>(x[d]);
        bad |= static_cast<std::uint64_t>((bits & kExponent) == kExponent);
    }
    return bad == 0;
}

/// @p x rounded down (up) to three significant digits, so a suggested limit printed with %g is
/// one the check accepts.
double roundDown3(double x) {
    const double p = std::pow(10.0, std::floor(std::log10(x)) - 2);
    return std::floor(x / p) * p;
}
double roundUp3(double x) {
    const double p = std::pow(10.0, std::floor(std::log10(x)) - 2);
    return std::ceil(x / p) * p;
}

}  // namespace

double explicitSubstepsPerTick(const FemModel& model, double safetyFactor, double tickSeconds) {
    const double dt = safetyFactor * model.criticalTimeStep();
    if (!(dt > 0.0)) return std::numeric_limits<double>::infinity();
    return std::max(1.0, std::ceil(tickSeconds / dt));
}

void requireExplicitSubsteps(const FemModel& model, double safetyFactor, int maxSubsteps,
                             double tickSeconds, std::string_view maxSubstepsName) {
    const double need = explicitSubstepsPerTick(model, safetyFactor, tickSeconds);
    if (need <= static_cast<double>(maxSubsteps)) return;
    const ElasticMaterial& m = model.material();
    const HexMesh& mesh = model.mesh();
    double eMax = 0.0;
    for (int c = 0; c < mesh.cellCount(); ++c) {
        if (mesh.cellActive(c))
            eMax = std::max(eMax, mesh.cellYoungs()[static_cast<std::size_t>(c)]);
    }
    const double w = model.maxFrequencyBound(), h = mesh.edge();
    const double alpha = m.dampingAlpha, beta = m.dampingBeta;
    // The substep dt = safety * 2 / (w (sqrt(1 + xi^2) + xi)), xi = (alpha / w + beta w) / 2,
    // reaches tick / maxSubsteps exactly when w (sqrt(1 + xi^2) + xi) <= r with
    // r = 2 safety maxSubsteps / tick; squaring (w xi = (alpha + beta w^2) / 2 <= r / 2):
    // w^2 (1 + r beta) <= r (r - alpha). Solved for w (the stiffness) or for beta below.
    const double r = 2.0 * safetyFactor * maxSubsteps / tickSeconds;
    const std::string found = " (" + formatValue(need) + " substeps per tick)";
    const std::string budget = "the most that " + std::to_string(maxSubsteps) +
                               " explicit substeps of " + formatValue(safetyFactor) +
                               " x the critical step can step stably in the " +
                               formatValue(tickSeconds) + " s tick";
    const std::string raise = "; or raise " + std::string(maxSubstepsName) + " (at most " +
                              std::to_string(kMaxExplicitSubsteps) + ") or shorten the tick";
    if (alpha >= r) {
        throwExpected("material dampingAlpha",
                      "less than " + formatValue(roundDown3(r)) + " 1/s (" + budget + raise + ")",
                      formatValue(alpha) + " 1/s" + found);
    }
    if (!(w * w <= r * (r - alpha))) {
        // Too stiff even without stiffness-proportional damping: the modulus (or the cells).
        const double wFit2 = r * (r - alpha) / (1.0 + r * beta);
        // Coarser cells fit the modulus (w ~ 1 / h): worth saying while they are cells palp
        // accepts (bounds::kSpacing).
        const double hFit = roundUp3(h * w / std::sqrt(wFit2));
        const std::string cells = hFit <= bounds::kSpacing.max
                                      ? "; or cells of at least " + formatValue(hFit * 1e3) + " mm"
                                      : "";
        throwExpected("material youngsModulus",
                      "at most " + formatValue(roundDown3(eMax * wFit2 / (w * w))) +
                          " Pa for the stiffest cell (" + budget + " with " + formatValue(h * 1e3) +
                          " mm cells, density " + formatValue(m.density) +
                          " kg/m^3, poissonRatio " + formatValue(m.poissonRatio) +
                          ", dampingBeta " + formatValue(beta) + " s" + cells + raise + ")",
                      formatValue(eMax) + " Pa" + found);
    }
    throwExpected("material dampingBeta",
                  "at most " + formatValue(roundDown3((r * (r - alpha) - w * w) / (r * w * w))) +
                      " s (" + budget + " at Young's modulus " + formatValue(eMax) + " Pa with " +
                      formatValue(h * 1e3) + " mm cells" + raise + ")",
                  formatValue(beta) + " s" + found);
}

ExplicitSolver::ExplicitSolver(const FemModel& model, const Constraints& constraints,
                               const ExplicitOptions& options)
    : mModel(model), mOptions(options) {
    const int n = model.dofCount();
    if (constraints.dofCount() != n) {
        throwExpected("explicit solver constraints", std::to_string(n) + " dofs",
                      std::to_string(constraints.dofCount()));
    }
    if (!(options.safetyFactor > 0.0 && options.safetyFactor <= 1.0)) {
        throwExpected("explicit solver safety factor", "a value in (0, 1]",
                      formatValue(options.safetyFactor));
    }
    if (options.maxSubsteps < 1 || options.maxSubsteps > kMaxExplicitSubsteps) {
        throwExpected("explicit solver maxSubsteps",
                      "a count in [1, " + std::to_string(kMaxExplicitSubsteps) + "]",
                      std::to_string(options.maxSubsteps));
    }
    if (model.material().law == MaterialLaw::neoHookean) {
        mTled = std::make_unique<TledForces>(model, options.tled);
        mStableDt = options.safetyFactor * mTled->criticalTimeStep(mTled->restFrequencyBound());
    } else {
        mStableDt = options.safetyFactor * model.criticalTimeStep();
    }
    if (!(mStableDt > 0.0) || !std::isfinite(mStableDt)) {
        throwExpected("explicit solver critical time step", "a finite step > 0 s",
                      formatValue(mStableDt) + " s");
    }
    const Eigen::VectorXd& mass = model.lumpedMass();
    for (int d = 0; d < n; ++d) {
        if (constraints.isFixed(d) || mass[d] <= 0.0) {
            mConstrained.push_back(d);
        } else {
            mFree.push_back(d);
        }
    }
    mU = Eigen::VectorXd::Zero(n);
    for (int d : mConstrained) mU[d] = constraints.isFixed(d) ? constraints.values()[d] : 0.0;
    mUPrev = mU;
    mForce = Eigen::VectorXd::Zero(n);
    mInternal = Eigen::VectorXd::Zero(n);
    mWork = Eigen::VectorXd::Zero(n);
    mTarget = mU;
    mStart = mU;
    mInvDen = Eigen::VectorXd::Zero(n);
    mPrevCoef = Eigen::VectorXd::Zero(n);
    mTwoMass = Eigen::VectorXd::Zero(n);
    for (int d : mFree) mTwoMass[d] = 2.0 * model.lumpedMass()[d];
    mEnergyWork = Eigen::VectorXd::Zero(n);
    mEnergyForce = Eigen::VectorXd::Zero(n);
}

void ExplicitSolver::setDisplacement(const Eigen::VectorXd& u) {
    if (u.size() != mU.size() || !u.allFinite()) {
        std::ostringstream s;
        s << "explicit solver displacement: expected " << mU.size() << " finite values, found "
          << u.size() << (u.allFinite() ? "" : " with non-finite entries");
        throw ValueError(s.str());
    }
    for (int d : mFree) mU[d] = u[d];
    mUPrev = mU;
}

void ExplicitSolver::setCoefficients(double dt) noexcept {
    const Eigen::VectorXd& mass = mModel.lumpedMass();
    const double alpha = mModel.material().dampingAlpha;
    for (int d : mFree) {
        const double m = mass[d];
        const double c = alpha * m;
        mInvDen[d] = 1.0 / (m + 0.5 * dt * c);
        mPrevCoef[d] = m - 0.5 * dt * c;
    }
}

Eigen::Vector3d ExplicitSolver::springPoint(const CouplingSpring& spring) const noexcept {
    Eigen::Vector3d a = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < spring.nodes.size(); ++i)
        a += spring.weights[i] * mU.segment<3>(3 * static_cast<Eigen::Index>(spring.nodes[i]));
    return a;
}

template <bool kParallel>
StepResult ExplicitSolver::advance(double dtSeconds, const CouplingSpring* spring,
                                   SpringResult* out) noexcept {
    StepResult result;
    if (!(dtSeconds > 0.0) || !std::isfinite(dtSeconds)) {
        result.flags |= kStepBadTimeStep;
        return result;
    }
    if (spring && !spring->active()) spring = nullptr;
    // The spring raises the highest frequency: the substep shrinks with it.
    double stableDt = mStableDt;
    if (mTled) {
        // The current state's stiffness sets the substep of this step.
        const double w = mTled->frequencyBound(mU.data());
        mStableDt = mOptions.safetyFactor * mTled->criticalTimeStep(w);
        stableDt = spring ? mOptions.safetyFactor *
                                mTled->criticalTimeStep(w, springFrequencySquared(mModel, *spring))
                          : mStableDt;
    } else if (spring) {
        stableDt = mOptions.safetyFactor *
                   criticalTimeStepWith(mModel, springFrequencySquared(mModel, *spring));
    }
    double want = std::ceil(dtSeconds / stableDt);
    if (!(want >= 1.0)) want = std::numeric_limits<double>::infinity();  // NaN: a massless node
    int substeps = want > static_cast<double>(mOptions.maxSubsteps) ? mOptions.maxSubsteps
                                                                    : static_cast<int>(want);
    double dt = dtSeconds / substeps;
    if (want > static_cast<double>(mOptions.maxSubsteps)) {
        result.flags |= kStepSubstepLimit;
        dt = std::isfinite(stableDt) && stableDt > 0.0 ? std::min(stableDt, dt) : dt;
    }
    const std::size_t dofCount = static_cast<std::size_t>(mU.size());
    if (!allFinite(mForce.data(), dofCount)) {
        for (int d = 0; d < mForce.size(); ++d) {
            if (!std::isfinite(mForce[d])) {
                mForce[d] = 0.0;
                result.flags |= kStepBadForce;
            }
        }
    }
    if (dt != mDt) {
        // Keep the half-step velocity (u - uPrev) / dt when the substep changes.
        if (mDt > 0.0) {
            const double scale = dt / mDt;
            for (int d : mFree) mUPrev[d] = mU[d] - (mU[d] - mUPrev[d]) * scale;
        }
        setCoefficients(dt);
        mDt = dt;
    }
    for (int d : mConstrained) mStart[d] = mU[d];
    Eigen::Vector3d springImpulse = Eigen::Vector3d::Zero();
    Eigen::Vector3d springLast = Eigen::Vector3d::Zero();
    bool springClamped = false;
    const double beta = mModel.material().dampingBeta;
    const double dt2 = dt * dt;
    const int dofs = static_cast<int>(mU.size());
    for (int s = 0; s < substeps; ++s) {
        const double* operand = mU.data();
        if (beta > 0.0) {
            const double b = beta / dt;
            for (int d = 0; d < dofs; ++d) mWork[d] = mU[d] + b * (mU[d] - mUPrev[d]);
            operand = mWork.data();
        }
        if (mTled) {
            if constexpr (kParallel) {
                mTled->internalForcesParallel(operand, mInternal.data());
            } else {
                mInternal.setZero();
                mTled->addInternalForces(operand, mInternal.data());
            }
        } else if constexpr (kParallel) {
            mModel.stiffnessTimesParallel(operand, mInternal.data());
        } else {
            mInternal.setZero();
            mModel.addStiffnessTimes(operand, mInternal.data());
        }
        // The spring's force from the current displacement (u(n), before the update), and
        // a(u(n-1)) for the damper (the update overwrites u(n-1)).
        Eigen::Vector3d springF = Eigen::Vector3d::Zero();
        Eigen::Vector3d aPrev = Eigen::Vector3d::Zero();
        if (spring) {
            for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                aPrev += spring->weights[i] *
                         mUPrev.segment<3>(3 * static_cast<Eigen::Index>(spring->nodes[i]));
            }
            // The target moves with the probe over the step: k (c + v t - a).
            const double tIn = static_cast<double>(s) * dt;
            springF = springForce(*spring, springPoint(*spring) - tIn * spring->targetVelocity);
            if (springF.squaredNorm() >= spring->maxForce * spring->maxForce * (1 - 1e-12))
                springClamped = true;
            springImpulse += dt * springF;
            springLast = springF;
        }
        // The new displacement overwrites u(n-1), then the two buffers swap (no allocation).
        auto update = [&](std::size_t begin, std::size_t end) {
            centralDifference(begin, end, dt2, mForce.data(), mInternal.data(), mU.data(),
                              mTwoMass.data(), mPrevCoef.data(), mInvDen.data(), mUPrev.data());
        };
        if constexpr (kParallel) {
            parallelFor(
                tbb::blocked_range<std::size_t>(0, dofCount, 4096),
                [&](const tbb::blocked_range<std::size_t>& r) { update(r.begin(), r.end()); });
        } else {
            update(0, dofCount);
        }
        if (spring) {
            // The update is linear in the load: the spring's share w_i F enters the new
            // displacement of its nodes as dt^2 w_i F / (m + dt/2 c) (0 on constrained dofs,
            // which are overwritten below), so externalForce() is never touched.
            for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                const auto d = 3 * static_cast<Eigen::Index>(spring->nodes[i]);
                for (int c = 0; c < 3; ++c)
                    mUPrev[d + c] += dt2 * spring->weights[i] * springF[c] * mInvDen[d + c];
            }
            if (spring->damping > 0.0) {
                // (D + beta w w^T) u+ = r + beta w (w^T u-) with D = M + dt/2 alpha M and
                // beta = dt b / 2, per direction; with u^ = D^-1 r (done above) Sherman-Morrison
                // gives u+ = u^ - beta g (w^T u^ - w^T u-) / (1 + beta gamma), g = D^-1 w,
                // gamma = w^T g. Free dofs only (invDen is 0 on constrained ones).
                const double bt = 0.5 * dt * spring->damping;
                Eigen::Vector3d aHat = Eigen::Vector3d::Zero(), gamma = Eigen::Vector3d::Zero();
                for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                    const auto d = 3 * static_cast<Eigen::Index>(spring->nodes[i]);
                    const double w = spring->weights[i];
                    aHat += w * mUPrev.segment<3>(d);
                    gamma += w * w * mInvDen.segment<3>(d);
                }
                for (int c = 0; c < 3; ++c) {
                    const double scale = bt * (aHat[c] - aPrev[c]) / (1.0 + bt * gamma[c]);
                    for (std::size_t i = 0; i < spring->nodes.size(); ++i) {
                        const auto d = 3 * static_cast<Eigen::Index>(spring->nodes[i]) + c;
                        mUPrev[d] -= scale * spring->weights[i] * mInvDen[d];
                    }
                }
                // The damper is the tissue's own (to ground, like its mass damping): it is not
                // part of the contact force the spring reports; the hand feels it through the
                // spring, as the surface it brakes lags the probe.
            }
        }
        const double t = static_cast<double>(s + 1) / substeps;
        for (int d : mConstrained) mUPrev[d] = mStart[d] + t * (mTarget[d] - mStart[d]);
        mU.swap(mUPrev);
        mTime += dt;
        result.advancedSeconds += dt;
        ++result.substeps;
    }
    // With one substep u(n-1) is the u(n) that the previous call (or setDisplacement) checked.
    if (!allFinite(mU.data(), dofCount) || (substeps > 1 && !allFinite(mUPrev.data(), dofCount))) {
        for (int d : mFree) {
            mU[d] = 0.0;
            mUPrev[d] = 0.0;
        }
        mInternal.setZero();
        result.flags |= kStepDiverged;
    }
    if (out) {
        out->meanForce = result.advancedSeconds > 0.0 ? (springImpulse / result.advancedSeconds)
                                                      : Eigen::Vector3d::Zero().eval();
        out->endForce = springLast;
        out->endPoint = spring ? springPoint(*spring) : Eigen::Vector3d::Zero().eval();
        out->clamped = springClamped;
    }
    return result;
}

StepResult ExplicitSolver::step(double dtSeconds) noexcept {
    return advance<false>(dtSeconds, nullptr, nullptr);
}

StepResult ExplicitSolver::step(double dtSeconds, const CouplingSpring& spring,
                                SpringResult* out) noexcept {
    return advance<false>(dtSeconds, &spring, out);
}

StepResult ExplicitSolver::stepParallel(double dtSeconds) {
    return advance<true>(dtSeconds, nullptr, nullptr);
}

Eigen::Vector3d ExplicitSolver::reactionSum(const std::vector<int>& nodes) const {
    Eigen::Vector3d r = Eigen::Vector3d::Zero();
    for (int n : nodes) {
        for (int c = 0; c < 3; ++c) r[c] += reaction(3 * n + c);
    }
    return r;
}

double ExplicitSolver::kineticEnergy() const {
    if (mDt <= 0.0) return 0.0;
    double e = 0.0;
    const Eigen::VectorXd& mass = mModel.lumpedMass();
    for (int d : mFree) {
        const double v = (mU[d] - mUPrev[d]) / mDt;
        e += mass[d] * v * v;
    }
    return 0.5 * e;
}

double ExplicitSolver::strainEnergy() const noexcept {
    mEnergyWork = 0.5 * (mU + mUPrev);
    if (mTled) return mTled->strainEnergy(mEnergyWork.data());
    mEnergyForce.setZero();
    mModel.addStiffnessTimes(mEnergyWork.data(), mEnergyForce.data());
    return 0.5 * mEnergyWork.dot(mEnergyForce);
}

}  // namespace palp::fem
