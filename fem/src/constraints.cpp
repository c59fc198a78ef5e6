#include "palp/fem/constraints.h"

#include <cmath>
#include <sstream>

#include "palp/base/error.h"

namespace palp::fem {

void Constraints::fixNodes(const std::vector<int>& nodes, unsigned componentMask) {
    for (int n : nodes) {
        if (n < 0 || 3 * n + 2 >= dofCount()) {
            std::ostringstream s;
            s << "constraint node: expected an index in [0, " << dofCount() / 3 << "), found " << n;
            throw ValueError(s.str());
        }
        for (int c = 0; c < 3; ++c) {
            if (componentMask & (1u << c)) prescribe(3 * n + c, 0.0);
        }
    }
}

void Constraints::prescribe(int dof, double value) {
    if (dof < 0 || dof >= dofCount()) {
        std::ostringstream s;
        s << "constraint dof: expected an index in [0, " << dofCount() << "), found " << dof;
        throw ValueError(s.str());
    }
    if (!std::isfinite(value)) {
        std::ostringstream s;
        s << "constraint value of dof " << dof << ": expected a finite displacement, found "
          << value;
        throw ValueError(s.str());
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
