#pragma once
/// @file
/// The error lookup table of the asynchronous regions (docs/error_analysis.md, "Lookup table and
/// control"; thesis paper II, figure 3.3): a regular grid over some of the error sweep's
/// variables (`palp sweep`), each node the relative contact-force error the regions are
/// predicted not to exceed there (a high quantile of the sweep's error, fitted by `palp errormap
/// --table`), read by multilinear interpolation. The run-time side (this file and
/// error_control.h) lives here, with the tissue that uses it; the fit lives in the studies.
///
/// File format (JSON, `"palp_error_table": 1`):
/// ```
/// {"palp_error_table": 1, "response": "err_peak", "quantile": 0.95, "coupling": 1,
///  "axes": [{"name": "lod", "values": [2, 4]}, {"name": "primary", "values": [5, 10, ...]}, ...],
///  "error_percent": [...],         // one per grid node, row-major (the last axis fastest)
///  "provenance": {...}}            // the sweep's id, seed, samples, ranges, palp version, fit
/// ```

#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

namespace palp::haptics {

/// The quantities a table may have as axes: the error sweep's variables without the contact
/// rank and the coupling (a table is for one coupling; the contact is one of the things its
/// quantile covers). Names as in the sweep's table (`strain`, `frequency`, ...).
enum class ErrorVar : int {
    strain,     ///< input strain amplitude: contact displacement amplitude / reference length
    frequency,  ///< input frequency, Hz
    youngs,     ///< Young's modulus, Pa
    poisson,    ///< Poisson's ratio
    density,    ///< density, kg/m^3
    damping,    ///< mass-proportional Rayleigh damping alpha, 1/s
    lod,        ///< the regions' secondary level of detail (1, 2, 4)
    primary,    ///< the regions' primary size: seed nodes
    rate,       ///< the regions' secondary rate, Hz
};
constexpr int kErrorVarCount = 9;
/// The name of @p v as in the sweep's table and the table's axes.
const char* errorVarName(ErrorVar v) noexcept;

/// The index of @p v in an ErrorPoint.
constexpr std::size_t errorIndex(ErrorVar v) noexcept { return static_cast<std::size_t>(v); }

/// A point to look the error up at: one value per ErrorVar (index with errorIndex());
/// values of variables that are not axes of the table are ignored.
using ErrorPoint = std::array<double, kErrorVarCount>;

/// The stiffness JND for continuous pressure along the normal, percent (thesis paper III;
/// docs/algorithms.md, "Stiffness JNDs by way of touching"): the default error budget.
inline constexpr double kNormalPressureJndPercent = 5.23;

/// What a lookup gives.
struct ErrorEstimate {
    /// Predicted relative contact-force error, percent; NaN for a point with a non-finite
    /// coordinate on an axis.
    double percent = std::numeric_limits<double>::quiet_NaN();
    /// Bit a set when the point's coordinate on axis a was outside the axis's range and was
    /// clamped to it (the estimate is then an extrapolation the sweep did not measure).
    std::uint32_t clampedAxes = 0;
    bool inRange() const noexcept { return clampedAxes == 0 && percent == percent; }
};

/// A regular (rectilinear) grid of errors with multilinear interpolation.
/// @par Threading  Immutable after construction; any thread may call the const methods.
class ErrorTable {
  public:
    /// One axis: the variable and its strictly increasing node values (at least 2).
    struct Axis {
        ErrorVar var = ErrorVar::primary;
        std::vector<double> values;
    };

    /// A table over @p axes with one value per grid node in @p errorPercent (row-major, the last
    /// axis fastest). @p source names the table in errors.
    /// @throw palp::ValueError naming @p source and the field: no axis, more than 16, an axis
    /// repeated, with fewer than 2 values, not strictly increasing or not finite; a value count
    /// that is not the product of the axes' sizes; a value not finite or negative.
    ErrorTable(std::vector<Axis> axes, std::vector<double> errorPercent,
               const std::string& source = "error table");

    /// Parses a table file's @p text (format above); @p source names it in errors.
    /// @throw palp::FormatError (not JSON, a field of the wrong type, a missing field, an
    /// unknown axis name, another version) or palp::ValueError (as the constructor, a quantile
    /// outside (0, 1)), naming @p source and the field (`axes[1].values`, `error_percent[17]`).
    static ErrorTable parse(const std::string& text, const std::string& source);
    /// Reads and parses the file at @p path. @throw palp::IoError when it cannot be read, else as
    /// parse().
    static ErrorTable load(const std::filesystem::path& path);
    /// The table palp ships (fitted from a sweep of the 13^3-node cube with the condensed
    /// coupling; its provenance says which), parsed once.
    static const ErrorTable& builtIn();

    /// The table as JSON (the file format; numbers with 17 significant digits).
    std::string toJson() const;

    /// The interpolated error at @p x (multilinear over the axes; coordinates outside an axis's
    /// range are clamped to it and flagged).
    /// @par Real-time  noexcept, allocation-free, O(2^axes).
    ErrorEstimate estimate(const ErrorPoint& x) const noexcept;

    const std::vector<Axis>& axes() const noexcept { return mAxes; }
    /// The axis of @p v, or nullptr when @p v is not an axis.
    const Axis* axis(ErrorVar v) const noexcept;
    /// Grid values, row-major (the last axis fastest).
    const std::vector<double>& errorPercent() const noexcept { return mValues; }

    /// The sweep response the table was fitted to (`err_peak`, `err_rms` or `err_max`).
    std::string response = "err_peak";
    /// The quantile of the response the nodes hold (the fit's), in (0, 1).
    double quantile = 0.95;
    /// The coupling the sweep ran (1: condensed, 0: plain).
    int coupling = 1;
    /// The provenance object as canonical JSON (`{}` when none).
    std::string provenance = "{}";

  private:
    std::vector<Axis> mAxes;
    std::vector<double> mValues;
    std::vector<std::size_t> mStride;  // per axis
};

}  // namespace palp::haptics
