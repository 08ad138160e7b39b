// The CPU solver's instruments (solver.h): placing them, a grabber's grab and release, a
// scalpel's lowered blade and the springs its sweep cuts, and the particles each one touches.
// fp-contract is off here as in solver.cpp (grab_piece is shared with the gl backend).
#if defined(__clang__)
#pragma clang fp contract(off)
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif

#include "libmodel/sim/solver.h"
#include "libmodel/sim/cutting.h"
#include "libmodel/sim/solver_kernels.h"

#include "libmodel/errors.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace heartsim {

namespace {
using namespace solver_kernels;
}  // namespace

template <class Real>
void BasicSolver<Real>::set_instrument(int hand, const Instrument& instrument) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    for (int c = 0; c < 3; ++c)
        if (!(instrument.semi_axes[c] > 0) || !std::isfinite(instrument.semi_axes[c]))
            throw InputError("solver: instrument semi-axes must be positive and finite, mm");
    release(hand);
    hand_[std::size_t(hand)].instrument = instrument;
    hand_[std::size_t(hand)].placed = false;
    for (std::size_t c = 0; c < chunks_; ++c) touched_[c * hands + std::size_t(hand)].clear();
}

template <class Real>
const Instrument& BasicSolver<Real>::instrument(int hand) const {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    return hand_[std::size_t(hand)].instrument;
}

template <class Real>
void BasicSolver<Real>::set_pose(int hand, const InstrumentPose& pose) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    if (!pose.position.allFinite() || !pose.orientation.coeffs().allFinite() || pose.orientation.norm() < 1e-6)
        throw InputError("solver: an instrument pose must be finite with a non-zero quaternion");
    InstrumentPose p = pose;
    p.orientation.normalize();
    HandState& state = hand_[std::size_t(hand)];
    state.target = p;
    if (!state.placed) state.pose = p;  // the first pose of an instrument places it: no sweep from the origin
    state.placed = true;
}

std::vector<std::uint8_t> grab_piece(const std::vector<Eigen::Vector3d>& local, const std::vector<Eigen::Vector3d>& rest,
                                     const Eigen::Vector3d& semi_axes, double reach, const std::vector<std::array<std::int32_t, 2>>& joined) {
    std::vector<std::uint8_t> keep(local.size(), 1);
    if (local.empty() || (!(reach > 0) && joined.empty())) return keep;
    std::size_t anchor = 0;
    double nearest = std::numeric_limits<double>::infinity();
    for (std::size_t q = 0; q < local.size(); ++q) {
        const double r2 = local[q].cwiseQuotient(semi_axes).squaredNorm();
        if (r2 < nearest) {
            nearest = r2;
            anchor = q;
        }
    }
    const double limit = reach * semi_axes.maxCoeff();
    if (reach > 0)
        for (std::size_t q = 0; q < local.size(); ++q) keep[q] = (rest[q] - rest[anchor]).squaredNorm() <= limit * limit;
    if (joined.empty()) return keep;
    // The anchor's side of a cut: reached through springs that are not cut, among those kept.
    std::vector<std::uint8_t> reached(local.size(), 0);
    std::vector<std::size_t> stack{anchor};
    reached[anchor] = 1;
    while (!stack.empty()) {
        const std::size_t q = stack.back();
        stack.pop_back();
        for (const auto& [a, b] : joined) {
            const std::size_t other = std::size_t(a) == q ? std::size_t(b) : std::size_t(b) == q ? std::size_t(a) : local.size();
            if (other < local.size() && keep[other] && !reached[other]) {
                reached[other] = 1;
                stack.push_back(other);
            }
        }
    }
    for (std::size_t q = 0; q < local.size(); ++q) keep[q] = keep[q] && reached[q];
    return keep;
}

template <class Real>
std::size_t BasicSolver<Real>::begin_grab(int hand) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    HandState& state = hand_[std::size_t(hand)];
    if (state.instrument.kind == InstrumentKind::scalpel) {
        if (!state.cutting) state.blade = lowered_blade(options_.cutting_resistance, lattice_frame_);
        state.cutting = true;
        return 0;
    }
    if (!holds_tissue(state.instrument.kind)) throw InputError("solver: begin_grab on a hand that holds no grabber, retractor or scalpel");
    release(hand);
    state.grabbing = true;
    const Eigen::Matrix3d tool_from_world = state.pose.orientation.toRotationMatrix().transpose();
    for (std::size_t i = 0; i < n_; ++i) {
        if (!movable_[i] || held_by_[i] >= 0) continue;
        const Eigen::Vector3d x(static_cast<double>(current_[state_stride * i]), double(current_[state_stride * i + 1]), double(current_[state_stride * i + 2]));
        const Eigen::Vector3d local = tool_from_world * (x - state.pose.position);
        const Eigen::Vector3d reach = met_axes(state.instrument.semi_axes, reach_beyond(i));  // set_contact_skin
        if (local.cwiseQuotient(reach).squaredNorm() > 1.0) continue;
        state.held.push_back(std::int32_t(i));
        state.held_local.push_back(local);
        held_by_[i] = std::int8_t(hand);
    }
    const std::vector<std::array<std::int32_t, 2>> joined = joined_captured(
        state.held, slots, [&](std::size_t i, int s) { return neighbour_[entry_of(i, s)]; },
        [&](std::size_t i, int s) { return uncut_neighbour_[entry_of(i, s)]; });
    if ((options_.grab_reach > 0 || !joined.empty()) && !state.held.empty()) {
        std::vector<Eigen::Vector3d> rest(state.held.size());
        for (std::size_t q = 0; q < state.held.size(); ++q)
            for (int c = 0; c < 3; ++c) rest[q][c] = double(rest_[4 * std::size_t(state.held[q]) + std::size_t(c)]);
        const std::vector<std::uint8_t> keep = grab_piece(state.held_local, rest, state.instrument.semi_axes, options_.grab_reach, joined);
        state.keep_held([&](std::size_t q) {
            if (!keep[q]) held_by_[std::size_t(state.held[q])] = -1;
            return keep[q] != 0;
        });
    }
    return state.held.size();
}

template <class Real>
void BasicSolver<Real>::release(int hand) {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    release_hand(hand, true);
}

template <class Real>
void BasicSolver<Real>::release_hand(int hand, bool stay) {
    HandState& state = hand_[std::size_t(hand)];
    if (stay && state.grabbing && state.instrument.kind == InstrumentKind::retractor) {
        // Anchored where the grab left them, at rest: zero inverse mass and zero motion keep the
        // kernel's step at x + keep·0 + (f + m·g)·0 = x for good.
        for (std::int32_t q : state.held) {
            const std::size_t i = std::size_t(q);
            stayed_.push_back(q);
            stayed_support_stiffness_.push_back(support_stiffness_[i]);
            movable_[i] = 0;
            anchored_[i] = 1;
            inverse_mass_h2_[i] = Real(0);
            support_stiffness_[i] = Real(0);
            for (int c = 0; c < 3; ++c) motion_[state_stride * i + std::size_t(c)] = next_motion_[state_stride * i + std::size_t(c)] = Real(0);
        }
    }
    for (std::int32_t i : state.held) held_by_[std::size_t(i)] = -1;
    state.held.clear();
    state.held_local.clear();
    state.grabbing = false;
    if (state.cutting) strokes_.lift(hand);
    state.cutting = false;
    state.blade = {};  // a lifted blade exerts nothing
    state.cuts = 0;
}

template <class Real>
void BasicSolver<Real>::free_stayed() {
    if (stayed_.empty()) return;
    for (std::size_t q = 0; q < stayed_.size(); ++q) {
        const std::size_t i = std::size_t(stayed_[q]);
        movable_[i] = 1;
        anchored_[i] = 0;
        support_stiffness_[i] = stayed_support_stiffness_[q];
    }
    stayed_.clear();
    stayed_support_stiffness_.clear();
    build_step_constants();  // h²/(S·m) again for them, the same bits as at load
}

template <class Real>
std::size_t BasicSolver<Real>::cut(const BladeSweep& sweep) {
    if (!sweep.cuts_anything) return 0;
    // Each spring once, from its end of lower index (searched only near the sweep: cutting.h
    // cut_search_margin), in particle order per chunk; the chunks' lists joined in order: the
    // same list for any thread count.
    std::vector<std::vector<std::array<std::int32_t, 2>>> found(chunks_);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunks_), [&](const tbb::blocked_range<std::size_t>& range) {
        for (std::size_t chunk = range.begin(); chunk != range.end(); ++chunk) {
            const std::size_t end = std::min(n_, (chunk + 1) * chunk_groups * lane_count);
            for (std::size_t i = chunk * chunk_groups * lane_count; i < end; ++i) {
                const Real* xi = current_ + state_stride * i;
                const float p[3] = {float(xi[0]), float(xi[1]), float(xi[2])};
                if (!near_sweep(sweep, p)) continue;
                for (int s = 0; s < slot_count; ++s) {
                    const std::size_t j = std::size_t(neighbour_[entry_of(i, s)]);
                    if (j <= i) continue;
                    const Real* xj = current_ + state_stride * j;
                    const float q[3] = {float(xj[0]), float(xj[1]), float(xj[2])};
                    if (spring_crosses(sweep, p, q)) found[chunk].push_back({std::int32_t(i), std::int32_t(j)});
                }
            }
        }
    });
    std::size_t count = 0;
    for (const auto& list : found)
        for (const auto& [i, j] : list) {
            // Both ends' table entries point at themselves: an empty slot, zero force in every pass.
            for (const auto& [from, to] : {std::array<std::int32_t, 2>{i, j}, std::array<std::int32_t, 2>{j, i}})
                for (int s = 0; s < slot_count; ++s) {
                    const std::size_t t = entry_of(std::size_t(from), s);
                    if (neighbour_[t] == to) neighbour_[t] = from;
                }
            cut_.push_back({i, j});
            ++count;
        }
    if (count > 0) refresh_cells();  // a cell whose spring was cut loses its volume term
    return count;
}

template <class Real>
std::vector<std::int32_t> BasicSolver<Real>::contact_particles(int hand) const {
    if (hand < 0 || hand >= hands) throw InputError("solver: hand must be 0 or 1");
    const HandState& state = hand_[std::size_t(hand)];
    if (holds_tissue(state.instrument.kind)) return state.held;
    std::vector<std::int32_t> all;
    for (std::size_t c = 0; c < chunks_; ++c) {
        const auto& list = touched_[c * hands + std::size_t(hand)];
        all.insert(all.end(), list.begin(), list.end());
    }
    return all;
}

// The instruments' members for the two solvers (solver.cpp instantiates the rest).
#define HEARTSIM_SOLVER_INSTRUMENTS(Real)                                                                  \
    template void BasicSolver<Real>::set_instrument(int, const Instrument&);                              \
    template const Instrument& BasicSolver<Real>::instrument(int) const;                                  \
    template void BasicSolver<Real>::set_pose(int, const InstrumentPose&);                                \
    template std::size_t BasicSolver<Real>::begin_grab(int);                                              \
    template void BasicSolver<Real>::release(int);                                                        \
    template void BasicSolver<Real>::release_hand(int, bool);                                             \
    template void BasicSolver<Real>::free_stayed();                                                       \
    template std::size_t BasicSolver<Real>::cut(const BladeSweep&);                                       \
    template std::vector<std::int32_t> BasicSolver<Real>::contact_particles(int) const;
HEARTSIM_SOLVER_INSTRUMENTS(float)
HEARTSIM_SOLVER_INSTRUMENTS(double)
#undef HEARTSIM_SOLVER_INSTRUMENTS

}  // namespace heartsim
