#pragma once
/// @file
/// Export of a palp FEM problem to a CalculiX `.inp` file (C3D8 elements) and reading of the
/// nodal displacements that `ccx` prints to its `.dat` file.

#include <Eigen/Core>
#include <filesystem>
#include <vector>

#include "palp/fem/constraints.h"
#include "palp/fem/fem_model.h"

namespace palp::fem {

/// The analysis step written to the `.inp` file.
struct CalculixStep {
    bool dynamic = false;        ///< false: *STATIC; true: *DYNAMIC, DIRECT
    double timeIncrement = 1.0;  ///< seconds (fixed increments)
    double totalTime = 1.0;      ///< seconds
    double hhtAlpha = 0.0;       ///< *DYNAMIC ALPHA in [-1/3, 0]; 0 = average acceleration
    int printEvery = 1;          ///< *NODE PRINT FREQUENCY (increments)
};

/// Writes mesh (active nodes, active cells as C3D8; palp node n is CalculiX node n+1, cell c is
/// element c+1), one *MATERIAL per distinct Young's modulus (*ELASTIC, *DENSITY, *DAMPING with
/// the Rayleigh coefficients when non-zero), *BOUNDARY for every constrained dof with its value,
/// *CLOAD for every non-zero entry of @p nodalForce (newtons, #dofs) and the step with
/// *NODE PRINT of U for all nodes. Units are SI throughout.
/// @throw palp::ValueError on size mismatch, palp::IoError when the file cannot be written.
void writeCalculixInput(const std::filesystem::path& inpPath, const FemModel& model,
                        const Constraints& constraints, const Eigen::VectorXd& nodalForce,
                        const CalculixStep& step);

/// Displacements printed by ccx: one block per printed time.
struct CalculixResults {
    std::vector<double> times;                   ///< seconds
    std::vector<Eigen::VectorXd> displacements;  ///< #dofs each, metres (0 where not printed)
};

/// Reads the "displacements (vx,vy,vz)" blocks of a ccx `.dat` file for a model of
/// @p dofCount dofs. @throw palp::IoError when unreadable, palp::FormatError on bad content.
CalculixResults readCalculixDat(const std::filesystem::path& datPath, int dofCount);

}  // namespace palp::fem
