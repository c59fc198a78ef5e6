#pragma once
/// @file
/// Running a two-interval forced-choice (2IFC) stiffness study: the trial sequence, the
/// responders (a simulated observer that palpates, a person answering through a callback), the
/// log, a resume that replays a log, and the analysis of a log (docs/studies.md).
///
/// Each trial shows a reference (the condition's object at k_s) and a comparison (k_s (1 +
/// level / 100)) in an order drawn from the study's seed; the responder names the interval that
/// felt stiffer; the condition's adaptive procedure (a staircase or QUEST) sets the next level.
/// Conditions run in blocks, in the order of the participant's row of a balanced Latin square.
/// Every draw depends only on (seed, participant, condition, trial), never on a running
/// generator, so a study resumed from its log continues with exactly the trials an
/// uninterrupted run would have given.
/// @par Threading
/// One thread per runner.

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "palp/perception/psychometric_fit.h"
#include "palp/studies/study_log.h"
#include "palp/studies/study_spec.h"

namespace palp::haptics {

class StudyStimuli;

/// The next trial to present.
struct TrialPlan {
    int trial = 0;
    int condition = 0;
    int conditionTrial = 0;
    double levelPercent = 0;
    int comparisonInterval = 1;  ///< 1 or 2
    /// The simulated observer's seed for this trial.
    std::uint64_t observerSeed = 0;
};

/// A responder's answer.
struct TrialAnswer {
    int response = 1;  ///< the interval that felt stiffer, 1 or 2; 0 stops the study (resumable)
    double responseSeconds = 0;
    double felt1 = std::numeric_limits<double>::quiet_NaN();
    double felt2 = std::numeric_limits<double>::quiet_NaN();
    std::string trace;
};

/// Answers a trial (the C API / Python wrap a viewer's buttons in one).
using StudyResponder = std::function<TrialAnswer(const StudySpec&, const TrialPlan&)>;

/// The trial sequence and the procedures' state.
class StudyRunner {
  public:
    /// @throw palp::ValueError for a negative participant.
    StudyRunner(StudySpec spec, int participant);
    ~StudyRunner();

    bool finished() const;
    /// The trial to present next. @throw palp::ValueError once finished().
    TrialPlan next() const;
    /// Records @p answer to @p plan (which must be next()) and moves the procedure.
    /// @return the record to log.
    TrialRecord record(const TrialPlan& plan, const TrialAnswer& answer);
    /// Replays a log's trials (resume): each must be the trial next() plans (condition, level
    /// to 1e-9, interval order), or palp::ValueError names the log's row and field.
    void replay(std::span<const TrialRecord> trials, const std::string& logName);

    /// The conditions in the order this participant runs them.
    const std::vector<int>& order() const { return mOrder; }
    int participant() const { return mParticipant; }
    int trialsDone() const { return mTrials; }
    const StudySpec& spec() const { return mSpec; }
    StudyLogHeader logHeader() const;

  private:
    struct Procedure;
    int current() const;

    StudySpec mSpec;
    int mParticipant = 0;
    std::vector<int> mOrder;
    std::vector<std::unique_ptr<Procedure>> mProcedures;
    int mTrials = 0;
};

/// Runs trials until the study is finished, @p maxTrials more have run (< 0: no limit) or the
/// responder answers 0; each is appended to @p log before the next. @return trials run.
int runStudyTrials(StudyRunner& runner, const StudyResponder& responder, StudyLog& log,
                   int maxTrials = -1);

/// A simulated participant: palpates both intervals (StudyStimuli, cached per level) and
/// answers with the condition's observer seeded by the trial's observerSeed. When
/// @p traceDir is set, each interval's session is written there as a CSV trace.
StudyResponder simulatedResponder(std::shared_ptr<StudyStimuli> stimuli, std::string traceDir = {});

/// One condition's results from its trials.
struct ConditionResult {
    std::string name;
    int trials = 0;
    int reversals = 0;
    /// The procedure's threshold, percent: the staircase's mean of the reversals (after
    /// dropping drop_first; NaN with too few), or QUEST's posterior mean (10^mean).
    double procedureThreshold = std::numeric_limits<double>::quiet_NaN();
    /// The trials pooled per level.
    std::vector<perception::ResponseBlock> blocks;
    /// The maximum-likelihood fit of all trials (absent with fewer than two levels).
    std::optional<perception::PsychometricFit> fit;
    /// The level at psi = target on the fit, percent, and its bootstrap interval.
    double fitThreshold = std::numeric_limits<double>::quiet_NaN();
    perception::Interval fitInterval{std::numeric_limits<double>::quiet_NaN(),
                                     std::numeric_limits<double>::quiet_NaN()};
    /// Every bootstrap refit (for the plot's band).
    std::vector<perception::PsychometricFit> bootstrapFits;
    double target = 0.7071;
    std::string note;  ///< why a figure is missing
};

/// The results of @p trials (a log's rows, in order) under @p spec: the procedure's threshold
/// replayed from the rows, and a psychometric fit of all of them with its bootstrap.
std::vector<ConditionResult> analyseStudy(const StudySpec& spec,
                                          std::span<const TrialRecord> trials);

}  // namespace palp::haptics
