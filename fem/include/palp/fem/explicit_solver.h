#pragma once
/// @file
/// Explicit central-difference time integration with lumped mass and Rayleigh damping,
/// automatic substepping below the stable step, a real-time single-thread variant and a TBB one.

#include <Eigen/Core>
#include <memory>
#include <string_view>
#include <vector>

#include "palp/fem/constraints.h"
#include "palp/fem/coupling_spring.h"
#include "palp/fem/fem_model.h"
#include "palp/fem/tled.h"

namespace palp::fem {

/// Flags a step may raise; a step never throws and never leaves NaN in the state.
enum StepFlag : unsigned {
    kStepOk = 0,
    kStepSubstepLimit = 1u << 0,  ///< needed more than maxSubsteps: advanced less time than asked
    kStepBadForce = 1u << 1,      ///< non-finite external force entries were zeroed
    kStepDiverged = 1u << 2,      ///< state became non-finite and was reset to the constraints
    kStepBadTimeStep = 1u << 3,   ///< requested step was not finite and > 0: nothing done
};

/// What one call to step() did.
struct StepResult {
    int substeps = 0;              ///< central-difference steps taken
    double advancedSeconds = 0.0;  ///< simulated time advanced, seconds
    unsigned flags = kStepOk;      ///< StepFlag bits
};

/// The most substeps per step() any explicit integrator accepts as its bound (maxSubsteps): with
/// it, the work of one step is bounded whatever the inputs.
inline constexpr int kMaxExplicitSubsteps = 65536;

/// Options of ExplicitSolver.
struct ExplicitOptions {
    double safetyFactor = 0.9;  ///< substep = safetyFactor * model.criticalTimeStep(), in (0, 1]
    /// Bound on substeps per step() call (keeps a tick bounded), in [1, kMaxExplicitSubsteps].
    int maxSubsteps = 4096;
    /// The TLED element of a neo-Hookean model (material law MaterialLaw::neoHookean); unused
    /// for a linear one.
    TledOptions tled;
};

/// Central-difference substeps that one step of @p tickSeconds takes on @p model with substeps
/// of @p safetyFactor times model.criticalTimeStep(): ceil(tick / (safety * critical)), as a
/// double (it may exceed any int; +inf for a model without a finite frequency bound).
double explicitSubstepsPerTick(const FemModel& model, double safetyFactor, double tickSeconds);

/// Set-up check of an explicit integrator stepped every @p tickSeconds with at most
/// @p maxSubsteps substeps of @p safetyFactor times the critical step: a model that needs more
/// would either run unstable (a capped substep above the critical one) or advance less time
/// than asked, tick after tick. Throws palp::ValueError naming what makes it too stiff for the
/// tick and what would fit:
/// * the stiffness (the stiffest cell's Young's modulus with the cell size, density and
///   Poisson's ratio; it alone needs more): `material youngsModulus: expected at most <E> Pa ...
///   (or cells of at least <h> mm), found <E> Pa (<n> substeps per tick)`;
/// * else the stiffness-proportional damping: `material dampingBeta: expected at most <b> s
///   ...`; or the mass-proportional damping when it alone needs more (`material dampingAlpha`).
/// @p maxSubstepsName is the caller's name of the bound ("deformable solver.maxSubsteps"), shown
/// as the other way out.
/// @throw palp::ValueError
void requireExplicitSubsteps(const FemModel& model, double safetyFactor, int maxSubsteps,
                             double tickSeconds, std::string_view maxSubstepsName);

/// Central difference `u(n+1) = [dt^2 (f - K u~) + 2 M u(n) - (M - dt/2 C_M) u(n-1)] / (M + dt/2
/// C_M)` with `C_M = alpha M` diagonal and the stiffness-proportional damping folded into the
/// internal force as `K u~`, `u~ = u(n) + beta (u(n) - u(n-1)) / dt` (velocity lagged half a step).
/// Constrained dofs follow their prescribed values, interpolated linearly across the substeps of
/// one step() call.
///
/// With a neo-Hookean material (MaterialLaw::neoHookean) `K u~` is the TLED internal force
/// f_int(u~) (palp/fem/tled.h, options.tled), and each step() chooses its substep from the
/// current state (TledForces::frequencyBound of u(n)): compression stiffens the tissue and
/// shortens the substep; more than maxSubsteps is capped and flagged as for a linear model.
///
/// @par Threading  One thread drives a solver; the model must outlive it and is only read.
class ExplicitSolver {
  public:
    /// Allocates all state. @throw palp::ValueError when @p constraints does not match the model
    /// or options are out of range. The step a caller will use is not known here: set-up code
    /// that knows its tick checks it with requireExplicitSubsteps().
    ExplicitSolver(const FemModel& model, const Constraints& constraints,
                   const ExplicitOptions& options = {});

    /// Largest substep used, seconds: safetyFactor * model.criticalTimeStep(); for a
    /// neo-Hookean model that of the state at the last step() (at construction: the rest
    /// state's, safetyFactor * TledForces::criticalTimeStep(restFrequencyBound())).
    double stableTimeStep() const { return mStableDt; }

    /// Advances by @p dtSeconds, split into ceil(dt / stableTimeStep()) equal substeps. When that
    /// is more than maxSubsteps it takes maxSubsteps substeps of stableTimeStep() (stable, but
    /// less time than asked) and flags kStepSubstepLimit.
    /// @par Real-time  noexcept, allocation-free, lock-free, at most maxSubsteps substeps.
    StepResult step(double dtSeconds) noexcept;
    /// step() with a coupling @p spring (coupling_spring.h) evaluated at every substep from the
    /// current displacement and added to the external force of that substep (externalForce() is
    /// left unchanged). The substep is at most safetyFactor times the critical step raised by the
    /// spring (criticalTimeStepWith(springFrequencySquared)), so any stiffness is stable while
    /// maxSubsteps suffices (else kStepSubstepLimit, with substeps of that step). The spring's
    /// mean and last force and its end point go to @p out when given. Spring nodes must be free.
    /// @par Real-time  noexcept, allocation-free, O(#spring nodes) more per substep.
    StepResult step(double dtSeconds, const CouplingSpring& spring,
                    SpringResult* out = nullptr) noexcept;
    /// Same as step() with the element loop and vector updates on TBB worker threads.
    StepResult stepParallel(double dtSeconds);

    /// External nodal force per dof, newtons (#dofs), applied until changed.
    Eigen::VectorXd& externalForce() { return mForce; }
    /// Sets the displacement that constrained dof @p dof reaches at the end of the next step()
    /// (it must have been constrained at construction). @par Real-time
    void setPrescribed(int dof, double valueMetres) noexcept { mTarget[dof] = valueMetres; }

    /// Sets the state: displacement @p u (metres) at rest.
    void setDisplacement(const Eigen::VectorXd& u);

    /// Displacement at the current time, metres (#dofs).
    const Eigen::VectorXd& displacement() const { return mU; }
    /// Internal force K u~ (neo-Hookean: f_int(u~)) of the last substep, newtons (#dofs).
    const Eigen::VectorXd& internalForce() const { return mInternal; }
    /// Reaction at constrained dof @p dof, newtons: internal minus external force of the last
    /// substep (inertia of the constrained node itself is not included).
    double reaction(int dof) const { return mInternal[dof] - mForce[dof]; }
    /// Sum of reactions over the x, y, z dofs of @p nodes, newtons.
    Eigen::Vector3d reactionSum(const std::vector<int>& nodes) const;

    /// Kinetic energy `v^T M v / 2` with the half-step velocity v(n-1/2), joules.
    double kineticEnergy() const;
    /// Strain energy at the same instant as kineticEnergy(): `w^T K w / 2`,
    /// w = (u(n) + u(n-1)) / 2, joules (neo-Hookean: TledForces::strainEnergy(w)).
    /// @par Real-time
    double strainEnergy() const noexcept;
    /// Simulated time since construction, seconds.
    double time() const { return mTime; }
    /// Substep length of the last step, seconds (0 before the first).
    double lastSubstep() const { return mDt; }
    /// The TLED element of a neo-Hookean model, nullptr for a linear one.
    const TledForces* tled() const { return mTled.get(); }

  private:
    template <bool kParallel>
    StepResult advance(double dtSeconds, const CouplingSpring* spring, SpringResult* out) noexcept;
    Eigen::Vector3d springPoint(const CouplingSpring& spring) const noexcept;
    void setCoefficients(double dt) noexcept;

    const FemModel& mModel;
    ExplicitOptions mOptions;
    std::unique_ptr<TledForces> mTled;  // neo-Hookean models only
    double mStableDt = 0.0;
    double mDt = 0.0;  // current substep, seconds
    double mTime = 0.0;
    std::vector<int> mConstrained;  // constrained dofs (including inactive nodes)
    std::vector<int> mFree;         // free dofs with mass
    Eigen::VectorXd mU, mUPrev, mForce, mInternal, mWork, mTarget, mStart;
    // 1/(m + dt/2 c), (m - dt/2 c), 2 m per dof; all three 0 on constrained dofs, so the update
    // runs densely over every dof (constrained ones come out 0 and are then overwritten).
    Eigen::VectorXd mInvDen, mPrevCoef, mTwoMass;
    mutable Eigen::VectorXd mEnergyWork, mEnergyForce;
};

}  // namespace palp::fem
