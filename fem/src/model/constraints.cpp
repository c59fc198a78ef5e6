#include "palp/fem/constraints.h"

#include <cmath>
#include <string>

#include "palp/base/validate.h"

namespace palp::fem {

void Constraints::fixNodes(const std::vector<int>& nodes, unsigned componentMask) {
    for (int n : nodes) {
        if (n < 0 || 3 * n + 2 >= dofCount()) {
            throwExpected("constraint node",
                          "an index in [0, " + std::to_string(dofCount() / 3) + ")",
                          std::to_string(n));
        }
        for (int c = 0; c < 3; ++c) {
            if (componentMask & (1u << c)) prescribe(3 * n + c, 0.0);
        }
    }
}

void Constraints::prescribe(int dof, double value) {
    if (dof < 0 || dof >= dofCount()) {
        throwExpected("constraint dof", "an index in [0, " + std::to_string(dofCount()) + ")",
                      std::to_string(dof));
    }
    if (!std::isfinite(value)) {
        throwExpected("constraint value of dof " + std::to_string(dof), "a finite displacement",
                      formatValue(value));
    }
    mFixed[static_cast<std::size_t>(dof)] = 1;
    mValue[dof] = value;
}

int Constraints::fixedCount() const {
    int n = 0;
    for (auto f : mFixed) n += f;
    return n;
}

}  // namespace palp::fem
