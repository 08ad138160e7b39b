// The scalpel's cutting resistance (cutting_force.h). fp-contract is off: next_blade_force must
// evaluate the gl blade pass's operations, no multiply-add fused.
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/cutting_force.h"
#include "libmodel/sim/cutting.h"

#include <algorithm>
#include <cmath>

namespace heartsim {

LatticeFrame lattice_frame(const Lattice& lattice) {
    LatticeFrame frame;
    frame.spacing_mm = lattice.spacing;
    for (int c = 0; c < 3; ++c) {
        const Eigen::Vector3d column = lattice.index_to_world.block<3, 1>(0, c);
        if (column.norm() > 0) frame.axes.col(c) = column.normalized();
    }
    return frame;
}

double lattice_crossings(const Eigen::Vector3d& n) {
    Eigen::Vector3d a = n.cwiseAbs();
    std::sort(a.data(), a.data() + 3, [](double x, double y) { return x > y; });
    return 5.0 * a[0] + 3.0 * a[1] + a[2];
}

double area_per_spring(const LatticeFrame& frame, const Eigen::Vector3d& normal) {
    const double h = frame.spacing_mm;
    return h * h / lattice_crossings(frame.axes.transpose() * normal.normalized());
}

BladeStep blade_step(const CuttingResistance& resistance, const LatticeFrame& frame, const InstrumentPose& from, const InstrumentPose& to,
                     double length_mm, double step_ms) {
    BladeStep r;
    if (resistance.smoothing_ms > 0 && step_ms > 0) {
        r.keep = std::exp(-step_ms / resistance.smoothing_ms);
        r.alpha = 1.0 - r.keep;
    }
    const auto a = blade_segment(from, length_mm), b = blade_segment(to, length_mm);
    // The midpoint's motion gives the direction; the blade's travel is the mean of its ends'
    // (the midpoint's own for a blade that does not turn, more where it turns).
    const Eigen::Vector3d middle = 0.5 * ((b[0] - a[0]) + (b[1] - a[1]));
    const double travel = 0.5 * ((b[0] - a[0]).norm() + (b[1] - a[1]).norm());
    if (!std::isfinite(travel) || !middle.allFinite() || !(travel > 0)) return r;
    r.travel = travel;
    const double window = resistance.smoothing_spacings * frame.spacing_mm;
    r.distance_keep = window > 0 ? std::exp(-travel / window) : 0.0;
    if (step_ms > 0 && std::isfinite(step_ms)) {
        r.motion_rate = middle / step_ms;
        r.travel_rate = travel / step_ms;
    }
    // The swept quad's normal: the sum of its two triangles' (tip_A, end_A, end_B) and
    // (tip_A, end_B, tip_B) normals (twice its vector area), the second turned to the first's side
    // where the quad folds over itself (a blade turned about its middle).
    const Eigen::Vector3d first = (a[1] - a[0]).cross(b[1] - a[0]);
    Eigen::Vector3d second = (b[1] - a[0]).cross(b[0] - a[0]);
    if (first.dot(second) < 0) second = -second;
    const Eigen::Vector3d area = first + second;
    if (!(area.norm() > 0)) return r;
    r.energy_per_spring = resistance.toughness_n_per_mm * area_per_spring(frame, area);
    return r;
}

BladeState lowered_blade(const CuttingResistance& resistance, const LatticeFrame& frame) {
    BladeState state;
    state.travel = resistance.smoothing_spacings > 0 ? frame.spacing_mm : 0.0;
    return state;
}

BladeState next_blade_state(const BladeState& previous, const BladeStep& step, std::size_t springs_cut) {
    const double energy = double(springs_cut) * step.energy_per_spring;
    BladeState next;
    next.energy = step.distance_keep * previous.energy + energy;
    next.travel = step.distance_keep * previous.travel + step.travel;
    for (int c = 0; c < 3; ++c) next.motion_rate[c] = step.keep * previous.motion_rate[c] + step.alpha * step.motion_rate[c];
    next.travel_rate = step.keep * previous.travel_rate + step.alpha * step.travel_rate;
    return next;
}

Eigen::Vector3d blade_force(const BladeState& state, const CuttingResistance& resistance, double length_mm) {
    const double speed = std::max(state.travel_rate, resistance.min_speed_mm_per_ms);
    if (!(state.travel > 0) || !(state.energy > 0) || !(speed > 0)) return Eigen::Vector3d::Zero();
    // A moving segment sweeps at most its length × its travel: more is the count's jitter.
    const double force = std::min(state.energy / state.travel, resistance.toughness_n_per_mm * length_mm);
    const Eigen::Vector3d f = -(force * state.travel_rate / (speed * speed)) * state.motion_rate;
    return f.allFinite() ? f : Eigen::Vector3d::Zero();
}

}  // namespace heartsim
