#pragma once
/// @file
/// The error-analysis sweep's design (docs/error_analysis.md, thesis paper II): the variables,
/// their ranges from a JSON file, and the sampler (Latin hypercube or plain Monte Carlo) whose
/// every draw comes from a Philox4x32 stream keyed by (seed, what is drawn), so that a sample's
/// values depend on the ranges, the seed, the sample count and its index only, never on how many
/// processes ran the sweep or in what order.
///
/// Nested design. Samples come in groups of `adaptivityPerReference` consecutive indices. The
/// user-input and material variables (strain, frequency, contact, E, nu, density, damping) are
/// drawn per group, the adaptivity variables (level of detail, primary size, secondary rate,
/// coupling) per sample: the reference (whole fine mesh) depends only on the group, so it is
/// computed once per group and reused by the group's adaptivity samples.

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace palp::haptics {

/// The sweep's variables, in table order.
enum class SweepVar : int {
    strain,     ///< input strain amplitude: contact displacement amplitude / cube height
    frequency,  ///< input frequency, Hz (raised cosine)
    contact,    ///< contact node: rank of a top-face node by distance from the face centre
    youngs,     ///< Young's modulus E, Pa
    poisson,    ///< Poisson's ratio nu
    density,    ///< density, kg/m^3
    damping,    ///< mass-proportional Rayleigh damping alpha, 1/s
    lod,        ///< secondary level of detail: coarse cell = lod fine cells a side (1, 2, 4)
    primary,    ///< primary size: seed nodes of the primary region
    rate,       ///< secondary rate, Hz
    coupling,   ///< 0 the thesis's plain staggered coupling, 1 palp's condensed coupling
};
constexpr int kSweepVarCount = 11;

/// Name (as in the ranges file and the table), unit and description of a variable.
struct SweepVarInfo {
    const char* name;
    const char* unit;
    const char* label;  ///< axis label for plots
    bool perGroup;      ///< input or material (per reference) rather than adaptivity
};
const SweepVarInfo& sweepVarInfo(SweepVar v);
const SweepVarInfo& sweepVarInfo(int v);

/// How one variable is drawn.
struct SweepRange {
    enum class Kind { fixed, uniform, logUniform, integer, values };
    Kind kind = Kind::fixed;
    double min = 0.0;            ///< fixed: the value; uniform/log/integer: the lower end
    double max = 0.0;            ///< uniform/log/integer: the upper end (integer: inclusive)
    std::vector<double> values;  ///< values: equally likely choices
    /// Value for a uniform draw @p u in (0, 1).
    double at(double u) const;
    /// Whether the variable varies (not fixed, not a single value).
    bool varies() const;
};

/// A ranges file: the variables and the problem they are drawn for.
struct SweepRanges {
    std::array<SweepRange, kSweepVarCount> vars;
    int meshNodes = 13;              ///< nodes per side of the cube
    double spacingM = 0.005;         ///< node spacing, m
    double durationS = 0.1;          ///< simulated time per sample, s (1 ms ticks)
    int adaptivityPerReference = 8;  ///< samples per group (per reference run)
    std::string canonical;           ///< the parsed ranges as canonical JSON (for the sweep id)
    /// Top-face nodes a contact index may name (interior of the top face, by distance from its
    /// centre, ties by node index).
    std::vector<int> contactNodes() const;
};

/// Parses a ranges file's @p text; @p source names it in errors.
/// Format (all keys required except where a default is given):
/// `{"palp_sweep_ranges": 1, "mesh": {"nodes": 13, "spacing_mm": 5}, "duration_s": 0.1,
///   "adaptivity_per_reference": 8, "variables": {NAME: SPEC, ...}}` with every variable of
/// SweepVar given once, SPEC one of `{"value": x}`, `{"min": a, "max": b}` (uniform, a < b),
/// `{"min": a, "max": b, "scale": "log"}` (log-uniform, 0 < a < b), `{"min": a, "max": b,
/// "integer": true}` (integers a..b) or `{"values": [x, ...]}`; each checked against the
/// variable's physical range and the mesh (contact rank, primary size, lod dividing the cells).
/// @throw palp::FormatError (not JSON, wrong type) or palp::ValueError (unknown variable, empty
/// or inverted range, non-finite or out-of-range number), naming @p source, the field, what was
/// expected and what was found.
SweepRanges parseSweepRanges(const std::string& text, const std::string& source);
/// Reads and parses the ranges file at @p path. @throw palp::IoError when it cannot be read.
SweepRanges loadSweepRanges(const std::filesystem::path& path);

/// Latin hypercube (each variable's range cut into as many equal-probability strata as draws,
/// one draw per stratum, strata permuted independently per variable) or plain Monte Carlo.
enum class SweepDesign { lhs, mc };

/// Everything that defines a sweep's samples and results.
struct SweepSpec {
    SweepRanges ranges;
    SweepDesign design = SweepDesign::lhs;
    std::uint64_t seed = 1;
    std::int64_t samples = 0;
    /// Samples per group (ranges.adaptivityPerReference).
    std::int64_t groupSize() const;
    /// Number of groups, ceil(samples / groupSize()).
    std::int64_t groups() const;
    /// 16 hex digits: FNV-1a 64 of the canonical ranges, design, seed, samples and palp version.
    std::string id() const;
};

/// The palp version the sweep records ("0.1.0").
const char* sweepPalpVersion();

/// One Philox4x32-10 block: four 32-bit words for @p key (2 words) and @p counter (4 words).
std::array<std::uint32_t, 4> philox(std::array<std::uint32_t, 2> key,
                                    std::array<std::uint32_t, 4> counter);
/// A uniform double in (0, 1) from 52 bits of a 64-bit word: `((x >> 12) + 0.5) 2^-52`.
double unitOpen(std::uint64_t x);

/// The values of every sample of a sweep. Construction builds each varying variable's Latin
/// hypercube permutation (Fisher-Yates over a Philox stream keyed by (seed, variable): O(samples)
/// per variable, the same in every process); sample() is then O(variables).
/// @par Threading  const methods may be called from any thread.
class SweepSampler {
  public:
    /// @throw palp::ValueError for samples < 1 or above 1e9.
    explicit SweepSampler(const SweepSpec& spec);
    /// The variables of sample @p index (0 <= index < samples), in SweepVar order.
    std::array<double, kSweepVarCount> sample(std::int64_t index) const;
    const SweepSpec& spec() const { return mSpec; }

  private:
    SweepSpec mSpec;
    std::array<std::vector<std::uint32_t>, kSweepVarCount> mPermutation;  // empty for mc/fixed
};

}  // namespace palp::haptics
