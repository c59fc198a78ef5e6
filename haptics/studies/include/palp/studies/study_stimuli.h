#pragma once
/// @file
/// The stimuli of a stiffness study: one interval is a palpation session on the stiffness
/// phantom (docs/algorithms.md section 9), the simulated hand running the condition's touch path
/// (touch_modes.h) with the coupling's stiffness scaled by (1 + level / 100); what it felt is
/// summarised for a simulated observer.
///
/// Sessions are deterministic (the phantom's noise is seeded, the hand scripted), so the felt
/// figures of a (condition, level) pair are computed once and cached; the observer's noise is
/// what varies from trial to trial.
/// @par Threading
/// One thread per StudyStimuli.

#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "palp/haptics/scene.h"
#include "palp/haptics/session.h"
#include "palp/studies/study_spec.h"

namespace palp::haptics {

/// What the simulated hand felt in one interval, over its contact ticks after the path first
/// pressed.
struct IntervalFelt {
    double meanStiffnessNpm = 0;  ///< mean rendered stiffness, N/m
    double meanForceN = 0;        ///< mean |force| sent, N
    double maxForceN = 0;
    int contactTicks = 0;
    /// The stiffness along the path's lateral axis (0.5 mm bins, increasing position, m and
    /// N/m), for a gradient observer; empty for a press.
    std::vector<double> profileM, profileNpm;
    /// The felt quantity @p q.
    double value(FeltQuantity q) const {
        return q == FeltQuantity::Force ? meanForceN : meanStiffnessNpm;
    }
};

/// Runs and caches the intervals of a study.
class StudyStimuli {
  public:
    /// @throw palp::ValueError for a condition whose touch path is refused.
    explicit StudyStimuli(StudySpec spec);
    ~StudyStimuli();

    /// What the hand felt touching condition @p condition's object at @p levelPercent (0: the
    /// reference); the session runs on the first call for that pair. With @p trace, the
    /// session always runs and its snapshots are returned there.
    /// @throw palp::ValueError for a condition out of range or a level outside [0, 1000].
    const IntervalFelt& feel(int condition, double levelPercent,
                             std::vector<Snapshot>* trace = nullptr);

    /// The coupling an interval of condition @p condition at @p levelPercent renders with.
    CouplingParams coupling(int condition, double levelPercent) const;
    /// The session parameters of an interval: coupling(), the study's friction, 1 kHz; servo,
    /// workspace and device fields at their defaults for the host to set.
    SessionParams sessionParams(int condition, double levelPercent) const;
    /// The phantom condition @p condition is touched on (built on first use, then shared).
    /// @throw palp::ValueError for a condition out of range.
    std::shared_ptr<const Scene> sceneFor(int condition);
    /// Sessions run so far.
    int sessionsRun() const { return mSessionsRun; }
    const StudySpec& spec() const { return mSpec; }

  private:
    std::shared_ptr<const Scene> scene(volume::TransitionProfile profile);
    IntervalFelt run(int condition, double levelPercent, std::vector<Snapshot>* trace);

    StudySpec mSpec;
    std::map<int, std::shared_ptr<const Scene>> mScenes;
    std::map<std::pair<int, double>, IntervalFelt> mFelt;
    int mSessionsRun = 0;
};

}  // namespace palp::haptics
