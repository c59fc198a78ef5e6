#pragma once
/// @file
/// Export of a palp FEM problem to a CalculiX `.inp` file (C3D8 elements) and reading of the
/// nodal displacements that `ccx` prints to its `.dat` file.

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

#include "palp/fem/constraints.h"
#include "palp/fem/fem_model.h"

namespace palp::fem {

/// The widest number CalculiX reads: it takes the first 20 characters of a field and drops the
/// rest without a word (a 21-character `4.444444444444445e-06` reads as ~4.4).
inline constexpr std::size_t kCalculixNumberWidth = 20;

/// @p v as the `.inp` file carries it: the shortest text that reads back to exactly @p v
/// (std::to_chars' round-trip form, fixed or scientific, whichever is shorter) with a compact
/// exponent (`6.25e-5`, `1e6`); only when that exceeds kCalculixNumberWidth characters, the
/// most significant digits that fit (rounded to nearest). 20 characters hold all 17 of
/// `d.ddddddddddddddddeN`; each further character (the number's minus, the exponent's minus,
/// each further exponent digit) costs one digit, down to 13 in the worst case
/// (`-d.dddddddddddde-308`; relative error <= 5e-13). A value whose shortest round-trip form
/// fits comes back exactly.
/// @throw palp::ValueError for NaN or an infinity.
std::string calculixNumber(double v);

/// The analysis step written to the `.inp` file.
struct CalculixStep {
    bool dynamic = false;        ///< false: *STATIC; true: *DYNAMIC, DIRECT
    double timeIncrement = 1.0;  ///< seconds (fixed increments)
    double totalTime = 1.0;      ///< seconds
    double hhtAlpha = 0.0;       ///< *DYNAMIC ALPHA in [-1/3, 0]; 0 = average acceleration
    int printEvery = 1;          ///< *NODE PRINT FREQUENCY (increments)
    /// Initial increment of a *STATIC step as a fraction of its unit step time, in (0, 1]:
    /// below 1 ccx applies the load in automatic increments (what a large-strain neo-Hookean
    /// step needs to converge).
    double staticIncrement = 1.0;
    bool printReactions = false;  ///< also print the nodal reaction forces (RF)
    /// The element: "C3D8" (full 2x2x2 integration, palp's TledIntegration::gauss2x2x2 and the
    /// linear element) or "C3D8R" (one point with ccx's hourglass control, the class of palp's
    /// real-time TledIntegration::onePointHourglass).
    std::string elementType = "C3D8";
};

/// Writes mesh (active nodes, active cells as C3D8; palp node n is CalculiX node n+1, cell c is
/// element c+1), one *MATERIAL per distinct Young's modulus (*ELASTIC, or for a neo-Hookean
/// material *HYPERELASTIC, NEO HOOKE with C10 = mu / 2 and D1 = 2 / K and the step with NLGEOM;
/// *DENSITY, *DAMPING with the Rayleigh coefficients when non-zero), *BOUNDARY for every
/// constrained dof with its value, *CLOAD for every non-zero entry of @p nodalForce (newtons,
/// #dofs) and the step with *NODE PRINT of U (and RF when step.printReactions) for all nodes. Units
/// are SI throughout; every number is written by calculixNumber(). The file is written to a
/// temporary beside @p inpPath and renamed into place when complete, so a refusal or a failed write
/// leaves no file.
/// @throw palp::ValueError on size mismatch, a non-finite node position, cell modulus,
/// constrained value or force (the message names the dof), a time increment or total time
/// outside (0, 3600] s, more than 1e7 increments, hhtAlpha outside [-1/3, 0], printEvery < 1
/// or staticIncrement outside (0, 1];
/// palp::IoError when the file cannot be written.
void writeCalculixInput(const std::filesystem::path& inpPath, const FemModel& model,
                        const Constraints& constraints, const Eigen::VectorXd& nodalForce,
                        const CalculixStep& step);

/// Displacements (and reactions) printed by ccx: one block per printed time.
struct CalculixResults {
    std::vector<double> times;                   ///< seconds
    std::vector<Eigen::VectorXd> displacements;  ///< #dofs each, metres (0 where not printed)
    /// Nodal reaction forces per printed time when printed (RF), #dofs each, newtons.
    std::vector<Eigen::VectorXd> reactions;
};

/// Reads the "displacements (vx,vy,vz)" blocks (and the "forces (fx,fy,fz)" ones, into
/// reactions) of a ccx `.dat` file for a model of @p dofCount dofs. @throw palp::IoError when
/// unreadable, palp::FormatError on bad content.
CalculixResults readCalculixDat(const std::filesystem::path& datPath, int dofCount);

}  // namespace palp::fem
