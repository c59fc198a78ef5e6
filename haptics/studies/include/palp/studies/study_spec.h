#pragma once
/// @file
/// A perception study as a file (JSON): the conditions (touch mode, transition profile, simulated
/// observer), the adaptive procedure (a transformed staircase or QUEST) and its stopping rule,
/// the psychometric fit of all trials, the seed. docs/studies.md documents the fields; every
/// field is checked on load and a refusal names the file and the field
/// (`study.json: conditions[1].touch: expected one of ..., found 'rub'`). Unknown fields are
/// refused too, so that a misspelt field never silently keeps its default.
///
/// Levels are the comparison's increment over the reference in percent (30 = the comparison is
/// 1.3 times as stiff).

#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "palp/haptics/rendering/coupling.h"
#include "palp/perception/observer.h"
#include "palp/perception/psychometric.h"
#include "palp/perception/quest.h"
#include "palp/perception/staircase.h"
#include "palp/studies/touch_modes.h"
#include "palp/volume/phantom.h"

namespace palp::haptics {

/// What the simulated observer compares.
enum class FeltQuantity {
    Stiffness,  ///< the mean stiffness rendered over the interval's contact ticks, N/m
    Force,      ///< the mean |force| sent over those ticks, N
};

/// A simulated observer of one condition.
struct StudyObserver {
    /// "weber": perception::WeberObserver on the felt quantity; "gradient":
    /// perception::GradientObserver on the stiffness profile along the path.
    std::string kind = "weber";
    FeltQuantity felt = FeltQuantity::Stiffness;
    perception::WeberObserverParams weber;
    perception::GradientObserverParams gradient;
};

/// One condition: how the hand touches and what it touches.
struct StudyCondition {
    std::string name;
    TouchMode touch = TouchMode::ContinuousPressure;
    /// The CL box's transition profile (the lateral sweep crosses it).
    volume::TransitionProfile profile = volume::TransitionProfile::Linear;
    /// The press depth below the surface, m (default: touchDefaults()).
    double depthM = 0;
    /// The hand's speed along the path, m/s (default: touchDefaults()).
    double speedMps = 0;
    /// The coupling that renders the phantom: AVC (the scene's default), VC (k_s everywhere: no
    /// field) or AVCEC (AVC with the energy terms).
    CouplingMode mode = CouplingMode::AVC;
    StudyObserver observer;
};

/// The adaptive procedure, per condition.
enum class StudyMethod { Staircase, Quest };

struct StudyProcedure {
    StudyMethod method = StudyMethod::Staircase;
    /// Staircase: levels in percent; 1-up-2-down with steps 8, 4, 2 % by default.
    perception::StaircaseParams staircase;
    /// The threshold from reversals: drop the first dropFirst, average the last useLast (0:
    /// all the rest).
    int dropFirst = 4;
    int useLast = 0;
    /// QUEST: intensities in log10(percent); maxTrials and maxIntervalWidth stop it.
    perception::QuestParams quest;
    /// Levels QUEST may ask for, percent (its next intensity is clamped into them).
    double minLevel = 0.5;
    double maxLevel = 100;
};

/// The psychometric fit of all trials of a condition (2AFC: gamma 0.5).
struct StudyFit {
    perception::PsychometricShape shape = perception::PsychometricShape::Weibull;
    double lambdaMax = 0.06;
    /// Bootstrap samples for the threshold's interval (0: no interval).
    int bootstrap = 200;
    double coverage = 0.95;
};

/// A whole study.
struct StudySpec {
    /// Identifies the study in its logs (letters, digits, '-', '_', '.').
    std::string id;
    std::uint64_t seed = 1;
    /// The reference's soft-tissue stiffness k_s, N/m (the coupling's base stiffness; the
    /// comparison's is k_s (1 + level / 100), and so is its maximum stiffness).
    double referenceStiffnessNpm = 100;
    /// The simulated hand's device (its force limit applies; its stiffness limit must hold the
    /// largest comparison, or the study is refused).
    std::string device = "3D Systems Touch X";
    /// Phantom voxel, m.
    double voxelM = 1e-3;
    /// The proxy's Coulomb friction (static = dynamic). 0 by default: with friction the proxy
    /// lags the hand in a sweep and the AVC rays, cast from proxy to probe, lean ahead of it and
    /// sample the field several millimetres in front of the finger (docs/studies.md).
    double friction = 0;
    std::vector<StudyCondition> conditions;
    StudyProcedure procedure;
    StudyFit fit;
    /// A digest of the file's content (FNV-1a of its canonical JSON, hex), written into every
    /// log so that a log is never resumed under another study.
    std::string digest;
    /// Where it was read from (for messages).
    std::string source;
};

/// Parses and checks a study from JSON text; @p source names it in messages.
/// @throw palp::ValueError naming @p source and the field.
StudySpec parseStudySpec(std::string_view json, const std::string& source);
/// Reads and checks a study file. @throw palp::IoError naming the file when it cannot be read;
/// palp::ValueError as parseStudySpec().
StudySpec loadStudySpec(const std::filesystem::path& path);

/// The target probability of the procedure (staircaseTarget() of the staircase, pThreshold of
/// QUEST): the psi level whose stimulus the study reports as the JND.
double procedureTarget(const StudyProcedure& procedure);

/// Row @p row of a balanced Latin square (Williams design) over @p n conditions: each condition
/// once per row, each in every position once over n rows, each ordered pair of neighbours once
/// (n even; for n odd the 2n rows that repeat each row reversed balance them). @p row is taken
/// modulo n (n even) or 2n (n odd).
std::vector<int> latinSquareRow(int n, int row);

}  // namespace palp::haptics
