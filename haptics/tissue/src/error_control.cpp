// Error control of the asynchronous regions: the primary's cost, the set-up choice and the
// run-time estimate (error_control.h).
#include "palp/haptics/tissue/error_control.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "palp/base/error.h"
#include "palp/fem/async_regions.h"
#include "palp/fem/explicit_solver.h"
#include "palp/haptics/tissue/deformable.h"

namespace palp::haptics {

namespace error_control_impl {

std::size_t sz(int i) { return static_cast<std::size_t>(i); }

std::string percent(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.2f %%", v);
    return buf;
}

}  // namespace error_control_impl

using namespace error_control_impl;

PrimaryCost primaryCost(const fem::FemModel& model, int contactNode, int lod, int primaryNodes,
                        double safetyFactor, double tickSeconds) {
    const fem::HexMesh& mesh = model.mesh();
    if (contactNode < 0 || contactNode >= mesh.nodeCount() || !mesh.nodeActive()[sz(contactNode)])
        throw ValueError("primaryCost: contact node " + std::to_string(contactNode) +
                         " is not an active node of the mesh");
    if (lod != 1 && lod != 2 && lod != 4)
        throw ValueError("primaryCost: lod: expected 1, 2 or 4, found " + std::to_string(lod));
    if (primaryNodes < 1)
        throw ValueError("primaryCost: primaryNodes: expected >= 1, found " +
                         std::to_string(primaryNodes));
    // The layouts' own primary (fem::primaryRegionCells), counted without building one.
    const std::vector<std::uint8_t> primary =
        fem::primaryRegionCells(mesh, {contactNode}, primaryNodes, lod);
    PrimaryCost cost;
    for (int c = 0; c < mesh.cellCount(); ++c)
        if (primary[sz(c)] && mesh.cellActive(c)) ++cost.cells;
    cost.substeps = fem::explicitSubstepsPerTick(model, safetyFactor, tickSeconds);
    return cost;
}

ErrorEstimate predictError(const ErrorTable& table, const ErrorPoint& conditions,
                           const RegionsSetting& setting, bool worstInput) {
    ErrorPoint x = conditions;
    x[errorIndex(ErrorVar::lod)] = setting.lod;
    x[errorIndex(ErrorVar::primary)] = setting.primaryNodes;
    x[errorIndex(ErrorVar::rate)] = setting.secondaryRate;
    if (!worstInput) return table.estimate(x);
    const ErrorTable::Axis* s = table.axis(ErrorVar::strain);
    const ErrorTable::Axis* f = table.axis(ErrorVar::frequency);
    const std::vector<double> one{std::numeric_limits<double>::quiet_NaN()};
    ErrorEstimate worst;
    worst.percent = -1;
    for (double sv : s ? s->values : one) {
        for (double fv : f ? f->values : one) {
            if (s) x[errorIndex(ErrorVar::strain)] = sv;
            if (f) x[errorIndex(ErrorVar::frequency)] = fv;
            const ErrorEstimate e = table.estimate(x);
            if (!(e.percent <= worst.percent)) worst = e;
        }
    }
    return worst;
}

ErrorControlChoice chooseRegionsSetting(const ErrorTable& table, const ErrorPoint& conditions,
                                        int lod, const std::function<PrimaryCost(int)>& cost,
                                        const ErrorControlOptions& o) {
    if (!(std::isfinite(o.budgetPercent) && o.budgetPercent > 0))
        throw ValueError("error budget: expected a positive percentage, found " +
                         std::to_string(o.budgetPercent));
    if (o.primaryCandidates.empty() || o.rateCandidates.empty())
        throw ValueError("error control: expected at least one primary size and one rate");
    std::vector<ErrorControlChoice> all;
    for (int n : o.primaryCandidates) {
        const PrimaryCost c = cost(n);
        for (double r : o.rateCandidates) {
            ErrorControlChoice e;
            e.setting = {lod, n, r};
            e.cost = c;
            e.predicted = predictError(table, conditions, e.setting, o.worstInput);
            e.meetsBudget = e.predicted.percent <= o.budgetPercent;
            e.meetsTime = c.elementSubsteps() <= o.maxElementSubsteps;
            all.push_back(e);
        }
    }
    // Fewest element-substeps (the servo tick), then the lowest rate (the secondary's
    // solves), then the smallest predicted error, then the candidates' order.
    auto cheaper = [](const ErrorControlChoice& a, const ErrorControlChoice& b) {
        if (a.cost.elementSubsteps() != b.cost.elementSubsteps())
            return a.cost.elementSubsteps() < b.cost.elementSubsteps();
        if (a.setting.secondaryRate != b.setting.secondaryRate)
            return a.setting.secondaryRate < b.setting.secondaryRate;
        return a.predicted.percent < b.predicted.percent;
    };
    const ErrorControlChoice* best = nullptr;
    for (const auto& e : all)
        if (e.meetsBudget && e.meetsTime && (!best || cheaper(e, *best))) best = &e;
    std::string why;
    if (best) {
        why = "the cheapest within the budget";
    } else {
        for (const auto& e : all)
            if (e.meetsTime && (!best || e.predicted.percent < best->predicted.percent)) best = &e;
        // Within 5 % of that error, the cheapest: a rate five times higher for a few hundredths
        // of a percent (the condensed coupling's rate barely matters) is not worth its solves.
        if (best) {
            const double near = 1.05 * best->predicted.percent;
            for (const auto& e : all)
                if (e.meetsTime && e.predicted.percent <= near && cheaper(e, *best)) best = &e;
        }
        why =
            "no setting meets the budget: the smallest predicted error within the tick (the "
            "cheapest within 5 % of it)";
        if (!best) {
            for (const auto& e : all)
                if (!best || cheaper(e, *best)) best = &e;
            why = "no setting fits the tick: the cheapest";
        }
    }
    ErrorControlChoice out = *best;
    out.candidates = static_cast<int>(all.size());
    char buf[256];
    std::snprintf(buf, sizeof buf,
                  "primary %d seeds, secondary %g Hz at lod %d: predicted %s (budget %s%s), "
                  "%d cells x %g substeps = %.0f of %.0f element-substeps; %s of %d",
                  out.setting.primaryNodes, out.setting.secondaryRate, lod,
                  percent(out.predicted.percent).c_str(), percent(o.budgetPercent).c_str(),
                  out.predicted.inRange() ? "" : ", outside the sweep's ranges", out.cost.cells,
                  out.cost.substeps, out.cost.elementSubsteps(), o.maxElementSubsteps, why.c_str(),
                  out.candidates);
    out.reason = buf;
    return out;
}

ErrorPoint errorConditions(const DeformableModel& model) {
    ErrorPoint x;
    x.fill(std::numeric_limits<double>::quiet_NaN());
    const fem::ElasticMaterial& m = model.model().material();
    x[errorIndex(ErrorVar::youngs)] = m.youngsModulus;
    x[errorIndex(ErrorVar::poisson)] = m.poissonRatio;
    x[errorIndex(ErrorVar::density)] = m.density;
    x[errorIndex(ErrorVar::damping)] = m.dampingAlpha;
    const fem::AsyncRegionsOptions& r = model.options().regions;
    x[errorIndex(ErrorVar::lod)] = r.lod;
    x[errorIndex(ErrorVar::primary)] = r.primaryNodes;
    x[errorIndex(ErrorVar::rate)] = r.secondaryRate;
    return x;
}

ErrorEstimate estimateBodyError(const DeformableModel& model, double strain, double frequencyHz) {
    if (model.options().solverKind != DeformableSolver::asyncRegions) {
        ErrorEstimate none;
        none.percent = 0;
        return none;
    }
    const ErrorTable& table = ErrorTable::builtIn();
    ErrorPoint x = errorConditions(model);
    const std::vector<double> given{0.0};
    const ErrorTable::Axis* sa = table.axis(ErrorVar::strain);
    const ErrorTable::Axis* fa = table.axis(ErrorVar::frequency);
    const bool worstS = std::isnan(strain) && sa, worstF = std::isnan(frequencyHz) && fa;
    ErrorEstimate worst;
    worst.percent = -1;
    for (double s : worstS ? sa->values : given) {
        for (double f : worstF ? fa->values : given) {
            x[errorIndex(ErrorVar::strain)] = worstS ? s : strain;
            x[errorIndex(ErrorVar::frequency)] = worstF ? f : frequencyHz;
            const ErrorEstimate e = table.estimate(x);
            if (!(e.percent <= worst.percent)) worst = e;
        }
    }
    return worst;
}

ErrorMonitor::ErrorMonitor(const ErrorTable& table, const ErrorPoint& conditions,
                           double referenceLength, double windowSeconds, double tickSeconds,
                           double budgetPercent)
    : mTable(&table),
      mPoint(conditions),
      mLength(referenceLength),
      mWindow(windowSeconds),
      mBudget(budgetPercent) {
    if (!(std::isfinite(referenceLength) && referenceLength > 0))
        throw ValueError("error monitor: reference length: expected > 0 m, found " +
                         std::to_string(referenceLength));
    if (!(std::isfinite(windowSeconds) && std::isfinite(tickSeconds) && tickSeconds > 0 &&
          windowSeconds >= tickSeconds))
        throw ValueError("error monitor: expected a tick > 0 s and a window of at least a tick");
    mWindowTicks = static_cast<int>(std::lround(windowSeconds / tickSeconds));
    mWindow = mWindowTicks * tickSeconds;
}

void ErrorMonitor::update(double d) noexcept {
    if (std::isfinite(d)) {
        if (mContactTicks == 0) mLo = mHi = d;
        mLo = std::min(mLo, d);
        mHi = std::max(mHi, d);
        mMaxAbs = std::max(mMaxAbs, std::abs(d));
        if (mHaveLast) mTravel += std::abs(d - mLast);
        mLast = d;
        mHaveLast = true;
        ++mContactTicks;
    } else {
        mHaveLast = false;
    }
    if (++mTicks >= mWindowTicks) finishWindow();
}

void ErrorMonitor::finishWindow() noexcept {
    if (mContactTicks > 0) {
        mPoint[errorIndex(ErrorVar::strain)] = mMaxAbs / mLength;
        const double span = mHi - mLo;
        mPoint[errorIndex(ErrorVar::frequency)] = span > 0 ? mTravel / (2 * span * mWindow) : 0.0;
        mCurrent = mTable->estimate(mPoint);
        if (mCurrent.percent == mCurrent.percent) {
            ++mWindows;
            if (mCurrent.percent > mBudget) ++mOver;
            if (!(mCurrent.percent <= mMax)) mMax = mCurrent.percent;
        }
    }
    mTicks = mContactTicks = 0;
    mMaxAbs = mTravel = 0;
}

}  // namespace palp::haptics
