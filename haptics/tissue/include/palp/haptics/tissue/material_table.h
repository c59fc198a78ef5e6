#pragma once
/// @file
/// Materials from the scan by a table: each element's Young's modulus from the scan's value at
/// its centre, by ranges of values (Hounsfield units of a CT) or by labels (a segmentation), and
/// the body's Poisson ratio and density, read from a CSV file a user edits and checked on load.
///
/// The format (docs/algorithms.md section 5.2): `#` starts a comment line; blank lines are
/// skipped; the first other line is the header, naming the columns in any order:
///
///     name,lo,hi,youngs_pa,poisson,density_kg_m3,source      (a range table: lo <= v < hi)
///     name,label,youngs_pa,poisson,density_kg_m3,source      (a label table: v == label)
///
/// then one row per tissue class. A field may be double-quoted (a source with commas; `""` is
/// a quote). Every row has every column; names are unique; ranges do not overlap, labels do not
/// repeat; E in [1, 1e12] Pa, nu in (-1, 0.5), density in [1, 1e5] kg/m^3, all finite; the
/// source is not empty. palp's solvers take one Poisson ratio and one density per body (the
/// linear element scales one unit stiffness by each element's modulus, which the regions'
/// condensed stencil relies on; the lumped mass is one density times the element volume), so
/// every row must give the same nu and the same density.

#include <filesystem>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "palp/fem/material.h"
#include "palp/fem/voxelize.h"

namespace palp::haptics {

/// One tissue class of a MaterialTable.
struct MaterialRow {
    std::string name;
    /// Range tables: the values v with lo <= v < hi. Label tables: lo == hi == the label.
    double lo = 0, hi = 0;
    double youngsModulus = 0;  ///< E, Pa
    double poissonRatio = 0;   ///< nu
    double density = 0;        ///< kg/m^3
    std::string source;        ///< where the numbers come from
    int line = 0;              ///< the row's line in its file, 1-based
};

/// How a MaterialTable matches a value: a range of values, or a label.
enum class MaterialTableKind { ranges, labels };

/// A checked table of tissue classes (MaterialRow), sorted by value.
class MaterialTable {
  public:
    /// The table in @p text; @p origin (a file name) starts every message.
    /// @throw palp::FormatError naming @p origin and the line for a missing, unknown or repeated
    /// column, a row with too few or too many fields, a field that is not a number, an empty
    /// name or source, no row; palp::ValueError naming the line and row for a value out of
    /// range (a modulus <= 0, nu >= 0.5, a density <= 0, NaN), a range with lo >= hi,
    /// overlapping ranges or a repeated label or name, rows that differ in nu or density.
    static MaterialTable parse(std::string_view text, std::string origin);
    /// The table in @p file. @throw palp::IoError when it cannot be read; as parse().
    static MaterialTable load(const std::filesystem::path& file);
    /// The table palp ships for CT (haptics/tissue/data/materials_ct.csv, compiled in): fat,
    /// soft tissue and a stiff lesion class, with their sources.
    static const MaterialTable& builtInCt();
    /// builtInCt() for @p nameOrFile "ct", else load(@p nameOrFile).
    /// @throw as load().
    static std::shared_ptr<const MaterialTable> named(const std::string& nameOrFile);

    const std::string& origin() const noexcept { return mOrigin; }
    MaterialTableKind kind() const noexcept { return mKind; }
    /// The rows, sorted by lo.
    const std::vector<MaterialRow>& rows() const noexcept { return mRows; }
    /// Every row's Poisson ratio and density (they are equal).
    double poissonRatio() const noexcept { return mRows.front().poissonRatio; }
    double density() const noexcept { return mRows.front().density; }
    /// The smallest and the largest Young's modulus of the rows, Pa.
    double softestModulus() const noexcept;
    double stiffestModulus() const noexcept;

    /// The row that covers @p value; nullptr when none does.
    const MaterialRow* find(double value) const noexcept;
    /// Young's modulus of the row that covers @p value, Pa.
    /// @throw palp::ValueError naming the table and the value when no row covers it.
    double youngsAt(double value) const;

  private:
    std::string mOrigin;
    MaterialTableKind mKind = MaterialTableKind::ranges;
    std::vector<MaterialRow> mRows;
};

/// Makes @p voxelize and @p material take their tissue from @p table: youngsFromValue looks the
/// cell's value up (a cell above voxelize.boneThreshold, as set before this call, is bone, its
/// nodes all fixed so that its stiffness never acts: it takes the softest row's modulus, so
/// that it never shortens the explicit step the tissue's rows allow); a label table samples the
/// nearest voxel (VoxelizeOptions::nearestValue); material takes the table's Poisson ratio and
/// density, and its youngsModulus (the body's nominal modulus, e.g. for the error table) the
/// softest row's. @p table must not be null.
void applyMaterialTable(const std::shared_ptr<const MaterialTable>& table,
                        fem::VoxelizeOptions& voxelize, fem::ElasticMaterial& material);

}  // namespace palp::haptics
