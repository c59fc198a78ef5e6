#pragma once
/// @file
/// TransferFunction: the piecewise-linear hardness sigma(value) of accumulate (volume_ray.h).

#include <array>
#include <span>

namespace palp::kernels {

/// Hardness transfer function sigma(value) >= 0 (per metre), piecewise linear through up to
/// kMaxNodes nodes (value, sigma) with non-decreasing values; two nodes with the same value make
/// a step. Constant beyond the end nodes.
/// @par Threading  A plain value.
class TransferFunction {
  public:
    static constexpr int kMaxNodes = 16;
    TransferFunction() = default;
    /// @throw palp::ValueError for no node, more than kMaxNodes, decreasing values, negative or
    ///        non-finite sigma.
    explicit TransferFunction(std::span<const std::array<float, 2>> nodes);
    /// sigma = 0 below @p threshold and @p height (1/m) from it on.
    static TransferFunction step(float threshold, float height);

    /// sigma(v), per metre. @par Real-time noexcept.
    float sigma(float v) const noexcept;
    /// An antiderivative S(v) = integral of sigma dv (per metre times value units).
    /// @par Real-time noexcept.
    double integral(double v) const noexcept;
    /// sigma(u) == 0 for every u < zeroBelow() (-inf when sigma is positive everywhere).
    float zeroBelow() const noexcept { return mZeroBelow; }

  private:
    std::array<float, kMaxNodes> mV{}, mS{};
    std::array<double, kMaxNodes> mCum{};  // S at each node
    int mCount = 0;
    float mZeroBelow = 0;
};

}  // namespace palp::kernels
