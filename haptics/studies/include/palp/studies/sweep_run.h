#pragma once
/// @file
/// The error-analysis sweep's runner (docs/error_analysis.md): one sample is the asynchronous
/// regions (palp::fem::AsyncRegions, synchronous mode: deterministic) and the whole fine mesh
/// (ExplicitSolver, substepped below its stable step: the reference) on the same recorded input,
/// a raised-cosine displacement of the contact node into the top face of a cube fixed at its
/// bottom; the sample's error compares the two contact forces tick by tick.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "palp/studies/sweep_design.h"

namespace palp::haptics {

/// What one sample gives. Everything but the two times is a deterministic function of the
/// sweep spec and the index.
struct SweepSampleResult {
    std::int64_t index = 0;
    std::array<double, kSweepVarCount> x{};  ///< the sample's variables (SweepVar order)
    int contactNode = -1;                    ///< fine node index driven
    int primaryFreeNodes = 0;                ///< the regions' primary free nodes ("N")
    double forceN = 0.0;            ///< peak |reference contact force|, N (the table's "force")
    double errPeak = 0.0;           ///< |peak F_async - peak F_ref| / peak F_ref
    double errRms = 0.0;            ///< rms(F_async - F_ref) / rms(F_ref) over the run
    double errMax = 0.0;            ///< max |F_async - F_ref| / peak F_ref
    bool diverged = false;          ///< non-finite force or a peak over 100x the reference's
    double asyncSeconds = 0.0;      ///< wall time of the regions' run (set-up included)
    double referenceSeconds = 0.0;  ///< wall time of the reference (0 when reused)
};

/// Input displacement of the contact node along -z at time @p t (s), m: `-a (1 - cos 2 pi f t) /
/// 2` with a = strain * cube height.
double sweepInput(const SweepRanges& ranges, const std::array<double, kSweepVarCount>& x, double t);

/// Runs samples of one sweep; keeps the last group's reference (samples of a group are run one
/// after the other, so each reference is computed once per group and process).
/// @par Threading  One thread per instance. run() uses one core: the FEM's TBB loops run inside
/// a one-thread arena, so results do not depend on the machine's core count.
class SweepRunner {
  public:
    explicit SweepRunner(const SweepSpec& spec);
    /// Runs sample @p index. @throw palp::ValueError naming the sample and its adaptivity when
    /// the regions or the solvers refuse it.
    SweepSampleResult run(std::int64_t index);
    const SweepSampler& sampler() const { return mSampler; }
    /// References computed so far.
    int referencesComputed() const { return mReferences; }

  private:
    void runIn(std::int64_t index, SweepSampleResult& out);
    SweepSampler mSampler;
    std::int64_t mCachedGroup = -1;
    std::vector<double> mReference;  // reference contact force per tick, N
    int mReferences = 0;
};

/// The table's columns: name, unit, role ("index", "variable", "derived", "response" or
/// "flag") and description, in order.
struct SweepColumn {
    std::string name, unit, role, description;
};
const std::vector<SweepColumn>& sweepColumns();
/// One CSV row (no newline) of @p r, numbers with 9 significant digits ("%.9g").
std::string sweepRow(const SweepSampleResult& r);

}  // namespace palp::haptics
