// Force interpolation names and the virtual coupling's passivity bound (coupling.h).
#include "runtime/haptics/coupling.h"

#include "libmodel/errors.h"

#include <cmath>

namespace heartsim::haptics {

const char* to_string(ForceInterpolation mode) { return mode == ForceInterpolation::hold ? "hold" : "extrapolate"; }

CouplingSettings choose_coupling(double b, double period_ms, double margin) {
    if (!(b > 0.0) || !(period_ms > 0.0) || !(margin > 0.0 && margin < 1.0))
        throw InputError("haptics: virtual coupling needs a positive device damping, period and a margin in (0, 1)");
    CouplingSettings c;
    c.enabled = true;
    c.damping_n_ms_per_mm = 0.25 * b;
    c.stiffness_n_per_mm = margin * 2.0 * (b - c.damping_n_ms_per_mm) / period_ms;
    return c;
}

bool within_passivity_bound(const CouplingSettings& c, double b, double period_ms) {
    return b > c.stiffness_n_per_mm * period_ms / 2.0 + std::abs(c.damping_n_ms_per_mm);
}

}  // namespace heartsim::haptics
