#pragma once
/// @file
/// Dirichlet constraints: per-dof fixed flags with prescribed displacements.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace palp::fem {

/// Per-dof Dirichlet constraints of a model with @p dofCount dofs: a constrained dof follows its
/// prescribed displacement (metres), every other dof is free.
class Constraints {
  public:
    explicit Constraints(int dofCount = 0)
        : mFixed(static_cast<std::size_t>(dofCount), 0), mValue(Eigen::VectorXd::Zero(dofCount)) {}

    /// Constrains components (bit 0 = x, 1 = y, 2 = z) of @p nodes to displacement 0.
    /// @throw palp::ValueError for a node outside the model.
    void fixNodes(const std::vector<int>& nodes, unsigned componentMask = 7u);
    /// Constrains dof @p dof to displacement @p value metres (a driven contact node, a roller).
    /// @throw palp::ValueError for a dof outside the model or a non-finite value.
    void prescribe(int dof, double value);
    /// Changes the prescribed value of an already constrained dof without checks.
    /// @par Real-time
    void setValue(int dof, double value) noexcept { mValue[dof] = value; }

    int dofCount() const { return static_cast<int>(mFixed.size()); }
    bool isFixed(int dof) const { return mFixed[static_cast<std::size_t>(dof)] != 0; }
    /// Per-dof flag (1 = constrained), #dofs.
    const std::vector<std::uint8_t>& fixed() const { return mFixed; }
    /// Prescribed displacement per dof, metres (#dofs; ignored on free dofs).
    const Eigen::VectorXd& values() const { return mValue; }
    /// Number of constrained dofs.
    int fixedCount() const;

  private:
    std::vector<std::uint8_t> mFixed;
    Eigen::VectorXd mValue;
};

}  // namespace palp::fem
