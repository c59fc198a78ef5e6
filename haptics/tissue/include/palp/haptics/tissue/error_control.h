#pragma once
/// @file
/// Error control of the asynchronous regions with an ErrorTable (docs/error_analysis.md,
/// "Lookup table and control"; thesis paper II, figure 3.3): at set-up, the cheapest primary
/// size and secondary rate whose predicted force error is within a budget (by default the
/// normal-pressure stiffness JND, 5.23 %) and whose primary fits the tick; at run time, the
/// input's strain amplitude and frequency estimated from the contact's displacement and the
/// error looked up for them.
///
/// What adapts when: the threaded regions (live sessions) cannot change their primary size or
/// secondary rate while running, so the setting is chosen once, at set-up, for the worst input
/// the table covers at the body's material; the run-time estimate (ErrorMonitor) then follows
/// the actual input and says when it passes the budget.

#include <functional>
#include <string>
#include <vector>

#include "palp/fem/fem_model.h"
#include "palp/haptics/tissue/error_table.h"

namespace palp::haptics {

class DeformableModel;

/// The regions' adaptivity the controller chooses (AsyncRegionsOptions' fields of that name).
struct RegionsSetting {
    int lod = 2;                 ///< secondary level of detail (kept as given: see chooser)
    int primaryNodes = 60;       ///< seed nodes of the primary region
    double secondaryRate = 100;  ///< secondary rate, Hz
};

/// What the primary costs a servo tick: its cells times the explicit substeps a tick takes.
struct PrimaryCost {
    int cells = 0;        ///< cells the primary integrates (AsyncRegions::primaryCellCount())
    double substeps = 0;  ///< explicit substeps per tick (the whole model's bound: an upper one)
    double elementSubsteps() const noexcept { return cells * substeps; }
};

/// The primary's cost with @p primaryNodes seeds around @p contactNode at level of detail
/// @p lod: the cells AsyncRegions would integrate (the seeds are the nodes nearest the contact
/// in graph distance over lattice edges between active nodes, ties by Euclidean distance; the
/// primary cells touch a seed, widened to whole coarse cells of lod^3 fine cells) times
/// fem::explicitSubstepsPerTick(model, safetyFactor, tickSeconds). O(seeds + cells), no
/// assembly. @throw palp::ValueError for a contact node that is not an active node, lod not 1,
/// 2 or 4, or primaryNodes < 1.
PrimaryCost primaryCost(const fem::FemModel& model, int contactNode, int lod, int primaryNodes,
                        double safetyFactor, double tickSeconds);

/// What the controller may choose from and what it must meet.
struct ErrorControlOptions {
    /// Largest predicted error, percent (> 0).
    double budgetPercent = kNormalPressureJndPercent;
    /// Largest primary cost a tick may take, element-substeps (the whole-mesh solver's budget:
    /// kWholeMeshElementSubsteps, ~0.75 ms of the 1 ms tick at ~94 ns an element-substep).
    double maxElementSubsteps = 8000;
    std::vector<int> primaryCandidates = {5, 10, 15, 20, 30, 40, 60};  ///< seed counts
    std::vector<double> rateCandidates = {25, 50, 100, 200, 500};      ///< Hz
    /// Input axes (strain, frequency) taken at their worst node instead of the given value:
    /// the input a live session will see is not known at set-up.
    bool worstInput = true;
};

/// What chooseRegionsSetting() chose.
struct ErrorControlChoice {
    RegionsSetting setting;
    ErrorEstimate predicted;   ///< the table's error for the setting (worst input when asked)
    PrimaryCost cost;          ///< the primary's cost for the setting
    bool meetsBudget = false;  ///< predicted.percent <= budgetPercent
    bool meetsTime = false;    ///< cost.elementSubsteps() <= maxElementSubsteps
    int candidates = 0;        ///< settings compared
    std::string reason;        ///< one line: what was chosen and why
};

/// The table's predicted error at @p conditions (material and input) with @p setting; with
/// @p worstInput, the largest over the table's nodes of its strain and frequency axes (the
/// multilinear interpolation's maximum over those axes lies on a node).
ErrorEstimate predictError(const ErrorTable& table, const ErrorPoint& conditions,
                           const RegionsSetting& setting, bool worstInput);

/// Chooses the primary size and secondary rate for a body at level of detail @p lod (the
/// layout's: the slide zone and the coarse space depend on it, so it is not the controller's
/// to change) under the material and input @p conditions: among the candidates whose primary
/// cost (@p cost, per seed count) is within maxElementSubsteps and whose predicted error is
/// within budgetPercent, the one with the fewest element-substeps, then the lowest secondary
/// rate (fewer secondary solves), then the smallest predicted error. When none meets the budget
/// within the time: the cheapest of those within 5 % of the smallest predicted error that fits the
/// time (meetsBudget false); when none fits the time: the cheapest (meetsTime false).
/// @throw palp::ValueError for a budget that is not a positive finite number, or no candidate.
ErrorControlChoice chooseRegionsSetting(const ErrorTable& table, const ErrorPoint& conditions,
                                        int lod, const std::function<PrimaryCost(int)>& cost,
                                        const ErrorControlOptions& options = {});

/// The material (E, nu, density, mass damping) and the regions' setting (lod, primary size,
/// secondary rate) of @p model as an ErrorPoint; strain and frequency NaN.
ErrorPoint errorConditions(const DeformableModel& model);

/// The error ErrorTable::builtIn() predicts for @p model's body on the regions at an input of
/// @p strain (contact displacement amplitude / the body's thickness along the press) and
/// @p frequencyHz; NaN for either: the worst over the table's nodes of that axis. A body on
/// the whole mesh has no regions' error: percent 0, in range.
ErrorEstimate estimateBodyError(const DeformableModel& model, double strain, double frequencyHz);

/// The run-time estimate: the input's strain amplitude and frequency from the contact's
/// displacement (one sample a tick), looked up in the table at the end of every window.
/// Over a window of W seconds with displacements d_k (m, along the press, from rest): strain
/// = max |d_k| / referenceLength (the sweep's amplitude / cube height), frequency =
/// sum |d_k - d_k-1| / (2 (max d - min d) W) (a raised cosine travels twice its amplitude a
/// period; a held press gives 0, which the table clamps to its lowest frequency).
/// @par Threading  One thread (the one that calls update()). @par Real-time  update() and the
/// accessors are noexcept, allocation-free and O(1) (a lookup of O(2^axes) at a window's end).
class ErrorMonitor {
  public:
    /// @p table must outlive the monitor; @p conditions holds the material and the setting
    /// (strain and frequency are overwritten); @p referenceLength m (> 0), @p windowSeconds and
    /// @p tickSeconds s (> 0). @throw palp::ValueError for a non-positive or non-finite length,
    /// window or tick.
    ErrorMonitor(const ErrorTable& table, const ErrorPoint& conditions, double referenceLength,
                 double windowSeconds, double tickSeconds, double budgetPercent);
    /// Adds one tick's contact displacement, m (NaN: no contact; the window's samples so far
    /// count, the next contact starts a new excursion).
    void update(double displacement) noexcept;
    /// The estimate of the last finished window with contact (NaN percent before one).
    const ErrorEstimate& current() const noexcept { return mCurrent; }
    /// The largest estimate so far, percent (NaN before one).
    double maxPercent() const noexcept { return mMax; }
    double strain() const noexcept { return mPoint[errorIndex(ErrorVar::strain)]; }
    double frequency() const noexcept { return mPoint[errorIndex(ErrorVar::frequency)]; }
    /// Windows with contact so far, and those whose estimate exceeded the budget.
    int windows() const noexcept { return mWindows; }
    int windowsOverBudget() const noexcept { return mOver; }
    double budgetPercent() const noexcept { return mBudget; }

  private:
    void finishWindow() noexcept;
    const ErrorTable* mTable;
    ErrorPoint mPoint;
    double mLength, mWindow, mBudget;
    int mWindowTicks, mTicks = 0, mContactTicks = 0;
    double mMaxAbs = 0, mLo = 0, mHi = 0, mTravel = 0, mLast = 0;
    bool mHaveLast = false;
    ErrorEstimate mCurrent;
    double mMax = std::numeric_limits<double>::quiet_NaN();
    int mWindows = 0, mOver = 0;
};

}  // namespace palp::haptics
